"""Headless: fit Cusick image(s) to a preset with the add-on's operators (import_images, fit, save_preset).

    blender --background --factory-startup --python-exit-code 1 --python tools/blender/fit_image.py -- \
        --images assets/cusick/fabric_02/silhouettes/sample_02_capture_1.jpg --out out/cotton_blue.json \
        [--density 0.192] [--model bdp] [--time-budget 300 | --epochs N] [--seed 0] [--name NAME] \
        [--effects tilt,prestrain] [--mesh-level N] [--no-calibration]

Without --density, an image of the bundled dataset (or of $DRAPELAB_CUSICK_DIR) gets its fabric's density, name and
thickness from the manifest; any other image needs --density. Exits 1 with the operator's message on any error.
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
if os.path.isdir(os.path.join(REPO, "addon", "drapelab")):  # a clone: its add-on and build; else the installed one
    sys.path.insert(0, os.path.join(REPO, "addon"))
    os.environ.setdefault("DRAPELAB_NATIVE_DIR", os.path.join(REPO, "build", "python"))

from drapelab.ui import headless  # noqa: E402


def arguments(p):
    p.add_argument("--images", nargs="+", required=True, metavar="IMG")
    p.add_argument("--out", required=True, metavar="PRESET.json")
    p.add_argument("--density", type=float, default=None, metavar="KG_M2")
    p.add_argument("--model", choices=["homo", "heter", "bdp"], default="bdp")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--epochs", type=int, default=0)
    g.add_argument("--time-budget", type=float, default=0.0, metavar="SECONDS")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--name", default=None)
    p.add_argument("--effects", default="", metavar="NAME,...", help="effects whose strength is fitted")
    p.add_argument("--mesh-level", type=int, default=0, choices=[0, 1, 2, 3, 4, 5])
    p.add_argument("--no-calibration", action="store_true")


def main():
    args = headless.script_args(__doc__.split("\n\n")[0], arguments)
    s = headless.ensure_registered()
    for image in args.images:
        headless.run("import_images", filepath=os.path.abspath(image))
    if args.density is not None:
        s.density = args.density
    elif not s.fabric_name:
        raise SystemExit("fit_image.py: --density is needed (the image is not in the dataset's manifest)")
    if args.name:
        s.fabric_name = args.name
    s.model, s.seed, s.mesh_level, s.calibrate = args.model.upper(), args.seed, args.mesh_level, not args.no_calibration
    for name in filter(None, (e.strip() for e in args.effects.split(","))):
        headless.run("add_effect", effect=name)
    headless.run("fit", epochs=args.epochs, time_budget=args.time_budget)
    headless.run("save_preset", filepath=os.path.abspath(args.out))
    m = (s.metrics() or {}).get("metrics") or {}
    print(f"fit_image: wrote {args.out} ({args.model}" + (f", IoU {m['iou']:.3f}, MSE {m['mse']:.4f}" if m else "")
          + ")", flush=True)


main()
