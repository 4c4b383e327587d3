"""fit --init PRESET: a fit that starts where a preset left off (its material, stretching, placement noise, mesh
level and effects), e.g. from a diagnosis's refit, with the effect then fitted together with the material."""
import copy
import json
import time

import numpy as np
import pytest

from drapelab import cli, infer
from drapelab._native import InputError

from fit_support import ASSET_IMAGE, SHIPPED_PRESET, small_config


def refit_like_preset():
    """The shipped preset as a diagnosis's tilt refit would leave it: a fitted tilt with a posterior sd, a fixed
    offset, its own placement noise."""
    p = infer.load_preset(SHIPPED_PRESET)
    p["active_effects"] = {
        "tilt": {"angle_rad": {"value": 0.12, "unit": "rad", "fitted": True, "std": 0.02,
                               "interval90": [0.087, 0.153]},
                 "azimuth_rad": {"value": 0.4, "unit": "rad", "fitted": True, "std": 0.1,
                                 "interval90": [0.235, 0.565]}},
        "offset": {"dx_m": {"value": 0.004, "unit": "m", "fitted": False},
                   "dy_m": {"value": 0.0, "unit": "m", "fitted": False}}}
    p["placement_noise"] = {"velocity_m_s": 0.03, "angular_modes": 16}
    return infer.validate_preset(p)


def test_the_job_starts_at_the_preset_and_skips_the_start_searches():
    p = refit_like_preset()
    cfg = small_config(samples_per_epoch=1)
    options = infer.init_options(p, {"config": cfg, "mesh_level": 1, "threads": 1}, {"tilt": None})
    # the preset's fixed effects stay fixed at its values, the named one is fitted
    assert options["effects"] == {"tilt": None, "offset": {"dx_m": 0.004, "dy_m": 0.0}}
    assert options["config"]["init"]["scale_search"] == [] and cfg["init"]["scale_search"]  # caller's untouched
    assert options["config"]["placement_noise"] == {"velocity_m_s": 0.03, "angular_modes": 16}
    f = cfg["init_preset"]["learning_rate_factor"]  # a start near the answer: smaller steps for everything
    assert 0 < f <= 1 and options["config"]["learning_rates"]["bdp"] == {
        k: f * v for k, v in cfg["learning_rates"]["bdp"].items()}
    assert options["config"]["effects"]["learning_rate"] == f * cfg["effects"]["learning_rate"]
    with pytest.raises(InputError, match="init_preset.learning_rate_factor"):
        infer.init_options(p, {"config": dict(cfg, init_preset={"learning_rate_factor": 0})}, None)
    job = infer.FitJob([ASSET_IMAGE], p["density_kg_m2"], model="bdp", seed=1, **options)
    given = job.start_from(p)
    assert given == ["tilt.angle_rad", "tilt.azimuth_rad"]
    np.testing.assert_allclose(job.log_bend0, p["posterior"]["bend"]["log_mean"], rtol=1e-12)
    np.testing.assert_allclose(job.prior_mu, p["posterior"]["bend"]["log_mean"], rtol=1e-12)  # prior "start"
    np.testing.assert_allclose(job.stretch, p["stretch_N_m"], rtol=0)  # kept strain-dependent
    mean, sd = job.family.posterior(job.theta)
    np.testing.assert_allclose(mean, p["posterior"]["bend"]["log_mean"], atol=1e-9)
    np.testing.assert_allclose(sd, np.maximum(p["posterior"]["bend"]["log_std"], infer.INIT_MIN_STD), rtol=1e-6)
    np.testing.assert_allclose(job.theta["effect_mu"], [0.12, 0.4])
    np.testing.assert_allclose(infer.softplus(job.theta["effect_eta"]), [0.02, 0.1], rtol=1e-9)
    assert job.effect_start["from"] == "the init preset"
    assert job.placement == (0.03, 16) and job.mesh_level == 1
    assert job.plan.values(job.theta["effect_mu"])["offset"] == {"dx_m": 0.004, "dy_m": 0.0}


def test_an_effect_the_preset_lacks_is_searched_from_off_and_the_presets_values_are_the_base():
    p = refit_like_preset()
    cfg = small_config(samples_per_epoch=1)
    options = infer.init_options(p, {"config": cfg, "mesh_level": 1, "threads": 1},
                                 {"tilt": None, "prestrain": {"strain": None}})
    job = infer.FitJob([ASSET_IMAGE], p["density_kg_m2"], model="bdp", seed=1, **options)
    assert job.start_from(p) == ["tilt.angle_rad", "tilt.azimuth_rad"]
    assert job.effect_start is None  # prestrain.strain has no value in the preset: the start search runs
    assert list(job.theta["effect_mu"][:2]) == [0.12, 0.4]  # registry order: tilt before prestrain
    assert list(job.plan.start_candidates(job.theta["effect_mu"])[0][:2]) == [0.12, 0.4]


def written_start(tmp_path, guard=False):
    """(the refit-like preset, its file, a circle1 config of one draw per epoch without the drape calibration and,
    unless `guard`, without the start guard)."""
    p = refit_like_preset()
    start = tmp_path / "refit.json"
    infer.write_preset(str(start), p)
    cfg = small_config(samples_per_epoch=1)
    cfg["calibration"]["enabled"] = False
    cfg["init_preset"] = dict(cfg["init_preset"], start_guard={"enabled": guard, "draws": 2})
    return p, start, cfg


def test_fit_from_a_preset_records_it_and_takes_its_model_density_and_effects(tmp_path):
    p, start, cfg = written_start(tmp_path)
    out = tmp_path / "continued.json"
    preset = infer.fit([ASSET_IMAGE], None, epochs=1, seed=2, out=str(out), config=cfg, threads=1,
                       mesh_level=1, init=str(start), effects={"tilt": {"angle_rad": None}})
    assert preset["model"] == p["model"] and preset["density_kg_m2"] == p["density_kg_m2"]
    assert preset["training"]["init"] == {"preset": str(start), "fabric": p["fabric"].get("name"),
                                          "model": "bdp", "effects_from_preset": ["tilt.angle_rad"]}
    assert preset["training"]["scale_search"] is None
    assert preset["training"]["effect_start_search"]["chosen"] == [0.12]
    tilt = preset["active_effects"]["tilt"]
    assert tilt["angle_rad"]["fitted"] and not tilt["azimuth_rad"]["fitted"]
    assert tilt["azimuth_rad"] == {"value": 0.4, "unit": "rad", "fitted": False}  # not named: the preset's value
    assert preset["active_effects"]["offset"]["dx_m"] == {"value": 0.004, "unit": "m", "fitted": False}
    assert abs(tilt["angle_rad"]["value"] - 0.12) < 0.05  # one epoch from the preset's value
    assert preset["placement_noise"] == {"velocity_m_s": 0.03, "angular_modes": 16}
    assert "init_bend" not in preset["provenance"]["options"]
    json.dumps(preset)  # nothing but JSON in it
    assert infer.load_preset(str(out))["training"]["init"]["preset"] == str(start)


def test_resuming_needs_the_same_start(tmp_path):
    p = refit_like_preset()
    cfg = small_config(samples_per_epoch=1)
    cfg["calibration"]["enabled"] = False
    ckpt = tmp_path / "fit.ckpt"
    infer.fit([ASSET_IMAGE], None, epochs=1, seed=2, config=cfg, threads=1, mesh_level=1, init=p,
              checkpoint=str(ckpt))
    resumed = infer.fit([ASSET_IMAGE], None, epochs=2, seed=2, config=cfg, threads=1, mesh_level=1, init=p,
                        resume=str(ckpt))
    assert resumed["training"]["epochs"] == 2
    # without the preset the fit would start from fit.json's stretching table: refused, naming the cause
    with pytest.raises(InputError, match="another stretching table.*--init"):
        infer.fit([ASSET_IMAGE], p["density_kg_m2"], model="bdp", epochs=2, seed=2, config=cfg, threads=1,
                  mesh_level=1, resume=str(ckpt), effects=infer.init_options(p, {}, None)["effects"])


def test_bad_init_and_a_missing_density_are_clear_errors(tmp_path):
    cfg = small_config(samples_per_epoch=1)
    with pytest.raises(InputError, match="density: give"):
        infer.fit([ASSET_IMAGE], None, epochs=1, config=cfg)
    with pytest.raises(InputError, match="cannot read preset"):
        infer.fit([ASSET_IMAGE], None, epochs=1, config=cfg, init=str(tmp_path / "missing.json"))
    bad = copy.deepcopy(refit_like_preset())
    bad["active_effects"]["tilt"]["angle_rad"]["value"] = 9.0
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(InputError, match="active_effects.tilt.angle_rad"):
        infer.fit([ASSET_IMAGE], None, epochs=1, config=cfg, init=str(path))
    with pytest.raises(InputError, match="init: expected a preset"):
        infer.fit([ASSET_IMAGE], None, epochs=1, config=cfg, init=3)


def fit_on_the_command_line(tmp_path, capsys, guard=False):
    """`fit --init` (the refit-like preset) --effects tilt, one epoch on circle1: (the start's file, the written
    preset's file, what it printed)."""
    _, start, cfg = written_start(tmp_path, guard)
    config = tmp_path / "fit.json"
    config.write_text(json.dumps(cfg))
    out = tmp_path / "continued.json"
    assert cli.main(["fit", "--images", ASSET_IMAGE, "--init", str(start), "--effects", "tilt", "--epochs", "1",
                     "--mesh-level", "1", "--config", str(config), "--threads", "1", "--out", str(out)]) == 0
    return start, out, capsys.readouterr().out


def test_the_command_line_fits_from_a_preset_without_density_or_model(tmp_path, capsys):
    _, out, text = fit_on_the_command_line(tmp_path, capsys)
    assert "wrote" in text and ": bdp," in text and "effect tilt: angle_rad" in text and "effect offset" in text
    assert infer.load_preset(str(out))["training"]["init"]["effects_from_preset"] == ["tilt.angle_rad",
                                                                                      "tilt.azimuth_rad"]
    assert cli.main(["fit", "--images", ASSET_IMAGE, "--epochs", "1", "--out", str(tmp_path / "x.json")]) == 2
    assert "density: give" in capsys.readouterr().err and not (tmp_path / "x.json").exists()


# ---------------------------------------------------------------- the start guard
def scaled(preset, factor):
    """`preset` with its mean bending table times `factor` (a material far from the drapes when factor is large)."""
    p = copy.deepcopy(preset)
    mu = np.asarray(p["posterior"]["bend"]["log_mean"]) + np.log(factor)
    p["posterior"]["bend"].update(log_mean=mu.tolist(), median_N_m=np.exp(mu).tolist())
    p["training"] = {"epochs": 3, "marker": "end"}
    p["provenance"] = dict(p.get("provenance") or {}, marker="end")
    return infer.validate_preset(p)


def guard(start, end, left=None, estimate=0.0, draws=2):
    cfg = small_config()
    return infer._start_guard(start, end, [ASSET_IMAGE], {"enabled": True, "draws": draws}, 4, 1, None, cfg, None,
                              left, estimate)


def test_the_start_guard_keeps_the_better_of_start_and_end_on_the_same_draws():
    p = infer.load_preset(SHIPPED_PRESET)
    p["simulation"] = dict(p["simulation"], mesh_level=1)
    stiff = scaled(p, 30.0)  # a drape that barely folds: far worse on the cotton's photo
    kept, record = guard(p, stiff)
    assert record["kept"] == "start" and record["start_mse"] < record["end_mse"]
    assert record["draws"] == 2 and record["mesh_level"] == 1 and record["seed"] == 4 + infer.START_GUARD_SEED_OFFSET
    # the start's posterior and calibration, this fit's training record and provenance
    assert kept["posterior"]["bend"]["log_mean"] == p["posterior"]["bend"]["log_mean"]
    assert kept["calibration"] == p["calibration"] and kept["training"]["marker"] == "end"
    assert kept["provenance"]["marker"] == "end"
    assert kept["metrics"]["training_image"] == {"iou": record["start_iou"], "mse": record["start_mse"], "best_of": 2}
    # the other way round the end is kept, unchanged
    kept, record = guard(stiff, p)
    assert record["kept"] == "end" and record["end_mse"] < record["start_mse"] and kept is p
    # the same preset on both sides: the same draws give the same MSE, and a tie keeps the end
    kept, record = guard(p, copy.deepcopy(p))
    assert record["start_mse"] == record["end_mse"] and record["kept"] == "end"


def test_the_start_guard_is_skipped_when_the_time_left_cannot_pay_for_it():
    p = infer.load_preset(SHIPPED_PRESET)
    end = scaled(p, 30.0)
    t0 = time.monotonic()
    kept, record = guard(p, end, left=3.0, estimate=40.0)
    assert time.monotonic() - t0 < 1.0  # nothing draped
    assert kept is end and record["kept"] == "end" and "start_mse" not in record
    assert record["skipped"].startswith("time budget: 3 s left, the start guard needs about 40 s")


def test_the_start_guard_runs_on_the_draws_the_time_left_pays_for():
    p = infer.load_preset(SHIPPED_PRESET)
    p["simulation"] = dict(p["simulation"], mesh_level=1)
    end = scaled(p, 30.0)
    # 10 draws in rounds of 1 estimated at 20 s: 1 s a draw and evaluation; 19 s left pays for 8 draws with the
    # run margin (19 // (1.1 x 2 x 1 s)), not for 10
    kept, record = guard(p, end, left=19.0, estimate=20.0, draws=10)
    assert record["draws"] == 8 and record["draws_planned"] == 10 and "skipped" not in record
    assert record["kept"] == "start" and {"start_mse", "end_mse"} <= set(record)
    assert kept["metrics"]["training_image"]["best_of"] == 8
    # below the fewest draws (min(draws, START_GUARD_MIN_DRAWS)) it is skipped
    kept, record = guard(p, end, left=15.0, estimate=20.0, draws=10)
    assert kept is end and record["kept"] == "end" and record["skipped"].startswith("time budget: 15 s left")
    # the estimate itself left, but not its margin: skipped rather than run past the budget
    kept, record = guard(p, end, left=20.5, estimate=20.0, draws=2)
    assert kept is end and "skipped" in record


def test_a_calibrated_fit_from_a_preset_keeps_its_start_guard_record(tmp_path):
    # the drape calibration returns a copy of the preset: the guard's record must reach the one written
    _, start, cfg = written_start(tmp_path, guard=True)
    cfg["calibration"] = dict(cfg["calibration"], enabled=True, draws=2, iterations=1,
                              node_search=dict(cfg["calibration"]["node_search"], enabled=False))
    out = tmp_path / "calibrated.json"
    infer.fit([ASSET_IMAGE], None, epochs=1, seed=2, out=str(out), config=cfg, threads=1, mesh_level=1,
              init=str(start))
    preset = infer.load_preset(str(out))
    g = preset["training"]["init"]["start_guard"]
    assert g["draws"] == 2 and g["kept"] in ("start", "end") and {"start_mse", "end_mse"} <= set(g)
    assert preset["training"]["init"]["preset"] == str(start)


def test_a_fit_from_a_preset_records_its_start_guard(tmp_path, capsys):
    start, out, text = fit_on_the_command_line(tmp_path, capsys, guard=True)
    preset = infer.load_preset(str(out))
    g = preset["training"]["init"]["start_guard"]
    assert g["draws"] == 2 and g["mesh_level"] == 1 and "skipped" not in g
    assert g["kept"] == ("start" if g["start_mse"] < g["end_mse"] else "end")
    assert f"best-of-2 MSE start {g['start_mse']:.4f}, end {g['end_mse']:.4f}" in text
    started = infer.load_preset(str(start))
    same = preset["active_effects"]["tilt"]["angle_rad"]["value"] == started["active_effects"]["tilt"]["angle_rad"]["value"]
    assert same == (g["kept"] == "start")  # one epoch moves the tilt; the kept start has the preset's
    assert preset["training"]["epochs"] == 1


def test_the_start_guard_never_drops_an_effect_the_fit_switched_on(tmp_path):
    # prestrain is not in the start: going back to the start would drop what the user asked for
    _, start, cfg = written_start(tmp_path, guard=True)
    preset = infer.fit([ASSET_IMAGE], None, epochs=1, seed=2, config=cfg, threads=1, mesh_level=1, init=str(start),
                       effects={"tilt": None, "prestrain": {"strain": None}})
    g = preset["training"]["init"]["start_guard"]
    assert g == {"skipped": "the fit switches on prestrain.strain, which the start does not carry; the fit's end "
                            "is kept", "kept": "end"}
    assert preset["active_effects"]["prestrain"]["strain"]["fitted"]


def test_bad_start_guard_settings_are_clear_errors(tmp_path):
    _, start, cfg = written_start(tmp_path, guard=True)
    for bad, field in (({"draws": 0}, "start_guard.draws"), ({"enabled": "yes"}, "start_guard.enabled"),
                       ([], "start_guard")):
        cfg["init_preset"] = dict(cfg["init_preset"], start_guard=bad)
        with pytest.raises(InputError, match=field):
            infer.fit([ASSET_IMAGE], None, epochs=1, config=cfg, threads=1, mesh_level=1, init=str(start))
