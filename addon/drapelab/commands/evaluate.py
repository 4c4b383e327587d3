"""`drapelab evaluate --preset P --images IMG... [--meshes OBJ...] [--samples N] [--seed S] --json OUT.json`:
posterior-predictive evaluation of a preset on test silhouettes.

Per image (meshes pair with images in order): best-of-N pixel mse and iou, hausdorff_m (best sample, when a
mesh is given), drape_coefficient {observed, predicted_mean, interval90}, node_count {observed,
predicted_mode}, node_amplitude_m {observed, predicted_mean, interval90}. "mean" averages mse, iou, hausdorff_m,
dc_abs_error and gives dc_coverage90, node_within1, amplitude_bias_m (predicted - observed node amplitude: < 0,
the model's folds are shallower than the measured) and amplitude_coverage90. N defaults to 1000 for bdp (1 for
the deterministic homo/heter). Ctrl-C cancels: nothing is written and the status is 130.
"""
import signal
import sys
import threading


def register(subparsers):
    p = subparsers.add_parser("evaluate", help="evaluate a preset on test images (best-of-N, coverage)",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--preset", required=True, metavar="P")
    p.add_argument("--images", nargs="+", required=True, metavar="IMG")
    p.add_argument("--meshes", nargs="+", default=None, metavar="OBJ")
    p.add_argument("--samples", type=int, default=None, metavar="N")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", required=True, metavar="OUT.json")
    p.add_argument("--forward", choices=["dynamic", "static"], default=None,
                   help="drape of each sample (default fit.json: dynamic, the paper's protocol)")
    p.add_argument("--threads", type=int, default=None)
    p.set_defaults(func=run)


def run(args):
    from .. import infer, measure

    measure.check_output_path(args.json, "evaluation")

    def progress(done, total):
        if done == total or done % max(1, total // 10) == 0:
            print(f"sample {done}/{total}", flush=True)

    cancel = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: cancel.set())
    try:
        result = infer.evaluate(args.preset, args.images, meshes=args.meshes, samples=args.samples, seed=args.seed,
                                threads=args.threads, forward=args.forward, progress=progress, cancel_event=cancel)
    except infer.Cancelled:
        print(f"evaluate cancelled; {args.json} not written", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGINT, previous)
    measure.write_json(args.json, result)
    m = result["mean"]
    line = f"{result['model']} N={result['samples']}: MSE {m['mse']:.4f}  IoU {m['iou']:.4f}  |dDC| {m['dc_abs_error']:.3f}  " \
           f"DC coverage90 {m['dc_coverage90']:.2f}  nodes within 1 {m['node_within1']:.2f}"
    line += f"  node amplitude bias {1000 * m['amplitude_bias_m']:+.1f} mm"
    if "hausdorff_m" in m:
        line += f"  Hausdorff {m['hausdorff_m']:.4f} m"
    print(line)
    return 0
