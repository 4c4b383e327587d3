#!/usr/bin/python3
"""Issue 18 item 5: the diagnosis of the shipped presets of fabrics 1-5 against their own test photos.

    tools/real_diagnosis.py --out DIR [--fabrics 1,2,3,4,5] [--time-budget 600] [--samples 16] [--seed 0]
                            [--candidates NAME,...] [--count 6]
    tools/real_diagnosis.py --out DIR --held-out [--fabrics ...] [--eval-samples 100] [--fit-init [--fit-budget 300]]

For each fabric: the shipped preset assets/presets/fabric_XX_*_bdp.json, diagnosed against the first --count
capture-1 photos of samples 03 onwards without the preset's training sample (the paper's training samples:
fabric 1: 5, 2: 2, 3: 1, 4: 4, 5: 2), on the preset's mesh, every registered effect a candidate. Each report goes
to DIR/fabric_XX/ (index.html, diagnosis.json, presets/ of the refits; with the photos' capture-1 meshes, so the
report compares them in 3D too); DIR/real.json collects one row per fabric
(rerunning skips the fabrics already in it) and the table is printed as Markdown.
--held-out: for each diagnosed fabric, the shipped preset ("before") and the refit of the effect the diagnosis
ranked first ("after", whether or not it was recommended) evaluated best-of-N (`evaluate`, the same seed and
draws for both) on the fabric's capture-1 test photos the diagnosis did not see (the paper's 11 test samples
without the --count diagnosed ones), with their meshes: MSE, Hausdorff, drape-coefficient error and fold-depth
(node amplitude) bias; DIR/held_out.json, and a Markdown table. --fit-init: also the verdict's next step and its
control, `fit --init` on the diagnosed photos (the refit's effect held) from the refit ("after_fit") and from the
shipped preset ("before_fit"), --fit-budget seconds each (DIR/fabric_XX/fit_init_*.json), evaluated the same way. Needs the full dataset
(../shared/data/cusick or DRAPELAB_CUSICK_DIR). Run with ./drapelab's environment:
`PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 tools/real_diagnosis.py --out out/real`.
"""
import argparse
import glob
import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
from drapelab import diagnose, infer, paths  # noqa: E402
from paper_protocol import TRAINING_SAMPLE  # noqa: E402  (the paper's training samples; tools/, this folder)


def test_photos(data, fabric, count):
    train = TRAINING_SAMPLE[fabric]
    out = []
    for sample in range(3, 13):
        if sample == train:
            continue
        p = os.path.join(data, f"fabric_{fabric:02d}", "silhouettes", f"sample_{sample:02d}_capture_1.jpg")
        if os.path.isfile(p):
            out.append(p)
        if len(out) == count:
            break
    return out


def held_out_photos(data, fabric, diagnosed):
    """(images, meshes) of the fabric's capture-1 test samples (all but the training one) not in `diagnosed`."""
    images, meshes = [], []
    for sample in range(1, 13):
        p = os.path.join(data, f"fabric_{fabric:02d}", "silhouettes", f"sample_{sample:02d}_capture_1.jpg")
        if sample == TRAINING_SAMPLE[fabric] or os.path.basename(p) in diagnosed or not os.path.isfile(p):
            continue
        images.append(p)
        meshes.append(os.path.join(data, f"fabric_{fabric:02d}", "meshes", f"sample_{sample:02d}_capture_1.obj"))
    return images, meshes


def held_out(args, data, rows):
    out_path = os.path.join(args.out, "held_out.json")
    done = json.load(open(out_path))["rows"] if os.path.isfile(out_path) else []
    for r in sorted(rows, key=lambda r: r["fabric"]):
        if any(d["fabric"] == r["fabric"] for d in done):
            continue
        images, meshes = held_out_photos(data, r["fabric"], set(r["images"]))
        first = r["ranked_first"]
        refit = ((r["refits"][first].get("preset") or f"presets/{first}.json")
                 if first and r["refits"].get(first) else None)
        row = {"fabric": r["fabric"], "images": [os.path.basename(p) for p in images], "effect": first,
               "recommended": r["recommended"]}
        folder = os.path.join(args.out, f"fabric_{r['fabric']:02d}")
        presets = [("before", os.path.join(ROOT, r["preset"])),
                   ("after", os.path.join(folder, refit) if refit else None)]
        if args.fit_init:  # the verdict's next step, and its control: fit --init on the diagnosed photos, same budget
            diagnosed = [os.path.join(data, f"fabric_{r['fabric']:02d}", "silhouettes", name) for name in r["images"]]
            for label, start in list(presets):
                path = os.path.join(folder, f"fit_init_{label}.json")
                if start is not None and not os.path.isfile(path):
                    t0 = time.monotonic()
                    infer.fit(diagnosed, init=start, time_budget=args.fit_budget, seed=args.seed, out=path)
                    print(f"fabric {r['fabric']} fit --init {label}: {time.monotonic() - t0:.0f} s", file=sys.stderr,
                          flush=True)
                presets.append((f"{label}_fit", path if start is not None else None))
        for label, preset in presets:
            if preset is None:
                row[label] = None
                continue
            e = infer.evaluate(preset, images, meshes=meshes, samples=args.eval_samples, seed=args.seed)
            row[label] = {k: e["mean"].get(k) for k in ("mse", "iou", "hausdorff_m", "dc_abs_error", "dc_coverage90",
                                                         "node_within1", "amplitude_bias_m")}
            if label == "after":
                row["values"] = (infer.load_preset(preset).get("active_effects") or {}).get(first)
            print(f"fabric {r['fabric']} {label}: {row[label]}", file=sys.stderr, flush=True)
        done.append(row)
        with open(out_path + ".tmp", "w") as f:
            json.dump({"rows": done, "samples": args.eval_samples, "seed": args.seed}, f, indent=1)
        os.replace(out_path + ".tmp", out_path)
    labels = ("before", "after", "before_fit", "after_fit") if args.fit_init else ("before", "after")
    lines = [f"| fabric | held-out photos | ranked first | MSE {' / '.join(labels)} (best-of-{args.eval_samples}) | "
             "Hausdorff m | abs DC error | fold-depth bias mm |", "|---|---|---|---|---|---|---|"]
    for d in done:
        def pair(key, scale=1.0, fmt=".4f"):
            return " / ".join(format(scale * x[key], fmt) if x.get(key) is not None else "-"
                              for x in (d.get(label) or {} for label in labels))
        lines.append(f"| {d['fabric']} | {len(d['images'])} | {d['effect']} | {pair('mse')} | {pair('hausdorff_m')} | "
                     f"{pair('dc_abs_error', fmt='.3f')} | {pair('amplitude_bias_m', 1000.0, '+.2f')} |")
    print("\n".join(lines))


def row_of(fabric, d, seconds):
    tested = [e for e in d["ranking"] if e.get("p_value") is not None]
    smallest = min(tested, key=lambda e: e["p_value"]) if tested else None
    return {"fabric": fabric, "seconds": round(seconds, 1), "base": d["base"], "threshold": d["threshold"],
            "recommended": d["recommended"], "alternatives": d.get("alternatives"),
            "ranked_first": d["ranking"][0]["effect"] if d["ranking"] else None,
            "smallest_p": {"effect": smallest["effect"], "p": smallest["p_value"]} if smallest else None,
            "p_values": {e["effect"]: e["p_value"] for e in tested},
            "p_values_score": {e["effect"]: e.get("p_value_score", e["p_value"]) for e in tested},
            "p_values_step": {e["effect"]: e["step"]["p_value"] for e in tested if e.get("step")},
            "p_values_step_3d": {e["effect"]: e["step_3d"]["p_value"] for e in tested if e.get("step_3d")},
            "statistics_step_3d": {e["effect"]: e["step_3d"]["statistic"] for e in tested if e.get("step_3d")},
            "refits": {e["effect"]: {k: e["refit"].get(k) for k in ("mse", "iou", "loss", "dc_error", "amplitude_error",
                                                                    "values", "epochs", "kept_start", "preset")}
                       for e in d["ranking"] if e.get("refit")},
            "geometry_words": (d.get("geometry") or {}).get("words")}


def table(rows):
    lines = ["| fabric | best-of-K MSE | re-drape floor | abs DC error | amplitude error | smallest p (threshold) "
             "| refits: best-of-K MSE | recommended | s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        b = r["base"]
        sp = r["smallest_p"]
        refits = ", ".join(f"{n} {f['mse']:.4f}" for n, f in r["refits"].items() if f.get("mse") is not None) or "none"
        lines.append(f"| {r['fabric']} | {b['mse']:.4f} | {b.get('redrape_mse') or float('nan'):.4f} | "
                     f"{b['dc_error']:.3f} | {1000 * b['amplitude_error']:.2f} mm | "
                     f"{sp['effect'] if sp else '-'} {sp['p'] if sp else float('nan'):.2g} ({r['threshold']:.2g}) | "
                     f"{refits} | {r['recommended']} | {r['seconds']:.0f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--fabrics", default="1,2,3,4,5")
    ap.add_argument("--time-budget", type=float, default=600.0)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--candidates", default=None)
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--held-out", action="store_true",
                    help="evaluate before/after on the test photos the diagnoses did not see (after the diagnoses)")
    ap.add_argument("--eval-samples", type=int, default=100)
    ap.add_argument("--fit-init", action="store_true",
                    help="--held-out: also fit --init (the effect held) from the shipped preset and from the refit on "
                         "the diagnosed photos, --fit-budget each, and evaluate both (before_fit, after_fit)")
    ap.add_argument("--fit-budget", type=float, default=300.0)
    args = ap.parse_args()
    data = paths.cusick_dataset_dir()
    if data is None:
        sys.exit("real_diagnosis: the Cusick dataset is not found (../shared/data/cusick or DRAPELAB_CUSICK_DIR)")
    os.makedirs(args.out, exist_ok=True)
    result = os.path.join(args.out, "real.json")
    rows = json.load(open(result))["rows"] if os.path.isfile(result) else []
    if args.held_out:
        wanted = {int(f) for f in args.fabrics.split(",")}
        return held_out(args, data, [r for r in rows if r["fabric"] in wanted])
    for fabric in [int(f) for f in args.fabrics.split(",")]:
        if any(r["fabric"] == fabric for r in rows):
            continue
        preset = glob.glob(os.path.join(ROOT, "assets", "presets", f"fabric_{fabric:02d}_*_bdp.json"))[0]
        images = test_photos(data, fabric, args.count)
        # each photo's capture-1 mesh (the dataset's reconstructions: circle3, the presets' mesh): Hausdorff per
        # image and the 3D comparison (diagnosis.json geometry)
        meshes = [p.replace(os.sep + "silhouettes" + os.sep, os.sep + "meshes" + os.sep).replace(".jpg", ".obj")
                  for p in images]
        meshes = meshes if all(os.path.isfile(m) for m in meshes) else None
        t0 = time.monotonic()
        d = diagnose.diagnose(preset, images, meshes=meshes, candidates=args.candidates, time_budget=args.time_budget,
                              samples=args.samples, seed=args.seed,
                              out_dir=os.path.join(args.out, f"fabric_{fabric:02d}"))
        rows.append(dict(row_of(fabric, d, time.monotonic() - t0), preset=os.path.relpath(preset, ROOT),
                         images=[os.path.basename(p) for p in images]))
        with open(result + ".tmp", "w") as f:
            json.dump({"rows": rows}, f, indent=1)
        os.replace(result + ".tmp", result)
        print(table(rows[-1:]), file=sys.stderr, flush=True)
    print(table(sorted(rows, key=lambda r: r["fabric"])))


if __name__ == "__main__":
    main()
