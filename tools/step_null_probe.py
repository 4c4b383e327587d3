"""The step test's null, measured: runs diagnose (no refits) on folders of synthetic drapes and records, per effect
and step, the change of the draws' mean pixel MSE against every measured image, posterior-predictive reference and
re-drape of P's mean (the `deltas` step_specimen_test sees), so that the variance between specimens (B) and between
re-drapes (W) and the p-values of the step test's nulls can be compared offline (docs/diagnose.md, the section on
the specimen null).

  tools/step_null_probe.py --preset P.json --out rows.json [--mesh-level L] [--time-budget S] [--samples K]
                           [--seed S] [--tight F] CASE=FOLDER ...

FOLDER holds fabric_00/silhouettes/*.png (synth's layout); --tight F multiplies P's per-entry posterior sd by F and
drops its per-draw scale (the round-trip test's P, F = 1/3)."""
import argparse
import copy
import glob
import json
import os
import sys
import tempfile

import numpy as np

from drapelab import diagnose, infer, measure


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--mesh-level", type=int, default=1)
    ap.add_argument("--time-budget", type=float, default=None)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--candidates", default=None)
    ap.add_argument("--tight", type=float, default=None)
    ap.add_argument("cases", nargs="+")
    args = ap.parse_args()
    preset = args.preset
    if args.tight is not None:
        p = infer.load_preset(preset)
        p["posterior"]["bend"]["log_std"] = (args.tight * np.asarray(p["posterior"]["bend"]["log_std"])).tolist()
        p["posterior"]["bend"]["global_log_std"] = 0.0
        preset = os.path.join(tempfile.mkdtemp(), "tight.json")
        infer.write_preset(preset, p)
    config = copy.deepcopy(infer.load_config())
    config["mesh_level"] = args.mesh_level
    config["calibration"]["enabled"] = False
    rows = json.load(open(args.out))["rows"] if os.path.isfile(args.out) else []
    calls = []
    original_tests, original_specimen = diagnose.step_tests, diagnose.step_specimen_test

    def step_tests(base_images, step_images, steps, observed, references, redrapes=()):
        calls.append({"names": list(steps), "steps": {n: [label for label, _ in st] for n, st in steps.items()},
                      "effects": [], "n": len(observed), "references": len(references), "redrapes": len(redrapes),
                      "draws": len(base_images)})
        return original_tests(base_images, step_images, steps, observed, references, redrapes)

    def step_specimen_test(deltas, n, n_references, n_redrapes=0):
        calls[-1]["effects"].append({"deltas": np.asarray(deltas).tolist()})
        return original_specimen(deltas, n, n_references, n_redrapes)

    diagnose.step_tests, diagnose.step_specimen_test = step_tests, step_specimen_test
    for spec in args.cases:
        case, folder = spec.split("=", 1)
        if any(r["case"] == case for r in rows):
            continue
        calls.clear()
        images = sorted(glob.glob(os.path.join(folder, "fabric_00", "silhouettes", "*.png")))
        d = diagnose.diagnose(preset, images, candidates=args.candidates, samples=args.samples, seed=args.seed,
                              config=config, mesh_level=args.mesh_level, time_budget=args.time_budget, max_refits=0)
        tested = [e for e in d["ranking"] if e.get("step")]
        rows.append({"case": case, "folder": folder, "calls": list(calls),
                     "tests": {e["effect"]: e["step"] for e in tested},
                     "score_p": {e["effect"]: e.get("p_value_score") for e in tested},
                     "threshold": d["threshold"], "seconds": d["seconds"]})
        print(f"{case}: " + ", ".join(f"{e['effect']} {e['step']['p_value']:.2g}/{e['step']['p_value_permutation']:.2g}"
                                      for e in tested), file=sys.stderr, flush=True)
        measure.write_json(args.out, {"settings": vars(args), "rows": rows})


if __name__ == "__main__":
    main()
