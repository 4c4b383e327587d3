"""What the fitting tests share: the repository's bundled image and shipped preset, and a small fit config."""
import copy
import os

from drapelab import infer

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ASSET_IMAGE = os.path.join(ROOT, "assets", "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
SHIPPED_PRESET = os.path.join(ROOT, "assets", "presets", "fabric_02_cotton_blue_bdp.json")


def small_config(**overrides):
    """fit.json on circle1, calibrating on the fit's mesh, with `overrides` on top."""
    cfg = copy.deepcopy(infer.load_config())
    cfg["mesh_level"] = 1
    cfg["calibration"]["mesh_level"] = None  # calibrate on the fit's mesh
    cfg.update(overrides)
    return cfg
