#!/usr/bin/python3
"""The protocol's metrics between real drapes: what best-of-N against another drape of the same fabric gives.

    tools/noise_floor.py [--fabrics 1,2,3,4,5] [--best-of-k] [--json OUT]

For each fabric, the capture-1 samples (12 for fabrics 1-5): for every sample, the pixel MSE (hard silhouettes
as `evaluate` loads them, all 256 x 256 pixels) and the symmetric Hausdorff distance (vertex-to-surface, m,
measure.hausdorff_distance, as `evaluate`) to each other sample; reported: the mean over samples of the best
of the other 11 ("nearest") and the median over pairs. A model's best-of-N figures compare with these: a real
re-drape of the fabric, picked as the closest of 11, is this far from a test drape.

--best-of-k adds the real drapes' best-of-k curve, to read beside `evaluate`'s `mse_best_of` (a model's best of
its first k draws): for each of the protocol's test drapes (capture 1 of every sample but the paper's training
sample), the expected best pixel MSE among k real drapes drawn at random (without replacement, exactly, not by
sampling) from (a) every capture of the fabric's other samples, neither the test's nor the training sample ("redrapes": what a perfect generative model of
the fabric would give with k draws) and (b) the captures of the training sample only ("training_sample": a
perfect model of that one sample, all a single training image can tell). The Hausdorff distance likewise
("hausdorff_m_redrapes", capture-1 meshes of the other samples only: the dataset has no meshes of later captures):
"best_of" the expected smallest among k, "at_best_mse_of" that of the draw with the best pixel MSE among k, as
`evaluate` picks its best sample.
Run with ./drapelab's environment: `PYTHONPATH=addon:build/python tools/noise_floor.py`.
"""
import argparse
import json
import math
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
import numpy as np  # noqa: E402

from drapelab import measure, paths  # noqa: E402

DATA = paths.cusick_dataset_dir()  # None when absent: main() says so


def fabric_rows(fabric, data=DATA):
    """The fabric's rows of the dataset's manifest (measure.load_manifest: typed, paths resolved)."""
    return [r for r in measure.load_manifest(os.path.join(data, "manifest.csv")) if r["fabric"] == fabric]


def load_mask(row):
    return measure.load_silhouette(row["silhouette"]).mask.astype(np.float64)


def floor(fabric, data=DATA):
    rows = sorted((r for r in fabric_rows(fabric, data) if r["capture"] == 1), key=lambda r: r["sample"])
    if len(rows) < 2:
        raise SystemExit(f"noise_floor: fabric {fabric} has {len(rows)} capture-1 samples; need 2 or more")
    masks = [load_mask(r) for r in rows]
    meshes = [r["mesh"] for r in rows]
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


def expected_best_of(values, k):
    """Expected minimum of k values drawn without replacement from `values` (exact: the i-th smallest of m is the
    minimum with probability C(m - i, k - 1) / C(m, k), i = 1..m)."""
    v = np.sort(np.asarray(values, dtype=float))
    m = len(v)
    if not 1 <= k <= m:
        raise ValueError(f"expected_best_of: k must be in 1..{m}, got {k}")
    return float(_minimum_probabilities(m, k) @ v)


def expected_at_best_of(select, report, k):
    """Expected `report` value of the draw with the smallest `select` value among k drawn without replacement
    (as expected_best_of, `report` taken in `select`'s order): evaluate's Hausdorff is that of its best-MSE draw."""
    select, report = np.asarray(select, dtype=float), np.asarray(report, dtype=float)
    if select.shape != report.shape:
        raise ValueError(f"expected_at_best_of: {select.shape} select values for {report.shape} report values")
    m = len(select)
    if not 1 <= k <= m:
        raise ValueError(f"expected_at_best_of: k must be in 1..{m}, got {k}")
    return float(_minimum_probabilities(m, k) @ report[np.argsort(select, kind="stable")])


def _minimum_probabilities(m, k):
    """P(the i-th smallest of m is the minimum of a random k-subset) = C(m - i, k - 1) / C(m, k), i = 1..m."""
    return np.array([math.comb(m - i, k - 1) for i in range(1, m + 1)], dtype=float) / math.comb(m, k)


def best_of_k_curve(fabric, training_sample, ks=(1, 2, 5, 10, 20, 40), data=DATA):
    """Best-of-k pixel MSE of real drapes against the protocol's test drapes (see the module docstring)."""
    rows = fabric_rows(fabric, data)
    masks = {(r["sample"], r["capture"]): load_mask(r) for r in rows}
    tests = sorted(k for k in masks if k[1] == 1 and k[0] != training_sample)
    own = sorted(k for k in masks if k[0] == training_sample)
    if not tests or not own:
        raise SystemExit(f"noise_floor: fabric {fabric} needs capture-1 test samples and captures of training "
                         f"sample {training_sample}")
    redrapes, trained = {}, []  # redrapes[t]: {drape: pixel MSE to test drape t}
    for t in tests:
        redrapes[t] = {k: measure.pixel_mse(masks[t], masks[k]) for k in masks
                       if k[0] != t[0] and k[0] != training_sample}
        trained.append([measure.pixel_mse(masks[t], masks[k]) for k in own])
    pool = min(len(r) for r in redrapes.values())
    out = {"fabric": fabric, "training_sample": training_sample, "tests": len(tests),
            "redrapes": {"pool": pool, "best_of": {str(k): float(np.mean([expected_best_of(list(r.values()), k)
                                                                         for r in redrapes.values()]))
                                                   for k in ks if k <= pool}},
            "training_sample_captures": {"pool": len(own), "best_of": {
                str(k): float(np.mean([expected_best_of(r, k) for r in trained])) for k in range(1, len(own) + 1)}}}
    # Hausdorff: only capture 1 has meshes, so the pool is the other samples' capture-1 drapes.
    meshes = {r["sample"]: r["mesh"] for r in rows if r["capture"] == 1 and r["mesh"]}
    if all(t[0] in meshes for t in tests):
        by_mse, haus = [], {}  # haus: per pair of samples (symmetric), computed once
        for t in tests:
            others = sorted(s for s in meshes if s != t[0] and s != training_sample)
            if not others:
                continue
            for s in others:
                pair = (min(s, t[0]), max(s, t[0]))
                if pair not in haus:
                    haus[pair] = measure.hausdorff_distance(meshes[pair[0]], meshes[pair[1]])
            by_mse.append(([redrapes[t][(s, 1)] for s in others],
                           [haus[(min(s, t[0]), max(s, t[0]))] for s in others]))
        if by_mse:
            pool = min(len(m) for m, _ in by_mse)
            out["hausdorff_m_redrapes"] = {
                "pool": pool,
                "best_of": {str(k): float(np.mean([expected_best_of(h, k) for _, h in by_mse])) for k in ks if k <= pool},
                "at_best_mse_of": {str(k): float(np.mean([expected_at_best_of(m, h, k) for m, h in by_mse]))
                                   for k in ks if k <= pool}}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fabrics", default="1,2,3,4,5")
    ap.add_argument("--best-of-k", action="store_true",
                    help="also the real drapes' best-of-k curves against the protocol's test drapes")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    paths.require_cusick_dataset()  # after parsing: --help works without the dataset
    fabrics = [int(f) for f in args.fabrics.split(",")]
    per = [floor(f) for f in fabrics]
    keys = [k for k in per[0] if k not in ("fabric", "samples")]
    mean = {k: float(np.mean([p[k] for p in per if k in p])) for k in keys}
    for p in per:
        print(p["fabric"], " ".join(f"{k} {p[k]:.4f}" for k in keys if k in p))
    print("mean", " ".join(f"{k} {v:.4f}" for k, v in mean.items()))
    result = {"fabrics": per, "mean": mean}
    if args.best_of_k:
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from paper_protocol import TRAINING_SAMPLE
        curves = [best_of_k_curve(f, TRAINING_SAMPLE[f]) for f in fabrics]
        for c in curves:
            print(c["fabric"], "redrapes best-of-k", " ".join(f"{k}:{v:.4f}" for k, v in c["redrapes"]["best_of"].items()),
                  "| training sample's captures", " ".join(f"{k}:{v:.4f}"
                                                           for k, v in c["training_sample_captures"]["best_of"].items()))
            if "hausdorff_m_redrapes" in c:
                h = c["hausdorff_m_redrapes"]
                print(c["fabric"], "redrapes Hausdorff m best-of-k", " ".join(f"{k}:{v:.4f}" for k, v in h["best_of"].items()),
                      "| at the best MSE of k", " ".join(f"{k}:{v:.4f}" for k, v in h["at_best_mse_of"].items()))
        result["best_of_k"] = curves
    if args.json:
        measure.write_json(args.json, result)


if __name__ == "__main__":
    main()
