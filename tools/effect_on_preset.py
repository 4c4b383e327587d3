#!/usr/bin/python3
"""A shipped preset with an effect switched on at a fixed value, re-calibrated and evaluated like the protocol: the
probe behind docs/lab/fold-depth.md's effect rows.

    tools/effect_on_preset.py FABRIC [--effects NAME=VALUE,...] [--samples 100] [--draws 12] --out OUT.json

For fabric FABRIC (1-5) the shipped preset (assets/presets/fabric_NN_*_bdp.json) gets the effects (fit's syntax with
values: ./drapelab effects), is drape-calibrated again on the paper's training image (DC and node search, fit.json's
calibration; omitted without --effects: the shipped preset as it is), evaluated best-of-N on the other 11 capture-1
images and meshes (infer.evaluate, seed 0), and its drapes' 3D fold statistics (drapelab.fold_geometry: rings'
height, radius and amplitude, crest and hoop hinge angles per band) are taken on --draws posterior draws on circle3.
Writes OUT.json (and OUT.preset.json, the re-calibrated preset) and prints one summary line.
Run from the repository root: `PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3
tools/effect_on_preset.py 4 --effects high_curvature_bending=-0.9 --out out/f4_hcb.json`.
"""
import argparse
import copy
import glob
import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
import numpy as np  # noqa: E402

from drapelab import fold_geometry, infer, measure, paths, sim  # noqa: E402

TRAINING_SAMPLE = {1: 5, 2: 2, 3: 1, 4: 4, 5: 2}  # the paper's (tools/paper_protocol.py)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("fabric", type=int, choices=sorted(TRAINING_SAMPLE))
    ap.add_argument("--effects", default=None)
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--draws", type=int, default=12)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    data = paths.require_cusick_dataset()
    config = infer.load_config()
    f = args.fabric
    preset = infer.load_preset(glob.glob(os.path.join(ROOT, "assets", "presets", f"fabric_{f:02d}_*_bdp.json"))[0])
    registry = {e["name"]: e for e in sim.effects()}

    def image(s):
        return os.path.join(data, f"fabric_{f:02d}", "silhouettes", f"sample_{s:02d}_capture_1.jpg")

    def mesh(s):
        return os.path.join(data, f"fabric_{f:02d}", "meshes", f"sample_{s:02d}_capture_1.obj")

    t0 = time.monotonic()
    if args.effects:
        values = sim.parse_effects_arg(args.effects, bare="moderate")
        units = {n: {q["name"]: q["unit"] for q in registry[n]["parameters"]} for n in values}
        p = copy.deepcopy(preset)
        p["active_effects"] = {n: {k: {"value": v, "unit": units[n][k]} for k, v in params.items()}
                               for n, params in values.items()}
        preset = infer.calibrate_preset(p, [image(TRAINING_SAMPLE[f])], config=config)
        infer.write_preset(args.out.replace(".json", "") + ".preset.json", preset)
    calibration_s = time.monotonic() - t0
    tests = [s for s in range(1, 13) if s != TRAINING_SAMPLE[f]]
    ev = infer.evaluate(preset, [image(s) for s in tests], meshes=[mesh(s) for s in tests], samples=args.samples,
                        seed=0, config=config)
    pred = infer._Predictive(preset, (256, 256), 2, config, mesh_level=3)
    m = pred.models[0]
    rest, edges = np.asarray(m.rest_positions), np.asarray(m.bending_edges)
    draws = infer.preset_bend_samples(preset, pred.num_edges, np.random.default_rng(0), args.draws)
    geometry = fold_geometry.summarise([fold_geometry.ring_stats(s["x"], rest, edges)
                                        for s in pred.drape(draws, 0) if "x" in s])
    c = preset.get("calibration", {})
    result = {"fabric": f, "effects": args.effects, "samples": args.samples, "mean": ev["mean"], "geometry": geometry,
              "calibration": {k: c.get(k) for k in ("dc_observed", "dc_predicted", "nodes_observed", "nodes_predicted",
                                                    "stretch_scale", "log_scale_shift")},
              "calibration_s": calibration_s, "seconds": time.monotonic() - t0}
    measure.write_json(args.out, result)
    mn = ev["mean"]
    bands = "; ".join(f"{b['crest_p99'][0]:.1f}/{b['hoop_p95'][0]:.1f}" for b in geometry["bands"] if b["crest_p99"])
    print(f"fabric {f} {args.effects or 'shipped'}: MSE best-of-1/10/100 {mn['mse_best_of']['1']:.4f}/"
          f"{mn['mse_best_of']['10']:.4f}/{mn['mse_best_of'][str(args.samples)]:.4f} Hausdorff {mn['hausdorff_m']:.4f} "
          f"DC abs {mn['dc_abs_error']:.3f} cov {mn['dc_coverage90']:.2f} nodes within 1 {mn['node_within1']:.2f} depth "
          f"bias {mn['amplitude_bias_m'] * 1e3:+.2f} mm cov {mn['amplitude_coverage90']:.2f}; crest p99 / hoop p95 per "
          f"band {bands}; {result['seconds']:.0f} s", flush=True)


if __name__ == "__main__":
    main()
