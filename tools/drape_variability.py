#!/usr/bin/python3
"""How much one fabric's drape coefficient scatters between drapes: the calibration.drape_log_sd of fit.json.

    tools/drape_variability.py [--fabrics 11,...,20] [--json OUT]

For each fabric, the drape coefficient of every silhouette of the dataset (all samples, all captures: new
specimens and re-drapes alike) and its sd (ddof 1); the slope s = dDC/dlog(bending scale) at the fabric's
shipped preset (assets/presets, measured by infer.calibrate_preset on its training image); the scatter in log
bending scale sd / s. Pooled: the median over the fabrics (fit.json calibration.drape_log_sd). Not the root mean
square: near DC 1 the slope vanishes and sd / s explodes (fabric 19, a knit at DC 0.83 with slope 0.045:
2.0, against 0.07-0.32 for the wovens), and one such fabric would set the spread of every other. Default fabrics 11-20 (2 samples, 4-10 captures each), which the paper's protocol (fabrics 1-5)
never sees: the protocol's figures do not depend on their own test images through this number.
Run with ./drapelab's environment: `PYTHONPATH=addon:build/python tools/drape_variability.py`.
"""
import argparse
import csv
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
import numpy as np  # noqa: E402

from drapelab import measure, paths  # noqa: E402

DATA = paths.cusick_dataset_dir()  # None when absent: main() says so
CALIBRATION_FABRICS = tuple(range(11, 21))


def drape_coefficients(fabrics=CALIBRATION_FABRICS, data=DATA):
    """{fabric: [drape coefficient of each of its silhouettes]} from the dataset's manifest."""
    with open(os.path.join(data, "manifest.csv")) as f:
        rows = [r for r in csv.DictReader(f) if int(r["fabric"]) in fabrics]
    out = {}
    for r in rows:
        mask = measure.load_silhouette(os.path.join(data, r["silhouette"])).mask
        out.setdefault(int(r["fabric"]), []).append(float(measure.drape_coefficient(mask)))
    return out


def pooled_sd(per_fabric):
    """Root of the mean (over fabrics) of each fabric's sample variance of its drape coefficients."""
    variances = [np.var(v, ddof=1) for v in per_fabric.values() if len(v) > 1]
    if not variances:
        raise ValueError("need at least one fabric with two or more silhouettes")
    return float(np.sqrt(np.mean(variances)))


def slopes(fabrics=CALIBRATION_FABRICS, data=DATA, presets=os.path.join(ROOT, "assets", "presets")):
    """{fabric: dDC/dlog(bending scale)} at each fabric's shipped bdp preset, at its fitted stretching (before the
    node search's scaling: L is defined there), on its training image (capture 1 of its training sample)."""
    from drapelab import infer
    with open(os.path.join(data, "manifest.csv")) as f:
        rows = list(csv.DictReader(f))
    out = {}
    for fabric in fabrics:
        found = [p for p in os.listdir(presets) if p.startswith(f"fabric_{fabric:02d}_") and p.endswith("_bdp.json")]
        if not found:
            raise FileNotFoundError(f"no shipped bdp preset of fabric {fabric} in {presets}")
        preset = infer.load_preset(os.path.join(presets, found[0]))
        sample = int(preset.get("fabric", {}).get("training_sample") or 1)
        image = [r for r in rows if int(r["fabric"]) == fabric and int(r["sample"]) == sample and r["capture"] == "1"][0]
        out[fabric] = infer.calibrate_preset(preset, [os.path.join(data, image["silhouette"])])["calibration"]["slope_dc_per_log_fit"]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fabrics", default=",".join(map(str, CALIBRATION_FABRICS)))
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    paths.require_cusick_dataset()  # after parsing: --help works without the dataset
    fabrics = tuple(int(f) for f in args.fabrics.split(","))
    per = drape_coefficients(fabrics)
    slope = slopes(fabrics)
    sd = {f: float(np.std(v, ddof=1)) for f, v in per.items()}
    result = {"fabrics": {str(f): {"silhouettes": len(v), "mean": float(np.mean(v)), "sd": sd[f],
                                   "slope_dc_per_log": slope[f], "log_sd": sd[f] / slope[f]}
                          for f, v in sorted(per.items())},
              "pooled_sd": pooled_sd(per)}
    result["pooled_log_sd"] = float(np.median([r["log_sd"] for r in result["fabrics"].values()]))
    result["rms_log_sd"] = float(np.sqrt(np.mean([r["log_sd"] ** 2 for r in result["fabrics"].values()])))
    for f, r in result["fabrics"].items():
        print(f"fabric {f}: {r['silhouettes']} drapes, DC mean {r['mean']:.3f}, sd {r['sd']:.4f}, "
              f"slope {r['slope_dc_per_log']:.3f} per log unit, log sd {r['log_sd']:.3f}")
    print(f"pooled sd {result['pooled_sd']:.4f} (drape coefficient), {result['pooled_log_sd']:.3f} (log bending scale, median; "
          f"root mean square {result['rms_log_sd']:.3f})")
    if args.json:
        measure.write_json(args.json, result)


if __name__ == "__main__":
    main()
