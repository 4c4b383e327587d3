"""`drapelab demo [--out DIR] [--mode dynamic|static] [--mesh-level N] [--steps N]`: drape a Cusick specimen.

Drapes the Cusick specimen circle{N} (default circle3, 2699 vertices: the dataset's template mesh, bundled
in assets/cusick/template_meshes) with the
published Cotton Blue starting tables (density 0.192 kg/m^2), by default 100 implicit Euler steps of 0.05 s
from the flat rest state (--mode static: Newton to equilibrium instead). Writes DIR/drape.obj (the draped
mesh, metres) and DIR/silhouette.png (its orthographic top view at 720 px/m, 256 x 256, centre at the image
centre: the dataset's camera; dark cloth on white like the dataset's silhouettes) and prints the drape
coefficient and node count measured on that silhouette.
"""
import os
import time

# Cotton Blue (fabric 2) measured in the bundled dataset: mean and sd across samples of the drape coefficient
# (shared/data/cusick/README.md, capture 1 of 12 samples).
COTTON_BLUE_MEASURED_DC = (0.643, 0.036)
IMAGE_SIZE = (256, 256)
PROGRESS_FRACTION = 0.2  # print a progress line every 20 % of the steps


def register(subparsers):
    p = subparsers.add_parser("demo", help="drape a Cusick specimen with the Cotton Blue tables",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", default=os.path.join("out", "demo"), metavar="DIR",
                   help="output folder (created; default out/demo)")
    p.add_argument("--mode", choices=["dynamic", "static"], default="dynamic",
                   help="dynamic rollout (default, the paper's) or static equilibrium")
    p.add_argument("--mesh-level", type=int, choices=[1, 2, 3, 4, 5], default=3, metavar="N",
                   help="Cusick mesh circle1..circle5 (297 .. 7496 vertices; default 3)")
    p.add_argument("--steps", type=int, default=100, metavar="N", help="dynamic steps of 0.05 s (default 100)")
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


def run(args):
    from .. import measure, render, sim, tables

    if args.steps < 1:
        raise ValueError(f"--steps must be at least 1, got {args.steps}")
    os.makedirs(args.out, exist_ok=True)
    obj_path = os.path.join(args.out, "drape.obj")
    png_path = os.path.join(args.out, "silhouette.png")
    for path, what in ((obj_path, "OBJ"), (png_path, "PNG")):
        measure.check_output_path(path, what)

    mesh = sim.cusick_specimen(args.mesh_level)
    source = sim.cusick_template_path(args.mesh_level)
    material = tables.COTTON_BLUE
    model = sim.ClothModel(mesh, density=material.density)
    params = model.parameters(material=material)
    print(f"specimen circle{args.mesh_level}: {model.num_vertices} vertices, {model.num_faces} faces, "
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

    sim.write_obj(obj_path, x, model.faces)
    camera = render.orthographic_camera(measure.DATASET_PX_PER_M, centre=(IMAGE_SIZE[0] / 2, IMAGE_SIZE[1] / 2),
                                        size=IMAGE_SIZE)
    mask = render.hard_silhouette(camera, x, model.faces)
    measure.write_image(png_path, 1.0 - mask)
    dc = measure.drape_coefficient(mask, measure.DATASET_PX_PER_M, support_radius=model.support_radius)
    nodes = measure.node_count(measure.r_theta(mask, measure.calibration()))
    mean, sd = COTTON_BLUE_MEASURED_DC
    print(f"drape coefficient {dc:.3f}, {nodes} nodes (measured Cotton Blue in the dataset: {mean} +- {sd})")
    print(f"wrote {obj_path}, {png_path}")
    return 0


class _StaticPrinter:
    """Prints every 25th Newton iteration (their number is not known in advance)."""

    def __init__(self):
        self.t0 = time.perf_counter()

    def __call__(self, done, total):
        if done % 25 == 0:
            print(f"  Newton iteration {done} ({time.perf_counter() - self.t0:.1f} s)", flush=True)
