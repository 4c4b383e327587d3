"""diagnose: the contract of diagnosis.json and the report, the score test's gradient against central
differences, a tilted drape (tilt ranked first) and a control (nothing significant), bad input."""
import copy
import types
import json
import math
import time
import os

import numpy as np
import pytest

from drapelab import cli, diagnose, fit_effects, infer, measure, render, sim
from drapelab._native import InputError

from fit_support import ROOT, SHIPPED_PRESET as PRESET, small_config

SCHEMA = os.path.join(ROOT, "addon", "drapelab", "schemas", "diagnosis.schema.json")
BASE_KEYS = {"mse", "iou", "dc_error", "node_error", "amplitude_error", "loss", "redrape_mse", "redrape_mse_sd",
             "redrape_change_mse"}
RANKING_KEYS = {"effect", "statistic", "p_value", "refit", "gain", "explanation"}


def drape_image(path, effects=None, seed=0):
    """A silhouette of the preset's mean material on circle1 (one re-drape: placement noise of its own seed)."""
    preset = infer.load_preset(PRESET)
    model = sim.ClothModel(sim.cusick_specimen(1), density=preset["density_kg_m2"], effects=effects)
    p = model.parameters(stretch=preset["stretch_N_m"], bend=np.exp(np.asarray(preset["posterior"]["bend"]["log_mean"])))
    v0 = infer.placement_velocities(model.rest_positions, np.random.default_rng([seed, 99]), 0.05, 32)
    x = model.simulate(p, mode="dynamic", record=False, velocities0=v0)
    measure.write_image(path, 1.0 - np.asarray(render.hard_silhouette(render.orthographic_camera(), x, model.faces)))
    return path


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    folder = tmp_path_factory.mktemp("diagnose")
    return {"tilt": drape_image(str(folder / "tilt.png"), {"tilt": {"angle_rad": 0.3, "azimuth_rad": 0.0}}),
            "control": drape_image(str(folder / "control.png"))}


def _one_draw(images, names, seed=3):
    cfg = small_config()
    preset = infer.load_preset(PRESET)
    obs = diagnose._observations([images["tilt"]])
    pred, models, shapes, grads, _, _, pseudo, drawn = diagnose._joint_drapes(preset, obs, names, 1, seed, cfg, 1,
                                                                           None, 1, None, None)
    return (cfg, preset, obs, pred, models[0], shapes[0], grads[0], drawn["bend"][0], drawn["velocities"][0],
            pseudo)


def test_model_with_candidates_at_off_drapes_the_base_model_bit_for_bit(images):
    cfg, preset, _, pred, _, shape, _, draw, v0, _ = _one_draw(images, list(fit_effects.registry()))
    base = sim.ClothModel(sim.cusick_specimen(1), heterogeneous=True, density=preset["density_kg_m2"])
    x = base.simulate(base.parameters(stretch=pred.stretch, bend=draw), record=False, velocities0=v0, **cfg["dynamic"])
    assert np.array_equal(x, shape["x"])


@pytest.mark.parametrize("key", [
    "tilt.angle_rad", "density_variation.radial", "heterogeneity_map.cos2",
    pytest.param("prestrain.strain", marks=pytest.mark.xfail(reason=(
        "measured: the drape is not smooth in prestrain.strain at 0 (central differences 5e4, -9e3, 3e6 at steps "
        "1e-5, 1e-6, 1e-7; the adjoint -5e4): a kink or branch switch in the native prestrain term at zero strain"),
        strict=False)),
])
def test_score_gradient_matches_central_differences(images, key):
    # The score is d(excess pixel data term)/d(effect parameter) at the off value (the data term against the
    # measured image minus the mean one against P's predictive references), back-propagated through the recorded
    # rollout of one posterior draw (with its placement noise): against central differences of that term.
    name, param = key.split(".")
    cfg, _, obs, pred, m, _, grads, draw, v0, pseudo = _one_draw(images, [name])
    assert len(pseudo) == diagnose.PSEUDO_MIN
    refs = [types.SimpleNamespace(mask=im) for im in pseudo]
    renderer = render.SoftRenderer(pred.camera, sigma=cfg["render_sigma_px"])
    offs = {name: {p["name"]: p["off"] for p in fit_effects.registry()[name]["parameters"]}}

    def data(value):
        effects = copy.deepcopy(offs)
        effects[name][param] = value
        xe = m.simulate(m.parameters(stretch=pred.stretch, bend=draw, effects=effects), record=False,
                        velocities0=v0, **cfg["dynamic"])
        image = renderer.render(xe, m.faces)
        return (infer.data_term(image, obs[0], cfg["sigma_obs"], diagnose.SCORE_SIGMA_DC)[0]
                - np.mean([infer.data_term(image, ref, cfg["sigma_obs"], diagnose.SCORE_SIGMA_DC)[0] for ref in refs]))

    eps = 1e-6
    fd = (data(eps) - data(-eps)) / (2 * eps)
    assert grads[key] == pytest.approx(fd, rel=1e-4, abs=1e-6), key
    if name == "tilt":
        assert grads["tilt.azimuth_rad"] == 0.0  # no gradient at zero angle: the angle is scored turned too
        turn = diagnose.second_directions(sim.effects())["tilt"]
        assert turn == {"azimuth_rad": pytest.approx(math.pi / 2)}  # the registry's second_direction
        offs["tilt"]["azimuth_rad"] = turn["azimuth_rad"]
        fd = (data(eps) - data(-eps)) / (2 * eps)
        assert grads["tilt.angle_rad@azimuth_rad"] == pytest.approx(fd, rel=1e-4, abs=1e-6)
        assert abs(fd - grads[key]) > 1e-3 * abs(fd)  # another direction


def test_score_test_statistic():
    rng = np.random.default_rng(0)
    null = diagnose.score_test(rng.standard_normal((16, 2)))
    assert null["rank"] == 2 and null["p_value"] > 0.01
    shifted = diagnose.score_test(rng.standard_normal((16, 2)) + [3.0, 0.0])
    assert shifted["p_value"] < 1e-3 and shifted["p_value_f"] < 1e-4
    assert shifted["p_value_chi2"] < shifted["p_value_f"]  # chi2 is anti-conservative for few draws
    # one huge draw alone sets the mean's direction: not significant
    tails = rng.standard_normal((16, 2))
    tails[0] = [80.0, 80.0]
    heavy = diagnose.score_test(tails)
    assert heavy["p_value"] >= 0.05
    flat = diagnose.score_test(np.c_[rng.standard_normal(8), np.zeros(8)])  # a parameter without gradient
    assert flat["rank"] == 1
    # the measured images' own variability (scatter): a mean pull of 3 draw-sd is significant when the images are
    # exact, not when each image's re-drape moves the pull by 3 as well (K = 16: the draws-only test says 1e-3)
    g = rng.standard_normal((16, 2)) + [3.0, 0.0]
    exact = diagnose.score_test(g, scatter=np.zeros((16, 2)))
    assert exact["p_value"] == pytest.approx(exact["p_value_f"]) and exact["p_value"] < 1e-4
    noisy = diagnose.score_test(g, scatter=3.0 * rng.standard_normal((16, 2)))
    assert noisy["p_value"] > 0.01 and noisy["p_value_draws"] < 1e-3
    assert noisy["statistic"] < exact["statistic"] / 5


def test_tilted_drape_finds_the_shift_family_and_the_control_is_clean(images, tmp_path):
    # Fabric 2's preset on circle1, images of its mean material draped once (placement seed 0), K = 16 draws.
    # Measured (excess score, 2026-11-23): tilted drape offset T^2 103 p 1e-6, camera 118 p 2.6e-5, tilt 28
    # p 7.9e-4, then density_variation 0.023; control: smallest p 0.074 (prestrain), camera 0.14. On one image a
    # tilted tester, an off-centre specimen and a shifted camera centre all move the silhouette sideways: the score
    # test says that the data differ, the refits (MAX_REFITS, the CLI test runs one) say which
    # (docs/diagnose.md).
    cfg = small_config()
    out = str(tmp_path / "tilt")
    tilt = diagnose.diagnose(PRESET, [images["tilt"]], samples=16, seed=0, config=cfg, mesh_level=1,
                             time_budget=1.0, out_dir=out)  # no time for a refit: the CLI test runs one
    assert sorted(e["effect"] for e in tilt["ranking"]) == sorted(fit_effects.registry())
    tested = sum(not e["switch"] for e in tilt["ranking"])  # Bonferroni over the score-tested effects
    assert tilt["threshold"] == pytest.approx(0.01 / tested)
    significant = {e["effect"] for e in tilt["ranking"] if e["p_value"] is not None and e["p_value"] < tilt["threshold"]}
    assert "tilt" in significant and significant <= {"tilt", "offset", "camera"}, tilt["ranking"]
    assert {e["effect"] for e in tilt["ranking"][:diagnose.MAX_REFITS]} == {"tilt", "offset", "camera"}
    control = diagnose.diagnose(PRESET, [images["control"]], samples=16, seed=0, config=cfg, mesh_level=1,
                                time_budget=1.0)
    assert control["recommended"] is None
    assert min(e["p_value"] for e in control["ranking"] if not e["switch"]) >= control["threshold"], control["ranking"]
    # disk_contact is a switch: listed without a score test, not refitted unless named
    switch = next(e for e in tilt["ranking"] if e["effect"] == "disk_contact")
    assert switch["switch"] and switch["p_value"] is None and switch["refit"] is None
    assert "judged by its refit alone" in switch["explanation"] and "--candidates disk_contact" in switch["explanation"]
    assert tilt["switches"] == ["disk_contact", "self_contact"]  # registry order; both have a structural primary
    assert control["verdict"].startswith("Nothing significant")
    print("tilt", [(e["effect"], e["statistic"], e["p_value"], e["refit"], e["gain"]) for e in tilt["ranking"]],
          tilt["seconds"], "control", [(e["effect"], e["statistic"], e["p_value"]) for e in control["ranking"]],
          control["seconds"])


def test_redrape_change_is_the_median_pair_and_effect_change_pairs_the_draws():
    rng = np.random.default_rng(4)
    refs = [(rng.random((8, 8)) > 0.5).astype(float) for _ in range(4)]
    pairs = [float(np.mean((refs[i] - refs[j]) ** 2)) for i in range(4) for j in range(i + 1, 4)]
    assert diagnose.redrape_change(refs) == pytest.approx(np.median(pairs))
    assert diagnose.redrape_change(refs[:1]) is None
    base = [{"image": r} for r in refs[:3]] + [{"error": "diverged"}]
    refit = [{"image": refs[1]}, {"error": "diverged"}, {"image": refs[3]}, {"image": refs[0]}]
    # draw 0 against refit draw 0, draw 2 against refit draw 2; the failed ones left out
    assert diagnose.effect_change(base, refit) == pytest.approx(
        np.median([np.mean((refs[0] - refs[1]) ** 2), np.mean((refs[2] - refs[3]) ** 2)]))
    assert diagnose.effect_change(base[3:], refit[3:]) is None


def test_strength_of_moderate_leaves_direction_parameters_out():
    reg = fit_effects.registry()
    second = diagnose.second_directions(reg)
    tilt = reg["tilt"]["parameters"]
    assert diagnose.strength_of_moderate(reg["tilt"], {"angle_rad": 0.5 * tilt[0]["moderate"], "azimuth_rad": 3.0},
                                         second) == pytest.approx(0.5)
    dx = {q["name"]: q for q in reg["offset"]["parameters"]}
    v = {"dx_m": 0.3 * dx["dx_m"]["moderate"], "dy_m": 0.4 * dx["dy_m"]["moderate"]}
    assert diagnose.strength_of_moderate(reg["offset"], v, second) == pytest.approx(0.5)
    assert diagnose.strength_of_moderate(reg["offset"], {"dx_m": 0.0, "dy_m": 0.0}, second) == 0.0


def test_cli_writes_the_report_the_contract_and_a_refit(images, tmp_path, capsys):
    # --alpha 1: the tilt is "significant" whatever 4 draws say, so that its refit runs (the budget leaves it time
    # on a loaded machine too: at 20 s, with draws at 10-14 s under load, the refit had none).
    out = str(tmp_path / "report")
    cfg = tmp_path / "fit.json"
    cfg.write_text(json.dumps(small_config()))
    code = cli.main(["diagnose", "--preset", PRESET, "--images", images["tilt"], "--samples", "4", "--seed", "1",
                     "--mesh-level", "1", "--config", str(cfg), "--candidates", "tilt", "--alpha", "1",
                     "--time-budget", "40", "--report", out])
    assert code == 0
    with open(os.path.join(out, "diagnosis.json")) as f:
        d = json.load(f)
    assert {"base", "ranking", "recommended", "threshold", "history"} <= set(d)
    validate(d)
    assert set(d["base"]) == BASE_KEYS and all(np.isfinite(v) for v in d["base"].values())
    (entry,) = d["ranking"]
    assert RANKING_KEYS <= set(entry) and entry["effect"] == "tilt" and d["threshold"] == 1.0
    assert entry["parameters"] == ["tilt.angle_rad", "tilt.azimuth_rad", "tilt.angle_rad@azimuth_rad"]
    assert entry["rank"] == 2  # the azimuth has no gradient at zero angle; the turned angle has
    assert set(entry["refit"]) >= {"mse", "iou", "loss"} and np.isfinite(entry["gain"])
    reg = fit_effects.registry()
    assert entry["refit"]["strength_of_moderate"] == pytest.approx(
        abs(entry["refit"]["values"]["angle_rad"]) / reg["tilt"]["parameters"][0]["moderate"])
    assert entry["refit"]["effect_change_mse"] >= 0 and d["base"]["redrape_change_mse"] > 0
    # where the refit ended and how it got there: one path entry per epoch, the last one at the end's values
    r = entry["refit"]
    epochs = [h["epoch"] for h in r["path"]]
    assert epochs == list(range(1, r["epochs"] + 1))
    search = r["search"]
    stat = (entry.get("step") or {}).get("statistic")
    assert (search is not None) == (stat is not None and stat < 0)
    if search is not None:  # a refit from the step: the line search on draws of their own seed, the best kept
        # it starts along the direction of all four tilt steps where their first harmonic explains them, else at
        # the best step
        direction = entry["step"]["direction"]
        assert math.isclose(direction["values"]["azimuth_rad"], direction["direction_rad"])
        assert search["seed"] == 1 + diagnose.SEARCH_SEED_OFFSET
        assert search["step"] == diagnose.refit_start(entry["step"])[0]
        if direction["used"]:
            assert search["step"] == direction["values"]
        scored = [pt for pt in search["points"] if pt["mse"] is not None]
        assert 1 <= len(search["points"]) <= diagnose.search_evaluations(reg["tilt"])
        smallest = min(scored, key=lambda pt: pt["mse"])
        vertex = [pt for pt in scored if pt["vertex"]]
        kept_vertex = bool(vertex) and vertex[0]["mse"] <= smallest["mse"] + search["vertex_within"]
        assert search["best"] == (vertex[0] if kept_vertex else smallest)["values"]
        assert search["vertex_within"] == pytest.approx(diagnose.SEARCH_VERTEX_WITHIN * d["base"]["redrape_mse"])
        assert {pt["values"]["azimuth_rad"] for pt in search["points"]} == {search["step"]["azimuth_rad"]}
        if r["kept_start"]:
            assert r["values"] == pytest.approx(search["best"])
    if r["end"] is None:  # the search used up the refit's share of the budget: its best point, no epochs
        assert r["epochs"] == 0 and r["path"] == [] and r["kept_start"]
    else:
        assert r["epochs"] >= 1
        n = r["averaged_epochs"]
        if n:  # a refit from the step: the mean of its last epochs
            assert r["end"]["values"] == pytest.approx({q: np.mean([h["values"][q] for h in r["path"][-n:]])
                                                        for q in r["end"]["values"]})
        else:  # the last epoch's values, or the one before when a failed drape undid the last step
            assert any(h["values"] == pytest.approx(r["end"]["values"]) for h in r["path"][-2:])
        if not r["kept_start"]:
            assert r["end"]["values"] == pytest.approx(r["values"]) and r["end"]["mse"] == pytest.approx(r["mse"])
    # the refit is judged against the base on the comparison's draws: more than the score test's 4 when the budget
    # pays for them (measured: 20 of the 40 s budget's), at most COMPARISON_SAMPLES_MAX
    cmp = d["comparison"]
    assert d["samples"] <= cmp["samples"] == entry["refit"]["samples"] <= diagnose.COMPARISON_SAMPLES_MAX
    assert cmp["redrape_mse"] > 0
    assert entry["mse_fall"] == pytest.approx((cmp["mse"] - entry["refit"]["mse"]) / cmp["mse"])
    removed = cmp["mse"] - entry["refit"]["mse"]
    assert entry["fall_of_redrape"] == pytest.approx(removed / cmp["redrape_mse"])
    assert d["history"][1]["mse"] == cmp["mse"] and d["history"][1]["samples"] == d["history"][2]["samples"] == cmp["samples"]
    assert d["recommended"] == ("tilt" if entry["mse_fall"] >= diagnose.MIN_MSE_FALL
                                and entry["fall_of_redrape"] >= diagnose.MIN_FALL_OF_REDRAPE else None)
    if entry["mse_fall"] >= diagnose.MIN_MSE_FALL and d["recommended"] is None:
        assert "less than re-draping does" in d["verdict"]
    refit = infer.load_preset(os.path.join(out, "presets", "tilt.json"))
    assert refit["active_effects"]["tilt"]["angle_rad"]["fitted"] == (r["epochs"] > 0)
    assert refit["posterior"]["bend"]["log_mean"] == infer.load_preset(PRESET)["posterior"]["bend"]["log_mean"]
    assert [h["source"] for h in d["history"]] == ["preset training metrics", "diagnose base", "diagnose refit"]
    assert {"model", "effects", "mse", "dc_error"} <= set(d["history"][-1]) and "tilt" in d["history"][-1]["effects"]
    for name in ("index.html", "overlay_0.png", "rtheta_0.png", "intervals.png", "ranking.png", "history.png"):
        assert os.path.getsize(os.path.join(out, name)) > 0, name
    # the base is infer.evaluate's predictive (same draws, effects and placement noise for a seed)
    ev = infer.evaluate(PRESET, [images["tilt"]], samples=4, seed=1, threads=1, mesh_level=1, config=small_config())
    assert d["base"]["mse"] == pytest.approx(ev["mean"]["mse"], abs=1e-12)
    ev = infer.evaluate(PRESET, [images["tilt"]], samples=cmp["samples"], seed=1, threads=1, mesh_level=1,
                        config=small_config())  # ... and so is the comparison, on its own draws
    assert cmp["mse"] == pytest.approx(ev["mean"]["mse"], abs=1e-12)
    assert "diagnosis.json" in capsys.readouterr().out
    # The loop goes on: the refit records what it was refitted from, fit --init continues from it with the effect
    # and the material together, and diagnosing that preset on the same images charts the earlier versions too.
    assert refit["training"]["init"]["preset"] == PRESET and refit["training"]["init"]["by"] == "diagnose refit"
    if d["recommended"]:
        assert f"fit --init {os.path.join(out, 'presets', 'tilt.json')} --effects tilt" in d["verdict"]
    fit_cfg = small_config(samples_per_epoch=1)
    fit_cfg["calibration"]["enabled"] = False
    continued = str(tmp_path / "continued.json")
    infer.fit([images["tilt"]], None, epochs=1, seed=4, threads=1, config=fit_cfg, mesh_level=1,
              init=os.path.join(out, "presets", "tilt.json"), effects={"tilt": None}, out=continued)
    out2 = str(tmp_path / "report2")
    d2 = diagnose.diagnose(continued, [images["tilt"]], candidates="offset", samples=4, seed=1, config=small_config(),
                           mesh_level=1, max_refits=0, out_dir=out2)
    validate(d2)
    earlier = [h for h in d2["history"] if "report" in h]
    # P was trained on another image: its training metrics are not a version measured on these images
    assert [(h["model"], h["mse"]) for h in earlier] == [(h["model"], h["mse"]) for h in d["history"]
                                                         if h["source"] != diagnose.TRAINING_SOURCE]
    assert "images" not in d["history"][0] and d["history"][0]["source"] == diagnose.TRAINING_SOURCE
    assert all(h["images"] == d2["history"][-1]["images"] for h in d2["history"] if "images" in h)
    # the continued preset was fitted on exactly these images: its training metrics carry their fingerprint
    assert [h["source"] for h in d2["history"][len(earlier):]] == [diagnose.TRAINING_SOURCE, "diagnose base"]
    assert d2["history"][len(earlier)]["images"] == d2["history"][-1]["images"]
    assert os.path.getsize(os.path.join(out2, "history.png")) > 0
    with open(os.path.join(out2, "index.html")) as f:
        assert "model versions diagnosed on these images" in f.read()


def test_earlier_versions_come_from_the_lineage_reports_with_the_same_images(tmp_path):
    # P <- fit --init A/presets/x.json <- (diagnosis A of reference.json); B/presets/y.json is not in P's lineage
    def write(path, obj):
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            json.dump(obj, f)
    a, b = str(tmp_path / "A"), str(tmp_path / "B")
    write(os.path.join(a, "presets", "x.json"), {"training": {"init": {"preset": str(tmp_path / "reference.json")}}})
    write(str(tmp_path / "reference.json"), {"training": {}})
    p = str(tmp_path / "p.json")
    write(p, {"training": {"init": {"preset": os.path.relpath(os.path.join(a, "presets", "x.json"), str(tmp_path))}}})
    entry = {"model": "reference", "source": "diagnose base", "mse": 0.03, "dc_error": 0.05, "images": "K"}
    write(os.path.join(a, "diagnosis.json"), {"history": [
        entry, dict(entry, model="reference + x", source="diagnose refit", mse=0.015),
        dict(entry, model="other images", images="L"), "not an entry"]})
    write(os.path.join(b, "diagnosis.json"), {"history": [dict(entry, model="not in the lineage")]})
    cwd = os.getcwd()
    os.chdir(str(tmp_path))  # a relative init path is looked up from the working folder first
    try:
        assert [os.path.abspath(x) for x in diagnose._lineage(p)] == [os.path.join(a, "presets", "x.json"),
                                                                     str(tmp_path / "reference.json")]
        got = diagnose._earlier_history(p, None, "K")
        assert [(h["model"], h["mse"]) for h in got] == [("reference", 0.03), ("reference + x", 0.015)]
        assert all(os.path.abspath(h["report"]) == os.path.join(a, "diagnosis.json") for h in got)
        # rewriting report B: its own earlier entries come after the lineage's, each once
        again = diagnose._earlier_history(p, b, "K")
        assert [h["model"] for h in again] == ["reference", "reference + x", "not in the lineage"]
        # a loop in the lineage, a missing or broken preset: stops there
        write(str(tmp_path / "reference.json"), {"training": {"init": {"preset": p}}})
        assert len(diagnose._lineage(p)) == 3
        write(str(tmp_path / "reference.json"), {"training": {"init": {"preset": "missing.json"}}})
        assert len(diagnose._lineage(p)) == 2
        with open(p, "w") as f:
            f.write("{broken")
        assert diagnose._lineage(p) == [] and diagnose._earlier_history(p, None, "K") == []
    finally:
        os.chdir(cwd)


@pytest.mark.parametrize("kwargs, message", [
    ({"candidates": ["tilt", "no_such_effect"]}, "unknown effect 'no_such_effect'"),
    ({"preset": "/nonexistent/preset.json"}, "/nonexistent/preset.json"),
    ({"images": []}, "images"),
    ({"images": ["/nonexistent/img.png"]}, "/nonexistent/img.png"),
    ({"samples": 2}, "samples"),
    ({"time_budget": 0}, "time_budget"),
    ({"max_refits": -1}, "max_refits"),
    ({"max_refits": 1.5}, "max_refits"),
])
def test_bad_input_is_named(images, kwargs, message):
    args = dict(preset=PRESET, images=[images["control"]], config=small_config(), mesh_level=1)
    args.update(kwargs)
    with pytest.raises(infer.InputError, match=message):
        diagnose.diagnose(args.pop("preset"), args.pop("images"), **args)


def test_images_of_different_calibration_are_refused(images, tmp_path):
    small = str(tmp_path / "small.png")
    yy, xx = np.mgrid[:128, :128]
    measure.write_image(small, np.where(np.hypot(xx - 64, yy - 64) < 40, 0.0, 1.0))  # a dark disk on white
    with pytest.raises(infer.InputError, match="one calibration"):
        diagnose.diagnose(PRESET, [images["control"], small], config=small_config(), mesh_level=1)


def test_cancel_writes_what_is_done(images, tmp_path):
    import threading
    cancel = threading.Event()

    def progress(e):
        if e.get("done", 0) >= 3:
            cancel.set()

    out = str(tmp_path / "cancelled")
    d = diagnose.diagnose(PRESET, [images["control"]], samples=8, seed=0, config=small_config(), mesh_level=1,
                          candidates=["tilt"], threads=1, out_dir=out, progress=progress, cancel_event=cancel)
    assert d["cancelled"] and d["draws_used"] == 3 and d["ranking"][0]["p_value"] is not None
    with open(os.path.join(out, "diagnosis.json")) as f:
        written = json.load(f)
    assert written["cancelled"] is True
    validate(written)
    assert os.path.getsize(os.path.join(out, "index.html")) > 0


def validate(d):
    """diagnosis.json against the schema shipped in the add-on (addon/drapelab/schemas/)."""
    import jsonschema
    with open(SCHEMA) as f:
        jsonschema.Draft202012Validator(json.load(f)).validate(d)


def test_redrape_floor_is_the_best_of_k_mse_against_the_references():
    rng = np.random.default_rng(3)
    draws = [{"image": (rng.random((8, 8)) > 0.5).astype(float)} for _ in range(3)] + [{"error": "diverged"}]
    refs = [(rng.random((8, 8)) > 0.5).astype(float) for _ in range(4)]
    best = [min(float(np.mean((d["image"] - r) ** 2)) for d in draws[:3]) for r in refs]
    mean, sd = diagnose._redrape_floor(draws, refs)
    assert mean == pytest.approx(np.mean(best)) and sd == pytest.approx(np.std(best, ddof=1))
    assert diagnose._redrape_floor(draws, []) is None


def test_the_schema_refuses_a_broken_diagnosis():
    import jsonschema
    with open(SCHEMA) as f:
        schema = json.load(f)
    jsonschema.Draft202012Validator.check_schema(schema)
    good = {"preset": "p.json", "model": "bdp", "images": ["a.png"], "samples": 4, "seed": 0, "candidates": ["tilt"],
            "base": {k: 0.1 for k in BASE_KEYS}, "ranking": [], "recommended": None, "alternatives": [],
            "threshold": 0.01, "threshold_rule": "alpha", "switches": [], "test": "T2", "history": [], "cancelled": False,
            "seconds": {"total": 1.0}}
    validate(good)
    for key, value in (("recommended", 3), ("threshold", 0), ("base", {"mse": 0.1}), ("images", []),
                       ("ranking", [{"effect": "tilt"}]), ("alternatives", [{"effect": "camera"}])):
        with pytest.raises(jsonschema.ValidationError):
            validate(dict(good, **{key: value}))


def test_step_permutation_test_finds_the_step_that_brings_the_draws_closer():
    rng = np.random.default_rng(5)
    n, refs = 6, 12
    null = rng.normal(0.0, 1e-3, size=(2, n + refs))
    best, stat, p = diagnose.step_permutation_test(null, n)
    assert p > 0.01  # exchangeable: no labelling stands out
    shifted = null.copy()
    shifted[1, :n] -= 0.01  # step 1 lowers the MSE against the measured images only
    best, stat, p = diagnose.step_permutation_test(shifted, n)
    assert best == 1 and stat == pytest.approx(shifted[1, :n].mean() - shifted[1, n:].mean())
    assert p == pytest.approx(1.0 / math.comb(n + refs, n))  # only the observed labelling is as extreme
    # the choice of step is part of the statistic: with more steps of noise the same shift is less surprising
    wide = np.vstack([shifted[1], rng.normal(0.0, 1e-3, size=(40, n + refs))])
    assert diagnose.step_permutation_test(wide, n)[2] >= p
    # a step that moves every image alike (the drape changes, but not towards the measurements) is not significant
    common = null.copy()
    common[0] -= 0.01
    assert diagnose.step_permutation_test(common, n)[2] > 0.01
    # drawn labellings beyond the enumeration limit: the observed labelling is among them
    best, _, p_drawn = diagnose.step_permutation_test(shifted, n, max_permutations=500)
    assert best == 1 and p_drawn == pytest.approx(1.0 / 500)
    with pytest.raises(ValueError):
        diagnose.step_permutation_test(shifted, 0)


def _specimen_sets(rng, between, within, n=6, refs=24, redrapes=12, shift=0.0, steps=1):
    """deltas [steps, n + refs + redrapes] under the specimen model: the measured images re-drapes of one specimen
    (its expected change drawn with variance `between`), each reference a specimen of its own, the re-drapes of the
    mean specimen; `shift` moves the measured images' changes."""
    b = rng.normal(0.0, np.sqrt(between), size=(steps, 1))
    m = shift + b + rng.normal(0.0, np.sqrt(within), size=(steps, n))
    r = rng.normal(0.0, np.sqrt(between), size=(steps, refs)) + rng.normal(0.0, np.sqrt(within), size=(steps, refs))
    q = rng.normal(0.0, np.sqrt(within), size=(steps, redrapes))
    return np.hstack([m, r, q])


def test_step_specimen_test_holds_its_level_where_the_relabelling_does_not():
    rng = np.random.default_rng(11)
    n, refs, redrapes = 6, 24, 12
    p_spec, p_perm = [], []
    for _ in range(300):  # P uncertain: specimens differ as much as re-drapes of one do (B = W)
        d = _specimen_sets(rng, 1.0, 1.0, n, refs, redrapes)
        p_spec.append(diagnose.step_specimen_test(d, n, refs, redrapes)[2])
        p_perm.append(diagnose.step_permutation_test(d[:, :n + refs], n)[2])
    p_spec, p_perm = np.array(p_spec), np.array(p_perm)
    assert 0.02 <= np.mean(p_spec < 0.05) <= 0.08      # the specimen null: its level
    assert np.mean(p_perm < 0.05) > 0.15                # every image a specimen of its own: far too many
    # P sure of the material (B = 0): a change of 3 re-drape sds towards the measured images is found
    d = _specimen_sets(np.random.default_rng(3), 0.0, 1.0, n, refs, redrapes, shift=-3.0)
    best, stat, p, z = diagnose.step_specimen_test(d, n, refs, redrapes)
    assert best == 0 and p < 1e-3 and z < -3 and stat == pytest.approx(d[0, :n].mean() - d[0, n:n + refs].mean())
    # the choice of step is part of the statistic (Sidak over the steps)
    wide = np.vstack([d, _specimen_sets(np.random.default_rng(4), 0.0, 1.0, n, refs, redrapes, steps=7)])
    assert diagnose.step_specimen_test(wide, n, refs, redrapes)[2] > p
    # a step that moves every image alike is not significant; one that changes nothing has p 1
    common = _specimen_sets(np.random.default_rng(5), 0.0, 1.0, n, refs, redrapes) - 5.0
    assert diagnose.step_specimen_test(common, n, refs, redrapes)[2] > 0.01
    assert diagnose.step_specimen_test(np.zeros((2, n + refs + redrapes)), n, refs, redrapes)[2] == 1.0
    # one measured image and no re-drapes: nothing separates B from W, the widest null
    one = _specimen_sets(np.random.default_rng(6), 0.0, 1.0, 1, refs, 0, shift=-3.0)
    assert diagnose.step_specimen_test(one, 1, refs, 0)[2] > diagnose.step_specimen_test(d, n, refs, redrapes)[2]
    with pytest.raises(ValueError):
        diagnose.step_specimen_test(d, n, refs, redrapes + 1)


def test_effect_steps_are_the_stepped_parameters_at_their_moderate_strength():
    reg = fit_effects.registry()
    steps = diagnose.effect_steps(reg, list(reg))
    assert set(steps) == {n for n, e in reg.items() if not e["parameters"][0].get("structural")}
    for n, st in steps.items():
        primary = reg[n]["parameters"][0]
        stepped = reg[n].get("step_parameters") or [primary["name"]]
        assert st[0][1][primary["name"]] == primary["moderate"]
        turned = diagnose.second_directions(reg).get(n, {})
        if reg[n].get("step_diagonals"):  # the diagonals come last: both stepped parameters on
            assert len(st) == 8
            st = st[:4]
        for _, values in st:  # exactly one stepped parameter on, at +- its moderate; the others off, unless turned
            assert set(values) == {q["name"] for q in reg[n]["parameters"]}
            on = [q for q in reg[n]["parameters"] if values[q["name"]] not in (q["off"], turned.get(q["name"]))]
            assert len(on) == 1 and on[0]["name"] in stepped
            assert abs(values[on[0]["name"]]) == pytest.approx(abs(on[0]["moderate"]))
            assert on[0]["lower"] <= values[on[0]["name"]] <= on[0]["upper"]
    tilt = steps["tilt"]
    assert [v["angle_rad"] for _, v in tilt] == pytest.approx([0.15, -0.15, 0.15, -0.15])
    assert [v["azimuth_rad"] for _, v in tilt] == pytest.approx([0.0, 0.0, math.pi / 2, math.pi / 2])
    # bending_anisotropy's 2-fold axis at 0, 90, 45 and 135 degrees: cos2 = +-m, then sin2 = +-m
    aniso = [(v["cos2"], v["sin2"]) for _, v in steps["bending_anisotropy"]]
    assert aniso == pytest.approx([(0.75, 0.0), (-0.75, 0.0), (0.0, 0.75), (0.0, -0.75)])
    # an offset in eight directions 45 degrees apart, each 1 cm: one along y is not seen by steps along x, nor well
    # one at 45 degrees by steps along x and y (docs/diagnose.md, "Measured: directions")
    offset = [(v["dx_m"], v["dy_m"]) for _, v in steps["offset"]]
    d = 0.01 / math.sqrt(2.0)
    assert offset == pytest.approx([(0.01, 0.0), (-0.01, 0.0), (0.0, 0.01), (0.0, -0.01),
                                    (d, d), (-d, -d), (-d, d), (d, -d)])
    assert not reg["bending_anisotropy"].get("step_diagonals")


def test_refit_with_effect_fits_the_given_parameters_with_the_given_likelihood(images):
    # The recovery table's refit (tools/effect_recovery.py): by default every parameter of the effect and the
    # pixel term only (diagnose's); spec={param: None} fits that one (the others off), sigma_dc adds the fit's
    # drape-coefficient term.
    preset = infer.load_preset(PRESET)
    cfg = small_config(default_epochs=1)
    refit, job = diagnose.refit_with_effect(preset, [images["control"]], "prestrain", 1, 5, cfg)
    assert job.plan.names == ["prestrain.strain", "prestrain.warp_minus_weft"] and job.sigma_dc == 0.0
    refit, job = diagnose.refit_with_effect(preset, [images["control"]], "prestrain", 1, 5, cfg,
                                            spec={"strain": None}, sigma_dc=0.0076)
    assert job.plan.names == ["prestrain.strain"] and job.sigma_dc == 0.0076
    block = refit["active_effects"]["prestrain"]
    assert block["strain"]["fitted"] and not block["warp_minus_weft"]["fitted"]
    assert block["warp_minus_weft"]["value"] == 0.0 and np.isfinite(block["strain"]["value"])
    # start (the step test's best step): the fit begins there, without its own start search
    refit, job = diagnose.refit_with_effect(preset, [images["control"]], "prestrain", 1, 5, cfg,
                                            start={"strain": 0.02, "warp_minus_weft": 0.0})
    assert job.effect_start["chosen"] == [0.02, 0.0] and job.effect_start["from"] == "the diagnosis's step test"
    assert job.history[0]["effects"]["prestrain.strain"] == pytest.approx(0.02, abs=0.01)  # one step from there
    # ... with smaller steps than a fit's, and the iterate average of its last epochs as its values
    moderate = {q["name"]: q["moderate"] for q in fit_effects.registry()["prestrain"]["parameters"]}
    assert job.learning_rates["effect_mu"] == pytest.approx(
        diagnose.REFIT_START_LEARNING_RATE_FACTOR * infer.effect_settings(cfg)["learning_rate"]
        * np.array([moderate["strain"], moderate["warp_minus_weft"]]))
    averaged, job3 = diagnose.refit_with_effect(preset, [images["control"]], "prestrain", 1, 5,
                                                small_config(default_epochs=4), start={"strain": 0.02})
    assert job3.averaged_epochs == 2
    assert averaged["active_effects"]["prestrain"]["strain"]["value"] == pytest.approx(
        np.mean([h["effects"]["prestrain.strain"] for h in job3.history[-2:]]))
    # taken back to its start (diagnose keeps the start when the refit's end is worse on the same draws)
    before = copy.deepcopy(refit)
    back = diagnose.with_effect_values(refit, "prestrain", {"strain": 0.02, "warp_minus_weft": 0.0})
    assert refit == before  # a copy
    fitted, started = refit["active_effects"]["prestrain"]["strain"], back["active_effects"]["prestrain"]["strain"]
    assert started["value"] == 0.02 and started["std"] == fitted["std"]
    assert np.subtract(started["interval90"], 0.02) == pytest.approx(np.subtract(fitted["interval90"], fitted["value"]))
    assert back["posterior"] == refit["posterior"]


def test_step_draws_take_a_larger_share_only_to_reach_the_minimum():
    # 13 steps, 6 extra references, 455 s left after the score tests (fabric 1's circle3 diagnosis, 2026-11-24,
    # where the usual 40 % paid for 2 draws per step and no step test ran), 4.5 s per forward drape and lane
    k = diagnose.step_draws(16, 455.0, 4.5, 6, 13)
    usual = int((diagnose.STEP_BUDGET_SHARE * 455.0 - 6 * 4.5) / (4.5 * 13))
    assert usual < diagnose.MIN_SAMPLES and k == diagnose.MIN_SAMPLES
    # plenty of time: the usual share, capped at the draws there are
    assert diagnose.step_draws(16, 1e5, 3.3, 6, 13) == 16
    assert diagnose.step_draws(16, 300.0, 1.0, 6, 13) == int((diagnose.STEP_BUDGET_SHARE * 300.0 - 6) / 13)
    # not even the larger share pays for the minimum: what it pays for, which the caller refuses
    assert diagnose.step_draws(16, 50.0, 3.3, 6, 13) < diagnose.MIN_SAMPLES
    assert diagnose.step_draws(16, 0.0, 3.3, 6, 13) == 0


def test_steps_within_drops_the_diagonals_then_the_least_promising_candidates():
    reg = fit_effects.registry()
    steps = diagnose.effect_steps(reg, list(reg))
    axes = diagnose.effect_steps(reg, list(reg), diagonals=False)
    full = sum(len(v) for v in steps.values())
    # fabric 4's re-run on circle3 (2026-11-29): about 350 s left after the score tests, 2.4 s a forward drape, 18
    # extra references; the whole library paid for 2 draws a step and no step test ran
    left, forward, refs = 350.0, 2.4, 18
    assert diagnose.step_draws(16, left, forward, refs, full) < diagnose.MIN_SAMPLES
    p = {n: 0.5 for n in steps}
    p.update(offset=0.002, camera=0.006, tilt=None)
    kept, k, dropped = diagnose.steps_within(steps, axes, p, 16, left, forward, refs)
    assert k == diagnose.MIN_SAMPLES == diagnose.step_draws(16, left, forward, refs, sum(len(v) for v in kept.values()))
    # only the offset's four diagonals went: its axis steps, 90 degrees apart, stay; every candidate is still tested
    assert set(kept) == set(steps) and kept["offset"] == steps["offset"][:4]
    assert dropped == [f"offset:{label}" for label, _ in steps["offset"][4:]]
    assert all(kept[n] == steps[n] for n in steps if n != "offset")
    # less time: whole candidates go, the largest score p first (untested as p = 1), the promising stay
    kept, k, dropped = diagnose.steps_within(steps, axes, p, 16, 250.0, forward, refs)
    assert k == diagnose.MIN_SAMPLES
    assert {"offset", "camera"} <= set(kept) and "tilt" not in kept
    assert dropped.index(f"tilt:{steps['tilt'][0][0]}") < min(
        i for i, d in enumerate(dropped) if not d.startswith(("offset:", "tilt:")))
    n_kept = sum(len(v) for v in kept.values())
    assert diagnose.step_draws(16, 250.0, forward, refs, n_kept) >= diagnose.MIN_SAMPLES
    assert n_kept + len(dropped) == full
    # as few as possible are dropped: putting back the last one dropped no longer fits
    last = dropped[-1].split(":")[0]
    assert diagnose.step_draws(16, 250.0, forward, refs, n_kept + len(steps[last])) < diagnose.MIN_SAMPLES
    # enough time: nothing dropped, the inputs untouched
    kept, k, dropped = diagnose.steps_within(steps, axes, p, 16, 1e5, forward, refs)
    assert kept == steps and dropped == [] and k == 16
    # no time at all: one candidate is left, and too few draws (the caller does not run the test)
    kept, k, dropped = diagnose.steps_within(steps, axes, p, 16, 10.0, forward, refs)
    assert list(kept) == ["offset"] and k < diagnose.MIN_SAMPLES


def test_step_drapes_run_draw_after_draw_and_stop_at_their_deadline(monkeypatch):
    steps = {"tilt": [("a", {"angle_rad": 0.1}), ("b", {"angle_rad": -0.1})], "camera": [("c", {"scale_error": 0.03})]}
    tasks = diagnose.step_tasks(steps, 3)
    assert [(n, si, u) for n, si, _, u in tasks] == [(n, si, u) for u in range(3)
                                                     for n, si in (("tilt", 0), ("tilt", 1), ("camera", 0))]
    # complete_draws: the marker False (not draped) ends the count; None (a failed drape) does not
    assert diagnose.complete_draws({"x": [1, None, False], "y": [1, 1, 1]}, 3) == 2
    assert diagnose.complete_draws({"x": [1, 1, 1], "y": [False, 1, 1]}, 3) == 0
    assert diagnose.complete_draws({"x": [1, None]}, 2) == 2

    started = []

    class Model:
        def parameters(self, **kw):
            return kw

    def fake_forward(m, p, v0, pred, config, cancel_event, with_positions=False):
        started.append(time.monotonic())
        time.sleep(0.1)
        return (np.ones((2, 2)), np.zeros((3, 3))) if with_positions else np.ones((2, 2))

    class Light:  # _ForwardModels: one model per lane and stepped effect
        def get(self, lane, effect=None, off=None):
            return Model()

    monkeypatch.setattr(diagnose, "_forward_silhouette", fake_forward)
    pred = type("P", (), {"stretch": None})()
    drawn = {"bend": [None] * 8, "effects": None, "offs": {"tilt": {}, "camera": {}}, "velocities": [None] * 8,
             "light": Light()}
    used = list(range(8))
    positions = {}
    full = diagnose._step_drapes(pred, drawn, steps, used, {}, 2, None, None, positions=positions)
    assert {len(v) for v in full.values()} == {8} and all(im is not None for v in full.values() for im in v)
    assert positions.keys() == full.keys() and all(x.shape == (3, 3) for v in positions.values() for x in v)
    started.clear()
    deadline = time.monotonic() + 0.5  # 24 drapes of 0.1 s on two lanes take 1.2 s
    cut = diagnose._step_drapes(pred, drawn, steps, used, {}, 2, None, None, deadline=deadline)
    lengths = {len(v) for v in cut.values()}
    assert len(lengths) == 1 and 0 < lengths.pop() < 8  # complete draws only, fewer than all
    assert started and max(started) < deadline  # no drape started after the deadline
    past = diagnose._step_drapes(pred, drawn, steps, used, {}, 1, None, None, deadline=time.monotonic())
    assert all(v == [] for v in past.values())


def test_forward_models_drape_as_the_scoring_model_with_every_candidate_does():
    # the step test's and the references' drapes run on models with P's effects and the one stepped effect
    # (_ForwardModels); the scored draws on one with every candidate at its off value: the drapes must be the same,
    # up to the round-off of summing the terms in another order
    reg = fit_effects.registry()
    names = [n for n in reg if not diagnose._is_switch(reg[n])]
    offs = {n: {q["name"]: q["off"] for q in reg[n]["parameters"]} for n in names}
    mesh = sim.cusick_specimen(1)
    joint = sim.ClothModel(mesh, heterogeneous=True, effects=offs)
    light = diagnose._ForwardModels(mesh, sim.DEFAULT_DENSITY, {}, 720.0, 1)
    v0 = 0.05 * np.random.default_rng(5).standard_normal((joint.num_vertices, 3))
    steps = diagnose.effect_steps(reg, ["tilt", "offset", "camera", "prestrain"], diagnose.second_directions(reg))
    cases = [(None, {})] + [(n, values) for n, st in steps.items() for _, values in st[:2]]
    for n, values in cases:
        m = light.plain[0] if n is None else light.get(0, n, offs[n])
        assert m is (light.get(0) if n is None else light.get(0, n))  # built once
        p = m.parameters(effects={n: values} if n else {})
        pj = joint.parameters(effects={**offs, **({n: values} if n else {})})
        x = m.simulate(p, steps=15, velocities0=v0, record=False)
        xj = joint.simulate(pj, steps=15, velocities0=v0, record=False)
        y, yj = infer._observed(m, x, p), infer._observed(joint, xj, pj)
        if n is None:  # every candidate off: the same drape bit for bit
            assert np.array_equal(y, yj)
        else:  # a stepped effect on: its force summed with the others in another order (1e-15 m on circle1)
            assert np.abs(y - yj).max() < 1e-12, (n, values)


def test_confirmation_plan_keeps_the_most_promising_the_time_pays_for():
    screen = {"tilt": {"p_value": 0.001, "statistic": -0.01}, "offset": {"p_value": 0.05, "statistic": -0.002},
              "camera": {"p_value": 0.05, "statistic": -0.004}, "damping": {"p_value": 0.5, "statistic": 0.01}}
    steps_of = {"tilt": 4, "offset": 2, "camera": 2, "damping": 1}
    # plenty of time: every candidate below SCREEN_P_MAX, most promising first (p, then statistic), all fresh draws
    assert diagnose.confirmation_plan(screen, steps_of, 1e4, 1.0, 12, 4) == (["tilt", "camera", "offset"], 12)
    # 8 steps x 1 s: 60 s pays for 7 draws of all three
    assert diagnose.confirmation_plan(screen, steps_of, 60.0, 1.0, 12, 4) == (["tilt", "camera", "offset"], 7)
    # 30 s: 3 draws of all three would not double the screen's 4; without offset (6 steps) 5 draws do
    assert diagnose.confirmation_plan(screen, steps_of, 30.0, 1.0, 12, 4) == (["tilt", "camera"], 5)
    # nothing below SCREEN_P_MAX, or no time: nothing confirmed
    assert diagnose.confirmation_plan({"damping": screen["damping"]}, steps_of, 1e4, 1.0, 12, 4) == ([], 0)
    assert diagnose.confirmation_plan(screen, steps_of, -5.0, 1.0, 12, 4) == ([], 0)
    # fewer fresh draws than the screen had: all of them are enough
    assert diagnose.confirmation_plan(screen, steps_of, 1e4, 1.0, 2, 4) == (["tilt", "camera", "offset"], 2)
    # the tests' own computation, 0.25 s a draw and step, on the screen's 4 draws again (8 s) and on each fresh
    # draw: 60 s pays for 5 draws of all three, not 7
    assert diagnose.confirmation_plan(screen, steps_of, 60.0, 1.0, 12, 4, 0.25) == (["tilt", "camera", "offset"], 5)
    # 40 s: (40 - 8) / 10 = 3 draws of all three would not double the screen's; without offset (40 - 6) / 7.5 = 4
    assert diagnose.confirmation_plan(screen, steps_of, 40.0, 1.0, 12, 4, 0.25) == (["tilt", "camera"], 4)


def test_the_confirmation_keeps_time_for_the_refits_the_score_already_makes_likely():
    # nothing significant by its score alone (combined p = 2 x score p at best): one refit evaluation is kept, for
    # what the confirmation may make significant, not max_refits of them (fabrics 3-5 on circle3: the reserve for
    # three left the confirmation no time, and nothing was refitted)
    assert diagnose.refits_reserved({"camera": 0.049, "tilt": 0.17, "offset": None}, 0.001, 3) == 1
    # two candidates already below the threshold by their score: two evaluations; never more than max_refits
    assert diagnose.refits_reserved({"camera": 1e-5, "offset": 2e-6, "tilt": 0.3}, 0.001, 3) == 2
    assert diagnose.refits_reserved({"a": 1e-9, "b": 1e-9, "c": 1e-9, "d": 1e-9}, 0.001, 3) == 3
    # a score p just under the threshold is not yet significant combined (2 x 0.0006 > 0.001); no refits: none kept
    assert diagnose.refits_reserved({"camera": 0.0006}, 0.001, 3) == 1
    assert diagnose.refits_reserved({"camera": 1e-9}, 0.001, 0) == 0


def test_alternatives_are_the_refits_within_half_the_redrape_floor_of_the_recommended():
    def entry(name, mse):
        return {"effect": name, "refit": {"mse": mse}}
    gaining = [entry("heterogeneity_map", 0.0133), entry("density_variation", 0.0200), entry("camera", 0.0240)]
    # floor 0.015: half of it is 0.0075; density 0.0067 above the best is as good, camera 0.0107 above is not
    got = diagnose.alternatives(gaining, 0.015)
    assert [a["effect"] for a in got] == ["density_variation"]
    assert got[0]["above"] == pytest.approx(0.0067) and got[0]["of_redrape"] == pytest.approx(0.0067 / 0.015)
    assert got[0]["of_redrape"] < diagnose.ALTERNATIVE_WITHIN
    # a larger floor takes camera in too; no floor, a single refit or none: no alternatives
    assert [a["effect"] for a in diagnose.alternatives(gaining, 0.03)] == ["density_variation", "camera"]
    assert diagnose.alternatives(gaining, None) == [] and diagnose.alternatives(gaining[:1], 0.015) == []
    assert diagnose.alternatives([], 0.015) == []
    words = diagnose.alternatives_words(got, "heterogeneity_map", 16)
    assert "density_variation (best-of-16 MSE 0.0200, 0.45 of the re-drape floor above)" in words
    assert "do not tell it from heterogeneity_map" in words and diagnose.alternatives_words([], "x", 16) == ""


def test_screened_step_test_confirms_on_fresh_draws_as_the_full_test_would(images, tmp_path, monkeypatch):
    # Three tilted drapes (placement seeds 0-2), 8 draws, tilt and offset; with the screen forced (SCREEN_BELOW
    # above 1: any budget screens), every candidate is screened on SCREEN_DRAWS draws and those below SCREEN_P_MAX
    # are confirmed on the other draws: a confirmed candidate's step test is then the full test's on all 8 draws.
    folder = tmp_path / "tilted"
    folder.mkdir()
    tilted = [images["tilt"]] + [drape_image(str(folder / f"tilt{s}.png"), {"tilt": {"angle_rad": 0.3,
                                                                                     "azimuth_rad": 0.0}}, seed=s)
                                 for s in (1, 2)]
    cfg = small_config()
    args = dict(candidates="tilt,offset", samples=8, seed=0, config=cfg, mesh_level=1, max_refits=0)
    full = diagnose.diagnose(PRESET, tilted, time_budget=1e4, **args)
    assert full["step_test"]["draws"] == 8 and full["step_test"]["screen"] is None
    monkeypatch.setattr(diagnose, "SCREEN_BELOW", 10.0)
    # three images and four draws: against the specimen null (2026-11-28) the tilt's screen p is 0.24, the offset's
    # 0.67; a screen line between them confirms the one and not the other
    monkeypatch.setattr(diagnose, "SCREEN_P_MAX", 0.5)
    screened = diagnose.diagnose(PRESET, tilted, time_budget=1e4, out_dir=str(tmp_path / "report"), **args)
    with open(tmp_path / "report" / "diagnosis.json") as f:
        validate(json.load(f))
    info = screened["step_test"]["screen"]
    # the refits' evaluations are planned at the drape time measured on the step drapes
    for d in (full, screened):
        assert d["step_test"]["forward_s"] > 0
        assert d["refit_evaluation_s"] == pytest.approx(8 * d["step_test"]["forward_s"] * diagnose.EVALUATION_OVERHEAD)
    assert screened["step_test"]["draws"] == diagnose.SCREEN_DRAWS == info["draws"]
    assert "tilt" in info["confirmed"] and info["confirmation_draws"] == 8 - diagnose.SCREEN_DRAWS
    assert info["confirmed"] == [n for n in info["confirmed"] if n in info["passed"]]
    by_name = {e["effect"]: e for e in screened["ranking"]}
    full_by_name = {e["effect"]: e for e in full["ranking"]}
    for name, e in by_name.items():
        st = e["step"]
        assert st["screen"]["draws"] == diagnose.SCREEN_DRAWS
        if name in info["confirmed"]:
            assert st["draws"] == 8 and "confirmed on 4 fresh draws" in e["explanation"]
            assert st["statistic"] == pytest.approx(full_by_name[name]["step"]["statistic"], rel=1e-9)
            assert st["p_value"] == pytest.approx(full_by_name[name]["step"]["p_value"], rel=1e-9)
        else:  # its p is the screen's, at least SCREEN_P_MAX
            assert st["draws"] == diagnose.SCREEN_DRAWS
            assert st["p_value"] == max(st["screen"]["p_value"], diagnose.SCREEN_P_MAX)
            assert "not confirmed" in e["explanation"]
    assert "offset" not in info["confirmed"]
    print({n: (e["step"]["screen"]["p_value"], e["step"]["p_value"], e["p_value"]) for n, e in by_name.items()},
          screened["seconds"], full["seconds"])


def test_refit_mode_searches_or_steps_with_what_the_later_refits_leave():
    # 40 s an evaluation, a search of 5 points plus end and start: 280 s
    assert diagnose.refit_mode(12.0, 0.0, 40.0, 280.0, True) == "epochs"  # its share pays for epochs
    assert diagnose.refit_mode(-3.0, 300.0, 40.0, 280.0, True) == "search"  # no epochs: its search's best point
    assert diagnose.refit_mode(-3.0, 100.0, 40.0, 280.0, True) == "step"  # one evaluation: the step itself
    assert diagnose.refit_mode(-3.0, 30.0, 40.0, 280.0, True) is None  # not even that
    assert diagnose.refit_mode(-3.0, 300.0, 40.0, 280.0, False) is None  # no start: only epochs would refit it
    # a grid search needs no start: it searches when the time pays for it, and without a start never steps
    assert diagnose.refit_mode(-3.0, 300.0, 40.0, 280.0, False, True) == "search"
    assert diagnose.refit_mode(-3.0, 100.0, 40.0, 280.0, False, True) is None
    assert diagnose.refit_mode(-3.0, 100.0, 40.0, 280.0, True, True) == "step"


def test_refit_order_sums_the_ranks_of_both_tests():
    def entry(name, p, stat=None):
        return {"effect": name, "p_value": p, **({"step": {"statistic": stat}} if stat is not None else {})}
    # seed 651's offset drapes: the offset's step statistic was the strongest, its combined p only 5th, and the
    # three refits by p alone missed it
    offset = [entry("prestrain", 1.4e-6, -0.0193), entry("density_variation", 6.7e-6, -0.0091),
              entry("rest_curvature", 7.1e-6, -0.0200), entry("camera", 4.2e-5, -0.0069),
              entry("offset", 1.1e-4, -0.0588), entry("bending_anisotropy", 1.1e-4, -0.0318)]
    order = [e["effect"] for e in diagnose.refit_order(offset)]
    # ranks (p, step): prestrain (0, 3), offset (4, 0), rest_curvature (2, 2), density_variation (1, 4), ...
    assert order == ["prestrain", "offset", "rest_curvature", "density_variation", "bending_anisotropy", "camera"]
    # ties go to the better step rank; without any step statistic the order is the p order
    assert [e["effect"] for e in diagnose.refit_order([entry("a", 0.01, -0.01), entry("b", 0.001, 0.0)])] == ["a", "b"]
    plain = [entry("a", 0.02), entry("b", 0.001), entry("c", 0.01)]
    assert [e["effect"] for e in diagnose.refit_order(plain)] == ["b", "c", "a"]
    assert diagnose.refit_order([]) == []
    # with the step test's p (the specimen null's, continuous) the step rank goes by it, the statistic breaking
    # ties: the round trip's stiffness-map drapes, where prestrain's statistic was the larger
    stepped = [{"effect": "prestrain", "p_value": 0.0022, "step": {"p_value": 0.0011, "statistic": -0.0190}},
               {"effect": "heterogeneity_map", "p_value": 4.7e-6, "step": {"p_value": 2.4e-6, "statistic": -0.0187}}]
    assert [e["effect"] for e in diagnose.refit_order(stepped)] == ["heterogeneity_map", "prestrain"]


def test_a_recommendation_names_the_candidates_left_without_a_refit():
    # circle3, seed 731's prestrain drapes (threshold 0.001): heterogeneity_map recommended; the camera significant
    # and prestrain near the threshold had no refit (time); orientation is far from it
    ranking = [{"effect": "heterogeneity_map", "p_value": 0.00088, "refit": {"mse": 0.0137}},
               {"effect": "camera", "p_value": 0.00098, "refit": None},
               {"effect": "prestrain", "p_value": 0.0016, "refit": None},
               {"effect": "orientation", "p_value": 0.58, "refit": None},
               {"effect": "disk_contact", "p_value": None, "refit": None}]
    items = diagnose.unrefitted(ranking, 0.001, exclude=("heterogeneity_map",))
    assert items == [{"effect": "camera", "p_value": 0.00098, "significant": True},
                     {"effect": "prestrain", "p_value": 0.0016, "significant": False}]
    words = diagnose.unrefitted_words(items, "heterogeneity_map", diagnose.not_refitted_reason(False, 3))
    assert "camera (p = 0.00098, significant)" in words and "prestrain (p = 0.0016, near the threshold)" in words
    assert "--candidates heterogeneity_map,camera,prestrain" in words and "no time" in words
    assert "cancelled" in diagnose.unrefitted_words(items, "heterogeneity_map", diagnose.not_refitted_reason(True, 3))
    assert diagnose.unrefitted([dict(e, refit={"mse": 0.02}) for e in ranking[:3]], 0.001) == []
    assert diagnose.unrefitted_words([], "tilt", "any") == ""


def test_refit_order_puts_the_significant_candidates_first():
    def entry(name, p, stat=None):
        return {"effect": name, "p_value": p, **({"step": {"statistic": stat}} if stat is not None else {})}
    # seed 701's tilt drapes on circle3 (threshold 0.001): orientation, not significant, had the larger step
    # statistic and went before the significant tilt, whose refit was then dropped for time
    tilt = [entry("rest_curvature", 0.00065, -0.0225), entry("tilt", 0.00086, -0.0041),
            entry("orientation", 0.0042, -0.0139), entry("camera", 0.00424, -0.0017)]
    assert [e["effect"] for e in diagnose.refit_order(tilt)][:3] == ["rest_curvature", "orientation", "tilt"]
    assert [e["effect"] for e in diagnose.refit_order(tilt, 0.001)] == ["rest_curvature", "tilt", "orientation",
                                                                          "camera"]
    # within each group the rank sum still decides; with nothing or everything significant nothing changes
    assert diagnose.refit_order(tilt, 1e-9) == diagnose.refit_order(tilt) == diagnose.refit_order(tilt, 1.0)


def test_line_search_finds_the_minimum_along_the_step_and_turns_a_two_parameter_step():
    reg = fit_effects.registry()
    tilt = reg["tilt"]
    # a tilt step turned by the second direction: the azimuth is carried, only the angle is scaled
    step = {"angle_rad": 0.15, "azimuth_rad": math.pi / 2}

    def mse_of(v):
        assert v["azimuth_rad"] == math.pi / 2
        return 0.01 + (v["angle_rad"] - 0.2) ** 2
    best, points = diagnose.line_search(tilt, step, mse_of)
    # t = 0.5, 1, 1.5, 2 at 0.075 .. 0.3 rad; the parabola's vertex is exact for a quadratic: 0.2 rad
    assert [round(p["values"]["angle_rad"], 6) for p in points] == [0.075, 0.15, 0.225, 0.3, 0.2]
    assert best["angle_rad"] == pytest.approx(0.2, abs=1e-9) and best["azimuth_rad"] == math.pi / 2
    assert len(points) <= diagnose.search_evaluations(tilt)
    # the minimum beyond 2x the step: one more point at 3x, clipped to the registry's bound (0.5 rad)
    best, points = diagnose.line_search(tilt, {"angle_rad": 0.2, "azimuth_rad": 0.0},
                                        lambda v: (v["angle_rad"] - 0.6) ** 2)
    assert [round(p["values"]["angle_rad"], 6) for p in points] == [0.1, 0.2, 0.3, 0.4, 0.5]
    assert best["angle_rad"] == 0.5
    # the minimum below half the step: 0.25x, then the parabola through 0.25, 0.5 and 1 (exact: 0.4x)
    best, points = diagnose.line_search(tilt, step, lambda v: (v["angle_rad"] - 0.06) ** 2)
    assert [round(p["values"]["angle_rad"], 6) for p in points] == [0.075, 0.15, 0.225, 0.3, 0.0375, 0.06]
    assert best["angle_rad"] == pytest.approx(0.06, abs=1e-9)
    assert len(points) == diagnose.search_evaluations(tilt)
    # failed points (None) are never the best; all failed: the step itself
    best, points = diagnose.line_search(tilt, step, lambda v: None)
    assert best == step and all(p["mse"] is None for p in points)
    # bending_anisotropy steps (cos2, sin2): the step (0.75, 0) turned by +-45 degrees in their plane first; the
    # best turn, +45, is then scaled
    aniso = reg["bending_anisotropy"]
    target = 0.9 * np.array([math.cos(math.pi / 4), math.sin(math.pi / 4)])
    off = {q["name"]: q["off"] for q in aniso["parameters"]}
    best, points = diagnose.line_search(aniso, {**off, "cos2": 0.75, "sin2": 0.0},
                                        lambda v: float(np.sum((np.array([v["cos2"], v["sin2"]]) - target) ** 2)))
    assert [round(p["turn_rad"], 6) for p in points[:3]] == [0.0, round(-math.pi / 4, 6), round(math.pi / 4, 6)]
    assert all(p["turn_rad"] == pytest.approx(math.pi / 4) for p in points[3:])
    assert best["cos2"] == pytest.approx(target[0], abs=1e-6) and best["sin2"] == pytest.approx(target[1], abs=1e-6)
    assert len(points) <= diagnose.search_evaluations(aniso)


def test_grid_search_finds_a_narrow_basin_the_line_search_from_the_best_step_misses():
    reg = fit_effects.registry()
    offset = reg["offset"]
    assert offset["search_grid_spacing"] > 0 and offset["search_grid_reach"] >= offset["search_grid_spacing"]
    assert all(not e["search_grid_spacing"] for n, e in reg.items() if n != "offset")
    assert diagnose.grid_points(reg["tilt"]) == []
    grid = diagnose.grid_points(offset)
    h, reach = offset["search_grid_spacing"], offset["search_grid_reach"]
    # the square grid in the (dx, dy) plane out to the reach, the off point first, each point once
    assert grid[0] == {"dx_m": 0.0, "dy_m": 0.0}
    keys = {(round(v["dx_m"] / h), round(v["dy_m"] / h)) for v in grid}
    n = round(reach / h)
    assert keys == {(i, j) for i in range(-n, n + 1) for j in range(-n, n + 1) if math.hypot(i, j) <= n}
    assert len(keys) == len(grid)
    for v in grid:
        assert v["dx_m"] == pytest.approx(h * round(v["dx_m"] / h), abs=1e-12)
    # an offset's landscape (docs/lab/effect-recovery.md): flat away from the truth, worse than off everywhere
    # but in a basin 3 mm wide around it, at (-4.6, 12.1) mm as at seed 791; a few draws score each point with
    # noise, K draws without
    truth = np.array([-0.0046, 0.0121])
    calls = []

    def mse_of(v, draws):
        calls.append(draws)
        d = np.hypot(v["dx_m"] - truth[0], v["dy_m"] - truth[1])
        noise = 0.0 if draws == 16 else 0.004 * math.sin(1e4 * v["dx_m"] + 3e3 * v["dy_m"])
        return (0.05 if v["dx_m"] == v["dy_m"] == 0 else 0.08) - (0.06 * max(0.0, 1 - d / 0.003)) + noise
    best, points = diagnose.grid_search(offset, mse_of, 16)
    assert np.hypot(best["dx_m"] - truth[0], best["dy_m"] - truth[1]) <= h / math.sqrt(2) + 1e-12
    assert calls == [diagnose.SEARCH_GRID_DRAWS] * len(grid) + [16] * diagnose.SEARCH_GRID_FINALISTS
    finalists = [p for p in points if p["finalist"]]
    assert len(finalists) == diagnose.SEARCH_GRID_FINALISTS and all(p["draws"] == 16 for p in finalists)
    assert best == min(finalists, key=lambda p: p["mse"])["values"]
    # its cost, in evaluations of K draws, is what the refits' time plan reserves
    assert diagnose.search_evaluations(offset, 16) == pytest.approx(
        len(grid) * (diagnose.SEARCH_GRID_DRAWS + diagnose.SEARCH_GRID_CALL_DRAWS) / 16 + diagnose.SEARCH_GRID_FINALISTS)
    # the line search from the step test's best 1 cm step (at -45 degrees, as at seed 791) stays on its line
    line_best, _ = diagnose.line_search(offset, {"dx_m": 0.00707, "dy_m": -0.00707}, lambda v: mse_of(v, 16))
    assert np.hypot(line_best["dx_m"] - truth[0], line_best["dy_m"] - truth[1]) > 0.01
    # nothing there (a flat landscape, off best): the grid keeps the off point; every point failed: no best
    best, _ = diagnose.grid_search(offset, lambda v, draws: 0.02 + 0.01 * (v["dx_m"] != 0 or v["dy_m"] != 0), 16)
    assert best == {"dx_m": 0.0, "dy_m": 0.0}
    best, points = diagnose.grid_search(offset, lambda v, draws: None, 16)
    assert best is None and len(points) == len(grid) and not any(p["finalist"] for p in points)


def test_line_search_keeps_the_vertex_within_the_tolerance_of_the_best_point():
    tilt = fit_effects.registry()["tilt"]
    step = {"angle_rad": 0.2, "azimuth_rad": 0.0}
    # a smooth landscape with its minimum at 0.23 rad plus one lucky draw at the step (0.2 rad): the points at
    # 0.1, 0.2, 0.3, 0.4 rad, then the vertex of the parabola through 0.1, 0.2 and 0.3
    noise = {0.2: -0.002}

    def mse_of(v):
        a = round(v["angle_rad"], 9)
        return 0.01 + (a - 0.23) ** 2 + noise.get(a, 0.0)
    best, points = diagnose.line_search(tilt, step, mse_of)  # no tolerance: the smallest point, the lucky step
    vertex = [p for p in points if p["vertex"]]
    assert len(vertex) == 1 and [p["vertex"] for p in points].count(True) == 1
    assert vertex[0]["mse"] > min(p["mse"] for p in points)
    assert best["angle_rad"] == pytest.approx(0.2)
    # within 0.002 of it the vertex is kept: it lies between the lucky point and the landscape's minimum
    gap = vertex[0]["mse"] - min(p["mse"] for p in points)
    best2, points2 = diagnose.line_search(tilt, step, mse_of, vertex_within=gap + 1e-12)
    assert points2 == points and best2 == vertex[0]["values"] and 0.2 < best2["angle_rad"] < 0.23
    best3, _ = diagnose.line_search(tilt, step, mse_of, vertex_within=0.5 * gap)
    assert best3["angle_rad"] == pytest.approx(0.2)
    # no vertex (the minimum at the grid's end) or a failed vertex: the smallest point whatever the tolerance
    best4, points4 = diagnose.line_search(tilt, step, lambda v: (v["angle_rad"] - 0.6) ** 2, vertex_within=1.0)
    assert not any(p["vertex"] for p in points4) and best4["angle_rad"] == 0.5
    best5, points5 = diagnose.line_search(tilt, step, lambda v: None if round(v["angle_rad"], 9) not in (0.1, 0.2, 0.3, 0.4)
                                          else mse_of(v), vertex_within=1.0)
    assert points5[-1]["vertex"] and points5[-1]["mse"] is None and best5["angle_rad"] == pytest.approx(0.2)


def test_step_direction_reads_the_direction_from_every_step():
    def per_step(values, stats):  # step_tests' per_step entries
        return [{"values": v, "statistic": x} for v, x in zip(values, stats)]
    reg = fit_effects.registry()
    second = diagnose.second_directions(reg)
    rng = np.random.default_rng(5)
    for name in ("tilt", "offset", "bending_anisotropy"):
        steps = diagnose.effect_steps(reg, [name])[name]
        direction_of = {}
        for psi in rng.uniform(-math.pi, math.pi, 4):
            t = 0.8 * np.array([math.cos(psi), math.sin(psi)])
            h = np.array([[1.0, 0.2], [0.2, 1.0]]) if name == "offset" else np.eye(2)

            def stat(values):  # second order: s'Hs - 2 s'Ht, in units of the step's length
                info = diagnose.step_direction(reg[name], second.get(name), per_step([values] * 3, [0.0] * 3))
                assert info is None  # three copies of one direction do not span the plane
                params = {q["name"]: q for q in reg[name]["parameters"]}
                if name == "tilt":
                    a = values["angle_rad"] / params["angle_rad"]["moderate"]
                    s = a * np.array([math.cos(values["azimuth_rad"]), math.sin(values["azimuth_rad"])])
                else:
                    a, b = diagnose.stepped_parameters(reg[name])
                    s = np.array([values[a] / params[a]["moderate"], values[b] / params[b]["moderate"]])
                return float(s @ h @ s - 2 * s @ h @ t)
            info = diagnose.step_direction(reg[name], second.get(name),
                                           per_step([v for _, v in steps], [stat(v) for _, v in steps]))
            got = info["direction_rad"]
            want = math.atan2(*(h @ t)[::-1])  # the first harmonic points along Ht (t itself where H is round)
            assert math.cos(got - want) == pytest.approx(1.0, abs=1e-9), (name, psi)
            direction_of[psi] = info["values"]
            assert info["r2"] > 0.95 and info["used"]  # first harmonic (and a little second where H is not round)
            if name == "tilt":  # a positive angle at the moderate strength towards the direction
                assert info["values"]["angle_rad"] == pytest.approx(0.15)
                assert info["values"]["azimuth_rad"] == pytest.approx(got)
            else:
                a, b = diagnose.stepped_parameters(reg[name])
                assert math.atan2(info["values"][b], info["values"][a]) == pytest.approx(got)
        # a failed step (None) is left out; all but two failed: no direction
        stats = [stat(v) for _, v in steps]
        assert diagnose.step_direction(reg[name], second.get(name),
                                       per_step([v for _, v in steps], [None] * (len(steps) - 2) + stats[-2:])) is None
    # steps the first harmonic does not explain (a second harmonic, as an offset's folds rearranging): not used
    steps = diagnose.effect_steps(reg, ["offset"])["offset"]
    angles = [math.atan2(v["dy_m"], v["dx_m"]) for _, v in steps]
    info = diagnose.step_direction(reg["offset"], None, per_step([v for _, v in steps],
                                                                 [0.2 * math.cos(a) + math.cos(2 * a) for a in angles]))
    assert math.cos(info["direction_rad"] - math.pi) == pytest.approx(1.0)
    assert info["r2"] == pytest.approx(0.02 / 0.52) and not info["used"]
    # an effect without a direction: none
    assert diagnose.step_direction(reg["prestrain"], None, per_step(
        [v for _, v in diagnose.effect_steps(reg, ["prestrain"])["prestrain"]], [-1.0, 1.0])) is None


def test_refit_start_goes_by_the_change_not_the_p():
    plus, minus = {"strain": 0.03, "warp_minus_weft": 0.0}, {"strain": -0.03, "warp_minus_weft": 0.0}
    # seed 761's prestrain: the -0.03 step had the smaller p (the reported step), +0.03 the larger fall
    st = {"statistic": -0.039, "values": minus, "step": "strain=-0.03",
          "per_step": [{"step": "strain=+0.03", "values": plus, "statistic": -0.043},
                       {"step": "strain=-0.03", "values": minus, "statistic": -0.039}]}
    assert diagnose.refit_start(st) == (plus, "statistic", "strain=+0.03")
    # a failed step (None) is left out; no step closer: no start
    st["per_step"][0]["statistic"] = None
    assert diagnose.refit_start(st) == (minus, "statistic", "strain=-0.03")
    st["per_step"][1]["statistic"] = 0.002
    assert diagnose.refit_start(st) == (None, None, None)
    # a directional effect whose steps follow a first harmonic: along it
    tilt = {"angle_rad": 0.15, "azimuth_rad": -1.9}
    st = {"statistic": -0.01, "values": {"angle_rad": -0.15, "azimuth_rad": math.pi / 2},
          "per_step": [{"step": "a", "values": {}, "statistic": -0.01}],
          "direction": {"values": tilt, "direction_rad": -1.9, "used": True}}
    assert diagnose.refit_start(st) == (tilt, "harmonic", None)
    st["direction"]["used"] = False
    assert diagnose.refit_start(st) == ({}, "statistic", "a")
    # without per-step statistics: the reported step when its statistic is negative
    assert diagnose.refit_start({"statistic": -0.01, "values": minus, "step": "m"}) == (minus, "statistic", "m")
    assert diagnose.refit_start({"statistic": 0.01, "values": minus, "step": "m"}) == (None, None, None)


def test_step_family_p_counts_the_steps_by_their_correlation(monkeypatch):
    # an offset's eight directions move the draws alike: correlated steps are fewer chances than Sidak's S, and the
    # level holds (simulated specimen nulls with B = W, eight steps sharing 80 % of their variance)
    monkeypatch.setattr(diagnose, "STEP_FAMILY_DRAWS", 20000)
    rng = np.random.default_rng(21)
    n, refs, redrapes, steps, share = 6, 24, 12, 8, 0.8

    def correlated(shift=0.0):
        common = _specimen_sets(rng, 1.0, 1.0, n, refs, redrapes, shift=shift)
        own = _specimen_sets(rng, 1.0, 1.0, n, refs, redrapes, shift=shift, steps=steps)
        return np.sqrt(share) * common + np.sqrt(1.0 - share) * own

    p_null = np.array([diagnose.step_specimen_test(correlated(), n, refs, redrapes)[2] for _ in range(200)])
    assert 0.01 <= np.mean(p_null < 0.05) <= 0.09
    d = correlated(shift=-2.5)
    best, _, p, _ = diagnose.step_specimen_test(d, n, refs, redrapes)
    p_single = diagnose.step_specimen_test(d[best:best + 1], n, refs, redrapes)[2]
    assert p_single <= p < -np.expm1(steps * np.log1p(-p_single))  # between the one step's p and Sidak's
    # independent steps: Sidak (within the draws' upper bound, never above Bonferroni); identical steps: one chance;
    # opposite steps (+- a parameter): up to two
    many = 400000
    assert diagnose.step_family_p([1e-3] + [0.5] * 7, np.eye(8), many) == pytest.approx(1 - (1 - 1e-3) ** 8, rel=0.05)
    assert diagnose.step_family_p([1e-3] + [0.5] * 7, np.ones((8, 8)), many) == pytest.approx(1e-3, rel=0.25)
    assert diagnose.step_family_p([1e-3, 0.9], [[1.0, -1.0], [-1.0, 1.0]], many) == pytest.approx(2e-3, rel=0.05)
    assert diagnose.step_family_p([2e-3], [[1.0]]) == 2e-3


def test_meshes_on_the_models_topology_get_the_3d_comparison(images, tmp_path):
    """--meshes: each best draw's Hausdorff distance, and with meshes on the model's topology the 3D comparison
    (drapelab.fold_geometry) in diagnosis.json and the report; a mesh of another topology is skipped, saying why."""
    preset = infer.load_preset(PRESET)
    model = sim.ClothModel(sim.cusick_specimen(1), density=preset["density_kg_m2"])
    p = model.parameters(stretch=preset["stretch_N_m"], bend=np.exp(np.asarray(preset["posterior"]["bend"]["log_mean"])))
    v0 = infer.placement_velocities(model.rest_positions, np.random.default_rng([0, 99]), 0.05, 32)
    x = model.simulate(p, mode="dynamic", record=False, velocities0=v0)  # the control image's drape (drape_image)
    mesh = str(tmp_path / "control.obj")
    sim.write_obj(mesh, x, model.faces)
    out = str(tmp_path / "with_mesh")
    d = diagnose.diagnose(PRESET, [images["control"]], meshes=[mesh], candidates="tilt", samples=4, seed=0,
                          config=small_config(), mesh_level=1, max_refits=0, threads=1, out_dir=out)
    validate(d)
    g = d["geometry"]
    assert g["measured_meshes"] == 1 and g["drapes"] == d["draws_used"]
    assert [r["r0_m"] for r in g["rings"]] == pytest.approx(list(diagnose.fold_geometry.RINGS))
    hem = g["rings"][-1]
    assert hem["z"]["measured"] < -0.02 and hem["z"]["model"] < -0.02  # both hang down
    assert isinstance(g["words"], list)
    assert d["per_image"][0]["hausdorff_m"] > 0
    assert os.path.getsize(os.path.join(out, "geometry.png")) > 0
    with open(os.path.join(out, "index.html")) as f:
        assert "In 3D: the measured meshes against the draws" in f.read()
    other = sim.cusick_specimen(2)
    mesh2 = str(tmp_path / "circle2.obj")
    sim.write_obj(mesh2, np.asarray(other.positions), np.asarray(other.faces))
    d2 = diagnose.diagnose(PRESET, [images["control"]], meshes=[mesh2], candidates="tilt", samples=4, seed=0,
                           config=small_config(), mesh_level=1, max_refits=0, threads=1)
    assert "circle2.obj" in d2["geometry"]["skipped"] and "model's topology" in d2["geometry"]["skipped"]
    # the 3D step test (module doc, 2c): on the model's topology every step-tested candidate gets one, and its
    # p enters the combined p with the other two tests' (Bonferroni over three)
    mt = d["step_test"]["mesh"]
    assert mt["measured_meshes"] == 1 and mt["tested"] == ["tilt"] and mt["noise_m"] == pytest.approx(0.12e-3)
    assert "band 14-15 cm: crest_p99" in mt["features"]
    tilt = d["ranking"][0]
    s3 = tilt["step_3d"]
    assert 0 < s3["p_value"] <= 1 and s3["features"] == mt["features"] and s3["draws"] == tilt["step"]["draws"]
    assert tilt["p_value"] == diagnose.combined_p(tilt["p_value_score"], tilt["step"]["p_value"], s3["p_value"])
    assert diagnose.combined_p(0.01, 0.002, 0.3) == pytest.approx(0.006)
    assert diagnose.combined_p(0.01, 0.002, None) == pytest.approx(0.004) and diagnose.combined_p(None, 0.5) == 0.5
    assert diagnose.combined_p(0.5, 0.9, 0.4) == 1.0
    assert "in 3D" in tilt["explanation"]
    assert "step_3d" not in d2["ranking"][0] and "model's topology" in d2["step_test"]["mesh"]["skipped"]
    with pytest.raises(InputError, match="mesh_noise"):
        diagnose.diagnose(PRESET, [images["control"]], meshes=[mesh], candidates="tilt", samples=4,
                          mesh_noise_m=-1e-4)


def test_fold_features_name_every_entry_and_see_a_flat_disk_as_flat():
    model = sim.ClothModel(sim.cusick_specimen(3), density=0.2)
    rest, edges = np.asarray(model.rest_positions), np.asarray(model.bending_edges)
    names = diagnose.fold_geometry.feature_names()
    f = diagnose.fold_geometry.features(rest, rest, edges)
    assert f.shape == (len(names),) and not np.isnan(f).any()  # circle3 measures every band and ring
    by = dict(zip(names, f))
    assert by["band 12-14 cm: crest_p99"] == pytest.approx(0.0, abs=1e-6)
    assert by["ring 14.5 cm: amplitude"] == pytest.approx(0.0, abs=1e-9) and by["ring 14.5 cm: z"] == pytest.approx(rest[0, 2])
    noisy = diagnose.fold_geometry.features(rest, rest, edges, 0.12e-3, np.random.default_rng(1))
    angles = [i for i, n in enumerate(names) if n.startswith("band")]
    rings = [i for i, n in enumerate(names) if n.startswith("ring")]
    assert np.all(noisy[angles] > 0.5) and np.array_equal(noisy[rings], f[rings])  # the noise reaches the angles only
    # the drapes' noise is fixed by their key, not by the order the lanes drape them in
    mf = diagnose.MeshFeatures(rest, edges, 0.12e-3, seed=5)
    assert np.array_equal(mf.simulated(rest, (4, 2, 1, 0)), mf.simulated(rest, (4, 2, 1, 0)))
    assert not np.array_equal(mf.simulated(rest, (4, 2, 1, 0)), mf.simulated(rest, (4, 2, 1, 1)))
    assert mf.simulated(None, (0, 1)) is None


def test_the_3d_step_test_projects_the_steps_feature_change_on_the_measured_difference():
    """step_tests_3d's statistic is -2/F sum_k dF_k (mean measured_k - mean reference_k) / s_k^2 (the quadratic's
    terms in the draw cancel); a step towards where the measured meshes lie is significant, one across it is not,
    and features unmeasured anywhere (NaN) are left out."""
    rng = np.random.default_rng(3)
    F, n, j, f_re, k = 5, 6, 24, 12, 8
    s_true = np.array([1.0, 2.0, 0.5, 3.0, 1.0])
    shift = np.array([5.0, 0.0, 0.0, 0.0, 0.0]) * s_true  # the measured meshes differ from P in feature 0
    measured = list(rng.normal(shift, 0.3 * s_true, (n, F)))
    references = list(rng.normal(0.0, s_true, (j, F)))
    redrapes = list(rng.normal(0.0, 0.3 * s_true, (f_re, F)))
    for x in measured + references + redrapes:
        x[4] = np.nan  # a feature the mesh does not measure
    base = [rng.normal(0.0, s_true) for _ in range(k)]
    towards = [b + np.array([0.5, 0, 0, 0, 0]) * s_true for b in base]
    across = [b + np.array([0, 0.5, 0, 0, 0]) * s_true for b in base]
    steps = {"towards": [("a", {})], "across": [("b", {})]}
    out = diagnose.step_tests_3d(base, {("towards", 0): towards, ("across", 0): across}, steps, measured,
                                 references, redrapes)
    scale, kept = diagnose.feature_scale(measured, references + redrapes)
    assert list(kept) == [True, True, True, True, False]
    assert out["towards"]["features"] == [diagnose.fold_geometry.feature_names()[i] for i in range(4)]
    for name, moved in (("towards", towards), ("across", across)):
        d_f = np.mean(np.array(moved) - np.array(base), axis=0)[:4]
        diff = np.mean(measured, axis=0)[:4] - np.mean(references, axis=0)[:4]
        assert out[name]["statistic"] == pytest.approx(-2.0 / 4 * np.sum(d_f * diff / scale[:4] ** 2), rel=1e-9)
    assert out["towards"]["statistic"] < 0 and out["towards"]["p_value"] < 1e-3
    assert out["across"]["p_value"] > 0.01
    # a step that leaves every drape as it is (the camera's; its drapes take their draws' vertex noise) is no
    # evidence either way
    same = diagnose.step_tests_3d(base, {("same", 0): [b.copy() for b in base]}, {"same": [("c", {})]}, measured,
                                  references, redrapes)
    assert same["same"]["statistic"] == 0.0 and same["same"]["p_value"] == 1.0
    # a failed step drape (None) is left out on both sides
    towards[0] = None
    again = diagnose.step_tests_3d(base, {("towards", 0): towards, ("across", 0): across}, steps, measured,
                                   references, redrapes)
    assert again["towards"]["p_value"] < 1e-3


def test_a_candidate_found_in_3d_is_fitted_and_judged_in_3d():
    """found_in_3d: the 3D step test's p is the smallest of the candidate's tests and the silhouettes' tests alone
    are not significant; recommendable_in_3d: a 3D refit
    that lowers the 3D error by half its re-drape floor, 5 % of it and a quarter of the gap above the floor with the silhouettes' MSE within half
    theirs of the base's, only when something is significant, largest 3D fall first."""
    e = {"p_value_score": 0.3, "step": {"p_value": 0.01}, "step_3d": {"p_value": 0.001}}
    assert diagnose.found_in_3d(e, 0.005)
    assert not diagnose.found_in_3d(e, 0.05)  # the silhouettes alone (p 0.02) show it: refitted on them
    assert not diagnose.found_in_3d(dict(e, step_3d={"p_value": 0.02}), 0.005)
    assert not diagnose.found_in_3d({"p_value_score": 0.3, "step": {"p_value": 0.01}}, 0.005)
    assert diagnose.found_in_3d({"p_value_score": None, "step_3d": {"p_value": 0.5}}, 0.005)

    def refit(name, error_3d, mse, fall, fitted_in="3d"):
        return {"effect": name, "refit": {"error_3d": error_3d, "mse": mse, "fitted_in": fitted_in},
                "fall_3d_of_redrape": fall}

    ranking = [refit("a", 1.5, 0.030, 0.6), refit("b", 1.0, 0.030, 1.2), refit("c", 1.0, 0.036, 1.2),
               refit("d", 1.85, 0.030, 0.6), refit("g", 1.95, 0.030, 0.6), refit("e", 1.0, 0.030, 1.2, "silhouettes"), refit("f", 1.8, 0.03, 0.4)]
    # base 3D error 2.0, base MSE 0.030, MSE floor 0.01: c's MSE rose 0.006 > 0.005; g's 3D error fell 2.5 % of the
    # base's (d's 7.5 %); f below half the floor; e fitted on the silhouettes
    # (3D floor 0.2: the gap 1.8, a quarter of it 0.45: a and d close 0.5 and 0.15 of it)
    got = diagnose.recommendable_in_3d(ranking, 2.0, 0.2, 0.030, 0.01, True)
    assert [x["effect"] for x in got] == ["b", "a"]  # d's fall is 8 % of the gap
    assert [x["effect"] for x in diagnose.recommendable_in_3d(ranking, 2.0, 1.9, 0.030, 0.01, True)] == ["b", "a", "d"]
    assert diagnose.recommendable_in_3d(ranking, 2.0, 0.2, 0.030, 0.01, False) == []  # nothing significant
    assert diagnose.recommendable_in_3d(ranking, None, 0.2, 0.030, 0.01, True) == []


def test_refit_order_3d_puts_the_largest_3d_changes_first_in_their_places():
    # fabric 4 with --meshes (2026-11-30, threshold 9.1e-4): every candidate but the camera, orientation and offset
    # was found in 3D; by p the three refits went to tilt, bending_anisotropy and damping, whose best steps lowered
    # the 3D error least; by the 3D statistic prestrain went first, and its step raised the 3D error (here each
    # entry's change is its best-of-K fall, negated, the figures of that run)
    def entry(name, p, stat3, fall, found=True):
        return {"effect": name, "p_value": p, "found": found,
                "step_3d": {"p_value": p / 3, "statistic": stat3, "best_of_k_fall": fall,
                            "per_step": [{"step": "a", "statistic": stat3, "change": -fall},
                                         {"step": "b", "statistic": 1.0, "change": None}]}}
    order = [entry("tilt", 4.7e-6, -0.58, 0.77), entry("bending_anisotropy", 2e-8, -1.7, 0.96),
             entry("offset", 0.073, -2.9, -4.38, found=False), entry("damping", 2.2e-4, -0.85, 0.41),
             entry("prestrain", 0.0016, -10.9, -2.69), entry("high_curvature_bending", 0.0021, -10.8, 2.26),
             entry("camera", 0.02, 0.0, 0.0, found=False), entry("heterogeneity_map", 0.017, -8.75, 1.66)]
    out = [e["effect"] for e in diagnose.refit_order_3d(order, lambda e: e["found"])]
    assert out == ["high_curvature_bending", "heterogeneity_map", "offset", "bending_anisotropy", "tilt",
                   "damping", "camera", "prestrain"]
    # equal changes go by the statistic; without per-step changes the best-of-K fall decides, without either the
    # entry goes last; the entries not found in 3D keep their places; with none found nothing moves
    tied = [entry("a", 0.001, -1.0, 0.5), entry("b", 0.002, -2.0, 0.5),
            {"effect": "c", "p_value": 0.003, "step_3d": {"statistic": -9.0, "p_value": 0.001}},
            {"effect": "d", "p_value": 0.004, "step_3d": {"statistic": 0.0, "p_value": 0.5, "best_of_k_fall": 0.7}}]
    assert [e["effect"] for e in diagnose.refit_order_3d(tied, lambda e: True)] == ["d", "b", "a", "c"]
    assert diagnose.refit_order_3d(order, lambda e: False) == order
    assert diagnose.refit_order_3d([], lambda e: True) == []


def test_a_refit_found_in_3d_starts_at_the_step_with_the_largest_3d_change():
    st = {"step": "strain=-0.03", "statistic": -10.9, "values": {"strain": -0.03},
          "per_step": [{"step": "strain=+0.03", "values": {"strain": 0.03}, "statistic": 1.8, "change": -0.4},
                       {"step": "strain=-0.03", "values": {"strain": -0.03}, "statistic": -10.9, "change": 2.5}]}
    assert diagnose.refit_start(st) == ({"strain": -0.03}, "statistic", "strain=-0.03")
    assert diagnose.refit_start(st, by="change") == ({"strain": 0.03}, "change", "strain=+0.03")
    worse = {**st, "per_step": [dict(x, change=abs(x["change"])) for x in st["per_step"]]}
    assert diagnose.refit_start(worse, by="change") == (None, None, None)


def test_a_3d_recommendation_says_whether_it_is_significant_itself():
    # fabric 2 with --meshes (2026-11-30): high_curvature_bending recommended at p 0.0019, above the threshold; the
    # verdict said "significant (p = 0.0019 < 0.00091)"
    ranking = [{"effect": "high_curvature_bending", "p_value": 0.0019}, {"effect": "tilt", "p_value": 2.2e-5},
               {"effect": "bending_anisotropy", "p_value": 3.8e-7}, {"effect": "camera", "p_value": None}]
    words = diagnose.why_in_3d(ranking[0], ranking, 0.00091)
    assert "significant (p" not in words and "its own p = 0.0019" in words
    assert "bending_anisotropy's p = 3.8e-07 < 0.00091" in words
    assert diagnose.why_in_3d(ranking[1], ranking, 0.00091) == \
        "significant (p = 2.2e-05 < 0.00091, by its 3D step test)"


def test_the_verdict_names_the_3d_candidates_left_without_a_refit():
    # fabric 2 with --meshes (2026-11-30, threshold 9.1e-4): only rest_curvature's 3D refit ran; the steps of
    # heterogeneity_map, density_variation and high_curvature_bending also brought the folds closer on average
    def entry(name, p3, changes, refit=None, p_score=0.5, p_step=0.3):
        return {"effect": name, "p_value": min(1.0, 3 * p3), "p_value_score": p_score, "refit": refit,
                "step": {"p_value": p_step},
                "step_3d": {"p_value": p3, "statistic": min(changes),
                            "per_step": [{"step": str(i), "statistic": c, "change": c} for i, c in enumerate(changes)]}}
    ranking = [entry("rest_curvature", 0.00016, [-3.32, -1.35], refit={"mse": 0.0478, "fitted_in": "3d"}),
               entry("high_curvature_bending", 0.00065, [-2.38, 4.32]),
               entry("heterogeneity_map", 0.005, [9.19, -3.08]),
               entry("density_variation", 0.006, [-2.86, 10.84]),
               entry("damping", 0.015, [-0.7]),
               entry("prestrain", 1.6e-5, [-0.26, 6.93]),
               entry("offset", 0.00072, [0.66, 0.6], p_score=0.0003),  # its silhouettes' test is smaller: not 3D-found
               entry("tilt", 7.3e-6, [0.28, 0.75])]  # no step brought the folds closer
    items = diagnose.unrefitted_3d(ranking, 0.00091)
    assert items == [{"effect": "heterogeneity_map", "change": -3.08}, {"effect": "density_variation", "change": -2.86},
                     {"effect": "high_curvature_bending", "change": -2.38}]
    words = diagnose.unrefitted_3d_words(items)
    assert "--candidates heterogeneity_map,density_variation,high_curvature_bending" in words
    assert "high_curvature_bending (-2.4)" in words
    assert diagnose.unrefitted_3d(ranking, 0.00091, limit=5)[-1] == {"effect": "prestrain", "change": -0.26}
    assert diagnose.unrefitted_3d_words([]) == ""
