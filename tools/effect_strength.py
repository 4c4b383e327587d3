#!/usr/bin/python3
"""How far an effect moves a drape: the probe behind the registry's "moderate" strengths (docs/physics.md).

    tools/effect_strength.py EFFECT.PARAM=V1,V2,... [EFFECT.PARAM=...] [--mesh-level 3] [--mode dynamic]

For each value, one drape of the Cotton Blue material (density 0.192 kg/m^2, the config's dynamic protocol:
100 x 0.05 s from flat, no placement noise) with that one parameter set (the effect's others off), against the
base model's drape of the same mesh: the change of the drape coefficient (DC), the pixel MSE between the hard
orthographic silhouettes (the dataset's 720 px/m, 256 x 256), the node count and the 2-fold harmonic of r(theta)
(amplitude, axis in degrees mod 180: an anisotropy's signature, tools/two_fold_axes.py). The re-drape noise floor to
compare with (../shared/data/cusick/README.md): 0.031 in DC, 0.042 in pixel MSE.
Run from the repository root: `PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3
tools/effect_strength.py rest_curvature.crease_rad=0.25,0.5`.
"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))
import numpy as np  # noqa: E402

from drapelab import infer, measure, render, sim, synth  # noqa: E402

DENSITY = 0.192


def parse(spec):
    try:
        key, values = spec.split("=", 1)
        effect, param = key.split(".", 1)
        return effect, param, [float(v) for v in values.split(",") if v.strip()]
    except ValueError:
        raise SystemExit(f"effect_strength: expected EFFECT.PARAM=V1,V2,..., got {spec!r}") from None


def drape(mesh, effects, mode, dynamic, camera):
    mat = synth.resolve_material(None)  # the Cotton Blue tables as the fitter starts from them (synth's default)
    model = sim.ClothModel(mesh, density=DENSITY, effects=effects)
    p = model.parameters(stretch=mat["stretch_N_m"], bend=mat["bend_N_m"], density=DENSITY, effects=effects)
    t0 = time.monotonic()
    x = model.simulate(p, mode=mode, record=False, **(dynamic if mode == "dynamic" else {}))
    mask = np.asarray(render.hard_silhouette(camera, x, model.faces), dtype=np.float64)
    dc = float(measure.drape_coefficient(mask, measure.DATASET_PX_PER_M, support_radius=model.support_radius))
    rt = measure.r_theta(mask, measure.calibration(measure.DATASET_PX_PER_M))
    nodes = int(measure.node_count(rt))
    amplitude, axis = measure.two_fold(rt)  # the axis counter-clockwise from +x, as tools/two_fold_axes.py prints it
    return mask, dc, nodes, time.monotonic() - t0, (amplitude * 1e3, axis)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("specs", nargs="+", help="EFFECT.PARAM=V1,V2,...")
    ap.add_argument("--mesh-level", type=int, default=3)
    ap.add_argument("--mode", choices=sim.MODES, default="dynamic")
    args = ap.parse_args()
    mesh = sim.cusick_template_path(args.mesh_level)
    dynamic = dict(infer.load_config()["dynamic"])
    camera = render.orthographic_camera(measure.DATASET_PX_PER_M, centre=(128, 128), size=(256, 256))
    base, dc0, n0, s0, (a0, ax0) = drape(mesh, None, args.mode, dynamic, camera)
    print(f"base (circle{args.mesh_level}, {args.mode}): DC {dc0:.4f}, {n0} nodes, 2-fold {a0:.1f} mm at "
          f"{ax0:.0f} deg ({s0:.0f} s)", flush=True)
    print("| parameter | value | DC | dDC | pixel MSE vs base | nodes | 2-fold mm (axis deg) |")
    print("|---|---|---|---|---|---|---|")
    for spec in args.specs:
        effect, param, values = parse(spec)
        for v in values:
            try:
                mask, dc, n, _, (a2, ax2) = drape(mesh, {effect: {param: v}}, args.mode, dynamic, camera)
            except Exception as e:  # a diverged rollout is a measurement too
                print(f"| {effect}.{param} | {v:g} | failed: {e} | | | | |", flush=True)
                continue
            print(f"| {effect}.{param} | {v:g} | {dc:.4f} | {dc - dc0:+.4f} | {measure.pixel_mse(mask, base):.4f} "
                  f"| {n} | {a2:.1f} ({ax2:.0f}) |", flush=True)


if __name__ == "__main__":
    main()
