"""`drapelab diagnose --preset P --images IMG... [--meshes OBJ...] [--candidates NAME,...] [--time-budget S]
[--samples K] [--seed S] [--mesh-noise-mm MM] --report DIR`: where the model P fails on these silhouettes, and which registered
effect is missing.

Drapes K posterior-predictive draws of P (the same draws as `evaluate --seed S`) and reports per image the
best draw's overlay, r(theta) of the measurement and of the best draw with the residual and its harmonics
k = 1..6 (against the re-drape floor), and the drape coefficient, node count and node amplitude against the
draws' 90 % interval. For every registered effect not in P (or only --candidates) it runs a score test at the
effect's off value (the data term's gradient per draw, back-propagated through the rollout; Hotelling's T^2
over the draws, p from sign flips of the draws) and a step test (the same draws with the effect at its moderate
strength, forward only; p against n re-drapes of one specimen drawn from P, its spread from P's own predictive
silhouettes and re-drapes of P's mean); with --meshes on the model's topology also a 3D step test (the same step
drapes compared with the measured meshes by their fold features: crest and hoop hinge angles, ring heights and
fold amplitudes). The tests are combined per candidate (the smallest p times the number of tests), with the threshold --alpha (0.01) Bonferroni-corrected over the candidates
tested. Once one is below it, up to --max-refits (3) candidates with p below 0.05 are refitted (fit --effects NAME
with P's material held at its posterior: only the effect is fitted) and written as DIR/presets/NAME.json;
`recommended` is the refit that lowers the best-of-K MSE most, if by at least 5 % and by at least half of what
re-draping alone leaves (the re-drape floor), or null ("nothing significant", or why not).

--time-budget S covers the whole job: the draws and score tests run first (K drapes with backward; not
shortened by the budget: choose K), then the step test (at most 40 % of what is left; draws dropped first),
then what remains, less an estimate of the refits' evaluations (K drapes each) and a 5 s reserve for the
report, is split equally between the refits. Without it each refit runs fit.json's default_epochs.

Writes DIR/index.html (figures), its PNGs and DIR/diagnosis.json (base, ranking, recommended, threshold,
history, and details). Progress goes to stderr. Ctrl-C stops cleanly: what is done is written (exit 130).
"""
import signal
import sys
import threading

DEFAULT_SAMPLES = 16  # drapelab.diagnose.DEFAULT_SAMPLES (repeated so that registering does not import the simulator)


def register(subparsers):
    p = subparsers.add_parser("diagnose", help="where a preset fails on measurements, and which effect is missing",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--preset", required=True, metavar="P", help="the preset (model) to diagnose")
    p.add_argument("--images", nargs="+", required=True, metavar="IMG", help="measured silhouettes")
    p.add_argument("--meshes", nargs="+", default=None, metavar="OBJ", help="measured meshes (pair with images)")
    p.add_argument("--mesh-noise-mm", type=float, default=0.12, metavar="MM",
                   help="the measured meshes' vertex noise sd, added to the model's drapes' hinge angles in 3D "
                        "(default 0.12: the Cusick reconstructions'; 0 for noise-free meshes such as synth's)")
    p.add_argument("--candidates", default=None, metavar="NAME,...",
                   help="effects to test (default: every registered effect not in the preset)")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="the whole job's budget: draws and score tests first, the rest split between the refits")
    p.add_argument("--samples", type=int, default=DEFAULT_SAMPLES, metavar="K",
                   help=f"posterior-predictive draws (default {DEFAULT_SAMPLES}; at least 3)")
    p.add_argument("--seed", type=int, default=0, metavar="S")
    p.add_argument("--alpha", type=float, default=0.01, metavar="A",
                   help="family-wise significance level, Bonferroni-corrected over the candidates (default 0.01)")
    p.add_argument("--max-refits", type=int, default=3, metavar="N",
                   help="refit at most the N most promising candidates (default 3; 0: tests only)")
    p.add_argument("--mesh-level", type=int, default=None, choices=[1, 2, 3, 4, 5],
                   help="Cusick template mesh of the draws and refits (default: the preset's)")
    p.add_argument("--config", default=None, metavar="FIT.json", help="fit settings (default addon/drapelab/config/fit.json)")
    p.add_argument("--threads", type=int, default=None, help="drape lanes (default: up to 2 cores)")
    p.add_argument("--report", required=True, metavar="DIR", help="report folder (created)")
    p.set_defaults(func=run)


def run(args):
    import os
    from .. import diagnose, infer

    if args.meshes:
        for path in args.meshes:
            if not os.path.isfile(path):
                raise infer.InputError(f"meshes: {path}: no such file")
    config = infer.load_config(args.config)
    cancel = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: cancel.set())

    def progress(e):
        print(e["message"], file=sys.stderr, flush=True)

    try:
        result = diagnose.diagnose(args.preset, args.images, meshes=args.meshes, candidates=args.candidates,
                                   time_budget=args.time_budget, samples=args.samples, seed=args.seed, config=config,
                                   threads=args.threads, mesh_level=args.mesh_level, out_dir=args.report,
                                   progress=progress, cancel_event=cancel, alpha=args.alpha,
                                   max_refits=args.max_refits, mesh_noise_m=args.mesh_noise_mm / 1000.0)
    finally:
        signal.signal(signal.SIGINT, previous)
    b = result.get("base")
    if b:
        print(f"base: best-of-{result['draws_used']} MSE {b['mse']:.4f}  IoU {b['iou']:.4f}  |dDC| {b['dc_error']:.3f}  "
              f"node error {b['node_error']:.2f}  amplitude error {1000 * b['amplitude_error']:.2f} mm  "
              f"loss {b['loss']:.4g}")
    for e in result["ranking"]:
        if e["p_value"] is None:
            continue
        refit = "" if e["refit"] is None else f"  refit MSE {e['refit']['mse']:.4f} loss {e['refit']['loss']:.4g} " \
                                              f"gain {e['gain']:.4g}/parameter"
        step = e.get("step")
        score_p = e.get("p_value_score")
        step = "" if not step else (f"  ({'' if score_p is None else f'score p {score_p:.2g}, '}step {step['step']} "
                                    f"p {step['p_value']:.2g})")
        score = "" if e["statistic"] is None else f"T^2 {e['statistic']:9.3g}  "
        print(f"{e['effect']:20s} {score}p {e['p_value']:.2g}{step}{refit}")
    print(result.get("verdict", ""))
    print(f"wrote {os.path.join(args.report, 'index.html')} and diagnosis.json")
    if result.get("cancelled"):
        print("diagnose cancelled: the report holds what was done", file=sys.stderr)
        return 130
    return 0
