"""diagnose's round trip on synthetic data (issue 18's check): drapes of the shipped preset's material with a
hidden effect are diagnosed with that preset; the true effect must come first and be significant, and its refit must
lower the error; control drapes must get no recommendation. Six drapes per case on circle1; candidates restricted to
the three effects of the round trip; only the first candidate is refitted (max_refits=1), to keep the test short."""
import glob
import os

import numpy as np
import pytest

from drapelab import diagnose, infer, synth

from fit_support import SHIPPED_PRESET as PRESET, small_config

# strengths above the registry's moderate ones where six drapes of this stiff fabric need it (a 0.4 radial stiffness
# map was found, p 2e-4, but 8 refit epochs did not lower the error): a fast check of the loop; the targets at
# moderate strengths are tools/confusion_table.py's. The third effect is an offset (1 cm, moderate), not a tilt:
# against the step test's specimen null (2026-11-28) even a 0.4 rad tilt on these six drapes is not significant
# (combined p 0.0037, 0.3 rad: 0.0094; docs/diagnose.md). The offset lies along y: the step test once stepped an
# offset along x alone and missed one along y (docs/diagnose.md, "Measured: directions")
CASES = {"prestrain": {"prestrain": {"strain": 0.03}},
         "heterogeneity_map": {"heterogeneity_map": {"radial": 0.8}},
         "offset": {"offset": {"dy_m": 0.01}},
         "control": None}
CANDIDATES = "prestrain,heterogeneity_map,offset"
COUNT = 6
SEED = 7
SAMPLES = 8
POSTERIOR_SD_FACTOR = 1.0 / 3.0
REFIT_EPOCHS = 6


@pytest.fixture(scope="module")
def diagnoses(tmp_path_factory):
    # P: the shipped preset with a tight posterior (a third of its per-entry sd, no per-draw scale), so that on
    # control drapes of its mean material P is right and its predictive varies mostly by placement, as a preset fitted
    # on many drapes would; no time budget (the refits run REFIT_EPOCHS), so that the outcome does not depend on
    # the machine's load
    preset = infer.load_preset(PRESET)
    preset["posterior"]["bend"]["log_std"] = (POSTERIOR_SD_FACTOR * np.asarray(preset["posterior"]["bend"]["log_std"])).tolist()
    preset["posterior"]["bend"]["global_log_std"] = 0.0
    path = str(tmp_path_factory.mktemp("preset") / "tight.json")
    infer.write_preset(path, preset)
    config = small_config(default_epochs=REFIT_EPOCHS)
    out = {}
    for case, effects in CASES.items():
        folder = str(tmp_path_factory.mktemp(case))
        synth.synth(folder, preset["density_kg_m2"], effects=effects, material=path, count=COUNT, seed=SEED,
                    mesh_level=1, force=True, config=small_config())
        images = sorted(glob.glob(os.path.join(folder, "fabric_00", "silhouettes", "*.png")))
        assert len(images) == COUNT
        # another seed than synth's: the draws' placement noise must not be the drapes' own (both use
        # default_rng([seed, i, 1]))
        out[case] = diagnose.diagnose(path, images, candidates=CANDIDATES, samples=SAMPLES, seed=SEED + 100,
                                      config=config, mesh_level=1, max_refits=1)
        d = out[case]
        print(case, d["recommended"], d["base"]["mse"], d["seconds"],
              [(e["effect"], e["p_value"], e.get("p_value_score"), (e.get("step") or {}).get("p_value"),
                (e.get("refit") or {}).get("mse")) for e in d["ranking"]])
    return out


@pytest.mark.parametrize("case", ["prestrain", "heterogeneity_map", "offset"])
def test_the_hidden_effect_is_found_and_its_refit_lowers_the_error(diagnoses, case):
    d = diagnoses[case]
    entry = d["ranking"][0]
    assert entry["effect"] == case, d["verdict"]
    assert entry["p_value"] < d["threshold"], d["verdict"]  # found, not merely the first of nothing
    assert entry["refit"]["mse"] < d["base"]["mse"], d["verdict"]
    assert d["recommended"] in (case, None), d["verdict"]  # null only when the fall is below the re-drape rule
    assert d["verdict"].endswith("."), d["verdict"]  # one sentence or more, each ended (with or without a recommendation)
    assert d["step_test"]["draws"] == SAMPLES and d["step_test"]["references"] >= diagnose.STEP_REFERENCES_MIN


def test_control_drapes_get_no_recommendation(diagnoses):
    d = diagnoses["control"]
    assert d["recommended"] is None, d["verdict"]
    assert d["verdict"].endswith("."), d["verdict"]
    assert all(e["p_value"] >= d["threshold"] for e in d["ranking"] if e["p_value"] is not None)
