"""Headless: diagnose a preset against Cusick image(s) with the add-on's operators (load_preset, import_images,
diagnose): which registered effect is missing, with the report written to a folder.

    blender --background --factory-startup --python-exit-code 1 --python tools/blender/diagnose.py -- \
        --preset assets/presets/fabric_02_cotton_blue_bdp.json \
        --images assets/cusick/fabric_02/silhouettes/sample_02_capture_1.jpg --report out/diagnosis \
        [--time-budget 300] [--samples 16] [--seed 0]

Writes REPORT/index.html, its figures, diagnosis.json and REPORT/presets/<effect>.json per refit; prints the
ranking and the verdict. Exits 1 with the operator's message on any error.
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
if os.path.isdir(os.path.join(REPO, "addon", "drapelab")):
    sys.path.insert(0, os.path.join(REPO, "addon"))
    os.environ.setdefault("DRAPELAB_NATIVE_DIR", os.path.join(REPO, "build", "python"))

from drapelab.ui import headless  # noqa: E402


def arguments(p):
    p.add_argument("--preset", required=True, help="preset file, or the name of a shipped or user preset")
    p.add_argument("--images", nargs="+", required=True, metavar="IMG")
    p.add_argument("--report", required=True, metavar="DIR", help="report folder (created)")
    p.add_argument("--time-budget", type=float, default=300.0, metavar="SECONDS")
    p.add_argument("--samples", type=int, default=16, metavar="K")
    p.add_argument("--seed", type=int, default=0)


def main():
    args = headless.script_args(__doc__.split("\n\n")[0], arguments)
    s = headless.ensure_registered()
    from drapelab.ui import operators, presets
    headless.run("load_preset", filepath=presets.resolve(args.preset, operators.user_presets_dir()))
    for image in args.images:
        headless.run("import_images", filepath=os.path.abspath(image))
    s.seed = args.seed
    os.makedirs(args.report, exist_ok=True)
    headless.run("diagnose", time_budget=args.time_budget, samples=args.samples,
                 report_dir=os.path.abspath(args.report))
    d = operators.diagnosis(s)
    for e in d["ranking"]:
        p = e.get("p_value")
        print(f"  {e['effect']:20s} p {p:.2g}" if p is not None else f"  {e['effect']:20s} not tested", flush=True)
    print(f"diagnose: {d.get('verdict')}\ndiagnose: wrote {os.path.join(args.report, 'index.html')}", flush=True)


main()
