#!/usr/bin/python3
"""Why `offset` is not recovered (docs/lab/effect-recovery.md "offset: the diagnosis"): the fit's loss and its
exact gradient along dx_m (dy_m = 0) and along dy_m (dx_m at the truth), with the material known (Cotton Blue's
tables, linear stretch, circle1, the 100 x 0.05 s rollout from flat, homo MAP objective: the data term plus the
effect prior), against
  clean  one drape made with offset dx_m = TRUTH and no placement noise,
  synth  `synth`'s drapes (COUNT, seed SEED, placement noise as the dataset's) with offset dx_m = TRUTH,
and the silhouette's centroid shift per metre of dx (the signal a fit reads), compared with the rigid tester-frame
shift the observation applies.

Usage (from the repository root):
    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/offset_landscape_probe.py \
        [--truth 0.01] [--count 6] [--seed 101] [--out /tmp/offset_probe]
"""
import argparse
import glob
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))

from drapelab import infer, measure, render, sim, synth, tables  # noqa: E402

DENSITY = 0.192


def linear_stretch():
    s = np.array(tables.COTTON_BLUE.stretch, dtype=float)
    s[1:] = s[0]
    return s


def config():
    cfg = infer.load_config()
    cfg["mesh_level"] = 1
    cfg["calibration"]["mesh_level"] = None
    cfg["samples_per_epoch"] = 1
    cfg["init"]["scale_search"] = []
    return cfg


def centroid(img, px_per_m):
    rows, cols = np.nonzero(img > 0.5)
    return (cols.mean() / px_per_m, -rows.mean() / px_per_m)


def scan(job, points):
    out = []
    for dx, dy in points:
        job.theta["effect_mu"] = np.array([dx, dy])
        terms, grads = job.objective(job.theta, 0)
        out.append((dx, dy, terms["data"], terms["loss"], *grads["effect_mu"]))
    return out


def print_scan(title, rows):
    print(f"\n{title}\n| dx_m | dy_m | data term | loss | dL/ddx [1/m] | dL/ddy [1/m] |\n|---|---|---|---|---|---|")
    for dx, dy, data, loss, gx, gy in rows:
        print(f"| {dx:+.4f} | {dy:+.4f} | {data:.3f} | {loss:.3f} | {gx:+.4g} | {gy:+.4g} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--truth", type=float, default=0.01)
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--out", default="/tmp/offset_probe")
    ap.add_argument("--skip-synth", action="store_true")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    bend, stretch = tables.COTTON_BLUE.bend, linear_stretch()
    mesh = sim.cusick_specimen(1)
    cam = render.orthographic_camera()
    px = measure.DATASET_PX_PER_M

    # The signal: the silhouette's centroid (tester frame) against dx, with the observation's rigid shift dx.
    print("| dx_m | centroid x [mm] | centroid y [mm] | pixel MSE vs dx = 0 |\n|---|---|---|---|")
    ref = None
    for dx in (0.0, 0.0025, 0.005, 0.0075, 0.01, 0.015, 0.02):
        eff = {"offset": {"dx_m": dx}}
        m = sim.ClothModel(mesh, density=DENSITY, effects=eff)
        p = m.parameters(stretch=stretch, bend=bend, effects=eff)
        x = m.simulate(p, mode="dynamic", record=False)
        img = np.asarray(render.hard_silhouette(cam, m.observe(x, p), m.faces), dtype=float)
        if ref is None:
            ref = img
        c = centroid(img, px)
        print(f"| {dx:.4f} | {1e3 * c[0]:+.2f} | {1e3 * c[1]:+.2f} | {float(np.mean((img - ref) ** 2)):.4f} |",
              flush=True)
        if dx == args.truth:
            measure.write_image(os.path.join(args.out, "clean.png"), 1.0 - img)

    grid = [(-0.01, 0.0), (-0.005, 0.0), (0.0, 0.0), (0.0025, 0.0), (0.005, 0.0), (0.0075, 0.0), (0.01, 0.0),
            (0.0125, 0.0), (0.015, 0.0), (0.02, 0.0)]
    grid_y = [(args.truth, v) for v in (-0.01, -0.005, 0.005, 0.01)]
    cfg = config()
    job = infer.FitJob([os.path.join(args.out, "clean.png")], DENSITY, model="homo", seed=0, config=cfg, threads=1,
                       init_bend=bend, init_stretch=stretch, effects={"offset": None})
    print(f"\nAdam step size {job.learning_rates['effect_mu']} m; prior scale {job.plan.prior_scale} m; "
          f"prior weight {infer.effect_settings(cfg)['prior_weight']}")
    print_scan("clean (one drape, no placement noise)", scan(job, grid + grid_y))
    if args.skip_synth:
        return
    folder = os.path.join(args.out, "synth")
    synth.synth(folder, DENSITY, effects={"offset": {"dx_m": args.truth}}, count=args.count, seed=args.seed,
                mesh_level=1, force=True)
    images = sorted(glob.glob(os.path.join(folder, "fabric_00", "silhouettes", "*.png")))
    job = infer.FitJob(images, DENSITY, model="homo", seed=0, config=cfg, threads=1, init_bend=bend,
                       init_stretch=stretch, effects={"offset": None})
    print_scan(f"synth ({len(images)} drapes with placement noise; the model drapes without)", scan(job, grid + grid_y))


if __name__ == "__main__":
    main()
