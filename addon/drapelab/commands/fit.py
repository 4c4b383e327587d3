"""`drapelab fit --images IMG... --density KG_M2 [--model homo|heter|bdp] [--epochs N | --time-budget S] [--seed S]
[--no-calibration] [--init PRESET.json] --out PRESET.json`: fit a material posterior to Cusick silhouettes and write
a preset.

Learns the bending table in log space (stretching stays at its starting table; see drapelab.infer). Settings
(learning rates, likelihood sigma, prior, Monte Carlo samples, mesh resolution) come from
addon/drapelab/config/fit.json or --config. A checkpoint is written after every epoch (--checkpoint, default
PRESET.json.ckpt) and --resume continues from one. Ctrl-C cancels cleanly: the last checkpoint stays valid.
--time-budget covers the whole fit, drape calibration included (see its help).

--effects switches on effects from the registry (./drapelab effects): a bare NAME fits all its parameters
with the material, from their off values (prior: the registry's prior scale); NAME=VALUE fixes the effect's
primary parameter (its others stay off), NAME.PARAM=VALUE fixes one parameter and a bare NAME.PARAM fits that
one parameter from its off value (the effect's others stay off unless given). The preset's
active_effects records the values (fitted: with the posterior sd and 90 % interval for bdp).

--init PRESET.json starts the fit where that preset left off: its bending table (and bdp posterior sd), its
stretching table, placement noise and mesh level, no scale search; its active effects stay fixed at its values
unless --effects names them, and a named one starts at the preset's values. --model and --density default to the
preset's. The loop of `diagnose`: fit --init REPORT/presets/NAME.json --effects NAME fits the recommended effect
together with the material, from the diagnosis's refit.
"""
import os
import signal
import math
import sys
import threading


def register(subparsers):
    p = subparsers.add_parser("fit", help="fit a material posterior (HOMO/HETER/BDP) to Cusick images",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--images", nargs="+", required=True, metavar="IMG", help="training silhouettes")
    p.add_argument("--density", type=float, default=None, metavar="KG_M2",
                   help="area density in kg/m^2 (required unless --init gives it)")
    p.add_argument("--model", choices=["homo", "heter", "bdp"], default=None,
                   help="variational family (default: bdp, or the --init preset's)")
    p.add_argument("--init", default=None, metavar="PRESET.json",
                   help="start from this preset (e.g. a diagnosis's refit REPORT/presets/NAME.json): its material, "
                        "stretching, placement noise, mesh level and effects; --effects NAME fits that effect from "
                        "the preset's value")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--epochs", type=int, default=None, metavar="N")
    g.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="time for the whole fit (set-up, epochs, bdp drape calibration, writing). A bdp fit first "
                        "times one round of calibration drapes (other fits: one drape), then gives the calibration what its fewest sets "
                        "of drapes need, up to half the budget (fit.json time_budget.calibration_share) or what "
                        "its longest node search needs, and the epochs the rest; a budget too small for the "
                        "calibration, the scale search and one epoch is refused with these estimates")
    p.add_argument("--no-calibration", action="store_true",
                   help="skip the bdp drape calibration (fit.json calibration.enabled false)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, metavar="PRESET.json")
    p.add_argument("--camera", choices=["ortho", "perspective"], default="ortho",
                   help="shorthand for the camera effect: perspective = camera.inv_distance_per_m fixed at "
                        "1/0.7 m (the paper's camera height) on the images' calibration; ortho = the calibration "
                        "as it is. Any other camera model: --effects camera.PARAM=VALUE (or a bare camera: fitted)")
    p.add_argument("--mesh-level", type=int, default=None, choices=[1, 2, 3, 4, 5],
                   help="Cusick template mesh circleN used for simulation (default from fit.json)")
    p.add_argument("--config", default=None, metavar="FIT.json", help="fit settings (default addon/drapelab/config/fit.json)")
    p.add_argument("--checkpoint", default=None, metavar="CKPT.json")
    p.add_argument("--resume", default=None, metavar="CKPT.json", help="continue a fit from its checkpoint")
    p.add_argument("--threads", type=int, default=None, help="Monte Carlo lanes (default: up to 2 cores)")
    p.add_argument("--name", default=None, help="fabric name recorded in the preset")
    p.add_argument("--effects", default=None, metavar="NAME[=VALUE][,NAME.PARAM[=VALUE]...]",
                   help="effects to switch on: a bare NAME is fitted, a bare NAME.PARAM fits that parameter only, "
                        "a value fixes it (see ./drapelab effects)")
    p.set_defaults(func=run)


PAPER_CAMERA_HEIGHT_M = 0.7  # the paper's released scripts: eye 0.7 m above the support (render.perspective_camera)


def camera_shorthand(camera, effects):
    """--camera as the camera effect (CONVENTIONS.md: the effect is the one place the measurement model is set):
    'perspective' fixes camera.inv_distance_per_m at 1 / PAPER_CAMERA_HEIGHT_M; 'ortho' changes nothing."""
    from .._native import InputError

    if camera != "perspective":
        return effects
    effects = dict(effects or {})
    given = effects.get("camera")
    if given is not None and (not given or "inv_distance_per_m" in given):
        raise InputError("--camera perspective and --effects camera both set the perspective; give one "
                         "(e.g. --effects camera.inv_distance_per_m=1.43)")
    effects["camera"] = {**(given or {}), "inv_distance_per_m": 1.0 / PAPER_CAMERA_HEIGHT_M}
    return effects


def run(args):
    from .. import infer, measure, sim

    measure.check_output_path(args.out, "preset")
    effects = camera_shorthand(args.camera, sim.parse_effects_arg(args.effects, bare=None))
    config = infer.load_config(args.config)
    if args.no_calibration:
        config["calibration"] = dict(config.get("calibration") or {}, enabled=False)
    checkpoint = args.checkpoint or args.out + ".ckpt"
    cancel = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: cancel.set())

    def progress(e):
        fitted = "".join(f"  {k} {v:+.4g}" for k, v in (e.get("effects") or {}).items())
        print(f"epoch {e['epoch']:4d}  loss {e['loss']:.5f} (data {e['data']:.5f}, kl {e['kl']:.5f})  "
              f"IoU {e['iou']:.4f}  MSE {e['mse']:.4f}{fitted}  {e['seconds']:.1f} s", flush=True)

    def calibration_progress(c):
        print(f"calibration {c['evaluation']:2d}: stretching x{c['stretch_scale']:g}, bending x{c['bend_scale']:.3f}: "
              f"drape coefficient {c['dc']:.3f} +- {c['dc_sd']:.3f} (observed {c['dc_observed']:.3f}), nodes "
              f"{c['nodes']:.1f} (observed {c['nodes_observed']:.1f})  {c['seconds']:.1f} s", flush=True)

    def plan_progress(p):
        line = f"time budget {p['total_s']:g} s: set-up {p['setup_s']:.1f} s, epochs {p['epochs_s']:.1f} s"
        if p["calibration_sets"][1]:
            line += (f", drape calibration {p['calibration_s']:.1f} s ({p['calibration_sets'][0]}-"
                     f"{p['calibration_sets'][1]} sets of drapes of {p['calibration_set_s']:.1f} s)")
        print(line, flush=True)

    def guard_progress(g):
        if g["stage"] == "start":
            print(f"start guard: the start ({args.init}) and the fit's end on the same {g['draws']} draws per "
                  f"image" + (f" (about {g['estimate_s']:.0f} s)" if g["estimate_s"] else ""), flush=True)
            return
        words = {"start": "the start is kept: the epochs made the training images' fit worse",
                 "end": "the fit's end is kept"}[g["kept"]]
        print(f"start guard ({g['seconds']:.1f} s): best-of-{g['draws']} MSE start "
              + (f"{g['start_mse']:.4f}" if "start_mse" in g else "failed") + ", end "
              + (f"{g['end_mse']:.4f}" if "end_mse" in g else "failed") + f": {words}", flush=True)

    try:
        preset = infer.fit(args.images, args.density, model=args.model, epochs=args.epochs, init=args.init,
                           time_budget=args.time_budget, seed=args.seed, out=args.out, checkpoint=checkpoint,
                           resume=args.resume, progress=progress, calibration_progress=calibration_progress,
                           plan_progress=plan_progress, guard_progress=guard_progress,
                           cancel_event=cancel,
                           fabric={"name": args.name} if args.name else None, config=config,
                           camera="ortho", mesh_level=args.mesh_level, threads=args.threads, effects=effects)
    except infer.Cancelled:
        print(f"fit cancelled; the last checkpoint is {checkpoint} (resume with --resume)", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGINT, previous)
    t = preset["training"]
    print(f"wrote {args.out}: {preset['model']}, {t['epochs']} epochs in {t['seconds']:.1f} s, "
          f"training IoU {preset['metrics']['training_image']['iou']:.4f}")
    for name, params in preset["active_effects"].items():
        text = ", ".join(f"{p} {e['value']:.4g} {e['unit']}" + (f" (90 % {e['interval90'][0]:.4g} .. {e['interval90'][1]:.4g})"
                                                               if "interval90" in e else "") + ("" if e["fitted"] else " fixed")
                         for p, e in params.items())
        print(f"effect {name}: {text}")
    c = preset.get("calibration")
    if c:
        print(f"drape calibration ({c['seconds']:.1f} s): drape coefficient {c['dc_predicted_before']:.3f} -> "
              f"{c['dc_predicted']:.3f} (observed {c['dc_observed']:.3f}), scale x{math.exp(c['log_scale_shift']):.3f}, "
              f"global log sd {c['global_log_std']:.3f}; nodes {c['nodes_predicted_before']:.1f} -> "
              f"{c['nodes_predicted']:.1f} (observed {c['nodes_observed']:.1f}), stretching x{c['stretch_scale']:g}; "
              f"on circle{c['mesh_level']}" + (" (node search cut short by the time budget)"
                                               if c.get("node_search_stopped_by_time_budget") else ""))
    g = (t.get("init") or {}).get("start_guard") or {}
    if g.get("skipped"):
        print(f"start guard skipped: {g['skipped']}")
    b = t.get("time_budget")
    if b:
        print(f"time budget {b['total_s']:g} s: done in {b['end_s']:.1f} s (epochs ended at {b['epochs_end_s']:.1f} s)")
    return 0
