"""`drapelab bench --json OUT.json [--meshes 1,2,3] [--steps N] [--fit]`: speed and memory of the simulator, and
the time of one whole fit.

For each Cusick mesh circle1..circle5 (the dataset's template meshes, bundled in assets/), homogeneous model with the Cotton Blue starting tables, in its own
subprocess (so that peak memory is per mesh), with OPENBLAS_NUM_THREADS=1 and OMP_NUM_THREADS=1:
  forward_ms_per_step, backward_ms_per_step   one rollout of --steps implicit Euler steps of 0.05 s from the
                                              flat rest state and its adjoint, in steady state: after one
                                              recorded rollout + backward (a fit's first epoch)
  forward_first_ms_per_step                   that first recorded rollout of the process (it also pays for
                                              the memory of the kept factors, which later rollouts reuse)
  forward_unrecorded_ms_per_step              the same rollout without keeping what the adjoint needs
  epoch_s                                     that rollout + its backward (one training epoch of the paper)
  peak_rss_mb                                 peak resident memory of the process right after that backward
                                              (ru_maxrss; the backward keeps one factor per step)
  factorize_ms                                one numeric CHOLMOD factorisation of the step matrix at the
                                              draped state (median of 5)
  static_solve_ms, static_iterations          Newton to equilibrium from the flat rest state (or
                                              static_error when it does not converge in 200 iterations)
  static_warm_solve_ms, static_warm_iterations  the same from the end of the rollout
  static_adjoint_ms                           its adjoint at the last equilibrium found (one Hessian
                                              factorisation and solve)
Then one row per registered effect (`drapelab effects`), beside the base model's row, each in its own subprocess
on circle3 (or, when --meshes leaves it out, the first mesh listed), every parameter of the effect at its moderate
strength (the registry's value):
  effects: forward_ms_per_step, backward_ms_per_step   as above (steady state, after one recorded rollout +
                                                       backward), and the effect's values
Contact (issue 19), on the effect rows' mesh, in its own subprocess: --contact-draws drapes (default 20; 0 skips) from
random placements (fit.json's placement velocities, seeds 0..N-1) with the contact effects on at their registry
values (disk_contact: 2 cm clamp) beside the same placements without contact, forward + backward timed per step:
  contact: draws, effects, forward_ratio, backward_ratio (contact / contact-free, means over the draws, one run),
           forward_ms_per_step, backward_ms_per_step, base_forward_ms_per_step, base_backward_ms_per_step,
           min_signed_distance_m (the smallest clearance to the disk of a free vertex or a point along a free edge),
           vertices_below_disk_max, intersecting_pairs_max (sim.contact_report of each draw's last state),
           min_self_distance_m (its smallest distance between primitives sharing no vertex, within the mean edge
           length; null if none is that close)
Garments (issue 21), unless --no-garment: the bundled skirt (--garment-vertices, default 6000, flared) on the walking
dress form for --garment-frames (default 48) with our simulator (drapelab.garment.simulate; the stiffest and the
softest shipped presets, wool fabric 5 and viscose fabric 3) and with Blender's own cloth modifier at its default
quality, collisions and self-collision on (tools/blender/blender_cloth_bench.py), each in its own process:
  garment: vertices, frames, ours_seconds_per_frame, blender_cloth_seconds_per_frame,
           ours_vs_blender_cloth_time_ratio (< 1: ours is faster), max_body_penetration_m, self_intersections_final,
           hem_radius_m {wool, viscose}, blender_hem_radius_m
Also the soft renderer's forward and backward (ms, 256 x 256, Gaussian profile, sigma 1 px, median of 10)
on the circle3 drape, and the paper's GPU figures (seconds per step, NVIDIA TITAN Xp) for comparison.
With --fit (or --meshes none --fit), also one whole BDP fit as a user runs it (`fit` with its defaults: fit.json's
default_epochs, then the drape calibration, Monte Carlo lanes on up to 2 cores) of the bundled Cotton Blue
silhouette (assets/cusick, the paper protocol's training image of fabric 2, the slowest of fabrics 1-5 to
calibrate), in its own subprocess, against the 300 s target:
  fit: total_s, training_s, epochs, calibration_s, calibration_sets, threads, target_s, and what the fit
       reached (training IoU, drape coefficient and node count predicted / observed, stretching scale)
Writes the JSON atomically and prints a table. circle4/5 take minutes (the backward is the slow part).
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import time

LEVELS = (1, 2, 3, 4, 5)
_ROOT = os.environ.get("DRAPELAB_ROOT") or os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
    os.path.abspath(__file__)))))
FIT_IMAGE_NAME = "fabric_02/silhouettes/sample_02_capture_1.jpg"  # Cotton Blue, the protocol's training sample
FIT_IMAGE = os.path.join(_ROOT, "assets", "cusick", FIT_IMAGE_NAME)
FIT_TARGET_S = 300.0  # issue 4: one fabric fitted in <= 5 minutes on this 2-core machine
RENDER_LEVEL = 3
EFFECT_LEVEL = 3  # the effect rows' mesh (issue 17: circle3)
RENDER_REPEATS = 10
FACTORIZE_REPEATS = 5
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
# Supplement of Gong, Mao, Wang (CVPR 2024): seconds per simulation step on an NVIDIA TITAN Xp.
# (The paper's smallest mesh is listed with 279 vertices; the dataset's circle1.obj has 297.)
PAPER_GPU = [
    {"vertices": 279, "forward_s_per_step": 0.038, "backward_s_per_step": 0.062},
    {"vertices": 1205, "forward_s_per_step": 0.073, "backward_s_per_step": 0.228},
    {"vertices": 2699, "forward_s_per_step": 0.178, "backward_s_per_step": 0.660},
]


def register(subparsers):
    p = subparsers.add_parser("bench", help="time the simulator, its adjoint and the renderer (single thread)",
                              description=__doc__.split("\n\n", 1)[1],
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", required=True, metavar="OUT.json", help="write the results here")
    p.add_argument("--meshes", default="1,2,3,4,5", metavar="LIST",
                   help="comma-separated mesh levels among 1..5 (default 1,2,3,4,5)")
    p.add_argument("--steps", type=int, default=100, metavar="N", help="rollout steps (default 100)")
    p.add_argument("--no-static", action="store_true", help="skip the static solve and its adjoint")
    p.add_argument("--no-effects", action="store_true",
                   help="skip the rows with each registered effect on (circle3, moderate strength)")
    p.add_argument("--contact-draws", type=int, default=20, metavar="N",
                   help="drapes with contact on (and off) for the contact block (default 20; 0 skips it)")
    p.add_argument("--no-garment", action="store_true", help="skip the garment block (ours against Blender cloth)")
    p.add_argument("--garment-vertices", type=int, default=6000, metavar="N", help="garment block skirt size")
    p.add_argument("--garment-frames", type=int, default=48, metavar="N", help="garment block frames")
    p.add_argument("--fit", action="store_true",
                   help="also time one whole BDP fit of the bundled Cotton Blue silhouette (about 3-4 minutes)")
    p.add_argument("--fit-epochs", type=int, default=None, metavar="N",
                   help="epochs of that fit (default: fit.json default_epochs)")
    p.add_argument("--fit-config", default=None, metavar="FIT.json",
                   help="fit settings for that fit (default addon/drapelab/config/fit.json)")
    p.set_defaults(func=run)


def parse_levels(text):
    if str(text).strip().lower() == "none":
        return []
    try:
        levels = [int(t) for t in str(text).split(",") if t.strip()]
    except ValueError:
        raise ValueError(f"--meshes: expected comma-separated levels among {LEVELS}, got {text!r}") from None
    bad = [v for v in levels if v not in LEVELS]
    if not levels or bad:
        raise ValueError(f"--meshes: expected comma-separated levels among {LEVELS}, got {text!r}")
    return sorted(set(levels))


def single_thread_environment():
    env = dict(os.environ)
    for name in THREAD_VARIABLES:
        env[name] = "1"
    # The child imports drapelab the same way as this process.
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    native_dir = os.path.dirname(sys.modules["drapelab_native"].__file__) if "drapelab_native" in sys.modules else ""
    paths = [here, native_dir] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(p for p in paths if p))
    return env


def run_child(task, env):
    """Runs `python -m drapelab.commands.bench --child TASK-JSON` and returns its result dict."""
    cmd = [sys.executable, "-m", "drapelab.commands.bench", "--child", json.dumps(task)]
    proc = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = [l for l in proc.stdout.splitlines() if l.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"error": f"exit status {proc.returncode}: {tail}"}
    return json.loads(lines[-1])


def run(args):
    from .. import measure

    levels = parse_levels(args.meshes)
    if args.steps < 1:
        raise ValueError(f"--steps must be at least 1, got {args.steps}")
    if not levels and not args.fit:
        raise ValueError("--meshes none: nothing to time (add --fit)")
    if args.fit_epochs is not None and args.fit_epochs < 1:
        raise ValueError(f"--fit-epochs must be at least 1, got {args.fit_epochs}")
    if args.fit_config is not None:
        from .. import infer
        infer.load_config(args.fit_config)  # a bad file fails here, before minutes of simulation
    if args.fit and not os.path.exists(FIT_IMAGE):
        raise ValueError(f"--fit: the bundled silhouette {FIT_IMAGE} is missing")
    measure.check_output_path(args.json, "JSON")
    env = single_thread_environment()
    if levels:
        print(f"drapelab bench: meshes {','.join(f'circle{l}' for l in levels)}, {args.steps} steps, 1 thread "
              f"(one subprocess per mesh)", flush=True)
    results, failed = [], 0
    render = None
    for level in levels:
        t0 = time.perf_counter()
        print(f"  circle{level} ...", end="", flush=True)
        task = {"task": "mesh", "level": level, "steps": args.steps, "static": not args.no_static,
                "render": level == RENDER_LEVEL}
        r = run_child(task, env)
        if "error" in r:
            failed += 1
            print(f" error: {r['error']}", flush=True)
            results.append({"name": f"circle{level}", **r})
            continue
        render = r.pop("render", None) or render
        results.append(r)
        print(f" {time.perf_counter() - t0:.0f} s", flush=True)
    if render is None and levels:
        render = run_child({"task": "render", "level": RENDER_LEVEL}, env)
    effects = None
    if levels and not args.no_effects:
        effects, effect_failures = run_effect_rows(EFFECT_LEVEL if EFFECT_LEVEL in levels else levels[0], args.steps, env)
        failed += effect_failures
    contact = None
    if levels and args.contact_draws > 0:
        level = EFFECT_LEVEL if EFFECT_LEVEL in levels else levels[0]
        t0 = time.perf_counter()
        print(f"  contact on circle{level} ({args.contact_draws} draws) ...", end="", flush=True)
        contact = run_child({"task": "contact", "level": level, "steps": args.steps, "draws": args.contact_draws}, env)
        if "error" in contact:
            failed += 1
            print(f" error: {contact['error']}", flush=True)
        else:
            print(f" {time.perf_counter() - t0:.0f} s", flush=True)
    garment = None
    if levels and not args.no_garment:
        t0 = time.perf_counter()
        print(f"  garment ({args.garment_vertices} vertices, {args.garment_frames} frames, walk) ...", end="",
              flush=True)
        garment = run_garment_block(args.garment_vertices, args.garment_frames, env)
        failed += int("error" in garment)
        print(f" {time.perf_counter() - t0:.0f} s" + (f" error: {garment['error']}" if "error" in garment else ""),
              flush=True)
    fit = None
    if args.fit:
        t0 = time.perf_counter()
        print(f"  fit (bdp, {FIT_IMAGE_NAME}) ...", end="", flush=True)
        fit = run_child({"task": "fit", "epochs": args.fit_epochs, "config": args.fit_config}, env)
        if "error" in fit:
            failed += 1
            print(f" error: {fit['error']}", flush=True)
        else:
            print(f" {time.perf_counter() - t0:.0f} s", flush=True)
    report = {
        "schema": "drapelab.bench/1",
        "threads": 1,
        "steps": args.steps,
        "time_step_s": 0.05,
        "material": "Cotton Blue starting tables (homogeneous), density 0.192 kg/m^2",
        "machine": machine_info(),
        "meshes": results,
        "render": render,
        "paper_gpu": {"device": "NVIDIA TITAN Xp", "source": "Gong, Mao, Wang, CVPR 2024, supplement",
                      "meshes": PAPER_GPU},
    }
    if effects is not None:
        report["effects"] = effects
    if contact is not None:
        report["contact"] = contact
    if garment is not None:
        report["garment"] = garment
    if fit is not None:
        report["fit"] = fit
    measure.write_json(args.json, report)
    print_table(report)
    print(f"wrote {args.json}")
    return 1 if failed else 0


def run_effect_rows(level, steps, env):
    """The base model and each registered effect at its moderate strength on one mesh, one subprocess each."""
    from .. import sim

    names = [None] + [e["name"] for e in sim.effects()]
    print(f"  effects on circle{level} (moderate strength):", end="", flush=True)
    rows, failed = [], 0
    for name in names:
        r = run_child({"task": "effect", "level": level, "steps": steps, "effect": name}, env)
        r.setdefault("name", name or "base")
        if "error" in r:
            failed += 1
        rows.append(r)
        print(f" {r['name']}" + (" (error)" if "error" in r else ""), end="", flush=True)
    print(flush=True)
    return {"mesh": f"circle{level}", "steps": steps, "rows": rows}, failed


def machine_info():
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    from .._native import native
    return {"cpu": cpu, "cores": os.cpu_count(), "load_average_1min": os.getloadavg()[0],
            "python": platform.python_version(),
            "drapelab": getattr(native, "__version__", "?"), "date": time.strftime("%Y-%m-%d")}


def _fmt(value, width, spec):
    return f"{'-' if value is None else format(value, spec):>{width}}"


def _static_cell(r, key):
    if r.get(f"{key}_solve_ms") is None:
        return f"{'no conv.' if r.get(f'{key}_error') else '-':>15}"
    return f"{r[f'{key}_solve_ms']:>9.0f} ({r[f'{key}_iterations']:>3d})"


def print_table(report):
    if report["meshes"]:
        print_mesh_table(report)
    ft = report.get("fit")
    if ft and "error" in ft:
        print(f"fit: error: {ft['error']}")
    elif ft:
        print(f"fit ({ft['model']}, {ft['image']}, {ft['threads']} threads): {ft['total_s']:.0f} s "
              f"(target {ft['target_s']:.0f} s) = {ft['epochs']} epochs {ft['training_s']:.0f} s + calibration "
              f"{ft['calibration_s']:.0f} s ({ft['calibration_sets']} sets of drapes); training IoU "
              f"{ft['training_iou']:.3f}, drape coefficient {ft['dc_predicted']:.3f} (observed {ft['dc_observed']:.3f}), "
              f"nodes {ft['nodes_predicted']:.1f} (observed {ft['nodes_observed']:.1f}), stretching x{ft['stretch_scale']:g}")


def print_mesh_table(report):
    header = (f"{'mesh':<8} {'verts':>6} {'fwd ms/step':>11} {'(first)':>8} {'(no rec.)':>9} {'bwd ms/step':>11} {'factor ms':>9} "
              f"{'static ms (it)':>15} {'warm ms (it)':>15} {'adjoint ms':>10} {'epoch s':>8} {'peak MB':>8}")
    print(header)
    print("-" * len(header))
    for r in report["meshes"]:
        if "error" in r:
            print(f"{r['name']:<8} error: {r['error']}")
            continue
        print(f"{r['name']:<8} {r['vertices']:>6} {r['forward_ms_per_step']:>11.1f} "
              f"{_fmt(r.get('forward_first_ms_per_step'), 8, '.1f')} "
              f"{_fmt(r.get('forward_unrecorded_ms_per_step'), 9, '.1f')} {r['backward_ms_per_step']:>11.1f} "
              f"{r['factorize_ms']:>9.2f} {_static_cell(r, 'static')} {_static_cell(r, 'static_warm')} "
              f"{_fmt(r.get('static_adjoint_ms'), 10, '.1f')} "
              f"{r['epoch_s']:>8.1f} {r['peak_rss_mb']:>8.0f}")
    gpu = report["paper_gpu"]
    print(f"paper ({gpu['device']}), ms per step: " + ", ".join(
        f"{g['vertices']} verts {1000 * g['forward_s_per_step']:.0f} fwd / {1000 * g['backward_s_per_step']:.0f} bwd"
        for g in gpu["meshes"]))
    ef = report.get("effects")
    if ef:
        base = next((r for r in ef["rows"] if r["name"] == "base" and "error" not in r), None)
        print(f"effects on {ef['mesh']} at moderate strength ({ef['steps']} steps), ms per step:")
        for r in ef["rows"]:
            if "error" in r:
                print(f"  {r['name']:<20} error: {r['error']}")
                continue
            ratio = ""
            if base and r is not base:
                ratio = (f"  (x{r['forward_ms_per_step'] / base['forward_ms_per_step']:.2f} / "
                         f"x{r['backward_ms_per_step'] / base['backward_ms_per_step']:.2f} of base)")
            print(f"  {r['name']:<20} fwd {r['forward_ms_per_step']:>8.1f}  bwd {r['backward_ms_per_step']:>8.1f}{ratio}")
    rd = report.get("render") or {}
    if "error" in rd:
        print(f"soft renderer: error: {rd['error']}")
    elif rd:
        print(f"soft renderer ({rd['width']}x{rd['height']}, {rd['faces']} faces, {rd['shape']} circle{rd['level']}): "
              f"forward {rd['forward_ms']:.2f} ms, backward {rd['backward_ms']:.2f} ms (median of {rd['repeats']})")


# ---------------------------------------------------------------- child process
def _peak_rss_mb():
    import resource
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    peak = max(peak, int(line.split()[1]) / 1024.0)
    except OSError:
        pass
    return peak


def _current_rss_mb():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def _time_render(level, positions, faces, shape):
    from .. import render
    t = render.time_soft_render(positions, faces, repeats=RENDER_REPEATS, camera=render.orthographic_camera())
    return {"level": level, "shape": shape, "profile": "gaussian", "sigma_px": 1.0, **dict(t)}


def child_mesh(task):
    import numpy as np

    from .. import sim, tables
    from .._native import native

    level, steps = task["level"], task["steps"]
    mesh = sim.cusick_specimen(level)
    model = sim.ClothModel(mesh, density=tables.COTTON_BLUE.density)
    p = model.parameters(material=tables.COTTON_BLUE)
    h = sim.DEFAULT_TIME_STEP
    out = {"name": f"circle{level}", "vertices": model.num_vertices, "faces": model.num_faces,
           "bending_edges": model.num_bending_edges, "steps": steps,
           "mesh_source": "template"}
    rng = np.random.default_rng(0)
    weights = rng.standard_normal((model.num_vertices, 3))

    model.simulate(p, steps=1, time_step=h)  # solver set-up (symbolic analysis), caches
    model.backward(weights)
    t0 = time.perf_counter()  # the first epoch: its rollout also maps the memory of the kept factors
    model.simulate(p, steps=steps, time_step=h)
    out["forward_first_ms_per_step"] = 1000 * (time.perf_counter() - t0) / steps
    model.backward(weights)
    out["baseline_rss_mb"] = _current_rss_mb()
    t0 = time.perf_counter()
    x = model.simulate(p, steps=steps, time_step=h)
    t1 = time.perf_counter()
    model.backward(weights)
    t2 = time.perf_counter()
    out["peak_rss_mb"] = _peak_rss_mb()
    timing = model.last_result["timing"]
    out["forward_ms_per_step"] = 1000 * (t1 - t0) / steps
    out["backward_ms_per_step"] = 1000 * (t2 - t1) / steps
    out["epoch_s"] = t2 - t0
    out["forward_split_ms_per_step"] = {k: 1000 * v / steps for k, v in timing.items()}
    # The same rollout without recording (what evaluation and warm starts run): no factors kept.
    t0 = time.perf_counter()
    model.simulate(p, steps=steps, time_step=h, record=False)
    out["forward_unrecorded_ms_per_step"] = 1000 * (time.perf_counter() - t0) / steps

    # One numeric factorisation of a step matrix at the draped state (a separate solver: no tape).
    solver = native.ImplicitEuler(model.native)
    A, _ = solver.step_system(x.ravel(), np.zeros(x.size), p, h)
    times = []
    for _ in range(FACTORIZE_REPEATS):
        s = time.perf_counter()
        if not solver.factorize(A):
            raise RuntimeError("step matrix not positive definite")
        times.append(time.perf_counter() - s)
    out["factorize_ms"] = 1000 * float(np.median(times))
    out["factor_mb"] = solver.factor_bytes / 2 ** 20

    if task.get("render"):
        out["render"] = _time_render(level, x, model.faces, "dynamic drape")
    del solver

    if task.get("static", True):
        # Cold: Newton from the flat rest state (the alternative to the rollout). Warm: from the rollout's end
        # (how a fit would use it). The adjoint is timed at the warm equilibrium (else the cold one).
        static = sim.ClothModel(mesh, density=tables.COTTON_BLUE.density)
        adjoint_ready = False
        for key, start in (("static", None), ("static_warm", x)):
            try:
                s = time.perf_counter()
                static.simulate(p, mode="static", positions0=start)
                out[f"{key}_solve_ms"] = 1000 * (time.perf_counter() - s)
                out[f"{key}_iterations"] = static.last_result["iterations"]
                adjoint_ready = True
            except sim.SolverError as e:
                out[f"{key}_error"] = str(e)
                out[f"{key}_solve_ms"] = None
        if adjoint_ready:
            s = time.perf_counter()
            static.backward(weights)
            out["static_adjoint_ms"] = 1000 * (time.perf_counter() - s)
    return out


def child_effect(task):
    """Forward and backward ms per step with one effect on at its moderate strength (or the base model)."""
    import numpy as np

    from .. import sim, tables

    level, steps, name = task["level"], task["steps"], task.get("effect")
    effects = None
    if name:
        spec = next(e for e in sim.effects() if e["name"] == name)
        effects = {name: {q["name"]: q["moderate"] for q in spec["parameters"]}}
    model = sim.ClothModel(sim.cusick_specimen(level), density=tables.COTTON_BLUE.density, effects=effects)
    p = model.parameters(material=tables.COTTON_BLUE)  # keeps the effect's values
    h = sim.DEFAULT_TIME_STEP
    weights = np.random.default_rng(0).standard_normal((model.num_vertices, 3))
    model.simulate(p, steps=steps, time_step=h)  # first epoch: set-up, the kept factors' memory
    model.backward(weights)
    t0 = time.perf_counter()
    model.simulate(p, steps=steps, time_step=h)
    t1 = time.perf_counter()
    model.backward(weights)
    t2 = time.perf_counter()
    return {"name": name or "base", "values": (effects or {}).get(name, {}), "vertices": model.num_vertices,
            "forward_ms_per_step": 1000 * (t1 - t0) / steps, "backward_ms_per_step": 1000 * (t2 - t1) / steps}


# The support disk as disk_contact builds it (native/src/effects/disk_contact.cpp, contact/distance.hpp): radius
# the support radius, top face 0.5 mm below the flat rest plane, rim rounded with the effect's rim radius.
DISK_TOP_M = -5e-4


def disk_clearance(positions, rest_radius, clamp, rim, radius=0.09, edges=None, samples=64):
    """Signed clearance (m) above the disk's surface (a plate with a rim rounded by `rim`) of each free vertex (rest
    radius >= clamp: disk_contact tests them all) and, with `edges` (E x 2 vertex indices), of points sampled along
    each edge between two free vertices (disk_contact's edge term keeps them out too)."""
    import numpy as np

    x = np.asarray(positions, dtype=float)
    on = rest_radius >= clamp
    inner, zc = radius - rim, DISK_TOP_M - rim

    def signed(q):
        r = np.hypot(q[..., 0], q[..., 1])
        dz = q[..., 2] - zc
        flat = np.where(dz >= 0, q[..., 2] - DISK_TOP_M, zc - rim - q[..., 2])
        return np.where(r <= inner, flat, np.hypot(r - inner, dz) - rim)

    out = [signed(x[on])]
    if edges is not None:
        e = np.asarray(edges)
        e = e[on[e[:, 0]] & on[e[:, 1]]]
        t = np.linspace(0.0, 1.0, samples)[None, :, None]
        for k in range(0, len(e), 512):
            a, b = x[e[k:k + 512, 0]][:, None, :], x[e[k:k + 512, 1]][:, None, :]
            out.append(signed(a + t * (b - a)).min(axis=1))
    return np.concatenate(out)


def child_contact(task):
    """Contact drapes against contact-free ones from the same placements (see the module doc)."""
    import numpy as np

    from .. import infer, sim, tables

    level, steps, draws = task["level"], task["steps"], task["draws"]
    contact_names = [e["name"] for e in sim.effects() if e["name"] in ("disk_contact", "self_contact")]
    effects = {n: {q["name"]: q["moderate"] for q in next(e for e in sim.effects() if e["name"] == n)["parameters"]
                   if q.get("structural")} for n in contact_names}
    mesh = sim.cusick_specimen(level)
    base = sim.ClothModel(mesh, density=tables.COTTON_BLUE.density)
    model = sim.ClothModel(mesh, density=tables.COTTON_BLUE.density, effects=effects)
    pb, pc = base.parameters(material=tables.COTTON_BLUE), model.parameters(material=tables.COTTON_BLUE)
    cfg = infer.load_config()
    placement = cfg.get("placement_noise") or {}
    rest = base.rest_positions
    rest_radius = np.hypot(rest[:, 0], rest[:, 1])
    clamp = effects.get("disk_contact", {}).get("clamp_radius_m", 0.09)
    rim = next(q["off"] for e in sim.effects() if e["name"] == "disk_contact" for q in e["parameters"]
               if q["name"] == "rim_radius_m")
    faces = np.asarray(mesh.faces)
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    weights = np.random.default_rng(0).standard_normal((base.num_vertices, 3))
    times = {"base_f": 0.0, "base_b": 0.0, "f": 0.0, "b": 0.0}
    clearances, below, crossings, self_distances = [], [], [], []
    for seed in range(draws):
        v0 = infer.placement_velocities(rest, np.random.default_rng([seed, 7]), float(placement.get("velocity_m_s", 0.0)),
                                        int(placement.get("angular_modes", 0)))
        for key, m, p in (("base_", base, pb), ("", model, pc)):
            t0 = time.perf_counter()
            x = m.simulate(p, steps=steps, velocities0=v0)
            t1 = time.perf_counter()
            m.backward(weights)
            t2 = time.perf_counter()
            times[key + "f"] += t1 - t0
            times[key + "b"] += t2 - t1
        if "disk_contact" in effects:
            clearances.append(float(disk_clearance(x, rest_radius, clamp, rim, edges=edges).min()))
            below.append(int((disk_clearance(x, rest_radius, clamp, rim) <= 0).sum()))
        report = sim.contact_report(mesh.faces, x)
        crossings.append(report["intersecting_pairs"])
        if np.isfinite(report["min_distance_m"]):
            self_distances.append(float(report["min_distance_m"]))
    n = draws * steps
    return {"mesh": f"circle{level}", "draws": draws, "steps": steps, "effects": effects,
            "forward_ratio": times["f"] / times["base_f"], "backward_ratio": times["b"] / times["base_b"],
            "forward_ms_per_step": 1000 * times["f"] / n, "backward_ms_per_step": 1000 * times["b"] / n,
            "base_forward_ms_per_step": 1000 * times["base_f"] / n,
            "base_backward_ms_per_step": 1000 * times["base_b"] / n,
            "min_signed_distance_m": min(clearances) if clearances else None,
            "vertices_below_disk_max": max(below) if below else None,
            "intersecting_pairs_max": max(crossings) if crossings else None,
            "min_self_distance_m": min(self_distances) if self_distances else None}


GARMENT_STYLE = "flared"
GARMENT_PRESETS = {"wool": "fabric_05_wool_red_bdp.json", "viscose": "fabric_03_viscose_white_bdp.json"}


def run_garment_block(vertices, frames, env):
    """Ours (two presets) and Blender's cloth on the same skirt, body and motion (see the module doc)."""
    import tempfile

    ours = {name: run_child({"task": "garment", "preset": preset, "vertices": vertices, "frames": frames}, env)
            for name, preset in GARMENT_PRESETS.items()}
    out = {"vertices": None, "frames": frames, "style": GARMENT_STYLE, "motion": "walk",
           "hem_radius_m": {n: r.get("hem_radius_m") for n, r in ours.items()}}
    wool = ours["wool"]
    if "error" in wool:
        return {**out, "error": wool["error"]}
    out.update(vertices=wool["vertices"], ours_seconds_per_frame=wool["seconds_per_frame"],
               max_body_penetration_m=max(r.get("max_body_penetration_m", 0) for r in ours.values()),
               self_intersections_final=wool["self_intersections_final"])
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "blender.json")
        cmd = ["blender", "--background", "--factory-startup", "--python-exit-code", "1", "--python",
               os.path.join(_ROOT, "tools", "blender", "blender_cloth_bench.py"), "--", "--json", path,
               "--vertices", str(vertices), "--style", GARMENT_STYLE, "--motion", "walk", "--frames", str(frames)]
        done = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if done.returncode != 0 or not os.path.exists(path):
            return {**out, "error": "blender cloth: " + (done.stdout + done.stderr)[-500:]}
        with open(path) as f:
            blender = json.load(f)
    spf = blender.get("seconds_per_frame_after_first") or blender.get("seconds_per_frame")
    out.update(blender_cloth_seconds_per_frame=spf, blender_hem_radius_m=blender.get("hem_radius_m"),
               ours_vs_blender_cloth_time_ratio=out["ours_seconds_per_frame"] / spf if spf else None,
               blender_cloth=blender)
    return out


def child_garment(task):
    """Our garment simulator on the bundled skirt walking (one preset)."""
    from ..garment import material, simulate, skirt

    g = skirt.make_skirt(GARMENT_STYLE, vertices=task["vertices"])
    m = material.sample_garment_material(os.path.join(_ROOT, "assets", "presets", task["preset"]), g, seed=0)[0]
    r = simulate.drape(g, m, motion="walk", frames=task["frames"], keep_frames=False)
    return {k: r[k] for k in ("vertices", "frames", "seconds_per_frame", "max_body_penetration_m",
                              "min_body_clearance_m", "self_intersections_final", "hem_radius_m", "newton_iterations")}


def child_render(task):
    from .. import sim
    mesh = sim.cusick_specimen(task["level"])
    model = sim.ClothModel(mesh)
    return _time_render(task["level"], model.rest_positions, model.faces, "flat")


def fit_density():
    """The bundled image's area density (kg/m^2) from assets/cusick/manifest.csv."""
    from .. import measure
    for row in measure.load_manifest(os.path.join(_ROOT, "assets", "cusick", "manifest.csv")):
        if os.path.normpath(row["silhouette"]) == os.path.normpath(FIT_IMAGE):
            return float(row["density_kg_m2"])
    raise ValueError(f"assets/cusick/manifest.csv: no row for {FIT_IMAGE_NAME}")


def child_fit(task):
    """One whole `fit` (bdp, defaults) of the bundled Cotton Blue silhouette, timed from the call to the preset."""
    from .. import infer

    config = infer.load_config(task.get("config"))
    density = fit_density()
    t0 = time.perf_counter()
    preset = infer.fit([FIT_IMAGE], density, model="bdp", epochs=task.get("epochs"), seed=0, config=config)
    total = time.perf_counter() - t0
    t = preset["training"]
    c = preset.get("calibration") or {}
    return {"model": "bdp", "image": FIT_IMAGE_NAME, "density_kg_m2": density, "threads": min(os.cpu_count() or 1, 2),
            "total_s": total, "training_s": t["seconds"], "epochs": t["epochs"],
            "calibration_s": c.get("seconds", 0.0), "calibration_sets": len(c.get("evaluated", [])),
            "target_s": FIT_TARGET_S, "training_iou": preset["metrics"]["training_image"]["iou"],
            "dc_observed": c.get("dc_observed", float("nan")), "dc_predicted": c.get("dc_predicted", float("nan")),
            "nodes_observed": c.get("nodes_observed", float("nan")),
            "nodes_predicted": c.get("nodes_predicted", float("nan")), "stretch_scale": c.get("stretch_scale", 1.0),
            "mesh_level": preset["simulation"]["mesh_level"]}


def child_main(argv):
    task = json.loads(argv[argv.index("--child") + 1])
    kinds = {"mesh": child_mesh, "render": child_render, "fit": child_fit, "effect": child_effect,
             "contact": child_contact, "garment": child_garment}
    result = kinds[task["task"]](task)
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(child_main(sys.argv))
