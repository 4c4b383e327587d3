"""Synthetic Cusick data with known truth: drapes of a known material, with or without effects, written as a
dataset that the measuring and fitting tools read exactly like the real one (bpy-free facade; ``drapelab synth``).

What a drape is: the fitter's forward model (fit.json "dynamic": the paper's 100 implicit Euler steps of 0.05 s
from the flat rest state) on the Cusick template circle{mesh_level}, with the named effects switched on. Drapes
differ the way real re-drapes do: drape i starts with the placement velocities the fitter and the evaluation
use (``infer.placement_velocities``, a random vertical field from ``default_rng([seed, i, 1])``; amplitude and
angular modes from the preset's ``placement_noise``, else fit.json's), so the folds land elsewhere each time.

The material:
    no preset   the Cotton Blue tables as the fitter starts from them (fit.json "init": the published bending
                table; the stretching table as the fitter holds it, its small-strain row on every row when
                "stretch_strain_dependent" is false), so that a fit of the control data can recover it exactly.
    a preset    its stretching table and its bending posterior (any model). material_draw "mean" (default):
                every drape uses the posterior median table exp(log_mean) on every bending edge, one specimen
                re-draped, so the truth is one table and the drapes differ only by placement (and effect);
                "per-drape": drape i draws its own per-edge tables from the posterior, like a posterior-
                predictive draw (``infer.preset_bend_samples``, the drape calibration's global factor
                included; stream ``default_rng([seed, i, 2])``): different specimens of the fabric.
The density is always the one given (a preset's own density is recorded in truth.json, not used).

Files (the dataset's layout and calibration, paths in the manifest relative to ``out``)::

    out/manifest.csv                                  the dataset's columns; fabric 0, samples 1..N, capture 1
    out/fabric_00/silhouettes/sample_SS_capture_1.png 256 x 256 8-bit grey, dark cloth on white, orthographic top
                                                      view at 720 px/m, disk centre at the image centre (128, 128)
    out/fabric_00/meshes/sample_SS_capture_1.obj      the drape (metres, z up, disk centred at the origin)
    out/truth.json                                    what made them: effects {name: {param: value}} (every
                                                      parameter of each active effect), density_kg_m2, material,
                                                      seed, count, and the rest of the protocol

Nothing in the images, meshes or manifest names an effect: a control set and an effect set of the same material
have the same columns and names; only truth.json tells them apart. Every file is written atomically, and the
manifest and truth.json are rewritten after each drape, so a cancelled (or killed) run leaves a consistent
dataset of the drapes completed (truth.json: count = drapes written, complete = false).

Output folder: created when missing; an existing empty folder is used; a non-empty one is refused unless
force=True and it holds a previous synth output (truth.json), whose manifest, truth and sample files
(fabric_00/*/sample_*_capture_1.*) are then removed first. A non-empty folder that is not a synth output is
never overwritten.
"""
import csv
import glob
import io
import os
import time

import numpy as np

from . import infer, measure, paths, render, sim, tables
from ._native import Cancelled, InputError, SolverError

__all__ = ["synth", "resolve_material", "MATERIAL_DRAWS", "IMAGE_SIZE", "FABRIC", "TRUTH_SCHEMA_VERSION",
           "DEFAULT_COUNT", "DEFAULT_MESH_LEVEL"]

MATERIAL_DRAWS = ("mean", "per-drape")
IMAGE_SIZE = (256, 256)      # (width, height) px: the dataset's silhouettes (shared/data/cusick/README.md)
FABRIC = 0                   # fabric number of synthetic data (the real dataset numbers its fabrics from 1)
DEFAULT_COUNT = 6            # drapes: the effect-recovery targets use 6
DEFAULT_MESH_LEVEL = 3       # circle3: the dataset's meshes have its topology
MAX_COUNT = 999              # sample numbers keep the dataset's 2-digit names up to 99, 3 digits beyond
TRUTH_SCHEMA_VERSION = 1
MANIFEST_COLUMNS = ("fabric", "name", "material", "weave", "density_kg_m2", "thickness_mm", "sample", "capture",
                    "silhouette", "mesh")
CAPTURE = 1
PLACEMENT_STREAM, MATERIAL_STREAM = 1, 2  # default_rng([seed, drape, stream]); 1 is infer's placement stream


# ---------------------------------------------------------------- inputs
def _shipped_preset(name):
    folder = os.path.join(paths.assets_dir(), "presets")
    base = name if name.endswith(".json") else name + ".json"
    path = os.path.join(folder, base)
    return path if os.sep not in name and os.path.isfile(path) else None


def resolve_material(material=None, config=None):
    """The material of a synth run: {name, source, model, stretch_N_m (6, 4), bend_N_m (3, 5) (the table of
    "mean" drapes), preset (the loaded preset or None), thickness_mm (or None), placement_noise}.

    material: None (the Cotton Blue tables as the fitter starts from them), a preset dict, a preset JSON path,
    or the name of a shipped preset in assets/presets/ (with or without .json)."""
    config = config or infer.load_config()
    placement = config.get("placement_noise") or {}
    if material is None:
        init = config["init"]
        stretch = np.array(tables.preset(init["stretch"]).stretch, dtype=float)
        if not init.get("stretch_strain_dependent", True):
            stretch[1:] = stretch[0]  # the fitter's linear membrane (see infer.FitJob)
        bend = tables.preset(init["bend"])
        return {"name": f"{bend.name} tables", "source": "drapelab.tables (fit.json init)", "model": "tables",
                "stretch_N_m": stretch, "bend_N_m": np.array(bend.bend, dtype=float), "preset": None,
                "thickness_mm": None, "placement_noise": dict(placement)}
    if isinstance(material, dict):
        preset, source = infer.validate_preset(material, "material"), "preset (in memory)"
    elif isinstance(material, (str, os.PathLike)):
        text = os.fspath(material)
        path = text if os.path.isfile(text) else _shipped_preset(text)
        if path is None:
            shipped = sorted(os.path.splitext(f)[0] for f in os.listdir(os.path.join(paths.assets_dir(), "presets"))
                             if f.endswith(".json"))
            raise InputError(f"material: {text!r} is neither a preset file nor a shipped preset "
                             f"(shipped: {', '.join(shipped)})")
        preset, source = infer.load_preset(path), path
    else:
        raise InputError(f"material: expected a preset path, a shipped preset name or a preset dict, "
                         f"got {type(material).__name__}")
    fabric = preset.get("fabric") or {}
    thickness = fabric.get("thickness_mm")
    return {"name": str(fabric.get("name") or os.path.splitext(os.path.basename(source))[0]), "source": source,
            "model": preset["model"], "stretch_N_m": np.asarray(preset["stretch_N_m"], dtype=float),
            "bend_N_m": np.exp(np.asarray(preset["posterior"]["bend"]["log_mean"], dtype=float)), "preset": preset,
            "thickness_mm": float(thickness) if isinstance(thickness, (int, float)) else None,
            "placement_noise": dict(preset.get("placement_noise") or placement)}


def _count(count):
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or not 1 <= count <= MAX_COUNT:
        raise InputError(f"count: expected an integer in [1, {MAX_COUNT}], got {count!r}")
    return int(count)


def _seed(seed):
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed: expected an integer >= 0, got {seed!r}")
    return int(seed)


def _mesh_level(level):
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or int(level) not in sim.TEMPLATE_LEVELS:
        raise InputError(f"mesh_level: expected one of {sim.TEMPLATE_LEVELS} (circle1..circle5), got {level!r}")
    return int(level)


def _effects(effects):
    if effects is None or isinstance(effects, str):
        return sim.parse_effects_arg(effects, bare="moderate")
    return sim.effect_values(effects)


# ---------------------------------------------------------------- output folder
def _sample_name(sample):
    return f"sample_{sample:02d}_capture_{CAPTURE}"


def _relative_paths(sample):
    fabric = f"fabric_{FABRIC:02d}"
    return (f"{fabric}/silhouettes/{_sample_name(sample)}.png", f"{fabric}/meshes/{_sample_name(sample)}.obj")


def _prepare_folder(out, force):
    """Creates `out` (and its sample folders) or clears a previous synth output there (force)."""
    out = os.fspath(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise InputError(f"out: {out} exists and is not a folder")
    if os.path.isdir(out) and os.listdir(out):
        if not force:
            raise InputError(f"out: {out} is not empty (give --force to replace a previous synth output there)")
        if not os.path.isfile(os.path.join(out, "truth.json")):
            raise InputError(f"out: {out} is not empty and holds no synth output (no truth.json); not overwriting "
                             "it, even with --force")
        fabric = os.path.join(out, f"fabric_{FABRIC:02d}")
        stale = [os.path.join(out, "manifest.csv"), os.path.join(out, "truth.json")]
        stale += glob.glob(os.path.join(fabric, "silhouettes", f"sample_*_capture_{CAPTURE}.png"))
        stale += glob.glob(os.path.join(fabric, "meshes", f"sample_*_capture_{CAPTURE}.obj"))
        for path in stale:
            if os.path.isfile(path):
                os.unlink(path)
    for sub in ("silhouettes", "meshes"):
        os.makedirs(os.path.join(out, f"fabric_{FABRIC:02d}", sub), exist_ok=True)
    return out


def _write_manifest(path, rows):
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(MANIFEST_COLUMNS)
    for row in rows:
        writer.writerow([row[c] for c in MANIFEST_COLUMNS])
    text = buffer.getvalue()

    def write(tmp):
        with open(tmp, "w", newline="") as f:
            f.write(text)
    measure._atomic_write(path, "manifest", ".csv", write)


# ---------------------------------------------------------------- the job
def synth(out, density, effects=None, material=None, count=DEFAULT_COUNT, seed=0, mesh_level=DEFAULT_MESH_LEVEL,
          material_draw="mean", force=False, progress=None, cancel_event=None, config=None, template_dir=None):
    """Writes `count` synthetic drapes into the folder `out` (see the module doc); returns the truth dict written
    to out/truth.json.

    density: kg/m^2 (> 0). effects: the command-line text (``sim.parse_effects_arg`` with bare="moderate": a bare
    NAME is the registry's moderate strength) or a dict {name: {param: value}} (parameters not given: off);
    None or "" = control data. material: see resolve_material; material_draw "mean" | "per-drape".
    progress(info) is called after each drape with {drape, count, sample, silhouette, mesh, drape_coefficient,
    node_count, seconds}; setting cancel_event (threading.Event) stops at the next step and raises Cancelled,
    the drapes done kept (manifest and truth.json list them). A drape that fails raises SolverError, likewise
    after the drapes before it are kept. Everything is checked before the folder is touched.
    """
    config = config or infer.load_config()
    density = infer.check_density(density)
    count, seed, level = _count(count), _seed(seed), _mesh_level(mesh_level)
    if material_draw not in MATERIAL_DRAWS:
        raise InputError(f"material_draw: expected one of {MATERIAL_DRAWS}, got {material_draw!r}")
    effects = _effects(effects)
    mat = resolve_material(material, config)
    if material_draw == "per-drape" and mat["preset"] is None:
        raise InputError("material_draw: 'per-drape' draws from a preset's posterior; give a material preset")
    per_drape = material_draw == "per-drape"
    mesh = sim.cusick_specimen(level, template_dir=template_dir)
    # Builds the model (the native registry checks effect names and ranges, naming "effect.param") before the
    # folder is touched.
    model = sim.ClothModel(mesh, heterogeneous=per_drape, density=density, effects=effects,
                           px_per_m=measure.DATASET_PX_PER_M)
    base = model.parameters(stretch=mat["stretch_N_m"], bend=mat["bend_N_m"], density=density, effects=effects)
    blocks = model.split(base)
    registry = {e["name"]: e["parameters"] for e in sim.effects()}
    truth_effects = {name: {q["name"]: float(blocks[f"{name}.{q['name']}"]) for q in registry[name]}
                     for name in model.active_effects}
    amplitude = float(mat["placement_noise"].get("velocity_m_s", 0.0))
    modes = int(mat["placement_noise"].get("angular_modes", 0))
    dynamic = dict(config["dynamic"])
    out = _prepare_folder(out, force)

    camera = render.orthographic_camera(measure.DATASET_PX_PER_M, centre=(IMAGE_SIZE[0] / 2, IMAGE_SIZE[1] / 2),
                                        size=IMAGE_SIZE)
    calibration = measure.calibration(measure.DATASET_PX_PER_M)
    rest = model.rest_positions
    material_record = {
        "name": mat["name"], "source": mat["source"], "model": mat["model"], "draw": material_draw,
        "stretch_N_m": mat["stretch_N_m"].tolist(), "bend_N_m": mat["bend_N_m"].tolist(),
        "bend_note": ("each drape's own posterior draw (per bending edge); bend_N_m is the posterior median"
                      if per_drape else "the same table on every bending edge of every drape")}
    if mat["preset"] is not None:
        material_record["preset_density_kg_m2"] = mat["preset"]["density_kg_m2"]
        if per_drape:
            material_record["posterior"] = mat["preset"]["posterior"]["bend"]
    rows, drapes = [], []

    def truth():
        return {"kind": "drapelab-synth-truth", "schema_version": TRUTH_SCHEMA_VERSION,
                "effects": truth_effects, "density_kg_m2": density, "material": material_record, "seed": seed,
                "count": len(drapes), "requested_count": count, "complete": len(drapes) == count,
                "mesh_level": level,
                "placement_noise": {"velocity_m_s": amplitude, "angular_modes": modes},
                "simulation": {"forward": "dynamic", **dynamic},
                "camera": {"kind": "ortho", "px_per_m": float(measure.DATASET_PX_PER_M),
                           "centre_px": [IMAGE_SIZE[0] / 2, IMAGE_SIZE[1] / 2], "size_px": list(IMAGE_SIZE),
                           "polarity": "dark_on_light"},
                "drapes": drapes,
                "software": f"drapelab {__import__('drapelab').__version__}"}

    def save():
        _write_manifest(os.path.join(out, "manifest.csv"), rows)
        measure.write_json(os.path.join(out, "truth.json"), truth())

    save()  # an empty dataset (count 0) until the first drape is written
    for i in range(count):
        if cancel_event is not None and cancel_event.is_set():
            raise Cancelled(f"synth: cancelled after {i} of {count} drapes (kept in {out})")
        t0 = time.monotonic()
        sample = i + 1
        p = base
        if per_drape:
            bend = infer.preset_bend_samples(mat["preset"], model.num_bending_edges,
                                             np.random.default_rng([seed, i, MATERIAL_STREAM]), 1)[0]
            p = model.parameters(stretch=mat["stretch_N_m"], bend=bend, density=density, effects=effects)
        v0 = infer.placement_velocities(rest, np.random.default_rng([seed, i, PLACEMENT_STREAM]), amplitude, modes) \
            if amplitude > 0 else None
        try:
            x = model.simulate(p, mode="dynamic", record=False, velocities0=v0, cancel_event=cancel_event, **dynamic)
        except SolverError as e:
            raise SolverError(f"synth: drape {sample} of {count} failed ({e}); the {i} drapes before it are kept "
                              f"in {out}") from None
        except Cancelled:
            raise Cancelled(f"synth: cancelled after {i} of {count} drapes (kept in {out})") from None
        # the measurement model (camera, offset's tester frame) before the render; the OBJ keeps the drape itself
        mask = np.asarray(render.hard_silhouette(camera, infer._observed(model, x, p), model.faces), dtype=np.float64)
        silhouette, mesh_path = _relative_paths(sample)
        sim.write_obj(os.path.join(out, mesh_path), x, model.faces)
        measure.write_image(os.path.join(out, silhouette), 1.0 - mask)
        dc = float(measure.drape_coefficient(mask, measure.DATASET_PX_PER_M, support_radius=model.support_radius))
        nodes = int(measure.node_count(measure.r_theta(mask, calibration)))
        rows.append({"fabric": FABRIC, "name": "synthetic", "material": mat["name"], "weave": "",
                     "density_kg_m2": repr(density), "thickness_mm": "" if mat["thickness_mm"] is None else
                     repr(mat["thickness_mm"]), "sample": sample, "capture": CAPTURE, "silhouette": silhouette,
                     "mesh": mesh_path})
        drapes.append({"sample": sample, "silhouette": silhouette, "mesh": mesh_path, "drape_coefficient": dc,
                       "node_count": nodes})
        save()
        if progress is not None:
            progress({"drape": sample, "count": count, "sample": sample, "silhouette": silhouette, "mesh": mesh_path,
                      "drape_coefficient": dc, "node_count": nodes, "seconds": time.monotonic() - t0})
    return truth()
