"""Fitting (drapelab.infer): KL and ELBO derivatives, a synthetic round trip, a short real fit, bad input."""
import copy
import hashlib
import importlib.util
import json
import math
import os
import shutil
import threading

import numpy as np
import pytest

from drapelab import infer, measure, paths, render, sim, tables

from fit_support import ROOT, ASSET_IMAGE, small_config


def assert_same_to_roundoff(a, b, rel=1e-12, where="result"):
    """a and b have the same structure and keys, equal strings/bools, and numbers equal to `rel` relative."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and sorted(a) == sorted(b), where
        for k in a:
            assert_same_to_roundoff(a[k], b[k], rel, f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_to_roundoff(x, y, rel, f"{where}[{i}]")
    elif isinstance(a, (float, np.floating)) and not isinstance(a, bool):
        assert b == pytest.approx(a, rel=rel, abs=0, nan_ok=True), where
    else:
        assert a == b, where


def test_kl_closed_form_matches_monte_carlo():
    rng = np.random.default_rng(0)
    mu, sigma = rng.normal(size=15), np.exp(rng.normal(scale=0.3, size=15))
    mu0, sigma0 = rng.normal(size=15), 1.3
    kl, d_mu, d_sigma = infer.kl_divergence(mu, sigma, mu0, sigma0)
    x = mu + sigma * rng.standard_normal((400000, 15))
    log_q = -0.5 * ((x - mu) / sigma) ** 2 - np.log(sigma)
    log_p = -0.5 * ((x - mu0) / sigma0) ** 2 - np.log(sigma0)
    mc = np.mean(np.sum(log_q - log_p, axis=1))
    assert abs(mc - kl) < 0.02 * abs(kl) + 0.02
    eps = 1e-6
    for i in (0, 7):
        e = np.zeros(15)
        e[i] = eps
        fd_mu = (infer.kl_divergence(mu + e, sigma, mu0, sigma0)[0] - infer.kl_divergence(mu - e, sigma, mu0, sigma0)[0]) / (2 * eps)
        fd_s = (infer.kl_divergence(mu, sigma + e, mu0, sigma0)[0] - infer.kl_divergence(mu, sigma - e, mu0, sigma0)[0]) / (2 * eps)
        assert d_mu[i] == pytest.approx(fd_mu, rel=1e-6)
        assert d_sigma[i] == pytest.approx(fd_s, rel=1e-6)


def _directional_checks(job, loss, grads, eps, names=("mu", "eta"), seed=1):
    """(name, adjoint, central difference) along one random direction per parameter block."""
    rng = np.random.default_rng(seed)
    out = []
    for name in names:
        d = rng.standard_normal(job.theta[name].shape)
        plus = {k: v.copy() for k, v in job.theta.items()}
        minus = {k: v.copy() for k, v in job.theta.items()}
        plus[name] += eps * d
        minus[name] -= eps * d
        out.append((name, float(np.sum(grads[name] * d)), (loss(plus) - loss(minus)) / (2 * eps)))
    return out


# The drape of a BDP draw (per-edge noise, random placement) is an exact-differentiable but rough function of
# the tables: folds bifurcate, so central differences agree with the adjoint only for steps below ~1e-6 in
# log-stiffness (at 1e-4..1e-5 they disagree with each other; measured, see README "Fitting"). Hence 1e-7.
ROUGH_EPS = 1e-7


def test_elbo_gradient_matches_central_differences_with_fixed_noise():
    # Static drapes solved tightly from the same warm start. Pixel term only here.
    cfg = small_config(samples_per_epoch=1, sigma_dc=0.0)
    cfg["static"] = {"force_tolerance": 1e-11, "max_iterations": 300}
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", seed=3, config=cfg, threads=1)
    job.theta["eta"] = job.theta["eta"] + 0.5  # a wider posterior: the noise matters
    job.objective(job.theta, 0)  # settles the warm start
    warm = copy.deepcopy(job.warm)

    def loss(theta):
        job.warm = copy.deepcopy(warm)
        return job.objective(theta, 0)[0]["loss"]

    job.warm = copy.deepcopy(warm)
    _, grads = job.objective(job.theta, 0)
    # The drape is rough (see README, "Gradients of a draw"): a single step size can straddle a kink (seed 3,
    # placement noise 0.05 m/s over 32 modes: mu's difference at 1e-7 is 7e-4 off, at 1e-6 and 1e-8 within 7e-5).
    # The median of three step sizes is what a smooth function would give at all three.
    checks = [_directional_checks(job, loss, grads, eps) for eps in (10 * ROUGH_EPS, ROUGH_EPS, ROUGH_EPS / 10)]
    for per_eps in zip(*checks):
        name, an = per_eps[0][0], per_eps[0][1]
        assert an == pytest.approx(float(np.median([fd for _, _, fd in per_eps])), rel=1e-4, abs=1e-6), name


@pytest.mark.parametrize("widen", [0.0, 0.5])
def test_bdp_draw_gradient_on_the_dynamic_forward_with_placement_noise(widen):
    # A BDP draw as trained: per-edge noise, a random placement, 100-step rollout, pixel + drape-coefficient
    # terms, KL. At the initial posterior width and at a wider one.
    cfg = small_config(samples_per_epoch=1, forward="dynamic")
    assert cfg["sigma_dc"] > 0 and cfg["placement_noise"]["velocity_m_s"] > 0
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", seed=5, config=cfg, threads=1)
    job.theta["eta"] = job.theta["eta"] + widen
    terms, grads = job.objective(job.theta, 0)
    for name, an, fd in _directional_checks(job, lambda th: job.objective(th, 0)[0]["loss"], grads, ROUGH_EPS):
        assert an == pytest.approx(fd, rel=1e-4), name


def _synthetic_image(path, bend, level=1, stretch=None):
    model = sim.ClothModel(sim.cusick_specimen(level), density=0.192)
    p = model.parameters(stretch=tables.COTTON_BLUE.stretch if stretch is None else stretch, bend=bend)
    x0 = model.simulate(p, mode="dynamic", record=False)
    x = model.simulate(p, mode="static", positions0=x0)
    img = render.hard_silhouette(render.orthographic_camera(), x, model.faces)
    # A dark drape on white, as in the dataset.
    measure.write_image(path, 1.0 - np.asarray(img))
    return model, x


def test_synthetic_round_trip_recovers_the_silhouette_and_bending_scale(tmp_path):
    true_bend = tables.COTTON_BLUE.bend * 3.0
    path = str(tmp_path / "synthetic.png")
    model, x_true = _synthetic_image(path, true_bend)
    cfg = small_config()
    cfg["learning_rates"]["homo"]["mu"] = 0.1
    cfg["kl_weight"] = 0.0  # maximum likelihood: the round trip checks what the data alone identify
    job = infer.FitJob([path], 0.192, model="homo", seed=0, config=cfg, threads=1)
    job.run(epochs=40)
    first, last = job.history[0], job.history[-1]
    assert last["iou"] >= 0.97, job.history
    assert last["iou"] > first["iou"]
    # What one silhouette identifies is the stiffness at the curvatures the drape actually has, not every
    # table entry (other curvature columns are never sampled). Measure it as the bending energy of the true
    # drape under each table (E_bend is linear in the table): recovered within a factor 1.5.
    def bend_energy(bend):
        stretch = tables.COTTON_BLUE.stretch
        return (model.energy(x_true, model.parameters(stretch=stretch, bend=bend))
                - model.energy(x_true, model.parameters(stretch=stretch, bend=np.zeros((3, 5)))))

    ratio = bend_energy(np.exp(job.theta["mu"])) / bend_energy(true_bend)
    start = bend_energy(tables.COTTON_BLUE.bend) / bend_energy(true_bend)
    assert abs(np.log(ratio)) < np.log(1.5), (ratio, start)
    assert abs(np.log(ratio)) < abs(np.log(start))


def test_short_real_fit_improves_iou():
    cfg = small_config()
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="homo", seed=0, config=cfg, threads=1)
    job.run(epochs=5)
    assert job.history[-1]["iou"] > job.history[0]["iou"]


def test_same_seed_same_result_any_thread_count():
    cfg = small_config(samples_per_epoch=2)
    a = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", seed=7, config=cfg, threads=1)
    b = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", seed=7, config=cfg, threads=2)
    a.run(epochs=2)
    b.run(epochs=2)
    # The same draws, placements and aggregation order; the lanes' native buffers may sit at different
    # alignments (per-thread malloc arenas), which can change a vectorised reduction's rounding: seen once in a
    # clean-clone run, 13 of 15 entries differing by <= 1e-14 relative. Same result to round-off.
    for k in a.theta:
        np.testing.assert_allclose(a.theta[k], b.theta[k], rtol=1e-12, atol=0)


def test_cancelled_fit_leaves_a_valid_checkpoint(tmp_path):
    ckpt = str(tmp_path / "fit.ckpt")
    cancel = threading.Event()
    cfg = small_config()

    def progress(entry):
        if entry["epoch"] == 2:
            cancel.set()

    with pytest.raises(infer.Cancelled):
        infer.fit([ASSET_IMAGE], 0.192, model="bdp", epochs=10, checkpoint=ckpt, progress=progress,
                  cancel_event=cancel, out=str(tmp_path / "p.json"), config=cfg, threads=1)
    assert not os.path.exists(tmp_path / "p.json")
    with open(ckpt) as f:
        state = json.load(f)
    assert state["epoch"] == 2
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", config=cfg, threads=1)
    job.load_checkpoint(ckpt)
    assert job.epoch == 2
    job.run(epochs=3)
    assert job.epoch == 3


def test_bad_inputs(tmp_path):
    with pytest.raises(infer.InputError, match="density"):
        infer.FitJob([ASSET_IMAGE], 0.0, model="homo", config=small_config())
    with pytest.raises(infer.InputError, match="kg/m"):
        infer.FitJob([ASSET_IMAGE], 192.0, model="homo", config=small_config())
    not_an_image = tmp_path / "notes.jpg"
    not_an_image.write_text("this is not an image")
    with pytest.raises(ValueError, match="notes.jpg"):
        infer.FitJob([str(not_an_image)], 0.192, model="homo", config=small_config())
    white = tmp_path / "white.png"
    measure.write_image(str(white), np.ones((256, 256)))
    with pytest.raises(ValueError, match="white.png"):
        infer.FitJob([str(white)], 0.192, model="homo", config=small_config())
    with pytest.raises(OSError):
        infer.fit([ASSET_IMAGE], 0.192, model="homo", epochs=1, out="/nonexistent-dir/p.json", config=small_config())


def test_preset_round_trip_and_nan_preset_rejected(tmp_path):
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", config=small_config(), threads=1)
    job.run(epochs=1)
    path = str(tmp_path / "p.json")
    infer.write_preset(path, job.preset(fabric={"name": "test"}))
    preset = infer.load_preset(path)
    assert preset["model"] == "bdp" and preset["schema_version"] == infer.PRESET_SCHEMA_VERSION
    assert np.asarray(preset["posterior"]["bend"]["log_mean"]).shape == (3, 5)
    bad = json.loads(open(path).read().replace(str(preset["posterior"]["bend"]["log_std"][0][0]), "NaN", 1))
    bad_path = tmp_path / "bad.json"
    bad_path.write_text(json.dumps(bad))
    with pytest.raises(infer.InputError, match="NaN"):
        infer.load_preset(str(bad_path))
    result = infer.evaluate(path, [ASSET_IMAGE], samples=2, threads=1, config=small_config())
    entry = result["images"][0]
    assert set(entry) >= {"image", "mse", "iou", "drape_coefficient", "node_count"}
    lo, hi = entry["drape_coefficient"]["interval90"]
    assert lo <= entry["drape_coefficient"]["predicted_mean"] <= hi
    assert set(result["mean"]) >= {"mse", "iou", "dc_abs_error", "dc_coverage90", "node_within1"}
    # the node amplitude (fold depth) diagnostic: observed as measure reads the image, predicted over the draws
    amp = entry["node_amplitude_m"]
    mask = np.asarray(measure.load_silhouette(ASSET_IMAGE, None).mask, dtype=float)
    assert amp["observed"] == pytest.approx(measure.node_amplitude(measure.r_theta(mask)))
    assert 0.001 < amp["observed"] < 0.05
    lo, hi = amp["interval90"]
    assert 0 < lo <= amp["predicted_mean"] <= hi < 0.05
    assert result["mean"]["amplitude_bias_m"] == pytest.approx(amp["predicted_mean"] - amp["observed"])
    assert result["mean"]["amplitude_coverage90"] == float(lo <= amp["observed"] <= hi)


def test_loss_gradient_with_drape_coefficient_term_on_the_dynamic_forward():
    # The default forward (100-step rollout) with both likelihood terms: rollout adjoint -> soft renderer VJP ->
    # pixel and drape-coefficient terms, against central differences. HOMO: a smooth function of the table.
    cfg = small_config(samples_per_epoch=1, forward="dynamic")
    assert cfg["sigma_dc"] > 0
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="homo", seed=5, config=cfg, threads=1)
    terms, grads = job.objective(job.theta, 0)
    no_dc = infer.FitJob([ASSET_IMAGE], 0.192, model="homo", seed=5, config=dict(cfg, sigma_dc=0.0), threads=1)
    assert terms["data"] > no_dc.objective(job.theta, 0)[0]["data"]  # the term is there
    [(_, an, fd)] = _directional_checks(job, lambda th: job.objective(th, 0)[0]["loss"], grads, 1e-5, ("mu",), seed=2)
    assert an == pytest.approx(fd, rel=1e-4)


def test_placement_noise_is_seeded_vertical_and_still_on_the_support_disk():
    rest = sim.ClothModel(sim.cusick_specimen(2)).rest_positions
    a = infer.placement_velocities(rest, np.random.default_rng(4), 0.1, 8)
    b = infer.placement_velocities(rest, np.random.default_rng(4), 0.1, 8)
    c = infer.placement_velocities(rest, np.random.default_rng(5), 0.1, 8)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    r = np.hypot(rest[:, 0], rest[:, 1])
    assert np.all(a[r <= 0.09] == 0) and np.all(a[:, :2] == 0)
    rim = a[r > 0.145, 2]
    assert 0.02 < np.sqrt(np.mean(rim ** 2)) < 0.3  # of the order of the amplitude at the rim
    assert np.all(infer.placement_velocities(rest, np.random.default_rng(4), 0.0, 8) == 0)


def test_bdp_predictive_spreads_over_placements_and_bad_placement_rejected(tmp_path):
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", config=small_config(), threads=1)
    job.run(epochs=1)
    preset = job.preset()
    assert preset["placement_noise"]["velocity_m_s"] > 0
    result = infer.evaluate(preset, [ASSET_IMAGE], samples=4, threads=2, config=small_config(), seed=1)
    lo, hi = result["images"][0]["drape_coefficient"]["interval90"]
    assert hi > lo and result["placement_noise"] == preset["placement_noise"]
    again = infer.evaluate(preset, [ASSET_IMAGE], samples=4, threads=1, config=small_config(), seed=1)
    # Seeded: the same draws whatever the thread count (to round-off: see test_same_seed_same_result_any_thread_count).
    assert_same_to_roundoff(again["images"][0], result["images"][0])
    bad = copy.deepcopy(preset)
    bad["placement_noise"]["velocity_m_s"] = -0.1
    with pytest.raises(infer.InputError, match="placement_noise"):
        infer.validate_preset(bad)


def test_gradient_clipping_scales_only_the_data_term_and_follows_the_median():
    cfg = small_config(samples_per_epoch=1, forward="dynamic")
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", seed=5, config=cfg, threads=1)
    terms, full = job.objective(job.theta, 0)
    assert terms["clip"] == 1.0 and terms["grad_norm"] > 0
    half, clipped = job.objective(job.theta, 0, clip=0.5 * terms["grad_norm"])
    # The loss is not clipped. Two evaluations agree to round-off, not bit for bit: the native buffers of the two
    # calls may sit at different alignments, which changes a vectorised reduction's rounding (seen in a clean-clone
    # run: 250.0891589666112 vs ...1176).
    assert half["clip"] == pytest.approx(0.5) and half["loss"] == pytest.approx(terms["loss"], rel=1e-12)
    # full = data + prior, clipped = data / 2 + prior: the data part has the reported norm, the prior part is
    # the KL's own gradient (unchanged).
    data = {k: 2 * (full[k] - clipped[k]) for k in full}
    assert np.sqrt(sum(np.sum(g * g) for g in data.values())) == pytest.approx(terms["grad_norm"], rel=1e-9)
    _, d_mu, d_sigma = infer.kl_divergence(job.theta["mu"], infer.softplus(job.theta["eta"]), job.prior_mu, job.prior_sigma)
    # full - data = 2 clipped - full: a difference of two evaluations, so round-off relative to the gradient's size
    # (entries ~1e2; the KL part is 0 at the prior's mean)
    assert np.allclose(full["mu"] - data["mu"], cfg["kl_weight"] * d_mu, rtol=1e-9,
                       atol=1e-12 * max(1.0, np.abs(full["mu"]).max()))
    # Threshold: factor x median of the first `window` recorded norms, once min_epochs are recorded; rejected
    # epochs ignored; later (exploding) norms do not move it.
    factor, window = cfg["gradient_clip"]["factor"], cfg["gradient_clip"]["window"]
    assert job.clip_threshold() is None
    job.history = [{"grad_norm": n} for n in (1.0, 50.0)] + [{"rejected": "x"}]
    assert job.clip_threshold() is None
    job.history.append({"grad_norm": 4.0})
    assert job.clip_threshold() == pytest.approx(factor * 4.0)
    job.history += [{"grad_norm": 2.0}] * (window - 3) + [{"grad_norm": 1e9}] * 3 * window
    assert job.clip_threshold() == pytest.approx(factor * 2.0)
    job.config = dict(cfg, gradient_clip={"factor": 0})
    assert job.clip_threshold() is None


@pytest.mark.dataset  # the provenance check reads the training images' files where the dataset is present
def test_shipped_presets_load_and_carry_their_settings_and_evaluation():
    folder = os.path.join(ROOT, "assets", "presets")
    names = sorted(f for f in os.listdir(folder) if f.endswith("_bdp.json"))
    assert len(names) == 15  # fabrics 1-5 and 11-20 of the shared data
    cal = infer.load_config()["calibration"]
    current = {"draws": cal["draws"], "iterations": cal["iterations"], "log_step": cal["log_step"],
               "shift_tolerance": cal["shift_tolerance"], "node_search": dict(cal["node_search"])}
    for name in names:
        preset = infer.load_preset(os.path.join(folder, name))
        assert preset["model"] == "bdp", name
        assert preset["likelihood"]["sigma_dc"] > 0 and preset["placement_noise"]["velocity_m_s"] > 0, name
        assert np.all(np.asarray(preset["posterior"]["bend"]["log_std"]) > 0), name
        ev = preset["evaluation"]
        assert ev["test_images"] >= 1 and ev["samples"] >= 1, name
        c = preset["calibration"]  # drape-calibrated: on the training DC, spread by the fabric scatter
        assert abs(c["dc_predicted"] - c["dc_observed"]) < 0.02 and c["slope_dc_per_log"] > 0, name
        g, L = c["global_log_std"], c["drape_log_sd"]
        assert preset["posterior"]["bend"]["global_log_std"] == g >= 0, name
        # g tops the simulated scatter up to L sqrt(2) (one training image); zero where the draws already
        # scatter that much (fabric 19: DC 0.94, near saturation, slope 0.045 per log unit).
        # In drape coefficient: (g s')^2 + sd_sim^2 = 2 (L s)^2, s the slope at the fitted stretching (where L is
        # defined), s' at the node search's.
        spread, simulated = 2 * (L * c["slope_dc_per_log_fit"]) ** 2, c["dc_sd_simulated"] ** 2
        assert (g * c["slope_dc_per_log"]) ** 2 + simulated == pytest.approx(spread) if g > 0 else simulated >= spread, name
        assert 0 < ev["mean"]["iou"] <= 1 and 0 <= ev["mean"]["mse"] < 0.2, name
        # Node search done, on the calibration's mesh, which the predictive (evaluate, garments) drapes.
        assert c["stretch_scale"] > 0 and c["mesh_level"] == preset["simulation"]["mesh_level"] == 3, name
        assert any(e["stretch_scale"] == c["stretch_scale"] for e in c["evaluated"]), name
        # Calibrated with the shipped fit.json's settings (a change of them means re-calibrating the presets).
        assert c["settings"] == current, name
        # Provenance names the training image from the repository, and the dataset's file (where the dataset
        # is present) is that image.
        prefix = "../shared/data/cusick/"
        for image in preset["provenance"]["images"]:
            assert not os.path.isabs(image["path"]) and image["path"].startswith(prefix), name
            dataset = paths.cusick_dataset_dir()
            data_file = os.path.join(dataset, image["path"][len(prefix):]) if dataset else None
            if dataset:
                with open(data_file, "rb") as f:
                    assert hashlib.sha256(f.read()).hexdigest() == image["sha256"], name


def _bdp_preset(bend, level=1, std=0.1):
    """A bdp preset with this median table (no fit): what calibrate_preset starts from."""
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", config=small_config(), threads=1)
    job.theta = {"mu": np.log(np.asarray(bend, dtype=float)), "eta": np.full((3, 5), infer.inverse_softplus(std))}
    preset = job.preset()
    preset["simulation"]["mesh_level"] = level
    return preset


def test_drape_calibration_matches_the_training_drape_coefficient_and_spreads_the_predictive(tmp_path):
    # Synthetic truth: the Cotton Blue table x 3 on circle1; the fit to calibrate is off by a factor 2.
    path = str(tmp_path / "synthetic.png")
    _synthetic_image(path, tables.COTTON_BLUE.bend * 3.0)
    observed = measure.drape_coefficient(measure.load_silhouette(path).mask)
    preset = _bdp_preset(tables.COTTON_BLUE.bend * 1.5)
    cfg = small_config()
    reports = []
    out = infer.calibrate_preset(preset, [path], config=cfg, threads=2, progress=reports.append)
    c = out["calibration"]
    assert c["dc_observed"] == pytest.approx(observed)
    # Progress: one report per set of drapes, in order, the same figures as the record's "evaluated".
    assert [r["evaluation"] for r in reports] == list(range(1, len(c["evaluated"]) + 1))
    assert np.allclose(sorted((r["stretch_scale"], np.log(r["bend_scale"]), r["dc"], r["nodes"]) for r in reports),
                       sorted((e["stretch_scale"], e["log_scale_shift"], e["dc"], e["nodes"]) for e in c["evaluated"]))
    assert all(r["dc_observed"] == c["dc_observed"] for r in reports)
    assert all(b["seconds"] >= a["seconds"] for a, b in zip(reports, reports[1:]))
    assert abs(c["dc_predicted_before"] - observed) > 0.02  # the uncalibrated fit is visibly off ...
    assert abs(c["dc_predicted"] - observed) < 0.01, c     # ... the calibrated one is not
    assert c["log_scale_shift"] > 0.2                      # towards the stiffer truth (log 2 = 0.69)
    mu0 = np.asarray(preset["posterior"]["bend"]["log_mean"])
    assert np.allclose(out["posterior"]["bend"]["log_mean"], mu0 + c["log_scale_shift"])
    assert np.allclose(out["posterior"]["bend"]["log_std"], preset["posterior"]["bend"]["log_std"])
    assert c["slope_dc_per_log"] > 0 and c["slope_dc_per_log_fit"] > 0
    # The spread, in drape coefficient: (global_log_std slope)^2 + simulated sd^2 = (L slope_fit)^2 (1 + 1/n), one
    # training image (slope_fit at the fitted stretching, where L is defined; slope at the node search's).
    L = cfg["calibration"]["drape_log_sd"]
    g = out["posterior"]["bend"]["global_log_std"]
    assert (g * c["slope_dc_per_log"]) ** 2 + c["dc_sd_simulated"] ** 2 == \
        pytest.approx(2 * (L * c["slope_dc_per_log_fit"]) ** 2, rel=1e-9)
    # The predictive now scatters by about L * sqrt(2) * slope in drape coefficient (64 draws: within 40 %).
    result = infer.evaluate(out, [path], samples=64, threads=2, config=cfg, seed=3)
    # Best of the first 1, 10 and all 64 draws: falls with the draws, ends at the reported best-of-64.
    curve = result["images"][0]["mse_best_of"]
    assert list(curve) == ["1", "10", "64"] and curve["1"] >= curve["10"] >= curve["64"] == result["images"][0]["mse"]
    assert result["mean"]["mse_best_of"] == curve  # one image
    lo, hi = result["images"][0]["drape_coefficient"]["interval90"]
    expected = 2 * 1.645 * np.sqrt(2) * L * c["slope_dc_per_log_fit"]
    assert 0.6 * expected < hi - lo < 1.4 * expected, (lo, hi, expected)
    assert lo < observed < hi
    # Idempotent: calibrating the calibrated preset starts again from the fit.
    again = infer.calibrate_preset(out, [path], config=cfg, threads=1)
    assert np.allclose(again["posterior"]["bend"]["log_mean"], out["posterior"]["bend"]["log_mean"])
    assert again["posterior"]["bend"]["global_log_std"] == pytest.approx(g)
    # Written and read back as a preset; homo/heter posteriors are not calibrated.
    infer.write_preset(str(tmp_path / "cal.json"), out)
    assert infer.load_preset(str(tmp_path / "cal.json"))["calibration"] == c
    with pytest.raises(infer.InputError, match="only a bdp"):
        infer.calibrate_preset(dict(preset, model="homo"), [path], config=cfg)


def test_node_search_scales_the_stretching_towards_the_training_node_count(tmp_path):
    # Synthetic truth on circle1: Cotton Blue bending with 4x stiffer stretching (DC ~0.6, 7 nodes); the preset
    # to calibrate has the Cotton Blue stretching, with which any bending that meets that drape coefficient
    # gives fewer nodes (5-6: measured). The search must move the stretching up and the node count towards 7.
    path = str(tmp_path / "synthetic.png")
    _synthetic_image(path, tables.COTTON_BLUE.bend, stretch=tables.COTTON_BLUE.stretch * 4.0)
    mask = measure.load_silhouette(path).mask
    observed_nodes = measure.node_count(measure.r_theta(mask, measure.calibration()))
    preset = _bdp_preset(tables.COTTON_BLUE.bend * 1.5)
    stretch0 = np.asarray(preset["stretch_N_m"])
    cfg = small_config()
    cfg["calibration"]["node_search"] = {"enabled": True, "min_log2": -2, "max_log2": 3, "tolerance": 0.5}
    out = infer.calibrate_preset(preset, [path], config=cfg, threads=2)
    c = out["calibration"]
    assert c["nodes_observed"] == observed_nodes
    assert c["stretch_scale"] >= 2.0, c
    assert abs(c["nodes_predicted"] - observed_nodes) < abs(c["nodes_predicted_before"] - observed_nodes), c
    assert np.allclose(out["stretch_N_m"], stretch0 * c["stretch_scale"])
    assert abs(c["dc_predicted"] - c["dc_observed"]) < 0.02, c
    assert c["mesh_level"] == c["fit_mesh_level"] == out["simulation"]["mesh_level"] == 1
    assert any(e["stretch_scale"] == c["stretch_scale"] and e["dc"] == c["dc_predicted"] for e in c["evaluated"])
    assert c["settings"]["node_search"] == {"enabled": True, "min_log2": -2, "max_log2": 3, "tolerance": 0.5,
                                            "patience": 2, "refine": False}
    assert c["settings"]["shift_tolerance"] == cfg["calibration"].get("shift_tolerance", 0.0)
    # The spread keeps the drape-coefficient scatter L * slope of the fitted stretching (where L is defined).
    g, L = out["posterior"]["bend"]["global_log_std"], cfg["calibration"]["drape_log_sd"]
    assert g > 0 and (g * c["slope_dc_per_log"]) ** 2 + c["dc_sd_simulated"] ** 2 == \
        pytest.approx(2 * (L * c["slope_dc_per_log_fit"]) ** 2, rel=1e-9)
    # Idempotent: the stretching, too, goes back to the fit's before calibrating again.
    again = infer.calibrate_preset(out, [path], config=cfg, threads=1)
    assert np.allclose(again["stretch_N_m"], out["stretch_N_m"])
    assert again["calibration"]["stretch_scale"] == c["stretch_scale"]
    # Switched off: the stretching stays; a bad search range is an error naming the setting.
    cfg["calibration"]["node_search"]["enabled"] = False
    off = infer.calibrate_preset(out, [path], config=cfg, threads=2)
    assert off["calibration"]["stretch_scale"] == 1.0 and np.allclose(off["stretch_N_m"], stretch0)
    assert off["calibration"]["settings"]["node_search"]["enabled"] is False  # recorded as configured
    assert off["calibration"]["settings"]["node_search"]["max_log2"] == 3
    cfg["calibration"]["node_search"] = {"enabled": True, "min_log2": 1, "max_log2": 3}
    with pytest.raises(infer.InputError, match="node_search"):
        infer.calibrate_preset(out, [path], config=cfg)
    cfg["calibration"]["node_search"] = {"enabled": True, "min_log2": -1, "max_log2": 3, "patience": 0}
    with pytest.raises(infer.InputError, match="patience"):
        infer.calibrate_preset(out, [path], config=cfg)


def test_calibration_skips_drapes_that_would_not_move_the_drape_coefficient(tmp_path):
    # shift_tolerance: a secant step smaller than it is not taken; a central difference about a centre within
    # log_step / 4 is reused. With a huge tolerance the calibration drapes exactly c = 0 and +-log_step (the first
    # slope) and reuses that difference as the slope at the fitted stretching: three sets of drapes in all.
    path = str(tmp_path / "synthetic.png")
    _synthetic_image(path, tables.COTTON_BLUE.bend * 3.0)
    preset = _bdp_preset(tables.COTTON_BLUE.bend * 3.0)  # at the truth: c = 0 is the closest of the three
    cfg = small_config()
    cfg["calibration"]["node_search"]["enabled"] = False
    cfg["calibration"].update(shift_tolerance=10.0, draws=4)
    c = infer.calibrate_preset(preset, [path], config=cfg, threads=2)["calibration"]
    step = cfg["calibration"]["log_step"]
    assert sorted(e["log_scale_shift"] for e in c["evaluated"]) == [-step, 0.0, step] and c["log_scale_shift"] == 0.0
    dc = {e["log_scale_shift"]: e["dc"] for e in c["evaluated"]}
    assert c["slope_dc_per_log_fit"] == c["slope_dc_per_log"] == pytest.approx((dc[step] - dc[-step]) / (2 * step))
    # Without it (0: the earlier behaviour) the secant steps go on towards the training drape coefficient.
    cfg["calibration"]["shift_tolerance"] = 0.0
    c0 = infer.calibrate_preset(preset, [path], config=cfg, threads=2)["calibration"]
    assert len(c0["evaluated"]) > 3
    assert abs(c0["dc_predicted"] - c0["dc_observed"]) <= abs(c["dc_predicted"] - c["dc_observed"])
    cfg["calibration"]["shift_tolerance"] = -1.0
    with pytest.raises(infer.InputError, match="shift_tolerance"):
        infer.calibrate_preset(preset, [path], config=cfg)


def test_node_search_steps_stop_rules():
    # The search's stepping on made-up node-count curves (observed 7, tolerance 0.5, range -3..4).
    def run(curve, patience=2, nodes0=None):
        calls = []

        def nodes_at(s):
            calls.append(s)
            return curve[s]
        visited = infer._stretch_search(curve[0] if nodes0 is None else nodes0, nodes_at, 7.0, -3, 4, 0.5, patience)
        assert visited == [c for c in calls if curve[c] is not None]  # each step asked once, in order
        return visited
    # Within tolerance at x1: no step.
    assert run({0: 6.6}) == []
    # A plateau of one step (fabric 5: 5.6 at x1 and x2) is crossed with patience 2, ends the search with 1.
    rising = {0: 5.6, 1: 5.6, 2: 6.2, 3: 6.8, 4: 7.9}
    assert run(rising) == [1, 2, 3]
    assert run(rising, patience=1) == [1]
    # Flat (as fabric 1: 7.1-7.4 from x1 to x16; here 5.0-5.1 against 7): two stale steps end it.
    assert run({0: 5.0, 1: 5.05, 2: 5.1, 3: 5.12, 4: 5.3}) == [1, 2]
    # Crossing ends it; so does the end of the range.
    assert run({0: 5.0, 1: 6.0, 2: 8.0, 3: 9.0}) == [1, 2]
    assert run({0: 5.0, 1: 5.5, 2: 5.9, 3: 6.2, 4: 6.4}) == [1, 2, 3, 4]
    # Too many nodes: the stretching goes down; a stretching that does not drape (None) ends the search.
    assert run({0: 9.0, -1: 8.2, -2: 7.3}) == [-1, -2]
    assert run({0: 9.0, -1: 8.2, -2: None}) == [-1]


def test_node_search_refinement_bisects_a_bracketing_octave():
    # signed: predictive mean nodes - observed per log2 stretching; tolerance 0.4.
    mid = infer._bracket_midpoint
    # Fabric 5 (calibrated, 7 observed): x4 6.5, x8 6.5, x16 7.75: the half-octave between x8 and x16.
    assert mid({0: -1.4, 1: -1.1, 2: -0.5, 3: -0.5, 4: 0.75}, 0.4) == 3.5
    # No bracket (all below), or a neighbour within tolerance: nothing to refine.
    assert mid({0: -1.4, 1: -1.1, 2: -0.5}, 0.4) is None
    assert mid({0: -1.0, 1: 0.3}, 0.4) is None
    assert mid({0: 0.5}, 0.4) is None
    # Going down in stretching (too many nodes), and of two brackets the one with the smaller gaps.
    assert mid({0: 1.2, -1: 0.9, -2: -0.6}, 0.4) == -1.5
    assert mid({0: -0.5, 1: 1.0, 2: -2.0}, 0.4) == 0.5
    # Octaves not adjacent (a stretching that did not drape in between) are not bracketed.
    assert mid({0: -0.8, 2: 0.8}, 0.4) is None


def test_global_log_std_scales_whole_draws_and_bad_values_are_rejected():
    preset = _bdp_preset(tables.COTTON_BLUE.bend, std=0.05)
    plain = infer.preset_bend_samples(preset, 50, np.random.default_rng(0), 400)
    preset["posterior"]["bend"]["global_log_std"] = 0.3
    scaled = infer.preset_bend_samples(preset, 50, np.random.default_rng(0), 400)
    # Same element noise (drawn first); each draw moved by one factor exp(g z).
    factor = np.log(scaled / plain)
    assert np.allclose(factor, factor[:, :1, :1, :1], atol=1e-12)
    assert np.std(factor[:, 0, 0, 0]) == pytest.approx(0.3, rel=0.15)
    for bad in (float("nan"), -0.1, "0.3", True):
        preset["posterior"]["bend"]["global_log_std"] = bad
        with pytest.raises(infer.InputError, match="global_log_std"):
            infer.validate_preset(preset)


def _tool(name):
    """tools/<name>.py loaded as a module (the tools are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, "tools", f"{name}.py"))
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def _copy_assets(folder, *rels):
    """Copies assets/cusick/<rel> to folder/<rel> (a hand-built dataset's files)."""
    for rel in rels:
        os.makedirs(os.path.dirname(folder / rel), exist_ok=True)
        shutil.copy(os.path.join(ROOT, "assets", "cusick", rel), folder / rel)


def test_drape_variability_pools_variances_over_fabrics():
    tool = _tool("drape_variability")
    per = {1: [0.1, 0.3], 2: [0.5, 0.5, 0.5], 3: [0.7]}  # variances 0.02, 0 (fabric 3: one drape, ignored)
    assert tool.pooled_sd(per) == pytest.approx(np.sqrt(0.01))
    with pytest.raises(ValueError):
        tool.pooled_sd({3: [0.7]})


def test_noise_floor_takes_the_best_other_drape(tmp_path):
    tool = _tool("noise_floor")
    a, b = "fabric_02/silhouettes/sample_02_capture_1.jpg", "fabric_05/silhouettes/sample_01_capture_1.jpg"
    mesh = "fabric_02/meshes/sample_02_capture_1.obj"
    _copy_assets(tmp_path, a, b, mesh)
    # Samples 1 and 2 are the same drape, sample 3 another: nearest 0, 0, m; pairs 0, m, m.
    rows = ["fabric,name,material,weave,density_kg_m2,thickness_mm,sample,capture,silhouette,mesh"]
    rows += [f"7,X,Cotton,Plain,0.2,0.3,{k},1,{img},{mesh}" for k, img in ((1, a), (2, a), (3, b))]
    rows += [f"7,X,Cotton,Plain,0.2,0.3,4,2,{b},"]  # another capture: not counted
    (tmp_path / "manifest.csv").write_text("\n".join(rows) + "\n")
    m = float(np.mean((measure.load_silhouette(str(tmp_path / a)).mask.astype(float)
                       - measure.load_silhouette(str(tmp_path / b)).mask.astype(float)) ** 2))
    assert m > 0.01
    out = tool.floor(7, data=str(tmp_path))
    assert out["samples"] == 3
    assert out["mse_nearest"] == pytest.approx(m / 3) and out["mse_median_pair"] == pytest.approx(m)
    assert out["hausdorff_m_nearest"] == pytest.approx(0.0, abs=1e-12)  # the same mesh for all three
    with pytest.raises(SystemExit, match="fabric 8"):
        tool.floor(8, data=str(tmp_path))


def test_noise_floor_best_of_k_curves_are_exact_expectations(tmp_path):
    import itertools
    tool = _tool("noise_floor")
    values = [0.3, 0.1, 0.4, 0.2, 0.5]
    for k in range(1, 6):  # against enumerating every k-subset
        brute = np.mean([min(c) for c in itertools.combinations(values, k)])
        assert tool.expected_best_of(values, k) == pytest.approx(brute)
    with pytest.raises(ValueError):
        tool.expected_best_of(values, 6)
    a, b = "fabric_02/silhouettes/sample_02_capture_1.jpg", "fabric_05/silhouettes/sample_01_capture_1.jpg"
    _copy_assets(tmp_path, a, b)
    # training sample 1 (captures a, b); test samples 2 (a) and 3 (b), sample 3 also re-draped as a
    rows = ["fabric,name,material,weave,density_kg_m2,thickness_mm,sample,capture,silhouette,mesh"]
    rows += [f"7,X,Cotton,Plain,0.2,0.3,{s},{c},{img}," for s, c, img in
             ((1, 1, a), (1, 2, b), (2, 1, a), (3, 1, b), (3, 2, a))]
    (tmp_path / "manifest.csv").write_text("\n".join(rows) + "\n")
    m = float(np.mean((measure.load_silhouette(str(tmp_path / a)).mask.astype(float)
                       - measure.load_silhouette(str(tmp_path / b)).mask.astype(float)) ** 2))
    out = tool.best_of_k_curve(7, 1, ks=(1, 2, 5), data=str(tmp_path))
    assert out["tests"] == 2
    # test 2 (a) against sample 3's (b, a): 1: m/2, 2: 0; test 3 (b) against sample 2's (a): m; k = 5 > pool: left out
    assert out["redrapes"]["pool"] == 1
    assert out["redrapes"]["best_of"] == pytest.approx({"1": (m / 2 + m) / 2})
    # both tests against the training sample's (a, b): one of each, best of 2 is 0
    assert out["training_sample_captures"]["best_of"] == pytest.approx({"1": m / 2, "2": 0.0})
    assert "hausdorff_m_redrapes" not in out  # no meshes in this manifest


def test_noise_floor_hausdorff_is_taken_at_the_best_mse_draw(tmp_path):
    import itertools
    tool = _tool("noise_floor")
    select, report = [0.3, 0.1, 0.4, 0.2, 0.5], [1.0, 2.0, 3.0, 4.0, 5.0]
    for k in range(1, 6):  # against enumerating every k-subset: the report value of the subset's smallest select
        brute = np.mean([report[min(c, key=lambda i: select[i])] for c in itertools.combinations(range(5), k)])
        assert tool.expected_at_best_of(select, report, k) == pytest.approx(brute)
    with pytest.raises(ValueError, match="report values"):
        tool.expected_at_best_of(select, report[:4], 2)
    a, b = "fabric_02/silhouettes/sample_02_capture_1.jpg", "fabric_05/silhouettes/sample_01_capture_1.jpg"
    mesh = "fabric_02/meshes/sample_02_capture_1.obj"
    _copy_assets(tmp_path, a, b, mesh)
    lifted = "fabric_02/meshes/lifted.obj"  # the same drape 1 cm higher: another mesh at a known distance
    with open(tmp_path / mesh) as f, open(tmp_path / lifted, "w") as g:
        for line in f:
            if line.startswith("v "):
                x, y, z = (float(t) for t in line.split()[1:4])
                line = f"v {x} {y} {z + 0.01}\n"
            g.write(line)
    # training sample 1; tests 2 (a, mesh), 3 (b, lifted), 4 (a, mesh); sample 4's silhouette equals sample 2's
    rows = ["fabric,name,material,weave,density_kg_m2,thickness_mm,sample,capture,silhouette,mesh"]
    rows += [f"7,X,Cotton,Plain,0.2,0.3,{s},1,{img},{m}" for s, img, m in
             ((1, a, mesh), (2, a, mesh), (3, b, lifted), (4, a, mesh))]
    (tmp_path / "manifest.csv").write_text("\n".join(rows) + "\n")
    h = measure.hausdorff_distance(str(tmp_path / mesh), str(tmp_path / lifted))
    assert 0.005 < h <= 0.0100001
    out = tool.best_of_k_curve(7, 1, ks=(1, 2, 5), data=str(tmp_path))
    haus = out["hausdorff_m_redrapes"]
    assert haus["pool"] == 2
    # test 2 against (3: lifted, 4: same) -> h, 0; test 3 against (2, 4): h, h; test 4 against (2: same, 3: lifted)
    assert haus["best_of"] == pytest.approx({"1": 2 * h / 3, "2": h / 3})
    # best of 2 by MSE picks the identical silhouette, which is the identical mesh here
    assert haus["at_best_mse_of"] == pytest.approx({"1": 2 * h / 3, "2": h / 3})


def test_protocol_table_averages_over_fabrics_with_fold_depth_columns():
    tool = _tool("paper_protocol")
    def row(mse, bias, cov, fit_s):
        mean = {"mse": mse, "hausdorff_m": 0.02, "dc_abs_error": 0.03, "dc_coverage90": 1.0, "node_within1": 0.5}
        if bias is not None:
            mean.update(amplitude_bias_m=bias, amplitude_coverage90=cov)
        return {"mean": mean, "samples": 100, "fit_seconds": fit_s}
    lines = tool.table_lines({"bdp": {1: row(0.04, -0.002, 0.5, 100), 2: row(0.02, 0.001, 1.0, 200),
                                      3: row(0.03, None, None, 300)}})
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    cells = dict(zip(header, (c.strip() for c in lines[2].strip("|").split("|"))))
    assert cells["model"] == "bdp" and cells["MSE (ours)"] == "0.0300" and cells["MSE (paper)"] == "0.0384"
    # the row without the fold-depth fields (an older run) is left out of their means
    assert cells["fold depth bias mm"] == "-0.5" and cells["fold depth 90% coverage"] == "0.75"
    assert cells["samples"] == "100" and cells["fit s"] == "200" and len(lines) == 3


def test_node_search_refinement_through_calibrate_preset(monkeypatch):
    # calibrate_preset end to end with a stand-in for the drapes (the search's logic, not the simulator, is under
    # test): the drape coefficient grows with the bending shift c (observed at c = 0.3), the node count with the
    # stretching 2^s (observed - 2 + 1.3 s). The octaves x2 (-0.7) and x4 (+0.6) bracket the observed count, neither
    # within tolerance 0.4: the refinement tries x2^1.5 (-0.05) and keeps it.
    obs = infer._Observation(ASSET_IMAGE, None)
    preset = _bdp_preset(tables.COTTON_BLUE.bend)
    stretch0 = np.asarray(preset["stretch_N_m"], dtype=float)
    base = {}
    calls = []

    def fake_drape(self, draws, seed, progress=None, cancel_event=None):
        level = float(np.mean(np.log(draws)))
        base.setdefault("level", level)  # the first set of drapes is at c = 0
        c = level - base["level"]
        s = math.log2(float(np.asarray(self.stretch)[0, 0] / stretch0[0, 0]))
        calls.append((s, c))
        k = len(draws)
        return [{"dc": obs.dc + 0.25 * (c - 0.3) + 0.01 * (i - (k - 1) / 2), "nodes": obs.nodes - 2 + 1.3 * s}
                for i in range(k)]

    monkeypatch.setattr(infer._Predictive, "drape", fake_drape)
    cfg = small_config()
    cfg["calibration"]["node_search"] = {"enabled": True, "min_log2": -2, "max_log2": 3, "tolerance": 0.4,
                                         "patience": 2, "refine": True}
    c = infer.calibrate_preset(copy.deepcopy(preset), [ASSET_IMAGE], config=cfg, threads=1)["calibration"]
    assert c["stretch_scale"] == pytest.approx(2 ** 1.5)
    assert sorted({round(e["stretch_scale"], 6) for e in c["evaluated"]}) == \
        [1.0, 2.0, round(2 ** 1.5, 6), 4.0]  # the search stops at the crossing; one half-octave
    assert c["nodes_predicted"] == pytest.approx(obs.nodes - 0.05)
    assert abs(c["log_scale_shift"] - 0.3) < 0.02 and abs(c["dc_predicted"] - obs.dc) < 0.005
    assert c["settings"]["node_search"]["refine"] is True
    # Without the refinement: x2 and x4 are within a quarter node of each other's gap (0.7, 0.6), so the smaller
    # change of stretching, x2.
    cfg["calibration"]["node_search"]["refine"] = False
    base.clear()
    out = infer.calibrate_preset(copy.deepcopy(preset), [ASSET_IMAGE], config=cfg, threads=1)
    assert out["calibration"]["stretch_scale"] == 2.0
    assert np.allclose(out["stretch_N_m"], stretch0 * 2.0)


def test_dc_term_compares_the_soft_drape_coefficient_less_its_bias_with_the_observation():
    # The soft silhouette's area exceeds the hard one's (the blur's halo): a fit estimates that bias on its mean
    # drape when it starts and subtracts it, so that at that drape the DC term measures the hard drape coefficient
    # against the observation's (hard) one.
    cfg = small_config(samples_per_epoch=1)
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="homo", seed=0, config=cfg, threads=1)
    job.config["init"]["scale_search"] = []
    job.run(epochs=1)
    assert 0.005 < job.dc_bias < 0.06, job.dc_bias  # measured 0.0255 on circle1 drapes
    w, o = job.workers[0], job.observations[0]
    x = w.model.simulate(w.model.parameters(stretch=job.stretch, bend=np.exp(job.previous_theta["mu"])),
                         mode="dynamic", record=False, **cfg["dynamic"])
    soft = w.renderer.render(x, w.faces)
    hard = np.asarray(render.hard_silhouette(job.camera, x, w.faces), dtype=float)
    px = o.calibration["px_per_m"]
    disk, span = np.pi * 0.09 ** 2, np.pi * (0.15 ** 2 - 0.09 ** 2)  # the Cusick tester's support and specimen radii
    dc_soft, dc_hard = (np.sum(soft) / px ** 2 - disk) / span, (np.sum(hard) / px ** 2 - disk) / span
    assert dc_soft - job.dc_bias == pytest.approx(dc_hard, abs=1e-12)
    pixel_only = infer.data_term(soft, o, job.sigma_obs, 0.0)[0]
    with_dc = infer.data_term(soft, o, job.sigma_obs, job.sigma_dc, job.dc_bias)[0]
    assert with_dc - pixel_only == pytest.approx((dc_hard - o.dc) ** 2 / (2 * job.sigma_dc ** 2), rel=1e-9)
    assert job.preset()["likelihood"]["dc_soft_bias"] == job.dc_bias
    fixed = infer.FitJob([ASSET_IMAGE], 0.192, model="homo", config=small_config(dc_soft_bias=0.0), threads=1)
    assert fixed.dc_bias == 0.0
