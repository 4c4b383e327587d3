"""`drapelab measure IMG... [--px-per-m S] [--centre CX CY] --json OUT.json`: rotation-free drape measures.

The calibration is the dataset's (720 px/m, centre at the image centre), given (--px-per-m, --centre), or
estimated from an undraped specimen image (--calibration-image) or a reference mesh (--calibration-mesh).

Writes {"images": [...]} with one object per image (see drapelab.measure.measure_image): image (the path
as given), drape_coefficient, node_count, node_amplitude_m, area_px, px_per_m, centre_px, r_theta_m
(360 values, m), harmonics (first 20 amplitudes, m), threshold, dark_on_light. Prints one summary line per
image. A bad image stops the run with an error naming it (nothing is written) unless --keep-going, which
records {"image": ..., "error": ...} for it and exits with status 1.
"""
import sys


def register(subparsers):
    p = subparsers.add_parser("measure", help="measure drape coefficient, nodes and r(theta) of silhouette images",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("images", nargs="+", metavar="IMG",
                   help="top-down Cusick images (PNG, JPEG, TIFF, OpenEXR or uncompressed BMP)")
    add_calibration_arguments(p)
    p.add_argument("--threshold", type=float, default=None,
                   help="silhouette threshold on the cloth value s in (0, 1) (default automatic)")
    p.add_argument("--polarity", choices=["auto", "dark_on_light", "light_on_dark"], default="auto",
                   help="cloth darker or lighter than the background (default detected)")
    p.add_argument("--no-calibration-check", action="store_true",
                   help="accept silhouettes implausible for a Cusick test under the calibration")
    p.add_argument("--keep-going", action="store_true", help="record errors per image instead of stopping")
    p.add_argument("--json", metavar="OUT.json", default=None, help="write the measurements here")
    p.set_defaults(func=run)


def add_calibration_arguments(p):
    """Calibration options shared by measure and compare: given, or estimated (one way at most)."""
    g = p.add_argument_group("calibration (default: orthographic, 720 px/m, centre at the image centre)")
    g.add_argument("--px-per-m", type=float, default=None, metavar="S", help="scale in pixels per metre")
    g.add_argument("--centre", type=float, nargs=2, default=None, metavar=("CX", "CY"),
                   help="disk centre in pixels (column, row from the top-left corner)")
    g.add_argument("--calibration-image", metavar="FLAT", default=None,
                   help="estimate scale and centre from an image of the undraped specimen")
    g.add_argument("--specimen-diameter", type=float, default=0.30, metavar="M",
                   help="diameter of the undraped specimen in --calibration-image (default 0.30 m)")
    g.add_argument("--calibration-mesh", nargs=2, metavar=("OBJ", "IMG"), default=None,
                   help="estimate scale and centre by fitting a reference 3D mesh to its silhouette image")


def calibration_from_args(args):
    from .. import measure

    estimated = [n for n, v in (("--calibration-image", args.calibration_image),
                                ("--calibration-mesh", args.calibration_mesh)) if v]
    if len(estimated) > 1 or (estimated and (args.px_per_m is not None or args.centre is not None)):
        raise ValueError("give the calibration one way: --px-per-m/--centre, --calibration-image or --calibration-mesh")
    if args.calibration_image:
        cal = measure.calibrate_from_disk(args.calibration_image, args.specimen_diameter)
        print(f"calibration from {args.calibration_image}: {cal.px_per_m:.1f} px/m, centre ({cal.cx:.1f}, {cal.cy:.1f})")
        return cal
    if args.calibration_mesh:
        obj, image = args.calibration_mesh
        cal, fit = measure.calibrate_from_mesh(image, obj)
        print(f"calibration from {obj} on {image}: {cal.px_per_m:.1f} px/m, centre ({cal.cx:.1f}, {cal.cy:.1f}), "
              f"IoU {fit:.3f}")
        return cal
    return measure.calibration(measure.DATASET_PX_PER_M if args.px_per_m is None else args.px_per_m, args.centre)


def run(args):
    from .. import measure

    if args.json:
        measure.check_output_path(args.json, "JSON")
    cal = calibration_from_args(args)
    results, failed = [], 0
    for path in args.images:
        try:
            r = measure.measure_image(path, cal, check_calibration=not args.no_calibration_check,
                                      threshold=args.threshold, polarity=args.polarity)
        except measure.InputError as e:
            if not args.keep_going:
                raise
            failed += 1
            print(f"{path}: error: {e}", file=sys.stderr)
            results.append({"image": path, "error": str(e)})
            continue
        results.append(r)
        print(f"{path}: drape coefficient {r['drape_coefficient']:.3f}, {r['node_count']} nodes "
              f"(amplitude {1000 * r['node_amplitude_m']:.1f} mm), area {r['area_px']} px at {r['px_per_m']:g} px/m")
    if args.json:
        measure.write_json(args.json, {"images": results})
        print(f"wrote {args.json}")
    return 1 if failed else 0
