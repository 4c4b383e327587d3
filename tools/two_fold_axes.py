#!/usr/bin/python3
"""The 2-fold harmonic of r(theta) (amplitude and axis in degrees mod 180, in measure.r_theta's angle) of every
photo of fabrics 1-5 of the Cusick dataset, per sample and capture: whether the drapes' long axis lies where the
model's material axes put it (0 or 90 degrees). docs/lab/orientation.md.

Usage (from the repository root):
    PYTHONPATH=addon:build/python /usr/bin/python3 tools/two_fold_axes.py [DATA_DIR (default ../shared/data/cusick)]
"""
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))

from drapelab import measure  # noqa: E402


def two_fold(mask):
    """(amplitude m, axis degrees mod 180, counter-clockwise from +x as measure.r_theta's angle) of the
    silhouette's r(theta) 2-fold harmonic (measure.two_fold)."""
    return measure.two_fold(measure.r_theta(np.asarray(mask)))


def main():
    data = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "..", "shared", "data", "cusick")
    rows = measure.load_manifest(os.path.join(data, "manifest.csv"))
    for fab in (1, 2, 3, 4, 5):
        out = []
        for r in rows:
            if r["fabric"] == fab:
                amp, ax = two_fold(measure.load_silhouette(r["silhouette"]).mask)
                out.append((int(r["sample"]), int(r["capture"]), amp * 1e3, ax))
        a = np.array(out)
        print(f"fabric {fab}: {len(a)} photos; 2-fold amplitude median {np.median(a[:, 2]):.1f} mm "
              f"({a[:, 2].min():.1f}-{a[:, 2].max():.1f}); axis [deg] (amplitude [mm]) per capture 1-4:")
        for s in sorted(set(a[:, 0])):
            b = a[a[:, 0] == s]
            print(f"   sample {int(s):2d}: " + " ".join(f"{x:5.0f} ({y:.1f})" for x, y in zip(b[:, 3], b[:, 2])))


if __name__ == "__main__":
    main()
