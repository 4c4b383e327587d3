#!/usr/bin/python3
"""The effects' start search of `fit --effects NAME` on given photos, at several start_search_drapes values.

    tools/start_search_probe.py --preset P --images IMG... --effect NAME [--drapes 1,4,8] [--seed 0]
                                [--mesh-level L] [--json OUT]
    tools/start_search_probe.py --preset P --synth "NAME=V,NAME.PARAM=V" --synth-dir DIR [--count 4]
                                [--synth-seed S] --effect NAME [--drapes 1,4] [--mesh-level L] [--json OUT]

The fit is set up as the diagnosis's refit does it (infer.start_options: P's material, stretching, placement noise
and mesh level; the effect's parameters fitted), and only its start search runs (FitJob.effect_start_search),
once per --drapes value: each start candidate's score (the mean over the photos of the best data term of its
drapes) and the chosen one. For bending_anisotropy the candidates' long axis is printed too (degrees
counter-clockwise from +x: A = 90 + atan2(sin2, cos2) / 2, docs/lab/bending-anisotropy.md). --synth makes the
photos first (synth, P's mean material on the probe's mesh, --count drapes with placement noise, seed
--synth-seed) and also prints which candidate is nearest the truth (in units of each parameter's moderate
strength): the start the search should pick. Run with ./drapelab's
environment: `PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 tools/start_search_probe.py ...`.
"""
import argparse
import copy
import csv
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))
import numpy as np  # noqa: E402

from drapelab import infer, synth  # noqa: E402


def axis_deg(names, c):
    values = dict(zip(names, c))
    cos2, sin2 = values.get("bending_anisotropy.cos2"), values.get("bending_anisotropy.sin2")
    if cos2 is None or sin2 is None or math.hypot(cos2, sin2) == 0:
        return None
    return (90.0 + math.degrees(math.atan2(sin2, cos2)) / 2.0) % 180.0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", required=True)
    ap.add_argument("--images", nargs="+")
    ap.add_argument("--synth", default=None)
    ap.add_argument("--synth-dir", default=None)
    ap.add_argument("--synth-seed", type=int, default=1)
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--effect", required=True)
    ap.add_argument("--drapes", default="1,4,8")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mesh-level", type=int, default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    preset = infer.load_preset(args.preset)
    truth = None
    if args.synth is not None:
        level = args.mesh_level or (preset.get("simulation") or {}).get("mesh_level")
        truth = synth.synth(args.synth_dir, preset["density_kg_m2"], effects=args.synth, material=args.preset,
                            count=args.count, seed=args.synth_seed, mesh_level=level, force=True)
        with open(os.path.join(args.synth_dir, "manifest.csv")) as f:
            args.images = [os.path.join(args.synth_dir, r["silhouette"]) for r in csv.DictReader(f)]
    elif not args.images:
        ap.error("give --images or --synth")
    rows = []
    for drapes in [int(d) for d in args.drapes.split(",")]:
        cfg = copy.deepcopy(infer.load_config())
        cfg["effects"] = dict(infer.effect_settings(cfg), start_search_drapes=drapes)
        options = infer.start_options(preset, {"config": cfg, "mesh_level": args.mesh_level}, {args.effect: None})
        job = infer.FitJob(args.images, preset["density_kg_m2"], model=preset["model"], seed=args.seed, **options)
        t0 = time.monotonic()
        start = job.effect_start_search()
        seconds = time.monotonic() - t0
        print(f"start_search_drapes {drapes} ({start['drapes']} used), {seconds:.0f} s:")
        for c, loss in zip(start["candidates"], start["loss"]):
            a = axis_deg(start["parameters"], c)
            mark = "  <- chosen" if c == start["chosen"] else ""
            print(f"  {c}  loss {loss:.4f}" + (f"  axis {a:.1f} deg" if a is not None else "") + mark)
        if truth is not None:
            values = truth["effects"].get(args.effect, {})
            target = np.array([float(values.get(q["name"], q["off"])) for _, q in job.plan.free])
            distance = [float(np.sum(((np.array(c) - target) / job.plan.moderate) ** 2)) for c in start["candidates"]]
            nearest = start["candidates"][int(np.argmin(distance))]
            start = dict(start, truth=target.tolist(), nearest=nearest, hit=nearest == start["chosen"])
            print(f"  truth {target.tolist()}: nearest candidate {nearest}, chosen {'=' if start['hit'] else '!='} nearest")
        rows.append(dict(start, seconds=seconds, requested=drapes))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"preset": args.preset, "images": args.images, "effect": args.effect, "seed": args.seed,
                       "synth": args.synth, "synth_seed": args.synth_seed, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
