#!/usr/bin/python3
"""The effect-recovery table (issue 17's targets): for each effect, synthetic drapes with the effect at its
registry moderate strength are fitted without it (base) and with it (`fit --effects NAME`), and a control set
(same material, same placements, no effect) is fitted without; each fit is evaluated on its own training drapes.

Per effect it reports the recovered strength of the primary parameter (posterior mean and 90 % interval), and
how far the best-of-K MSE and the drape-coefficient error fall from the base fit towards the control fit:
fall = (base - with effect) / (base - control) (1 = all the way; the target is >= 0.6).

Usage (from the repository root):
    PYTHONPATH=addon:build/python /usr/bin/python3 tools/effect_recovery.py --out /tmp/recovery \
        [--effects tilt,density_variation,...] [--count 6] [--seed 101] [--mesh-level 1] [--epochs 15] \
        [--samples 16] [--model bdp]
Writes OUT/recovery.json and prints a markdown table. The fits run without the drape calibration (it moves
the material after the fit and would blur what the effect's strength explains).
"""
import argparse
import copy
import glob
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "addon"))

from drapelab import infer, measure, sim, synth  # noqa: E402

DENSITY = 0.192


def images_of(folder):
    return sorted(glob.glob(os.path.join(folder, "fabric_00", "silhouettes", "*.png")))


def fit_and_evaluate(images, config, args, effects=None, label=""):
    t0 = time.monotonic()
    preset = infer.fit(images, DENSITY, model=args.model, epochs=args.epochs, seed=args.seed + 1, config=config,
                       effects=effects)
    ev = infer.evaluate(preset, images, samples=args.samples, seed=args.seed + 2, config=config)
    m = ev["mean"]
    out = {"mse": m["mse"], "dc_abs_error": m["dc_abs_error"], "iou": m["iou"],
           "active_effects": preset["active_effects"], "seconds": time.monotonic() - t0}
    print(f"  {label}: MSE {m['mse']:.4f}  |dDC| {m['dc_abs_error']:.4f}  ({out['seconds']:.0f} s)", file=sys.stderr,
          flush=True)
    return out


def fall(base, fixed, control):
    gap = base - control
    return None if abs(gap) < 1e-12 else (base - fixed) / gap


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--effects", default=None, help="comma-separated effect names (default: every registered)")
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--mesh-level", type=int, default=1)
    ap.add_argument("--epochs", type=int, default=15)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--model", default="bdp", choices=["homo", "heter", "bdp"])
    args = ap.parse_args()
    names = args.effects.split(",") if args.effects else [e["name"] for e in sim.effects()]
    registry = {e["name"]: e for e in sim.effects()}
    config = copy.deepcopy(infer.load_config())
    config["mesh_level"] = args.mesh_level
    config["calibration"]["enabled"] = False
    os.makedirs(args.out, exist_ok=True)
    control_dir = os.path.join(args.out, "control")
    synth.synth(control_dir, DENSITY, count=args.count, seed=args.seed, mesh_level=args.mesh_level, force=True)
    print("control", file=sys.stderr)
    control = fit_and_evaluate(images_of(control_dir), config, args, label="control fit")
    rows = []
    for name in names:
        primary = registry[name]["parameters"][0]
        truth = primary["moderate"]
        folder = os.path.join(args.out, name)
        synth.synth(folder, DENSITY, effects={name: {primary["name"]: truth}}, count=args.count, seed=args.seed,
                    mesh_level=args.mesh_level, force=True)
        print(name, file=sys.stderr)
        base = fit_and_evaluate(images_of(folder), config, args, label="base fit")
        fixed = fit_and_evaluate(images_of(folder), config, args, effects={name: None}, label=f"+{name} fit")
        rec = fixed["active_effects"][name][primary["name"]]
        row = {"effect": name, "parameter": primary["name"], "unit": primary["unit"], "truth": truth,
               "recovered": rec["value"], "interval90": rec.get("interval90"),
               "inside90": (rec["interval90"][0] <= truth <= rec["interval90"][1]) if "interval90" in rec else None,
               "relative_error": abs(rec["value"] - truth) / abs(truth),
               "mse": {"base": base["mse"], "with_effect": fixed["mse"], "control": control["mse"],
                       "fall": fall(base["mse"], fixed["mse"], control["mse"])},
               "dc_abs_error": {"base": base["dc_abs_error"], "with_effect": fixed["dc_abs_error"],
                                "control": control["dc_abs_error"],
                                "fall": fall(base["dc_abs_error"], fixed["dc_abs_error"], control["dc_abs_error"])},
               "fitted": fixed["active_effects"][name]}
        rows.append(row)
        measure.write_json(os.path.join(args.out, "recovery.json"),
                           {"settings": vars(args), "control": control, "rows": rows})
    print("| effect | truth | recovered | 90 % interval | MSE base / with / control (fall) | "
          "abs dDC base / with / control (fall) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        iv = "-" if r["interval90"] is None else f"{r['interval90'][0]:.3g} .. {r['interval90'][1]:.3g}"
        f1 = "-" if r["mse"]["fall"] is None else f"{r['mse']['fall']:.2f}"
        f2 = "-" if r["dc_abs_error"]["fall"] is None else f"{r['dc_abs_error']['fall']:.2f}"
        print(f"| {r['effect']}.{r['parameter']} | {r['truth']:.3g} {r['unit']} | {r['recovered']:.3g} | {iv} | "
              f"{r['mse']['base']:.4f} / {r['mse']['with_effect']:.4f} / {r['mse']['control']:.4f} ({f1}) | "
              f"{r['dc_abs_error']['base']:.4f} / {r['dc_abs_error']['with_effect']:.4f} / "
              f"{r['dc_abs_error']['control']:.4f} ({f2}) |")


if __name__ == "__main__":
    main()
