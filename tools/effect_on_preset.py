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
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
import numpy as np  # noqa: E402

from drapelab import fit_effects, fold_geometry, infer, measure, paths, sim  # noqa: E402
from paper_protocol import TRAINING_SAMPLE, captures, path, slug  # noqa: E402  (tools/, this script's folder)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("fabric", type=int, choices=sorted(TRAINING_SAMPLE))
    ap.add_argument("--effects", default=None)
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--draws", type=int, default=12)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    paths.require_cusick_dataset()
    config = infer.load_config()
    f = args.fabric
    rows = captures(f)
    train = [r for r in rows if int(r["sample"]) == TRAINING_SAMPLE[f]][0]
    tests = [r for r in rows if r is not train]
    preset = infer.load_preset(os.path.join(ROOT, "assets", "presets", f"{slug(train)}_bdp.json"))

    t0 = time.monotonic()
    if args.effects:
        p = copy.deepcopy(preset)
        p["active_effects"] = fit_effects.EffectPlan(sim.parse_effects_arg(args.effects, bare="moderate")).preset_block()
        preset = infer.calibrate_preset(p, [path(train["silhouette"])], config=config)
        infer.write_preset(args.out.replace(".json", "") + ".preset.json", preset)
    calibration_s = time.monotonic() - t0
    ev = infer.evaluate(preset, [path(r["silhouette"]) for r in tests], meshes=[path(r["mesh"]) for r in tests],
                        samples=args.samples, seed=0, config=config)
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
    curve = mn["mse_best_of"]  # best of 1, 10, 100, ... up to --samples
    print(f"fabric {f} {args.effects or 'shipped'}: MSE best-of-{'/'.join(curve)} "
          f"{'/'.join(f'{v:.4f}' for v in curve.values())} Hausdorff {mn['hausdorff_m']:.4f} "
          f"DC abs {mn['dc_abs_error']:.3f} cov {mn['dc_coverage90']:.2f} nodes within 1 {mn['node_within1']:.2f} depth "
          f"bias {mn['amplitude_bias_m'] * 1e3:+.2f} mm cov {mn['amplitude_coverage90']:.2f}; crest p99 / hoop p95 per "
          f"band {bands}; {result['seconds']:.0f} s", flush=True)


if __name__ == "__main__":
    main()
