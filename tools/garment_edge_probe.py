"""Probe for issue 21 (cloth edges against the garment body): body penetration of a `./drapelab drape` run's
frames, vertices AND edges, measured independently of the native edge code.

Reads DIR/sample_00.pc2 (every frame, the garment's vertex order), rebuilds the bundled skirt (--style, --vertices)
for its faces and the dress form's part poses at each frame (garment.body.part_transforms at t = frame / fps), and
computes per frame the clearance of every vertex and of every edge sampled at --samples interior points (the
same clearance as Body.clearance: distance from a part's axis minus its radius, beyond an apex the distance to
it, in the part's frame). Prints one JSON object: the deepest vertex and edge point inside the body over all
frames, the frame of each, the most edges cutting the body in one frame, the least vertex and edge clearance.

    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/garment_edge_probe.py \
        --out /tmp/drape_viscose --vertices 2000 --motion walk
"""
import argparse
import json
import os

import numpy as np


def part_clearance(q, origin, s, r):
    """Clearance (N,) of points q (N, 3) in a part's rest frame (Body.clearance's formula, one part)."""
    d = origin[2] - q[:, 2]
    radial = np.hypot(q[:, 0] - origin[0], q[:, 1] - origin[1])
    rad = np.interp(d, s, r, left=0.0, right=0.0)
    beyond = np.maximum(s[0] - d, d - s[-1])
    return np.where(beyond > 0, np.hypot(radial, beyond), radial - rad)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="the drape's output folder (sample_00.pc2)")
    ap.add_argument("--style", default="flared")
    ap.add_argument("--vertices", type=int, default=2000)
    ap.add_argument("--motion", default="walk")
    ap.add_argument("--fps", type=float, default=24.0)
    ap.add_argument("--samples", type=int, default=31, help="interior points per edge")
    args = ap.parse_args()
    from drapelab.garment import body as bodymod, skirt
    from drapelab.garment.pc2 import read_pc2

    garment = skirt.make_skirt(args.style, vertices=args.vertices)
    frames = read_pc2(os.path.join(args.out, "sample_00.pc2"))
    body = bodymod.make_body()
    f = np.asarray(garment.faces)
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    t = (np.arange(1, args.samples + 1) / (args.samples + 1))[None, :, None]
    poses = bodymod.part_transforms(body, args.motion, np.arange(len(frames)) / args.fps, args.fps)
    out = {"frames": len(frames), "edges": int(len(edges)), "samples_per_edge": args.samples,
           "max_vertex_penetration_m": 0.0, "max_edge_penetration_m": 0.0, "worst_vertex_frame": None,
           "worst_edge_frame": None, "max_edges_cutting_in_a_frame": 0, "min_vertex_clearance_m": np.inf,
           "min_edge_clearance_m": np.inf}
    for k, x in enumerate(np.asarray(frames, dtype=np.float64)):
        pts = x[edges[:, 0], None, :] + t * (x[edges[:, 1]] - x[edges[:, 0]])[:, None, :]  # (E, S, 3)
        cv = np.full(len(x), np.inf)
        ce = np.full(pts.shape[:2], np.inf)
        for p, (origin, s, r) in enumerate(body.profiles):
            R, c = poses[k, p, :3, :3], poses[k, p, :3, 3]
            cv = np.minimum(cv, part_clearance((x - c) @ R, origin, s, r))
            ce = np.minimum(ce, part_clearance((pts.reshape(-1, 3) - c) @ R, origin, s, r).reshape(ce.shape))
        edge_min = ce.min(axis=1)
        out["min_vertex_clearance_m"] = min(out["min_vertex_clearance_m"], float(cv.min()))
        out["min_edge_clearance_m"] = min(out["min_edge_clearance_m"], float(edge_min.min()))
        if -cv.min() > out["max_vertex_penetration_m"]:
            out["max_vertex_penetration_m"], out["worst_vertex_frame"] = float(-cv.min()), k
        if -edge_min.min() > out["max_edge_penetration_m"]:
            out["max_edge_penetration_m"], out["worst_edge_frame"] = float(-edge_min.min()), k
        out["max_edges_cutting_in_a_frame"] = max(out["max_edges_cutting_in_a_frame"], int((edge_min < 0).sum()))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
