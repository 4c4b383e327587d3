#!/usr/bin/python3
"""Hem radius of K posterior draws per fabric on the bundled skirt (issue 21's "draws differ less than fabrics").

Usage (from the repository, /usr/bin/python3 with PYTHONPATH=addon:build/python):
    tools/garment_draws.py [--vertices 2000] [--frames 48] [--samples 3] [--motion static] [--json OUT]
Prints one line per draw (hem radius, s/frame, penetration, self-intersections, retried frames) and the spread.
"""
import argparse
import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PRESETS = {"wool": "fabric_05_wool_red_bdp.json", "viscose": "fabric_03_viscose_white_bdp.json"}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--vertices", type=int, default=2000)
    p.add_argument("--frames", type=int, default=48)
    p.add_argument("--samples", type=int, default=3)
    p.add_argument("--motion", default="static")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    from drapelab.garment import material, simulate, skirt
    g = skirt.make_skirt("flared", vertices=a.vertices)
    out = {}
    for name, preset in PRESETS.items():
        draws = material.sample_garment_material(os.path.join(ROOT, "assets", "presets", preset), g, seed=0,
                                                 samples=a.samples)
        out[name] = []
        for k, m in enumerate(draws):
            t = time.time()
            r = simulate.drape(g, m, motion=a.motion, frames=a.frames, keep_frames=False)
            row = {"hem_radius_m": r["hem_radius_m"], "seconds_per_frame": r["seconds_per_frame"],
                   "max_body_penetration_m": r["max_body_penetration_m"],
                   "self_intersections_final": r["self_intersections_final"], "retried_frames": len(r["retries"])}
            out[name].append(row)
            print(name, k, row, f"{time.time() - t:.0f} s", flush=True)
        hems = [r["hem_radius_m"] for r in out[name]]
        print(f"{name}: hem radius spread {max(hems) - min(hems):.4f} m, mean {sum(hems) / len(hems):.4f} m")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
