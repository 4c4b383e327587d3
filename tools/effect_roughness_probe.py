#!/usr/bin/python3
"""How rough one draw's pixel data term is in an effect's parameters: central differences at several step sizes
against the adjoint, at given strengths (docs/diagnose.md, seed 661: a prestrain refit drifted away from the
truth because the term is rough in the strain at every step size).

Usage (from the repository root):
    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/effect_roughness_probe.py \
        --preset P --image IMG [--effect prestrain] [--at 0.03,0.035] [--seed 5] [--mesh-level 1]
Each value of --at sets the effect's primary parameter (its other parameters off); every parameter is probed.
"""
import argparse
import copy
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))

from drapelab import diagnose, fit_effects, infer, render  # noqa: E402

STEPS = (1e-3, 1e-4, 1e-5)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", required=True)
    ap.add_argument("--image", required=True)
    ap.add_argument("--effect", default="prestrain")
    ap.add_argument("--at", default="0.03,0.035")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--mesh-level", type=int, default=1)
    args = ap.parse_args()
    preset = infer.load_preset(args.preset)
    cfg = copy.deepcopy(infer.load_config())
    cfg["mesh_level"] = args.mesh_level
    cfg["calibration"]["enabled"] = False
    obs = diagnose._observations([args.image])
    pred, models, _, _, _, _, _, drawn = diagnose._joint_drapes(preset, obs, [args.effect], 1, args.seed, cfg, 1,
                                                                None, args.mesh_level, None, None)
    m = models[0]
    draw, v0 = drawn["bend"][0], drawn["velocities"][0]  # the diagnosis's first draw and its placement noise
    own = drawn["effects"][0] if drawn["effects"] else {}  # P's own effects, at that draw's values
    r = render.SoftRenderer(pred.camera, sigma=cfg["render_sigma_px"])
    params = fit_effects.registry()[args.effect]["parameters"]
    off = {q["name"]: q["off"] for q in params}

    def loss(values, grad=False):
        p = m.parameters(stretch=pred.stretch, bend=draw, effects={**own, args.effect: values})
        x = m.simulate(p, mode="dynamic", record=grad, velocities0=v0, **cfg["dynamic"])
        image = r.render(infer._observed(m, x, p), m.faces)
        value, g_image = infer.data_term(image, obs[0], cfg["sigma_obs"], 0.0)
        return (value, infer._observed_backward(m, x, p, r.backward(g_image))) if grad else value

    for at in (float(a) for a in args.at.split(",")):
        base = {**off, params[0]["name"]: at}
        value, g = loss(base, True)
        print(f"{args.effect}.{params[0]['name']} = {at:g}: data term {value:.4g}", flush=True)
        for q in params:
            diffs = []
            for h in STEPS:
                up, down = dict(base), dict(base)
                up[q["name"]] += h
                down[q["name"]] -= h
                diffs.append((loss(up) - loss(down)) / (2 * h))
            key = f"{args.effect}.{q['name']}"
            print(f"   {q['name']}: adjoint {float(g[key]):+.4g}; central differences "
                  + ", ".join(f"{d:+.4g} (h {h:g})" for d, h in zip(diffs, STEPS)), flush=True)


if __name__ == "__main__":
    main()
