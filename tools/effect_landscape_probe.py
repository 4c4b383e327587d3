#!/usr/bin/python3
"""The fit's loss along one effect parameter (docs/lab/effect-recovery.md): one clean drape (circle1, Cotton Blue's
tables with the linear stretch row, the 100 x 0.05 s rollout from flat, no placement noise) made with
NAME.PARAM = TRUTH is the observation; the homo MAP objective with the material known and held, the pixel term
only (diagnose's refit likelihood) and the effect's other parameters fixed at their off values, is evaluated
with its exact gradient at each VALUE, next to the hard-silhouette pixel MSE and drape coefficient.

Usage (from the repository root):
    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/effect_landscape_probe.py \
        damping.mass_per_s 10 0,2,4,6,8,10,12,16 [--out /tmp/landscape]
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))

from drapelab import infer, measure, render, sim, tables  # noqa: E402

DENSITY = 0.192


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("parameter", help="NAME.PARAM")
    ap.add_argument("truth", type=float)
    ap.add_argument("values", help="comma-separated values to evaluate")
    ap.add_argument("--out", default="/tmp/landscape")
    args = ap.parse_args()
    name, param = args.parameter.split(".")
    values = [float(v) for v in args.values.split(",")]
    os.makedirs(args.out, exist_ok=True)
    stretch = np.array(tables.COTTON_BLUE.stretch, dtype=float)
    stretch[1:] = stretch[0]
    bend = tables.COTTON_BLUE.bend
    mesh = sim.cusick_specimen(1)
    cam = render.orthographic_camera()
    px = measure.DATASET_PX_PER_M

    def image(value):
        eff = {name: {param: value}}
        m = sim.ClothModel(mesh, density=DENSITY, effects=eff)
        p = m.parameters(stretch=stretch, bend=bend, effects=eff)
        x = m.simulate(p, mode="dynamic", record=False)
        return np.asarray(render.hard_silhouette(cam, m.observe(x, p), m.faces), dtype=float)

    truth = image(args.truth)
    path = os.path.join(args.out, "truth.png")
    measure.write_image(path, 1.0 - truth)
    cfg = infer.load_config()
    cfg["mesh_level"] = 1
    cfg["calibration"]["mesh_level"] = None
    cfg["samples_per_epoch"] = 1
    cfg["init"]["scale_search"] = []
    cfg["sigma_dc"] = 0.0
    job = infer.FitJob([path], DENSITY, model="homo", seed=0, config=cfg, threads=1, init_bend=bend,
                       init_stretch=stretch, effects={name: {param: None}})
    print(f"{name}.{param}, truth {args.truth}: truth DC {measure.drape_coefficient(truth, px):.4f}; Adam step "
          f"{job.learning_rates['effect_mu'][0]:.3g}, prior scale {job.plan.prior_scale[0]:.3g}")
    print(f"| {param} | data term | loss (+ prior) | dL/d{param} (with prior) | hard MSE vs truth | DC |\n"
          "|---|---|---|---|---|---|")
    for v in values:
        job.theta["effect_mu"] = np.array([v])
        terms, grads = job.objective(job.theta, 0)
        img = image(v)
        print(f"| {v:g} | {terms['data']:.3f} | {terms['loss']:.3f} | {grads['effect_mu'][0]:+.4g} | {float(np.mean((img - truth) ** 2)):.4f} "
              f"| {measure.drape_coefficient(img, px):.4f} |", flush=True)


if __name__ == "__main__":
    main()
