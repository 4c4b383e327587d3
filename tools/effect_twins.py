#!/usr/bin/python3
"""Are two effects twins on a silhouette? The probe behind docs/diagnose.md's account of the radial confusions.

    tools/effect_twins.py --out DIR [--seed 681] [--count 6] [--mesh-level 1] SPEC [SPEC...]

Each SPEC is `synth --effects` text (e.g. density_variation.radial=0.35, heterogeneity_map.radial=-0.44,
camera.scale_error=0.03; `control` for none). For each, `count` synthetic drapes of Cotton Blue (0.192 kg/m^2)
with the same seed, i.e. the same placements (synth: drape i's placement noise is default_rng([seed, i, 1])), are
written to DIR/<spec> (kept: a rerun reuses them). Printed: per SPEC the mean drape coefficient and node counts,
and for every pair of SPECs the mean over placements of the hard pixel MSE between the two drapes of one
placement ("same placement"), beside the mean MSE between control drapes of different placements (the re-drape
noise). Two effects whose drapes are closer to each other than either is to the control drapes, by a margin the
re-drape noise does not cover, cannot be told apart by a silhouette, whatever the diagnosis does.
Run from the repository root with PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3.
"""
import argparse
import glob
import itertools
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))
import numpy as np  # noqa: E402

from drapelab import measure, synth  # noqa: E402

DENSITY = 0.192


def drapes(folder):
    """Hard masks, drape coefficients and node counts of the drapes in `folder`, in placement order."""
    paths = sorted(glob.glob(os.path.join(folder, "fabric_00", "silhouettes", "*.png")))
    masks = [(np.asarray(measure.load_silhouette(p).mask) > 0.5).astype(np.float64) for p in paths]
    dc = [float(measure.drape_coefficient(m)) for m in masks]
    nodes = [int(measure.node_count(measure.r_theta(m))) for m in masks]
    return masks, dc, nodes


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("specs", nargs="+")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=681)
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--mesh-level", type=int, default=1)
    args = ap.parse_args()
    specs = ["control"] + [s for s in args.specs if s != "control"]
    sets = {}
    for spec in specs:
        folder = os.path.join(args.out, spec.replace("=", "_"))
        if not os.path.isfile(os.path.join(folder, "truth.json")):
            synth.synth(folder, DENSITY, effects=None if spec == "control" else spec, count=args.count,
                        seed=args.seed, mesh_level=args.mesh_level, force=True)
        sets[spec] = drapes(folder)
    control = sets["control"][0]
    redrape = [measure.pixel_mse(a, b) for a, b in itertools.combinations(control, 2)]
    out = {"seed": args.seed, "count": args.count, "mesh_level": args.mesh_level,
           "redrape_mse": float(np.mean(redrape)), "sets": {}, "pairs": {}}
    print(f"re-drape noise (control drapes of different placements): MSE {np.mean(redrape):.4f} "
          f"({min(redrape):.4f} .. {max(redrape):.4f})")
    print("| set | DC mean | nodes |")
    print("|---|---|---|")
    for spec, (_, dc, nodes) in sets.items():
        out["sets"][spec] = {"dc": dc, "nodes": nodes}
        print(f"| {spec} | {np.mean(dc):.4f} | {','.join(map(str, nodes))} |")
    print("\n| pair | same-placement MSE mean (min .. max) |")
    print("|---|---|")
    for a, b in itertools.combinations(specs, 2):
        m = [measure.pixel_mse(x, y) for x, y in zip(sets[a][0], sets[b][0])]
        out["pairs"][f"{a} | {b}"] = m
        print(f"| {a} vs {b} | {np.mean(m):.4f} ({min(m):.4f} .. {max(m):.4f}) |")
    with open(os.path.join(args.out, "twins.json"), "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
