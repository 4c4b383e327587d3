"""Pictures the add-on shows (bpy-free; drapelab.ui.previews loads them into Blender as images).

- ``measurement_preview``: the photo with the detected silhouette outline, its centre, the support disk and
  flat specimen circles at the calibration's scale, and a 10 cm scale bar.
- ``fit_result``: drapes draws of a fitted preset on its camera, picks the one closest to the training image
  (best-of-N pixel MSE, as evaluate does), writes the overlay and the r(theta) plot, returns the metrics.
- ``history_chart``: the error of each model version (fits, diagnose's base and refits) in one bar chart.
All PNGs are written atomically (measure's temporary file + rename).
"""
import os

import numpy as np

from .. import infer, measure

__all__ = ["measurement_preview", "fit_result", "history_chart", "SCALE_BAR_M"]

SCALE_BAR_M = 0.10          # length of the scale bar drawn on the measurement preview
SUPPORT_RADIUS_M = 0.09     # Cusick support disk (BS EN ISO 9073-9)
SPECIMEN_RADIUS_M = 0.15    # flat specimen
PREVIEW_DRAWS = {"homo": 1, "heter": 1, "bdp": 4}  # draws draped for a finished fit's overlay


def _figure(size):
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path):
    measure._atomic_write(path, "figure", ".png", lambda tmp: fig.savefig(tmp, format="png"))


def measurement_preview(image_path, out_png, calibration=None):
    """Writes the preview PNG of one Cusick image; returns its measures (measure.measure_image's dict). Raises
    InputError naming the file when it is unreadable or not a plausible Cusick silhouette."""
    m = measure.measure_image(image_path, calibration)
    lum, _info = measure.read_image(image_path)
    sil = measure.load_silhouette(image_path, calibration)
    mask = np.asarray(sil.mask) > 0.5
    cal = sil.calibration
    h, w = mask.shape
    fig = _figure((5.0, 5.0))
    ax = fig.add_axes([0.0, 0.0, 1.0, 0.93])
    ax.imshow(np.asarray(lum), cmap="gray", vmin=0.0, vmax=1.0, extent=(0, w, h, 0), interpolation="bilinear")
    ax.contour(np.arange(w) + 0.5, np.arange(h) + 0.5, mask.astype(float), levels=[0.5], colors=["#d55e00"],
               linewidths=1.5)
    from matplotlib.patches import Circle
    for radius, style in ((SUPPORT_RADIUS_M, ":"), (SPECIMEN_RADIUS_M, "--")):
        ax.add_patch(Circle((cal.cx, cal.cy), radius * cal.px_per_m, fill=False, ls=style, lw=1.0, ec="#0072b2"))
    ax.plot([cal.cx], [cal.cy], marker="+", ms=14, mew=2, color="#009e73")
    bar = SCALE_BAR_M * cal.px_per_m
    x0, y0 = 0.05 * w, 0.95 * h
    ax.plot([x0, x0 + bar], [y0, y0], color="#e69f00", lw=3)
    ax.text(x0 + bar / 2, y0 - 0.02 * h, f"{SCALE_BAR_M * 100:.0f} cm", color="#e69f00", ha="center", va="bottom",
            fontsize=9)
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.axis("off")
    fig.text(0.5, 0.965, f"{os.path.basename(os.fspath(image_path))}: DC {m['drape_coefficient']:.3f}, "
             f"{m['node_count']} nodes, {cal.px_per_m:.0f} px/m", ha="center", va="center", fontsize=9)
    _save(fig, out_png)
    return m


def _predictive_draws(preset, image_path, draws, seed, progress=None, cancel_event=None):
    config = infer.load_config()
    obs = infer._Observation(image_path, measure.calibration(preset["camera"]["px_per_m"],
                                                             tuple(preset["camera"]["centre_px"])))
    pred = infer._Predictive(preset, obs.mask.shape, min(2, draws), config)
    bend = infer.preset_bend_samples(preset, pred.num_edges, np.random.default_rng(seed), draws)
    shapes = pred.drape(bend, seed, progress=progress, cancel_event=cancel_event)
    return obs, pred, [s for s in shapes if "error" not in s]


def fit_result(preset, image_path, overlay_png, rtheta_png, seed=0, draws=None, progress=None, cancel_event=None):
    """Drapes `draws` posterior draws of `preset` (default PREVIEW_DRAWS by model) against `image_path`, writes the
    best draw's overlay and the r(theta) plot (measured and best draw), returns the metrics dict: iou, mse,
    drape_coefficient {observed, predicted}, node_count {observed, predicted}, r_theta_rmse_m, draws."""
    preset = infer.validate_preset(preset) if isinstance(preset, dict) else infer.load_preset(preset)
    n = int(draws or PREVIEW_DRAWS[preset["model"]])
    obs, pred, shapes = _predictive_draws(preset, image_path, n, seed, progress, cancel_event)
    if not shapes:
        raise infer.SolverError(f"the preset's {n} preview draws all failed to drape")
    mses = [measure.pixel_mse(s["image"], obs.mask) for s in shapes]
    best = shapes[int(np.argmin(mses))]
    cal = pred.calibration
    r_obs = np.asarray(measure.r_theta(obs.mask, cal))
    r_model = np.asarray(measure.r_theta(best["image"], cal))
    rmse, _rotation = measure.r_theta_rmse(r_obs, r_model)
    # the model curve turned by its best circular shift, as the rmse is taken (fold positions are random)
    shift = int(np.argmin([np.mean((r_obs - np.roll(r_model, k)) ** 2) for k in range(len(r_model))]))
    r_model = np.roll(r_model, shift)
    metrics = {"iou": float(measure.iou(best["image"], obs.mask)), "mse": float(min(mses)),
               "drape_coefficient": {"observed": obs.dc, "predicted": float(best["dc"])},
               "node_count": {"observed": obs.nodes, "predicted": int(best["nodes"])},
               "r_theta_rmse_m": float(rmse), "draws": len(shapes),
               "mesh_level": pred.level}
    name = (preset.get("fabric") or {}).get("name") or preset["model"]
    measure.write_overlay(overlay_png, obs.mask, best["image"], title=f"{name}: best of {len(shapes)} draws",
                          notes=[f"IoU  {metrics['iou']:.3f}", f"MSE  {metrics['mse']:.4f}",
                                 f"DC   {best['dc']:.3f} (obs {obs.dc:.3f})",
                                 f"nodes {best['nodes']} (obs {obs.nodes})"], calibration=cal)
    fig = _figure((6.0, 3.2))
    ax = fig.add_axes([0.11, 0.16, 0.86, 0.72])
    theta = np.degrees(np.linspace(0.0, 2 * np.pi, len(r_obs), endpoint=False))
    ax.plot(theta, 100 * r_obs, color="#0072b2", lw=1.5, label="measured")
    ax.plot(theta, 100 * r_model, color="#d55e00", lw=1.2, label="model (best draw, best rotation)")
    ax.axhline(100 * SUPPORT_RADIUS_M, color="0.6", ls=":", lw=0.8)
    ax.axhline(100 * SPECIMEN_RADIUS_M, color="0.6", ls="--", lw=0.8)
    ax.set_xlim(0, 360)
    ax.set_xlabel("theta (degrees)")
    ax.set_ylabel("r (cm)")
    ax.set_title(f"r(theta): rmse after best rotation {1000 * metrics['r_theta_rmse_m']:.1f} mm", fontsize=9)
    ax.legend(fontsize=8, loc="lower right")
    _save(fig, rtheta_png)
    return metrics


def history_chart(entries, out_png, title="Error across model versions"):
    """Bar chart of best-of-N pixel MSE (and |dDC| when known) per model version; entries are dicts with
    `model` and `mse` (diagnose's history entries have this form). Entries without an MSE are skipped."""
    rows = [e for e in entries if e.get("mse") is not None]
    if not rows:
        raise ValueError("history chart: no entry has an MSE")
    fig = _figure((6.0, 0.9 + 0.42 * len(rows)))
    ax = fig.add_axes([0.42, 0.9 / (0.9 + 0.42 * len(rows)) * 0.7, 0.53, 0.42 * len(rows) / (0.9 + 0.42 * len(rows))])
    y = np.arange(len(rows))[::-1]
    ax.barh(y, [e["mse"] for e in rows], color="#0072b2", height=0.6)
    for yi, e in zip(y, rows):
        label = f"{e['mse']:.4f}" + (f"  |dDC| {e['dc_error']:.3f}" if e.get("dc_error") is not None else "")
        ax.text(e["mse"], yi, " " + label, va="center", fontsize=7)
    ax.set_yticks(y)
    ax.set_yticklabels([str(e["model"])[:40] for e in rows], fontsize=7)
    ax.set_xlim(0, max(e["mse"] for e in rows) * 1.6)
    ax.set_xlabel("pixel MSE (lower is better)", fontsize=8)
    ax.set_title(title, fontsize=9)
    _save(fig, out_png)
