"""Fitting with effects (fit --effects): the plan, exact gradients of the fitted strengths, presets that carry
them (schema 2, migration of 1), the predictive with effects, and a recovery round trip."""
import copy
import json

import numpy as np
import pytest

from drapelab import fit_effects, infer, measure, render, sim, tables

from fit_support import ASSET_IMAGE, SHIPPED_PRESET as PRESET, small_config


def registered(name):
    return {e["name"]: e for e in sim.effects()}[name]


def test_plan_fits_bare_effects_and_fixes_given_values():
    tilt = registered("tilt")
    primary, second = (p["name"] for p in tilt["parameters"])
    plan = fit_effects.EffectPlan({"tilt": None})
    assert plan.names == [f"tilt.{primary}", f"tilt.{second}"]
    assert list(plan.off) == [p["off"] for p in tilt["parameters"]]
    assert list(plan.prior_scale) == [p["prior_scale"] for p in tilt["parameters"]]
    fixed = fit_effects.EffectPlan({"tilt": {primary: 0.07}})  # NAME=VALUE: fixed; the others stay off
    assert fixed.size == 0 and fixed.values() == {"tilt": {primary: 0.07, second: tilt["parameters"][1]["off"]}}
    one = fit_effects.EffectPlan({"tilt": {primary: 0.07, second: None}})  # NAME.PARAM bare: that one fitted
    assert one.names == [f"tilt.{second}"] and one.values([0.3])["tilt"] == {primary: 0.07, second: 0.3}
    assert one.describe() == {"tilt": {primary: 0.07, second: "fitted"}}
    assert fit_effects.EffectPlan(None).size == 0 and fit_effects.EffectPlan({}).values() == {}
    # start candidates: the off point, the primary at +- moderate, and with the primary at + moderate the other
    # parameters at +- theirs (within bounds)
    m1, m2 = (p["moderate"] for p in tilt["parameters"])
    starts = plan.start_candidates(plan.off)
    assert [list(c) for c in starts] == [[0.0, 0.0], [m1, 0.0], [-m1, 0.0], [m1, m2], [m1, -m2]]
    clipped, inside = plan.clip([10.0, 0.1])
    assert clipped[0] == tilt["parameters"][0]["upper"] and list(inside) == [False, True]


def test_the_command_line_plan_of_a_bare_name_param_fits_that_parameter_only():
    # fit --effects NAME.PARAM: the parameter fitted from its off value, the effect's others off (fixed) unless
    # given; a bare NAME still fits them all.
    prestrain = registered("prestrain")
    primary, second = (p["name"] for p in prestrain["parameters"][:2])
    off = {p["name"]: p["off"] for p in prestrain["parameters"]}
    plan = fit_effects.EffectPlan(sim.parse_effects_arg(f"prestrain.{primary}", bare=None))
    assert plan.names == [f"prestrain.{primary}"] and list(plan.off) == [off[primary]]
    assert plan.values([0.02])["prestrain"] == {**off, primary: 0.02}
    assert plan.describe()["prestrain"] == {**off, primary: "fitted"}
    given = fit_effects.EffectPlan(sim.parse_effects_arg(f"prestrain.{second},prestrain={0.01}", bare=None))
    assert given.names == [f"prestrain.{second}"] and given.values([0.005])["prestrain"] == {
        **off, primary: 0.01, second: 0.005}
    every = fit_effects.EffectPlan(sim.parse_effects_arg("prestrain", bare=None))
    assert every.names == [f"prestrain.{p['name']}" for p in prestrain["parameters"] if not p.get("structural")]
    # the start candidates of a one-parameter plan: off and +- the moderate strength
    m = prestrain["parameters"][0]["moderate"]
    assert [list(c) for c in plan.start_candidates(plan.off)] == [[0.0], [m], [-m]]


def test_structural_parameters_are_held_and_the_model_rejects_a_mismatch():
    # disk_contact's clamp radius chooses which vertices the model holds: never fitted (no gradient), held at the
    # given value or, when the effect is fitted bare, at its registry strength (the 2 cm clamp).
    disk = registered("disk_contact")
    clamp = disk["parameters"][0]
    assert clamp["name"] == "clamp_radius_m" and clamp["structural"] and clamp["moderate"] == 0.02
    plan = fit_effects.EffectPlan({"disk_contact": None})
    assert plan.names == ["disk_contact.friction", "disk_contact.rim_radius_m"]
    assert plan.values(plan.off)["disk_contact"]["clamp_radius_m"] == 0.02
    held = fit_effects.EffectPlan({"disk_contact": {"clamp_radius_m": 0.03, "friction": None}})
    assert held.names == ["disk_contact.friction"] and held.values([0.5])["disk_contact"]["clamp_radius_m"] == 0.03
    model = sim.ClothModel(sim.cusick_specimen(1), effects={"disk_contact": {"clamp_radius_m": 0.03}})
    params = model.parameters(material=tables.COTTON_BLUE)
    with pytest.raises(sim.InputError, match="structural"):
        model.parameters(material=tables.COTTON_BLUE, effects={"disk_contact": {"clamp_radius_m": 0.04}})
    x = model.simulate(params, steps=5)
    assert np.isfinite(x).all()


@pytest.mark.parametrize("spec, message", [
    ({"no_such_effect": None}, "unknown effect 'no_such_effect'"),
    ({"tilt": {"no_such_param": 1.0}}, "tilt.no_such_param"),
    ({"tilt": [1.0]}, "tilt"),
    ("tilt", "effects"),
])
def test_plan_refuses_bad_effects_naming_them(spec, message):
    with pytest.raises(infer.InputError, match=message):
        fit_effects.EffectPlan(spec)


def test_fixed_effect_out_of_range_is_refused_with_its_field():
    with pytest.raises(infer.InputError, match="tilt.angle_rad"):
        infer.FitJob([ASSET_IMAGE], 0.192, model="homo", config=small_config(), threads=1,
                     effects={"tilt": {"angle_rad": 2.0}})


def _loss(job):
    return lambda theta: job.objective(theta, 0)[0]["loss"]


def test_fitted_effect_gradient_matches_central_differences_homo():
    # MAP (homo) with a fitted tilt, the default dynamic forward, pixel + drape-coefficient terms + the
    # effect's prior: the objective's d/d(effect means) against central differences.
    cfg = small_config(samples_per_epoch=1, forward="dynamic")
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="homo", seed=5, config=cfg, threads=1, effects={"tilt": None})
    job.theta["effect_mu"] = np.array([0.12, 0.6])  # away from the off value (where the azimuth has no gradient)
    terms, grads = job.objective(job.theta, 0)
    assert terms["kl"] > 0 and np.all(grads["effect_mu"] != 0)
    for i in range(2):
        d = np.zeros(2)
        d[i] = 1.0
        eps = 1e-6
        plus, minus = copy.deepcopy(job.theta), copy.deepcopy(job.theta)
        plus["effect_mu"] = plus["effect_mu"] + eps * d
        minus["effect_mu"] = minus["effect_mu"] - eps * d
        fd = (_loss(job)(plus) - _loss(job)(minus)) / (2 * eps)
        assert grads["effect_mu"][i] == pytest.approx(fd, rel=1e-4, abs=1e-8), i


def test_fitted_effect_posterior_gradient_matches_central_differences_bdp():
    # bdp: the effect's posterior mean and sd (reparameterised with the epoch's fixed noise) and its KL. Without
    # placement noise the draw is smooth enough for 1e-6 steps.
    cfg = small_config(samples_per_epoch=2, forward="dynamic")
    cfg["placement_noise"] = {"velocity_m_s": 0.0, "angular_modes": 0}
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", seed=4, config=cfg, threads=1, effects={"tilt": None})
    job.theta["effect_mu"] = np.array([0.1, 0.4])
    job.theta["effect_eta"] = infer.inverse_softplus(np.array([0.03, 0.2]))
    terms, grads = job.objective(job.theta, 0)
    rng = np.random.default_rng(0)
    for name in ("effect_mu", "effect_eta"):
        d = rng.standard_normal(2)
        eps = 1e-6
        plus, minus = copy.deepcopy(job.theta), copy.deepcopy(job.theta)
        plus[name] = plus[name] + eps * d
        minus[name] = minus[name] - eps * d
        fd = (_loss(job)(plus) - _loss(job)(minus)) / (2 * eps)
        assert float(np.sum(grads[name] * d)) == pytest.approx(fd, rel=1e-4, abs=1e-8), name


def test_preset_carries_fitted_effects_and_round_trips(tmp_path):
    cfg = small_config(samples_per_epoch=1)
    cfg["calibration"]["enabled"] = False
    out = str(tmp_path / "tilt.json")
    preset = infer.fit([ASSET_IMAGE], 0.192, model="bdp", epochs=1, seed=2, out=out, config=cfg, threads=1,
                       effects={"tilt": {"azimuth_rad": 0.3, "angle_rad": None}})
    assert preset["schema_version"] == infer.PRESET_SCHEMA_VERSION == 2
    angle, azimuth = preset["active_effects"]["tilt"]["angle_rad"], preset["active_effects"]["tilt"]["azimuth_rad"]
    assert angle["unit"] == "rad" and angle["fitted"] and angle["std"] > 0
    assert angle["interval90"][0] <= angle["value"] <= angle["interval90"][1]
    assert azimuth == {"value": 0.3, "unit": "rad", "fitted": False}
    assert preset["provenance"]["options"]["effects"] == {"tilt": {"angle_rad": "fitted", "azimuth_rad": 0.3}}
    assert preset["training"]["effect_start_search"]["parameters"] == ["tilt.angle_rad"]
    loaded = infer.load_preset(out)
    assert loaded["active_effects"] == preset["active_effects"]
    # The predictive drapes with the preset's effects: its draws differ from the same preset without them.
    with_effects = infer.evaluate(loaded, [ASSET_IMAGE], samples=2, threads=1, config=cfg, seed=1)
    without = infer.evaluate(dict(loaded, active_effects={}), [ASSET_IMAGE], samples=2, threads=1, config=cfg, seed=1)
    assert with_effects["images"][0]["drape_coefficient"] != without["images"][0]["drape_coefficient"]


def test_older_presets_are_migrated_and_newer_ones_refused(tmp_path):
    v2 = infer.load_preset(PRESET)
    assert v2["schema_version"] == 2 and v2["active_effects"] == {}
    v1 = dict(v2, schema_version=1)
    del v1["active_effects"]
    path = tmp_path / "v1.json"
    path.write_text(json.dumps(v1))
    migrated = infer.load_preset(str(path))
    assert migrated["schema_version"] == 2 and migrated["active_effects"] == {}
    out = str(tmp_path / "saved.json")
    infer.write_preset(out, v1)  # saving writes the current schema
    assert json.loads(open(out).read())["schema_version"] == 2
    with pytest.raises(infer.InputError, match="newer drapelab"):
        infer.validate_preset(dict(v2, schema_version=3), "p.json")
    with pytest.raises(infer.InputError, match="version 1 preset cannot carry active_effects"):
        infer.validate_preset(dict(v1, active_effects={"tilt": {}}), "p.json")


@pytest.mark.parametrize("block, message", [
    ({"nope": {}}, "active_effects.nope: unknown effect"),
    ({"tilt": {"angle_rad": {"value": 0.1, "unit": "deg"}}}, "active_effects.tilt.angle_rad: unit must be 'rad'"),
    ({"tilt": {"angle_rad": {"value": float("nan"), "unit": "rad"}}}, "active_effects.tilt.angle_rad: value"),
    ({"tilt": {"angle_rad": {"value": 9.0, "unit": "rad"}}}, "active_effects.tilt.angle_rad: value 9.0 outside"),
    ({"tilt": {"angle_rad": {"value": 0.1, "unit": "rad", "std": -1}}}, "std must be"),
    ({"tilt": {"angle_rad": {"value": 0.1, "unit": "rad", "interval90": [0.2, 0.1]}}}, "interval90"),
    ({"tilt": {"speed": {"value": 0.1, "unit": "rad"}}}, "has no parameter 'speed'"),
    ([], "active_effects must be an object"),
])
def test_bad_active_effects_are_refused_naming_the_field(block, message):
    preset = dict(infer.load_preset(PRESET), active_effects=block)
    with pytest.raises(infer.InputError, match=message):
        infer.validate_preset(preset, "p.json")


def _tilted_image(path, angle, azimuth, bend):
    model = sim.ClothModel(sim.cusick_specimen(1), density=0.192, effects={"tilt": {"angle_rad": angle,
                                                                                     "azimuth_rad": azimuth}})
    p = model.parameters(stretch=tables.COTTON_BLUE.stretch, bend=bend)
    x = model.simulate(p, mode="dynamic", record=False)
    img = render.hard_silhouette(render.orthographic_camera(), x, model.faces)
    measure.write_image(path, 1.0 - np.asarray(img))


def test_tilt_recovery_round_trip(tmp_path):
    # A drape tilted by 0.15 rad towards azimuth 1.2 rad (not one of the start search's azimuths 0, +-0.7, pi):
    # a MAP fit of bending and tilt finds it. Measured (this config): start search picks (0.15, 0.7); epochs
    # 20-30 wander within angle 0.119-0.144, azimuth 1.20-1.29 (the drape is rough in its parameters and Adam's
    # step does not decay). Pixel term only: the soft silhouette's drape coefficient sits ~0.02 above the hard
    # one's, and that bias makes the drape-coefficient term pull against the pixel term (docs/fitting.md).
    path = str(tmp_path / "tilted.png")
    _tilted_image(path, 0.15, 1.2, tables.COTTON_BLUE.bend * 2.0)
    cfg = small_config(sigma_dc=0.0)
    cfg["init"]["scale_search"] = [1.0, 2.0, 4.0]
    job = infer.FitJob([path], 0.192, model="homo", seed=0, config=cfg, threads=1, effects={"tilt": None})
    job.run(epochs=30)
    assert job.effect_start["loss"][0] > min(job.effect_start["loss"])  # the off start is not the best
    angle, azimuth = job.theta["effect_mu"]
    if angle < 0:  # the same tilt
        angle, azimuth = -angle, azimuth + np.pi
    azimuth = (azimuth + np.pi) % (2 * np.pi) - np.pi
    assert 0.11 < angle < 0.19, (job.theta["effect_mu"], job.effect_start)
    assert abs(azimuth - 1.2) < 0.3, (job.theta["effect_mu"], job.effect_start)


def _effect_image(path, effects, bend):
    model = sim.ClothModel(sim.cusick_specimen(1), density=0.192, effects=effects)
    p = model.parameters(stretch=_linear_stretch(), bend=bend)
    x = model.simulate(p, mode="dynamic", record=False)
    img = render.hard_silhouette(render.orthographic_camera(), x, model.faces)
    measure.write_image(path, 1.0 - np.asarray(img))


def _linear_stretch():
    # The fitter's starting stretching (fit.json init: every row the small-strain row), so that only the
    # effect differs between the synthetic drape and the fit's model.
    s = np.array(tables.COTTON_BLUE.stretch, dtype=float)
    s[1:] = s[0]
    return s


@pytest.mark.parametrize("name", ["density_variation", "prestrain", "heterogeneity_map"])
def test_primary_strength_recovery_round_trip_with_the_material_known(name, tmp_path):
    # The effect's primary parameter at its moderate strength on one circle1 drape; the fit knows the material
    # (bending held at the truth: learning rate 0) and fits the strength from its off value (MAP, prior weight
    # from fit.json, pixel + drape-coefficient terms). Recovered within 25 %. (With the material fitted too, a
    # radial density or a prestrain trades off against the bending scale from one image: the diagnosis issue's
    # "material absorbs the effect"; that needs several drapes and the reference's posterior.)
    entry = registered(name)
    primary = entry["parameters"][0]
    truth = primary["moderate"]
    bend = tables.COTTON_BLUE.bend
    path = str(tmp_path / "effect.png")
    _effect_image(path, {name: {primary["name"]: truth}}, bend)
    cfg = small_config()
    cfg["init"]["scale_search"] = []
    cfg["learning_rates"]["homo"]["mu"] = 0.0
    job = infer.FitJob([path], 0.192, model="homo", seed=0, config=cfg, threads=1, init_bend=bend,
                       effects={name: {primary["name"]: None}})
    job.run(epochs=20)
    (value,) = job.theta["effect_mu"]
    assert value == pytest.approx(truth, rel=0.25), (job.effect_start, [h.get("effects") for h in job.history])


def _start_search_job(drapes, threads, tmp_path):
    # a bdp fit (placement noise) of the tilt on one tilted circle1 drape
    path = str(tmp_path / "tilted.png")
    if not (tmp_path / "tilted.png").exists():
        _tilted_image(path, 0.15, 1.2, tables.COTTON_BLUE.bend * 2.0)
    cfg = small_config(sigma_dc=0.0)
    cfg["init"]["scale_search"] = []
    cfg["effects"] = dict(cfg["effects"], start_search_drapes=drapes)
    return infer.FitJob([path], 0.192, model="bdp", seed=5, config=cfg, threads=threads, effects={"tilt": None},
                        init_bend=tables.COTTON_BLUE.bend * 2.0)


def test_the_effects_start_search_scores_each_candidate_by_its_best_placement_drape(tmp_path):
    # start_search_drapes = 1 keeps the one drape from flat at rest: its score is the data term of that drape's hard
    # silhouette (computed here through the facade: simulate, observe, hard render); with more, every candidate
    # drapes the same placements (a stream of their own) and scores the best of them per image, on the lanes
    # exactly as on one lane; the best of more placements is never worse than the best of fewer.
    one = _start_search_job(1, 2, tmp_path)
    start = one.effect_start_search()
    assert start["drapes"] == 1 and one._start_velocities(1) == [None]
    bend = one.family.tables(one.theta, one.num_edges)
    model = one.workers[0].model
    expected = []
    for c in one.plan.start_candidates(one.plan.off):
        p = model.parameters(stretch=one.stretch, bend=bend, effects=one.plan.values(c))
        x = model.simulate(p, mode="dynamic", record=False, **one.config["dynamic"])
        hard = np.asarray(render.hard_silhouette(one.camera, model.observe(x, p), model.faces), dtype=float)
        expected.append(np.mean([infer.data_term(hard, o, one.sigma_obs, one.sigma_dc)[0] for o in one.observations]))
    assert start["loss"] == pytest.approx(expected, rel=1e-12)

    job = _start_search_job(3, 2, tmp_path)
    assert job.start_search_drapes() == 3
    velocities = job._start_velocities(3)
    assert len(velocities) == 3 and not np.allclose(velocities[0], velocities[1])
    assert not np.allclose(velocities[0], job.placement_noise(0, 0))  # not an epoch's placement
    assert not np.allclose(velocities[0], job.placement_noise(3, 0))
    candidates = job.plan.start_candidates(job.theta["effect_mu"])
    bend = job.family.tables(job.theta, job.num_edges)
    params = [job.workers[0].model.parameters(stretch=job.stretch, bend=bend, effects=job.plan.values(c))
              for c in candidates]
    lanes = job._start_scores(params, velocities)
    serial = _start_search_job(3, 1, tmp_path)
    assert serial._start_scores(params, velocities) == lanes
    fewer = job._start_scores(params, velocities[:1])
    assert all(a <= b for a, b in zip(lanes, fewer)) and lanes != fewer
    chosen = job.effect_start_search()
    assert chosen["drapes"] == 3 and chosen["loss"] == lanes
    assert chosen["chosen"] == list(candidates[int(np.argmin(lanes))])
    assert chosen["loss"][0] > min(chosen["loss"])  # the tilted drape: not the off start


def test_a_time_budget_counts_the_effects_start_search(tmp_path):
    # the budget's fixed part (scale search + first epoch) grows by the start search's drapes on the lanes (one
    # drape per candidate, or start_search_drapes of them; the search runs on the job's two lanes either way)
    plans = {}
    for drapes in (1, 4):
        job = _start_search_job(drapes, 2, tmp_path)
        plans[drapes] = infer._plan_time_budget(job, 1000.0, 0.0, False)
    candidates = len(job.plan.start_candidates(job.plan.off))
    for drapes, lane_drapes in ((1, -(-candidates // 2)), (4, -(-candidates * 4 // 2))):
        plan = plans[drapes]
        assert plan.scale_search == pytest.approx(lane_drapes * plan.drape_estimate)
