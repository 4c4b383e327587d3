#!/usr/bin/python3
"""The protocol's metrics between real drapes: what best-of-N against another drape of the same fabric gives.

    tools/noise_floor.py [--fabrics 1,2,3,4,5] [--json OUT]

For each fabric, the capture-1 samples (12 for fabrics 1-5): for every sample, the pixel MSE (hard silhouettes
as `evaluate` loads them, all 256 x 256 pixels) and the symmetric Hausdorff distance (vertex-to-surface, m,
measure.hausdorff_distance, as `evaluate`) to each other sample; reported: the mean over samples of the best
of the other 11 ("nearest") and the median over pairs. A model's best-of-N figures compare with these: a real
re-drape of the fabric, picked as the closest of 11, is this far from a test drape.
Run with ./drapelab's environment: `PYTHONPATH=addon:build/python tools/noise_floor.py`.
"""
import argparse
import csv
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
import numpy as np  # noqa: E402

from drapelab import measure  # noqa: E402

DATA = os.path.join(ROOT, "..", "shared", "data", "cusick")


def floor(fabric, data=DATA):
    with open(os.path.join(data, "manifest.csv")) as f:
        rows = sorted((r for r in csv.DictReader(f) if int(r["fabric"]) == fabric and r["capture"] == "1"),
                      key=lambda r: int(r["sample"]))
    if len(rows) < 2:
        raise SystemExit(f"noise_floor: fabric {fabric} has {len(rows)} capture-1 samples; need 2 or more")
    masks = [measure.load_silhouette(os.path.join(data, r["silhouette"])).mask.astype(np.float64) for r in rows]
    meshes = [os.path.join(data, r["mesh"]) if r["mesh"] else None for r in rows]
    n = len(rows)
    mse = np.full((n, n), np.inf)
    haus = np.full((n, n), np.inf)
    for i in range(n):
        for j in range(i + 1, n):
            mse[i, j] = mse[j, i] = float(measure.pixel_mse(masks[i], masks[j]))
            if meshes[i] and meshes[j]:
                haus[i, j] = haus[j, i] = measure.hausdorff_distance(meshes[i], meshes[j])
    pairs = np.triu_indices(n, 1)
    out = {"fabric": fabric, "samples": n,
           "mse_nearest": float(mse.min(axis=1).mean()), "mse_median_pair": float(np.median(mse[pairs]))}
    if all(meshes):
        out.update(hausdorff_m_nearest=float(haus.min(axis=1).mean()),
                   hausdorff_m_median_pair=float(np.median(haus[pairs])))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fabrics", default="1,2,3,4,5")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    per = [floor(int(f)) for f in args.fabrics.split(",")]
    keys = [k for k in per[0] if k not in ("fabric", "samples")]
    mean = {k: float(np.mean([p[k] for p in per if k in p])) for k in keys}
    for p in per:
        print(p["fabric"], " ".join(f"{k} {p[k]:.4f}" for k in keys if k in p))
    print("mean", " ".join(f"{k} {v:.4f}" for k, v in mean.items()))
    if args.json:
        measure.write_json(args.json, {"fabrics": per, "mean": mean})


if __name__ == "__main__":
    main()
