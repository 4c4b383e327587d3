#!/usr/bin/python3
"""An effect's gap above the control in the recovery protocol, along its strength (docs/lab/effect-recovery.md):
for each VALUE, `synth` drapes (same material, seed and placements as tools/effect_recovery.py's) with NAME.PARAM =
VALUE (the effect's others off) are evaluated with a reference preset (the recovery run's OUT/reference.json),
next to the control drapes (the same placements, no effect). Per value: the best-of-K MSE and the drape-coefficient
error (mean over the drapes, with the standard error of the paired difference to the control: the gap's noise),
the observed DC and node counts, and the hard-silhouette pixel MSE between each effect drape and the control
drape of the same placement (how far the effect moves a drape) against the MSE between control drapes of
different placements (the re-drape noise of these synthetic drapes).

Usage (from the repository root):
    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/effect_gap_scan.py \
        --reference /tmp/recovery/reference.json damping.mass_per_s=2,4,8 [--count 6] [--seed 101] \
        [--mesh-level 1] [--samples 16] [--out /tmp/gap_scan]
The reference must be the one fitted on control drapes of the same --count, --seed and --mesh-level.
"""
import argparse
import copy
import glob
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))

from drapelab import infer, measure, synth  # noqa: E402

DENSITY = 0.192


def images_of(folder):
    return sorted(glob.glob(os.path.join(folder, "fabric_00", "silhouettes", "*.png")))


def masks(images):
    return [np.asarray(measure.load_silhouette(p, None).mask, dtype=np.float64) for p in images]


def per_image(reference, images, config, args):
    r = infer.evaluate(reference, images, samples=args.samples, seed=args.seed + 2, config=config)
    mse = np.array([e["mse"] for e in r["images"]])
    dc = np.array([abs(e["drape_coefficient"]["predicted_mean"] - e["drape_coefficient"]["observed"])
                   for e in r["images"]])
    observed = np.array([e["drape_coefficient"]["observed"] for e in r["images"]])
    nodes = [e["node_count"]["observed"] for e in r["images"]]
    return mse, dc, observed, nodes


def se(x):
    return float(np.std(x, ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("spec", help="NAME.PARAM=V1,V2,...")
    ap.add_argument("--reference", required=True)
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--mesh-level", type=int, default=1)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--out", default="/tmp/gap_scan")
    args = ap.parse_args()
    key, _, values = args.spec.partition("=")
    name, _, param = key.partition(".")
    values = [float(v) for v in values.split(",") if v.strip()]
    config = copy.deepcopy(infer.load_config())
    config["mesh_level"] = args.mesh_level
    config["calibration"]["enabled"] = False
    reference = infer.load_preset(args.reference)
    control_dir = os.path.join(args.out, "control")
    synth.synth(control_dir, DENSITY, count=args.count, seed=args.seed, mesh_level=args.mesh_level, force=True)
    c_images = images_of(control_dir)
    c_masks = masks(c_images)
    c_mse, c_dc, c_obs, c_nodes = per_image(reference, c_images, config, args)
    redrape = [measure.pixel_mse(c_masks[i], c_masks[j]) for i in range(len(c_masks)) for j in range(i)]
    print(f"control (seed {args.seed}, circle{args.mesh_level}, {args.count} drapes): MSE {c_mse.mean():.4f} "
          f"|dDC| {c_dc.mean():.4f}, DC {c_obs.mean():.4f}, nodes {c_nodes}; re-drape MSE between control drapes "
          f"{np.mean(redrape):.4f} (min {np.min(redrape):.4f}, max {np.max(redrape):.4f})", flush=True)
    print(f"| {name}.{param} | MSE (gap +- se) | abs dDC (gap +- se) | DC observed | nodes | MSE effect vs control "
          f"drape (mean, min .. max) |")
    print("|---|---|---|---|---|---|")
    for v in values:
        folder = os.path.join(args.out, f"{name}_{param}_{v:g}")
        synth.synth(folder, DENSITY, effects={name: {param: v}}, count=args.count, seed=args.seed,
                    mesh_level=args.mesh_level, force=True)
        images = images_of(folder)
        mse, dc, obs, nodes = per_image(reference, images, config, args)
        moved = [measure.pixel_mse(a, b) for a, b in zip(masks(images), c_masks)]
        print(f"| {v:g} | {mse.mean():.4f} ({mse.mean() - c_mse.mean():+.4f} +- {se(mse - c_mse):.4f}) | "
              f"{dc.mean():.4f} ({dc.mean() - c_dc.mean():+.4f} +- {se(dc - c_dc):.4f}) | {obs.mean():.4f} | "
              f"{','.join(str(n) for n in nodes)} | {np.mean(moved):.4f} ({np.min(moved):.4f} .. {np.max(moved):.4f}) |",
              flush=True)


if __name__ == "__main__":
    main()
