"""Probe for issue 19 (disk_contact's edge term): the bench's contact block (drapelab bench --contact-draws,
addon/drapelab/commands/bench.py child_contact) plus the clearance of every cloth EDGE to the support disk.

For N draws (random placements, seeds 0..N-1, as the bench) on circle<L>: a contact-free rollout and one with
disk_contact (2 cm clamp) + self_contact at their registry values, forward + backward timed; of each contact
drape's last state: the smallest clearance of any free vertex (all of them, not only those over the disk) and of
any free edge (segment minimum by dense sampling, 400 points per edge, for the edges within 5 mm) to the disk.
Prints one JSON object. Run against a build with PYTHONPATH=addon:build/python (before/after comparisons: the
other tree's addon and build).

    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/disk_edge_probe.py --draws 20
"""
import argparse
import json
import time

import numpy as np

DISK_TOP_M = -5e-4  # disk_contact's top face: 0.5 mm below the flat rest plane


def disk_distance(x, rim, radius=0.09):
    """Distance (m) of points x (..., 3) to the support disk (contact/distance.hpp SupportDisk)."""
    inner, zc = radius - rim, DISK_TOP_M - rim
    r = np.hypot(x[..., 0], x[..., 1])
    dz = x[..., 2] - zc
    flat = np.abs(dz) - rim
    rounded = np.hypot(r - inner, dz) - rim
    return np.where(r <= inner, flat, rounded)


def edge_clearance(x, edges, rim, samples=400):
    """Smallest distance of the segments `edges` (E, 2) of positions x (V, 3) to the disk, by sampling."""
    a, b = x[edges[:, 0]], x[edges[:, 1]]
    near = np.minimum(disk_distance(a, rim), disk_distance(b, rim)) - 0.5 * np.linalg.norm(b - a, axis=1) < 5e-3
    a, b = a[near], b[near]
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    best = np.inf
    for k in range(0, len(a), 256):
        pts = a[k:k + 256, None, :] + t * (b[k:k + 256, None, :] - a[k:k + 256, None, :])
        best = min(best, float(disk_distance(pts, rim).min()))
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--level", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0, help="draws use seeds first-seed .. first-seed + draws - 1")
    args = ap.parse_args()
    from drapelab import infer, sim, tables

    names = [e["name"] for e in sim.effects() if e["name"] in ("disk_contact", "self_contact")]
    effects = {n: {q["name"]: q["moderate"] for q in next(e for e in sim.effects() if e["name"] == n)["parameters"]
                   if q.get("structural")} for n in names}
    rim = next(q["off"] for e in sim.effects() if e["name"] == "disk_contact" for q in e["parameters"]
               if q["name"] == "rim_radius_m")
    clamp = effects["disk_contact"]["clamp_radius_m"]
    mesh = sim.cusick_specimen(args.level)
    base = sim.ClothModel(mesh, density=tables.COTTON_BLUE.density)
    model = sim.ClothModel(mesh, density=tables.COTTON_BLUE.density, effects=effects)
    pb, pc = base.parameters(material=tables.COTTON_BLUE), model.parameters(material=tables.COTTON_BLUE)
    placement = infer.load_config().get("placement_noise") or {}
    rest = base.rest_positions
    free = np.hypot(rest[:, 0], rest[:, 1]) >= clamp
    f = np.asarray(mesh.faces)
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    edges = edges[free[edges[:, 0]] & free[edges[:, 1]]]
    weights = np.random.default_rng(0).standard_normal((base.num_vertices, 3))
    times = {"base_f": 0.0, "base_b": 0.0, "f": 0.0, "b": 0.0}
    vertex_min, edge_min, iterations, cuts = [], [], [], []
    for seed in range(args.first_seed, args.first_seed + args.draws):
        v0 = infer.placement_velocities(rest, np.random.default_rng([seed, 7]), float(placement.get("velocity_m_s", 0.0)),
                                        int(placement.get("angular_modes", 0)))
        for key, m, p in (("base_", base, pb), ("", model, pc)):
            t0 = time.perf_counter()
            x = m.simulate(p, steps=args.steps, velocities0=v0)
            t1 = time.perf_counter()
            m.backward(weights)
            t2 = time.perf_counter()
            times[key + "f"] += t1 - t0
            times[key + "b"] += t2 - t1
        timing = model.last_result["timing"]
        iterations.append(int(timing["newton_iterations"]))
        cuts.append(int(timing["cut_iterations"]))
        x = np.asarray(x).reshape(-1, 3)
        vertex_min.append(float(disk_distance(x[free], rim).min()))
        edge_min.append(edge_clearance(x, edges, rim))
    n = args.draws * args.steps
    print(json.dumps({"mesh": f"circle{args.level}", "draws": args.draws, "steps": args.steps, "effects": effects,
                      "edges": int(len(edges)),
                      "forward_ratio": times["f"] / times["base_f"], "backward_ratio": times["b"] / times["base_b"],
                      "forward_ms_per_step": 1000 * times["f"] / n, "backward_ms_per_step": 1000 * times["b"] / n,
                      "base_forward_ms_per_step": 1000 * times["base_f"] / n,
                      "base_backward_ms_per_step": 1000 * times["base_b"] / n,
                      "min_vertex_clearance_m": min(vertex_min), "min_edge_clearance_m": min(edge_min),
                      "edge_clearance_per_draw_m": edge_min,
                      "newton_iterations_per_draw": iterations, "cut_iterations_per_draw": cuts}, indent=1))


if __name__ == "__main__":
    main()
