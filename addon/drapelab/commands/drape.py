"""`drapelab drape --preset P [--garment skirt|OBJ] [--body NAME] [--motion static|walk|twirl|jump] [--frames N]
[--samples K] [--seed S] --out DIR [--render PNG] [--json STATS]`: a digitised fabric on a garment.

Samples K per-element materials from the preset's posterior (drapelab.garment.material, oriented by the garment's
uv grain line) and simulates the garment on the moving body at 24 fps (drapelab.garment.simulate: the Cusick
drapes' cloth model on the garment welded at its seams, the waistband held to the pelvis, IPC contact with the body
and with itself: --thickness MM is self contact's reach, default the preset's fabric thickness, 0 = off). --garment skirt
(default) is the bundled parametric skirt (drapelab.garment.skirt, --style circle|flared|aline, --vertices);
an OBJ garment needs a UV map (its grain line: +v) and a waistband: the vertices within 3 cm of its top.
--body default is the bundled dress form (drapelab.garment.body); other bodies are not supported yet.
Writes, per sample KK: DIR/sample_KK.pc2 (every frame, a Mesh Cache cache growing frame by frame),
DIR/sample_KK_first.obj and DIR/sample_KK_last.obj (with the garment's UVs); --render PNG: the last frame of
sample 00 with the body (matplotlib, shaded); --json STATS: vertices, frames, seconds_per_frame,
max_body_penetration_m, self_intersections_final, hem_radius_m (the first sample's), and per sample in
"samples". Progress on stderr. Ctrl-C keeps the frames done (files and STATS written) and exits with 130.
"""
import os
import signal
import sys
import threading

MOTIONS = ("static", "walk", "twirl", "jump")
STYLES = ("circle", "flared", "aline")


def register(subparsers):
    p = subparsers.add_parser("drape", help="simulate a fabric preset on a garment on a moving body",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--preset", required=True, metavar="P", help="preset file or shipped preset name")
    p.add_argument("--garment", default="skirt", metavar="skirt|OBJ", help="garment (default: the bundled skirt)")
    p.add_argument("--style", choices=STYLES, default="flared", help="bundled skirt style (default flared)")
    p.add_argument("--vertices", type=int, default=6000, metavar="N", help="bundled skirt resolution (default 6000)")
    p.add_argument("--body", default="default", metavar="NAME", help="body (default: the bundled dress form)")
    p.add_argument("--motion", choices=MOTIONS, default="walk", help="body motion (default walk)")
    p.add_argument("--frames", type=int, default=48, metavar="N", help="frames at 24 fps (default 48)")
    p.add_argument("--substeps", type=int, default=None, metavar="S", help="implicit steps per frame (default 4)")
    p.add_argument("--contact-step", choices=("linearised", "newton"), default="linearised",
                   help="each step: one linear solve, as the Cusick fits (default), or IPC's Newton iterations "
                        "(several times slower)")
    p.add_argument("--thickness", type=float, default=None, metavar="MM",
                   help="self contact's reach in mm (default: the preset's fabric thickness; 0: no self contact)")
    p.add_argument("--body-friction", type=float, default=None, metavar="MU",
                   help="Coulomb coefficient between cloth and body (default 0.3; 0: frictionless)")
    p.add_argument("--samples", type=int, default=1, metavar="K", help="material draws (default 1)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="material draws' seed (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--render", default=None, metavar="PNG", help="render the last frame of sample 00")
    p.add_argument("--json", default=None, metavar="STATS", help="write the statistics here")
    p.set_defaults(func=run)


def _garment(args):
    from ..garment import mesh, skirt
    if args.garment == "skirt":
        if args.vertices < 200:
            raise ValueError(f"--vertices: at least 200, got {args.vertices}")
        return skirt.make_skirt(args.style, vertices=args.vertices)
    if not os.path.isfile(args.garment):
        raise ValueError(f"--garment: {args.garment}: no such file (or use 'skirt')")
    g = mesh.read_garment_obj(args.garment)
    if len(g.waist_vertices) == 0:
        from ..garment.simulate import top_band_vertices
        g.waist_vertices = top_band_vertices(g.positions)
    return g


def run(args):
    import numpy as np

    from .. import measure
    from ..garment import body as bodymod, material, simulate
    from ..garment.mesh import write_garment_obj

    if args.frames < 2:
        raise ValueError(f"--frames: at least 2, got {args.frames}")
    if args.samples < 1:
        raise ValueError(f"--samples: at least 1, got {args.samples}")
    if args.seed < 0:
        raise ValueError(f"--seed: must be >= 0, got {args.seed}")
    if args.body != "default":
        raise ValueError(f"--body {args.body}: only the bundled dress form ('default') is supported so far")
    for path, what in ((args.json, "STATS"), (args.render, "render")):
        if path:
            measure.check_output_path(path, what)
    garment = _garment(args)
    body = bodymod.make_body()
    bodymod.check_clear_of_body(garment.positions, body)
    materials = material.sample_garment_material(args.preset, garment, seed=args.seed, samples=args.samples)
    os.makedirs(args.out, exist_ok=True)
    cancel = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: cancel.set())
    results = []
    try:
        for k, m in enumerate(materials):
            def progress(done, total, k=k):
                print(f"\rdrape: sample {k + 1}/{len(materials)} frame {done}/{total}", end="", file=sys.stderr,
                      flush=True)
            options = {"contact_step": args.contact_step}
            if args.substeps is not None:
                options["substeps"] = args.substeps
            if args.thickness is not None:
                options["thickness_m"] = args.thickness * 1e-3
            if args.body_friction is not None:
                options["body_friction"] = args.body_friction
            r = simulate.drape(garment, m, body=body, motion=args.motion, frames=args.frames, progress=progress,
                               cancel_event=cancel, pc2_path=os.path.join(args.out, f"sample_{k:02d}.pc2"),
                               keep_frames=False, **options)
            print(file=sys.stderr)
            for name, x in (("first", r["first"]), ("last", r["last"])):
                write_garment_obj(os.path.join(args.out, f"sample_{k:02d}_{name}.obj"), _with_positions(garment, x))
            results.append({key: r[key] for key in ("vertices", "frames", "seconds_per_frame", "max_body_penetration_m",
                                                    "min_body_clearance_m", "self_intersections_final",
                                                    "hem_radius_m", "cancelled", "newton_iterations", "contact_step",
                                                    "retried_frames",
                                                    "simulated_vertices", "self_contact_thickness_m", "body_friction")})
            if r["cancelled"]:
                break
    finally:
        signal.signal(signal.SIGINT, previous)
    stats = dict(results[0])
    stats.update({"preset": args.preset, "garment": args.garment, "style": args.style if args.garment == "skirt"
                  else None, "body": args.body, "motion": args.motion, "fps": simulate.DEFAULT_FPS,
                  "samples": results, "hem_radius_spread_m": float(np.std([s["hem_radius_m"] for s in results]))})
    if args.json:
        measure.write_json(args.json, stats)
    if args.render:
        _render(args.render, _with_positions(garment, np.asarray(_last_positions(args.out))), body, args.motion,
                args.frames)
    print(f"drape: {stats['vertices']} vertices, {stats['frames']} frames, {stats['seconds_per_frame']:.2f} s/frame, "
          f"hem radius {stats['hem_radius_m'] * 1000:.0f} mm, body penetration "
          f"{stats['max_body_penetration_m'] * 1000:.2f} mm")
    return 130 if cancel.is_set() else 0


def _with_positions(garment, x):
    import copy
    g = copy.copy(garment)
    g.positions = x
    return g


def _last_positions(out):
    from ..garment.pc2 import read_pc2
    return read_pc2(os.path.join(out, "sample_00.pc2"))[-1]


def _render(path, garment, body, motion, frames):
    """A shaded side view of the last frame with the body at that frame (matplotlib, written atomically)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ..garment.body import body_frames
    from .. import measure

    bx = body_frames(body, motion, frames)[-1]
    fig = plt.figure(figsize=(5, 6), dpi=120)
    ax = fig.add_subplot(projection="3d")
    ax.plot_trisurf(bx[:, 0], bx[:, 1], bx[:, 2], triangles=body.faces, color="0.8", linewidth=0, alpha=0.6)
    x = garment.positions
    ax.plot_trisurf(x[:, 0], x[:, 1], x[:, 2], triangles=garment.faces, color="tab:red", linewidth=0.1,
                    edgecolor="0.3", shade=True)
    ax.set_box_aspect((1, 1, 1.6))
    ax.view_init(elev=8, azim=-70)
    ax.set_axis_off()
    tmp = path + ".tmp.png"
    fig.savefig(tmp, bbox_inches="tight")
    plt.close(fig)
    os.replace(tmp, path)
