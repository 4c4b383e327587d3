#!/usr/bin/python3
"""Why is the diagnosis' re-drape floor above the control drapes' base MSE? (docs/diagnose.md, "Not done yet")

    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 tools/redrape_floor_probe.py --out DIR [--seeds 101,102]

Per seed S, as tools/confusion_table.py builds its reference: six control drapes (synth, circle1, Cotton Blue's
mean table on every edge, placement noise of seed S), a bdp reference P fitted on them (15 epochs, seed S + 1, no
drape calibration), and the diagnosis' K = 16 posterior draws of P (seed S + 1000, placement noise). Then the
draws' best-of-K pixel MSE against each of several sets of references, averaged over the set:

- control: the six control drapes (the base MSE of a control case);
- truth re-drapes: 12 more drapes of the control material (synth, another seed): what the floor would be if P's
  mean material were the truth's;
- P median: 12 re-drapes of P's mean log table on every edge (the floor as diagnose measures it);
- P effective: 12 re-drapes of exp(log mean + log sd^2 / 2) on every edge (the arithmetic mean of P's lognormal
  per-edge draws);
- P predictive: 12 posterior draws of P (per-edge noise), other placements.

and each set's mean drape coefficient against the draws'. Writes DIR/floor.json and prints a Markdown table.
"""
import argparse
import copy
import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
from drapelab import diagnose, infer, measure, synth  # noqa: E402

DENSITY = 0.192
K = 16
J = 12


def images_of(folder):
    with open(os.path.join(folder, "truth.json")) as f:
        return [os.path.join(folder, d["silhouette"]) for d in json.load(f)["drapes"]]


def masks(paths):
    return [infer._Observation(p, None).mask for p in paths]


def floor(shapes, refs):
    ok = [s["image"] for s in shapes if "error" not in s]
    best = [min(measure.pixel_mse(s, q) for s in ok) for q in refs]
    return float(np.mean(best)), float(np.std(best, ddof=1) / np.sqrt(len(best)))


def dc(images):
    return float(np.mean([measure.drape_coefficient(m, measure.DATASET_PX_PER_M) for m in images]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--seeds", default="101")
    args = ap.parse_args()
    config = copy.deepcopy(infer.load_config())
    config["mesh_level"] = 1
    config["calibration"]["enabled"] = False
    os.makedirs(args.out, exist_ok=True)
    result_path = os.path.join(args.out, "floor.json")
    rows = json.load(open(result_path)) if os.path.isfile(result_path) else []
    for s in [int(x) for x in args.seeds.split(",")]:
        if any(r["seed"] == s for r in rows):
            continue
        control = os.path.join(args.out, f"control{s}")
        synth.synth(control, DENSITY, count=6, seed=s, mesh_level=1, force=True)
        truth = os.path.join(args.out, f"truth{s}")
        synth.synth(truth, DENSITY, count=J, seed=s + 50000, mesh_level=1, force=True)
        ref_path = os.path.join(args.out, f"reference{s}.json")
        if not os.path.isfile(ref_path):
            infer.fit(images_of(control), DENSITY, model="bdp", epochs=15, seed=s + 1, config=config, out=ref_path)
        preset = infer.load_preset(ref_path)
        shape = infer._Observation(images_of(control)[0], None).mask.shape
        pred = infer._Predictive(preset, shape, 2, config, mesh_level=1, forward="dynamic")
        seed = s + 1000
        draws = infer.preset_bend_samples(preset, pred.num_edges, np.random.default_rng(seed), K)
        shapes = pred.drape(draws, seed)
        effective = copy.deepcopy(preset)
        bend = effective["posterior"]["bend"]
        mu, sd = np.asarray(bend["log_mean"], dtype=float), np.asarray(bend["log_std"], dtype=float)
        bend["log_mean"] = (mu + sd ** 2 / 2).tolist()
        sets = {
            "control": masks(images_of(control)),
            "truth re-drapes": masks(images_of(truth)),
            "P median": diagnose._pseudo_observations(pred, preset, pred.models, {}, J, seed, config, 2, None, None,
                                                      stream=2, mean_material=True),
            "P effective": diagnose._pseudo_observations(pred, effective, pred.models, {}, J, seed, config, 2, None,
                                                         None, stream=2, mean_material=True),
            "P predictive": diagnose._pseudo_observations(pred, preset, pred.models, {}, J, seed, config, 2, None,
                                                          None, stream=2),
        }
        row = {"seed": s, "draws_dc": dc([sh["image"] for sh in shapes if "error" not in sh]),
               "log_std_mean": float(np.mean(sd)), "sets": {}}
        for name, refs in sets.items():
            m, se = floor(shapes, refs)
            row["sets"][name] = {"mse": m, "se": se, "dc": dc(refs), "n": len(refs)}
        rows.append(row)
        with open(result_path + ".tmp", "w") as f:
            json.dump(rows, f, indent=1)
        os.replace(result_path + ".tmp", result_path)
    print("| seed | P's mean log sd | draws' DC | " + " | ".join(rows[0]["sets"]) + " |")
    print("|---|---|---|" + "---|" * len(rows[0]["sets"]))
    for r in rows:
        cells = [f"{v['mse']:.4f} +- {v['se']:.4f} (DC {v['dc']:.3f})" for v in r["sets"].values()]
        print(f"| {r['seed']} | {r['log_std_mean']:.3f} | {r['draws_dc']:.3f} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
