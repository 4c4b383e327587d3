#!/usr/bin/python3
"""Where in 3D the model's folds differ from the real ones: the dataset's capture-1 meshes against a preset's draws.

    tools/fold_geometry.py [--fabrics 1,2,3,4,5] [--draws 12] [--seed 0] [--json OUT]

The dataset's 3D reconstructions share circle3's topology (../shared/data/cusick/README.md), so each vertex of a
real drape is a known point of the flat specimen, as in the model's drapes. For every real capture-1 mesh of a
fabric (12 samples) and `--draws` posterior-predictive drapes of its shipped preset (assets/presets, the
evaluation's protocol: dynamic rollout from flat with placement noise), per material ring (the vertices whose rest
radius lies in a 1 cm band around r0 = 9.5 .. 14.5 cm): the mean height z, the mean horizontal radius R, the ring's
fold amplitude (half the peak-to-trough of the radial move R - r0 over the rest angle, smoothed to its first 16
harmonics) and its fold count (maxima of that smoothed profile). Per band of rest radius, the bending edges'
dihedral angles (95th / 99th percentile, degrees): of the edges that run radially (their angle is the hoop
curvature: the folds' crests and troughs) and of those along the hoop (the radial curvature: the fall over the
support's edge); the model's again with `--noise-mm` of vertex noise, for the reconstructions' own noise (0.10-0.15
mm reproduces their hoop angles in the hanging skirt on fabric 4; the statistics: addon/drapelab/fold_geometry.py).
The meshes' in-plane strains are not compared: the reconstructions change triangle areas by -30 .. +40 % (1st / 99th
percentile on fabric 1), far beyond what a woven cotton stretches, so their in-plane lengths are not measurements;
positions and fold shapes are (IoU 0.94-0.98 against the silhouettes).
Run with ./drapelab's environment: `PYTHONPATH=addon:build/python /usr/bin/python3 tools/fold_geometry.py`.
"""
import argparse
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "addon"))
import numpy as np  # noqa: E402

from drapelab import infer, paths, sim  # noqa: E402
from drapelab.fold_geometry import RECONSTRUCTION_NOISE_M, ring_stats, summarise  # noqa: E402
from paper_protocol import captures, path, slug  # noqa: E402  (tools/, this script's folder)


def with_noise(x, sd, rng):
    """x with isotropic Gaussian noise of sd [m] on every vertex: what a reconstruction's noise does to the angles."""
    return x + rng.normal(0.0, sd, x.shape)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fabrics", default="1,2,3,4,5")
    ap.add_argument("--draws", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise-mm", type=float, default=RECONSTRUCTION_NOISE_M * 1e3,
                    help="sd of the vertex noise added to the model's drapes for the third column of the angles "
                         "(the reconstructions' own noise: 0.10-0.15 mm matches their hoop angles, fabric 4)")
    ap.add_argument("--json")
    args = ap.parse_args()
    data = paths.cusick_dataset_dir()
    if data is None:
        raise SystemExit("fold_geometry: needs the Cusick dataset (../shared/data/cusick), not found")
    config = infer.load_config()
    result = {}
    for f in (int(s) for s in args.fabrics.split(",")):
        rows = captures(f)
        preset = infer.load_preset(os.path.join(ROOT, "assets", "presets", f"{slug(rows[0])}_bdp.json"))
        pred = infer._Predictive(preset, (256, 256), 2, config, mesh_level=3)
        model = pred.models[0]
        rest, edges = np.asarray(model.rest_positions), np.asarray(model.bending_edges)
        real = []
        for r in rows:
            x = np.asarray(sim.read_obj(path(r["mesh"])).positions, dtype=float).reshape(-1, 3)
            if len(x) != len(rest):
                raise SystemExit(f"fold_geometry: fabric {f} sample {r['sample']}: {len(x)} vertices, circle3 has "
                                 f"{len(rest)}")
            real.append(ring_stats(x, rest, edges))
        draws = infer.preset_bend_samples(preset, pred.num_edges, np.random.default_rng(args.seed), args.draws)
        shapes = [s for s in pred.drape(draws, args.seed) if "x" in s]
        model_stats = [ring_stats(s["x"], rest, edges) for s in shapes]
        rng = np.random.default_rng([args.seed, 7])
        noisy = [ring_stats(with_noise(s["x"], args.noise_mm * 1e-3, rng), rest, edges) for s in shapes]
        result[f] = {"real": summarise(real), "model": summarise(model_stats), "model_noise": summarise(noisy),
                     "noise_mm": args.noise_mm, "draws": len(shapes)}
        print(f"fabric {f} ({len(shapes)} draws, 12 real meshes)")
        print("  r0 cm |   z real / model mm |   R real / model mm | amplitude real / model mm | folds real / model")
        for a, b in zip(result[f]["real"]["rings"], result[f]["model"]["rings"]):
            print(f"  {a['r0'] * 100:5.1f} | {a['z'][0] * 1e3:7.1f} / {b['z'][0] * 1e3:7.1f} | "
                  f"{a['R'][0] * 1e3:7.1f} / {b['R'][0] * 1e3:7.1f} | {a['amplitude'][0] * 1e3:5.1f} +- "
                  f"{a['amplitude'][1] * 1e3:4.1f} / {b['amplitude'][0] * 1e3:5.1f} +- "
                  f"{b['amplitude'][1] * 1e3:4.1f} | "
                  f"{a['folds'][0]:4.1f} / {b['folds'][0]:4.1f}")
        print(f"  hinge angles (deg): band | crest p95 / p99 real, model, model + {args.noise_mm:g} mm noise | "
              "hoop p95 real, model, model + noise")
        for a, b, c in zip(*(result[f][k]["bands"] for k in ("real", "model", "model_noise"))):
            print(f"  {a['r0'][0] * 100:.0f}-{a['r0'][1] * 100:.0f} cm | " + ", ".join(
                f"{e['crest_p95'][0]:4.1f} / {e['crest_p99'][0]:4.1f}" for e in (a, b, c)) + " | " + ", ".join(
                f"{e['hoop_p95'][0]:4.1f}" for e in (a, b, c)), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main()
