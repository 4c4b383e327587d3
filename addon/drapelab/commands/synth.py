"""`drapelab synth [--effects NAME[=VALUE][,NAME.PARAM=VALUE...]] --density KG_M2 [--material PRESET] [--count N]
[--seed S] [--mesh-level L] --out DIR`: synthetic Cusick drapes with known truth, in the dataset's layout.

Writes N drapes of one material that differ the way real re-drapes do (the fitter's placement noise), as
silhouettes (PNG in the dataset's calibration: 256 x 256, 720 px/m, centre at the image centre, dark cloth on
white) and meshes (OBJ), with DIR/manifest.csv in the dataset's columns and DIR/truth.json naming what made them.
Nothing but truth.json names the effects. Without --effects: control data. --effects: NAME sets the effect's
primary parameter (the first of its block, `./drapelab effects`) to the registry's moderate strength and the
others to their off values; NAME=VALUE sets the primary; NAME.PARAM=VALUE any one (its unit as listed).
The material is PRESET (a preset file or a shipped preset's name in assets/presets/; its posterior median table
on every drape, or with --material-draw per-drape one posterior draw per drape) or, by default, the Cotton Blue
tables the fitter starts from. The same seed writes the same files. DIR is created; a non-empty DIR is refused
unless --force and it holds a previous synth output, which is then replaced. Ctrl-C keeps the drapes done (the
manifest and truth.json list them) and exits with status 130.
"""
import signal
import sys
import threading

# drapelab.synth's MATERIAL_DRAWS, DEFAULT_COUNT, DEFAULT_MESH_LEVEL (repeated so that registering the command
# does not import the simulator; a test keeps them equal).
MATERIAL_DRAWS = ("mean", "per-drape")
DEFAULT_COUNT = 6
DEFAULT_MESH_LEVEL = 3


def register(subparsers):
    p = subparsers.add_parser("synth", help="write synthetic drapes with known effects in the dataset's layout",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--effects", default=None, metavar="NAME[=VALUE][,NAME.PARAM=VALUE...]",
                   help="effects switched on (default none: control data); a bare NAME is its moderate strength")
    p.add_argument("--density", type=float, required=True, metavar="KG_M2", help="area density in kg/m^2")
    p.add_argument("--material", default=None, metavar="PRESET",
                   help="preset file or shipped preset name (default: the Cotton Blue tables the fitter starts from)")
    p.add_argument("--material-draw", choices=MATERIAL_DRAWS, default="mean",
                   help="with a preset: its posterior median on every drape (mean, default) or one posterior draw "
                        "per drape (per-drape)")
    p.add_argument("--count", type=int, default=DEFAULT_COUNT, metavar="N",
                   help=f"number of drapes (default {DEFAULT_COUNT})")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="placement (and material) draws (default 0)")
    p.add_argument("--mesh-level", type=int, default=DEFAULT_MESH_LEVEL, metavar="L",
                   help=f"Cusick template mesh circleL, 1..5 (default {DEFAULT_MESH_LEVEL}: the dataset's meshes)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--force", action="store_true", help="replace a previous synth output in DIR")
    p.set_defaults(func=run)


def run(args):
    from .. import synth

    cancel = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: cancel.set())

    def progress(d):
        print(f"drape {d['drape']}/{d['count']} {d['silhouette']}: drape coefficient {d['drape_coefficient']:.3f}, "
              f"{d['node_count']} nodes, {d['seconds']:.1f} s", file=sys.stderr, flush=True)

    try:
        truth = synth.synth(args.out, args.density, effects=args.effects, material=args.material,
                            count=args.count, seed=args.seed, mesh_level=args.mesh_level,
                            material_draw=args.material_draw, force=args.force, progress=progress,
                            cancel_event=cancel)
    except synth.Cancelled as e:
        print(f"{e}: manifest.csv and truth.json list them", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGINT, previous)
    effects = ", ".join(f"{n}.{p}={v:g}" for n, block in truth["effects"].items() for p, v in block.items())
    print(f"wrote {truth['count']} drapes to {args.out} (manifest.csv, truth.json): {truth['material']['name']}, "
          f"density {truth['density_kg_m2']:g} kg/m^2, {effects or 'no effect (control)'}, seed {truth['seed']}")
    return 0
