#!/usr/bin/python3
"""Moderate strengths of `offset` and `camera` (docs/physics.md "Moderate strengths"): on circle3 with the Cotton
Blue tables (density 0.192 kg/m^2), the 100 x 0.05 s rollout from flat and the dataset's orthographic silhouette
(720 px/m), the change of the drape coefficient and the pixel MSE against the base model's drape, one parameter
at a time. Prints a markdown table (the floor: 0.031 in DC, 0.042 in re-drape pixel MSE).

Usage (from the repository root):
    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/observation_effects_probe.py
"""
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))

from drapelab import measure, render, sim, tables  # noqa: E402

DENSITY = 0.192
CASES = [("offset", "dx_m", v) for v in (0.003, 0.005, 0.01)] + \
        [("camera", "scale_error", v) for v in (0.02, 0.03, -0.03)] + \
        [("camera", "cx_px", v) for v in (2.0, 3.0, 5.0)] + \
        [("camera", "inv_distance_per_m", v) for v in (0.5, 1.0, 1.43)]


def main():
    mesh = sim.cusick_specimen(3)
    cam = render.orthographic_camera(measure.DATASET_PX_PER_M, centre=(128, 128), size=(256, 256))
    cal = measure.calibration(measure.DATASET_PX_PER_M)
    mat = tables.preset("cotton_blue")

    def drape(effects):
        m = sim.ClothModel(mesh, density=DENSITY, effects=effects)
        p = m.parameters(stretch=mat.stretch, bend=mat.bend, effects=effects)
        t0 = time.monotonic()
        x = m.simulate(p, mode="dynamic", record=False)
        img = np.asarray(render.hard_silhouette(cam, m.observe(x, p), m.faces), dtype=float)
        return x, img, time.monotonic() - t0

    _, base, t = drape(None)
    dc0 = measure.drape_coefficient(base, cal.px_per_m)
    print(f"base: DC {dc0:.4f} ({t:.1f} s per drape)")
    print("| parameter | value | dDC | MSE vs base |")
    print("|---|---|---|---|")
    cache = {}
    for name, param, value in CASES:
        effects = {name: {param: value}}
        if name == "camera":  # no physics: one drape, transformed
            if "x" not in cache:
                cache["x"] = drape({"camera": {}})[0]
            m = sim.ClothModel(mesh, density=DENSITY, effects=effects)
            p = m.parameters(stretch=mat.stretch, bend=mat.bend, effects=effects)
            img = np.asarray(render.hard_silhouette(cam, m.observe(cache["x"], p), m.faces), dtype=float)
        else:
            img = drape(effects)[1]
        dc = measure.drape_coefficient(img, cal.px_per_m)
        print(f"| {name}.{param} | {value:g} | {dc - dc0:+.4f} | {float(np.mean((img - base) ** 2)):.4f} |", flush=True)


if __name__ == "__main__":
    main()
