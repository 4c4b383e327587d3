"""`drapelab demo [--out DIR] [--time-budget SECONDS] [--specimen-only] [--mode dynamic|static] [--mesh-level N]
[--steps N] [--blender PATH]`: the whole story in one command, within a time budget.

1. Drapes the Cusick specimen circle{N} (default circle3, 2699 vertices: the dataset's template mesh, bundled in
   assets/cusick/template_meshes) with the published Cotton Blue starting tables (density 0.192 kg/m^2), by
   default 100 implicit Euler steps of 0.05 s from the flat rest state (--mode static: Newton to equilibrium
   instead). Writes DIR/drape.obj (the draped mesh, metres) and DIR/silhouette.png (its orthographic top view at
   720 px/m, 256 x 256, centre at the image centre: the dataset's camera; dark cloth on white like the dataset's
   silhouettes) and prints the drape coefficient and node count measured on that silhouette.
2. Fits a BDP posterior to the bundled Cotton Blue photo (assets/cusick/fabric_02/silhouettes/
   sample_02_capture_1.jpg, the README quick start's) with a short time budget: DIR/fit.json, a preset.
3. Diagnoses that preset against the photo (drapelab diagnose): DIR/diagnosis/ (index.html, diagnosis.json).
4. Drapes the fitted preset on the bundled circle skirt on the dress form in Blender and renders it
   (tools/blender/drape_skirt.py: Apply Material, Simulate, Cycles): DIR/skirt.png, and DIR/skirt.blend with the
   bake's cache in DIR/drapelab_cache/ (open it in Blender and play the timeline). Without Blender (or without
   the clone's tools/) this step is skipped, saying so.

--time-budget (default 240 s) covers the whole demo from the command's start: the specimen drape (not
shortened), then the rest split between the render (30 %, 22-75 s), the diagnosis (15 %, 10-40 s) and the fit
(what is left; on circle2 with the drape calibration from 100 s, else on circle1, with the calibration from 60 s
when it fits). If a step runs past what is left, it is stopped at the budget's end (a stopped diagnosis writes
what it did; a stopped fit ends the demo). DIR/demo.json records each step's time and outputs.
--specimen-only runs step 1 alone (seconds). Ctrl-C stops the step running and exits 130.
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time

# Cotton Blue (fabric 2) measured in the bundled dataset: mean and sd across samples of the drape coefficient
# (shared/data/cusick/README.md, capture 1 of 12 samples).
COTTON_BLUE_MEASURED_DC = (0.643, 0.036)
IMAGE_SIZE = (256, 256)
PROGRESS_FRACTION = 0.2  # print a progress line every 20 % of the steps
FIT_IMAGE = ("cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")  # under the assets folder

DEFAULT_BUDGET_S = 240.0
MIN_BUDGET_S = 40.0       # below this the steps after the specimen drape cannot all run
RESERVE_S = 2.0           # kept at the end for demo.json and the summary
RENDER_SHARE, RENDER_MIN_S, RENDER_MAX_S = 0.30, 22.0, 75.0        # Blender: start, scene, bake, Cycles
RENDER_FLOOR_S = 16.0     # less than this left for the render skips it (Blender's start, the scene, a frame, Cycles)
DIAGNOSE_SHARE, DIAGNOSE_MIN_S, DIAGNOSE_MAX_S = 0.15, 10.0, 40.0
DIAGNOSE_SAMPLES = 4      # posterior draws of the diagnosis (at least 3)
FIT_CIRCLE2_MIN_S = 100.0   # a fit budget from which the fit runs on circle2 (fit.json's mesh) instead of circle1
FIT_CALIBRATION_MIN_S = 60.0  # ... and from which it tries the drape calibration (on the fit's own mesh)
SKIRT_VERTICES, SKIRT_FRAMES = 1000, 48   # the render's skirt and the most frames it bakes (the budget stops it)
RENDER_SIZE, RENDER_SAMPLES = "480x480", 16
BLENDER_LINES = ("drape_skirt:", "Info:", "Error", "Traceback", "RuntimeError", "  File")


def register(subparsers):
    p = subparsers.add_parser("demo", help="the whole story: drape a specimen, fit a photo, diagnose, render a skirt",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", default=os.path.join("out", "demo"), metavar="DIR",
                   help="output folder (created; default out/demo)")
    p.add_argument("--time-budget", type=float, default=DEFAULT_BUDGET_S, metavar="SECONDS",
                   help=f"the whole demo's time (default {DEFAULT_BUDGET_S:g} s, at least {MIN_BUDGET_S:g} s)")
    p.add_argument("--specimen-only", action="store_true", help="only step 1, the Cusick specimen drape")
    p.add_argument("--mode", choices=["dynamic", "static"], default="dynamic",
                   help="specimen drape: dynamic rollout (default, the paper's) or static equilibrium")
    p.add_argument("--mesh-level", type=int, choices=[1, 2, 3, 4, 5], default=3, metavar="N",
                   help="specimen drape: Cusick mesh circle1..circle5 (297 .. 7496 vertices; default 3)")
    p.add_argument("--steps", type=int, default=100, metavar="N",
                   help="specimen drape: dynamic steps of 0.05 s (default 100)")
    p.add_argument("--blender", default="blender", metavar="PATH", help="Blender for the render (default: on PATH)")
    p.set_defaults(func=run)


class _ProgressPrinter:
    """Prints a line when a rollout crosses each PROGRESS_FRACTION of its steps (not every step)."""

    def __init__(self, what):
        self.what, self.next, self.t0 = what, PROGRESS_FRACTION, time.perf_counter()

    def __call__(self, done, total):
        if done >= total * self.next - 1e-9 or done == total:
            while self.next <= done / total + 1e-9:
                self.next += PROGRESS_FRACTION
            print(f"  {self.what} {done}/{total} ({time.perf_counter() - self.t0:.1f} s)", flush=True)


class _StaticPrinter:
    """Prints every 25th Newton iteration (their number is not known in advance)."""

    def __init__(self):
        self.t0 = time.perf_counter()

    def __call__(self, done, total):
        if done % 25 == 0:
            print(f"  Newton iteration {done} ({time.perf_counter() - self.t0:.1f} s)", flush=True)


class _Clock:
    """The demo's budget: seconds left, and a cancel Event set by Ctrl-C or when the budget (less the reserve) ends."""

    def __init__(self, budget):
        self.t0, self.budget = time.monotonic(), budget
        self.cancel = threading.Event()
        self.expired = threading.Event()
        self.interrupted = False
        self._timer = None
        if budget is not None:
            self._timer = threading.Timer(max(0.0, budget - RESERVE_S), self._expire)
            self._timer.daemon = True
            self._timer.start()

    def _expire(self):
        self.expired.set()
        self.cancel.set()

    def interrupt(self, *_):
        self.interrupted = True
        self.cancel.set()

    def elapsed(self):
        return time.monotonic() - self.t0

    def left(self):
        """Seconds left for steps (the budget less the time spent and the reserve)."""
        return self.budget - RESERVE_S - self.elapsed()

    def stop(self):
        if self._timer is not None:
            self._timer.cancel()


def check_budget(budget):
    import math
    if not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0):
        raise ValueError(f"--time-budget: must be a positive number of seconds, got {budget}")
    if budget < MIN_BUDGET_S:
        raise ValueError(f"--time-budget {budget:g} s: the whole demo needs at least {MIN_BUDGET_S:g} s (fit, "
                         "diagnosis and render after the specimen drape); --specimen-only drapes the specimen alone")
    return float(budget)


def prepare_out(out):
    """Creates the output folder; OSError naming it and the reason when it cannot be made or written."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise OSError(f"--out {out}: exists and is not a folder")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        raise OSError(f"--out {out}: cannot create the output folder: {e.strerror or e}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise OSError(f"--out {out}: the output folder is not writable")


def run(args):
    from .. import measure

    if args.steps < 1:
        raise ValueError(f"--steps must be at least 1, got {args.steps}")
    budget = None if args.specimen_only else check_budget(args.time_budget)
    prepare_out(args.out)
    outputs = {name: os.path.join(args.out, name) for name in ("drape.obj", "silhouette.png", "fit.json",
                                                               "demo.json", "skirt.png", "skirt.blend")}
    for name in (("drape.obj", "silhouette.png") if args.specimen_only else outputs):
        measure.check_output_path(outputs[name], name)
    clock = _Clock(budget)
    if args.specimen_only:
        specimen_step(args, outputs, "")
        return 0
    previous = signal.signal(signal.SIGINT, clock.interrupt)
    steps = []
    try:
        code = _story(args, outputs, clock, steps)
    finally:
        signal.signal(signal.SIGINT, previous)
        clock.stop()
    summary = {"time_budget_s": budget, "seconds": round(clock.elapsed(), 2), "steps": steps,
               "out": os.path.abspath(args.out)}
    measure.write_json(outputs["demo.json"], summary)
    print(f"demo: {sum(s['status'] == 'done' for s in steps)} of 4 steps done in {clock.elapsed():.1f} s of the "
          f"{budget:g} s budget; wrote {outputs['demo.json']}", flush=True)
    return code


def _story(args, outputs, clock, steps):
    def record(name, t0, status, files=(), **extra):
        steps.append({"step": name, "status": status, "seconds": round(time.monotonic() - t0, 2),
                      "outputs": [os.path.abspath(f) for f in files if os.path.exists(f)], **extra})

    t = time.monotonic()
    dc, nodes = specimen_step(args, outputs, "[1/4] ")
    record("specimen drape", t, "done", (outputs["drape.obj"], outputs["silhouette.png"]), drape_coefficient=dc,
           nodes=nodes)
    if clock.cancel.is_set():
        return _stopped(clock, "after the specimen drape")

    left = clock.left()
    render_s = min(RENDER_MAX_S, max(RENDER_MIN_S, RENDER_SHARE * left))
    diagnose_s = min(DIAGNOSE_MAX_S, max(DIAGNOSE_MIN_S, DIAGNOSE_SHARE * left))
    fit_s = left - render_s - diagnose_s
    print(f"time budget {clock.budget:g} s: {clock.elapsed():.1f} s used; fit {fit_s:.0f} s, diagnosis "
          f"{diagnose_s:.0f} s, skirt render {render_s:.0f} s", flush=True)
    t = time.monotonic()
    try:
        fitted = fit_step(outputs["fit.json"], fit_s, clock)
    except _Stop as e:
        record("fit", t, "stopped")
        return _stopped(clock, str(e))
    record("fit", t, "done", (outputs["fit.json"],), **fitted)

    t = time.monotonic()
    report = os.path.join(args.out, "diagnosis")
    left = clock.left() - render_s
    if left < 0.5 * DIAGNOSE_MIN_S:
        print(f"[3/4] diagnosis skipped: {max(0.0, left):.0f} s of the budget left for it", flush=True)
        record("diagnose", t, "skipped")
    else:
        verdict = diagnose_step(outputs["fit.json"], report, left, clock)
        status = "stopped" if clock.cancel.is_set() else "done"
        record("diagnose", t, status, (os.path.join(report, "index.html"), os.path.join(report, "diagnosis.json")),
               verdict=verdict)
        if clock.interrupted:
            return _stopped(clock, "during the diagnosis")

    t = time.monotonic()
    status, detail = render_step(args, outputs, clock)
    record("skirt render", t, status, (outputs["skirt.png"], outputs["skirt.blend"]), detail=detail)
    if clock.interrupted:
        return _stopped(clock, "during the render")
    return 1 if status == "failed" else 0


class _Stop(Exception):
    """A step stopped by the budget's end or Ctrl-C: the demo ends there."""


def _stopped(clock, where):
    if clock.interrupted:
        print(f"demo: interrupted {where}", file=sys.stderr, flush=True)
        return 130
    print(f"demo: the time budget ({clock.budget:g} s) ran out {where}; give a larger --time-budget",
          file=sys.stderr, flush=True)
    return 1


# ---------------------------------------------------------------- 1. the Cusick specimen
def specimen_step(args, outputs, prefix):
    from .. import measure, render, sim, tables

    mesh = sim.cusick_specimen(args.mesh_level)
    source = sim.cusick_template_path(args.mesh_level)
    material = tables.COTTON_BLUE
    model = sim.ClothModel(mesh, density=material.density)
    params = model.parameters(material=material)
    print(f"{prefix}specimen circle{args.mesh_level}: {model.num_vertices} vertices, {model.num_faces} faces, "
          f"{model.num_bending_edges} bending edges ({source})")
    print(f"material: {material.name} starting tables, density {material.density} kg/m^2")

    t0 = time.perf_counter()
    if args.mode == "dynamic":
        print(f"dynamic drape: {args.steps} implicit Euler steps of {sim.DEFAULT_TIME_STEP} s", flush=True)
        x = model.simulate(params, mode="dynamic", steps=args.steps, time_step=sim.DEFAULT_TIME_STEP,
                           record=False, progress=_ProgressPrinter("step"))
        detail = f"{1000 * (time.perf_counter() - t0) / args.steps:.0f} ms per step"
    else:
        print("static drape: Newton to equilibrium", flush=True)
        x = model.simulate(params, mode="static", progress=_StaticPrinter())
        r = model.last_result
        detail = f"{r['iterations']} Newton iterations, residual {r['residual']:.1e} of a vertex weight"
    print(f"draped in {time.perf_counter() - t0:.1f} s ({detail})")

    obj_path, png_path = outputs["drape.obj"], outputs["silhouette.png"]
    sim.write_obj(obj_path, x, model.faces)
    camera = render.orthographic_camera(measure.DATASET_PX_PER_M, centre=(IMAGE_SIZE[0] / 2, IMAGE_SIZE[1] / 2),
                                        size=IMAGE_SIZE)
    mask = render.hard_silhouette(camera, x, model.faces)
    measure.write_image(png_path, 1.0 - mask)
    dc = measure.drape_coefficient(mask, measure.DATASET_PX_PER_M, support_radius=model.support_radius)
    nodes = measure.node_count(measure.r_theta(mask, measure.calibration()))
    mean, sd = COTTON_BLUE_MEASURED_DC
    print(f"drape coefficient {dc:.3f}, {nodes} nodes (measured Cotton Blue in the dataset: {mean} +- {sd})")
    print(f"wrote {obj_path}, {png_path}", flush=True)
    return float(dc), int(nodes)


# ---------------------------------------------------------------- 2. fit the bundled photo
def fit_image():
    from .. import paths
    return os.path.join(paths.assets_dir(), *FIT_IMAGE)


def _fabric(image):
    """(name, density kg/m^2, thickness mm) of the bundled image from the assets' manifest."""
    from .. import measure, paths
    for row in measure.load_manifest(os.path.join(paths.assets_dir(), "cusick", "manifest.csv")):
        if os.path.realpath(row["silhouette"]) == os.path.realpath(image):
            return row["name"], row["density_kg_m2"], row["thickness_mm"]
    raise FileNotFoundError(f"{image}: not in the bundled assets' manifest.csv")


def fit_step(out, budget_s, clock):
    """A BDP fit of the bundled photo into `out` within budget_s seconds (module doc for the settings)."""
    from .. import infer

    image = fit_image()
    name, density, thickness = _fabric(image)
    level = 2 if budget_s >= FIT_CIRCLE2_MIN_S else 1
    calibrate = budget_s >= FIT_CALIBRATION_MIN_S
    print(f"[2/4] fit: bdp posterior of {name} ({density} kg/m^2) to {image} on circle{level}, time budget "
          f"{budget_s:.0f} s", flush=True)

    def progress(e):
        print(f"  epoch {e['epoch']:3d}  loss {e['loss']:.4f}  IoU {e['iou']:.4f}  MSE {e['mse']:.4f}  "
              f"{e['seconds']:.1f} s", flush=True)

    def calibration_progress(c):
        print(f"  drape calibration {c['evaluation']}: drape coefficient {c['dc']:.3f} (observed "
              f"{c['dc_observed']:.3f}), nodes {c['nodes']:.1f} (observed {c['nodes_observed']:.1f})", flush=True)

    def plan_progress(p):
        print(f"  plan: set-up {p['setup_s']:.1f} s, epochs {p['epochs_s']:.1f} s" +
              (f", drape calibration {p['calibration_s']:.1f} s" if p["calibration_sets"][1] else ""), flush=True)

    t0 = time.monotonic()
    while True:
        config = infer.load_config()
        config["mesh_level"] = level
        config["calibration"] = dict(config.get("calibration") or {}, mesh_level=None, enabled=calibrate)
        remaining = budget_s - (time.monotonic() - t0)
        try:
            preset = infer.fit([image], density, model="bdp", time_budget=remaining, seed=0, out=out,
                               progress=progress, calibration_progress=calibration_progress,
                               plan_progress=plan_progress, cancel_event=clock.cancel, config=config,
                               fabric={"name": name, "thickness_mm": thickness})
            break
        except infer.Cancelled:
            raise _Stop("during the fit (no preset written)") from None
        except infer.InputError as e:
            if "too small" not in str(e):
                raise
            if not calibrate:
                raise infer.InputError(f"--time-budget {clock.budget:g} s leaves the fit {budget_s:.0f} s, too little "
                                       f"on this machine now ({e}); give the demo a larger --time-budget") from None
            print(f"  the drape calibration does not fit in this budget on this machine now ({e}); fitting without "
                  "it", flush=True)
            calibrate = False
    t = preset["training"]
    m = preset["metrics"]["training_image"]
    c = preset.get("calibration")
    print(f"  wrote {out}: {t['epochs']} epochs, training IoU {m['iou']:.4f}" +
          (f", drape coefficient calibrated to {c['dc_predicted']:.3f} (observed {c['dc_observed']:.3f})" if c
           else ", without the drape calibration") + f" ({time.monotonic() - t0:.1f} s)", flush=True)
    return {"mesh_level": level, "epochs": t["epochs"], "training_iou": m["iou"], "calibrated": bool(c)}


# ---------------------------------------------------------------- 3. diagnose
def diagnose_step(preset, report, budget_s, clock):
    from .. import diagnose

    print(f"[3/4] diagnose: {preset} against the photo, {DIAGNOSE_SAMPLES} posterior draws, time budget "
          f"{budget_s:.0f} s", flush=True)
    result = diagnose.diagnose(preset, [fit_image()], samples=DIAGNOSE_SAMPLES, time_budget=budget_s, seed=0,
                               out_dir=report, progress=lambda e: print(f"  {e['message']}", flush=True),
                               cancel_event=clock.cancel)
    b = result.get("base")
    if b:
        print(f"  base: best-of-{result['draws_used']} MSE {b['mse']:.4f}, IoU {b['iou']:.4f}, |dDC| "
              f"{b['dc_error']:.3f}")
    verdict = result.get("verdict") or ("stopped at the budget's end: the report holds what was done"
                                        if result.get("cancelled") else "")
    print(f"  {verdict}")
    print(f"  wrote {os.path.join(report, 'index.html')} and diagnosis.json", flush=True)
    return verdict


# ---------------------------------------------------------------- 4. the skirt in Blender
def render_step(args, outputs, clock):
    """Runs tools/blender/drape_skirt.py on the fitted preset; returns (status, detail)."""
    from .. import paths

    script = os.path.join(paths.repository_root(), "tools", "blender", "drape_skirt.py")
    blender = shutil.which(args.blender)
    left = clock.left()
    why = None
    if blender is None:
        why = (f"Blender not found ({args.blender!r}; Debian: apt-get install blender, or --blender PATH)")
    elif not os.path.isfile(script):
        why = f"{script} not found (the render needs a clone of the repository)"
    elif left < RENDER_FLOOR_S:
        why = f"{max(0.0, left):.0f} s of the budget left, the render needs at least {RENDER_FLOOR_S:g} s"
    if why:
        print(f"[4/4] skirt render skipped: {why}", flush=True)
        return "skipped", why
    print(f"[4/4] skirt: the fitted preset on the bundled circle skirt on the dress form in Blender (Apply "
          f"Material, Simulate for at most {SKIRT_FRAMES} frames, Cycles), at most {left:.0f} s", flush=True)
    import drapelab_native
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(OPENBLAS_NUM_THREADS=env.get("OPENBLAS_NUM_THREADS", "1"),
               DRAPELAB_NATIVE_DIR=os.path.dirname(os.path.abspath(drapelab_native.__file__)))
    command = [blender, "--background", "--factory-startup", "--python-exit-code", "1", "--python", script, "--",
               "--preset", os.path.abspath(outputs["fit.json"]), "--out", os.path.abspath(outputs["skirt.png"]),
               "--vertices", str(SKIRT_VERTICES), "--frames", str(SKIRT_FRAMES), "--samples", str(RENDER_SAMPLES),
               "--size", RENDER_SIZE, "--time-limit", f"{left:.1f}", "--blend", os.path.abspath(outputs["skirt.blend"])]
    lines = []
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               errors="replace", start_new_session=True)  # Ctrl-C reaches the demo, which stops it

    def read():
        for line in process.stdout:
            lines.append(line.rstrip())
            if line.startswith(BLENDER_LINES) and not line.startswith("Info: Total files"):
                print(f"  {line.rstrip()}", flush=True)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    while process.poll() is None:
        if clock.cancel.is_set():  # Ctrl-C, or the budget's end: Blender is stopped
            process.kill()
            process.wait()
            break
        time.sleep(0.1)
    reader.join(2.0)
    if process.returncode == 0 and os.path.isfile(outputs["skirt.png"]):
        done = next((ln for ln in lines if ln.startswith("drape_skirt: wrote")), "")
        print(f"  wrote {outputs['skirt.png']} and {outputs['skirt.blend']} (its bake in "
              f"{os.path.join(args.out, 'drapelab_cache')})", flush=True)
        return "done", done
    if clock.cancel.is_set():
        why = "interrupted" if clock.interrupted else "the time budget ran out"
        print(f"  Blender stopped: {why}", file=sys.stderr, flush=True)
        return "stopped", why
    tail = "\n".join(lines[-15:])
    print(f"  Blender failed (exit {process.returncode}):\n{tail}", file=sys.stderr, flush=True)
    return "failed", f"exit {process.returncode}"
