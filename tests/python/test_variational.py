"""The trainer's native numerical core (drapelab.variational over drapelab_native.infer) against the numpy
formulas the Python trainer used before it moved (dfbe31f): same numbers to round-off, the fit's shapes, and clear
errors. The derivatives themselves are finite-difference tested in C++ (tests/native/infer/test_infer.cpp)."""
import numpy as np
import pytest

from drapelab import infer, variational

EDGES = 7


def numpy_softplus(x):
    return np.logaddexp(0.0, x)


def numpy_sigmoid(x):
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def theta_of(kind, rng, effects=0):
    theta = variational.Family(kind).initial(rng.normal(-10, 0.5, (3, 5)), EDGES, 0.2)
    theta = {k: v + rng.normal(0, 0.1, v.shape) for k, v in theta.items()}
    if effects:
        theta["effect_mu"] = rng.uniform(-0.1, 0.1, effects)
        if kind == "bdp":
            theta["effect_eta"] = rng.normal(-3, 0.5, effects)
    return theta


@pytest.mark.parametrize("kind, per_element, stochastic, shapes", [
    ("homo", False, False, {"mu": (3, 5)}),
    ("heter", True, False, {"mu": (EDGES, 3, 5)}),
    ("bdp", True, True, {"mu": (3, 5), "eta": (3, 5)}),
])
def test_families_have_their_blocks_and_draw_the_old_tables(kind, per_element, stochastic, shapes):
    f = variational.Family(kind)
    assert (f.name, f.per_element, f.stochastic) == (kind, per_element, stochastic)
    rng = np.random.default_rng(1)
    theta = theta_of(kind, rng)
    assert {k: v.shape for k, v in theta.items()} == shapes
    noise = rng.standard_normal((EDGES, 3, 5))
    tables = f.tables(theta, EDGES, noise)
    if kind == "bdp":
        old = np.exp(theta["mu"][None] + numpy_softplus(theta["eta"])[None] * noise)
    else:
        old = np.exp(theta["mu"])
    assert tables.shape == old.shape
    np.testing.assert_allclose(tables, old, rtol=1e-15, atol=0)
    np.testing.assert_allclose(infer.sample_bend_tables(kind, theta, EDGES, noise), old, rtol=1e-15, atol=0)
    if kind == "bdp":  # no noise: the median table on every edge
        np.testing.assert_allclose(f.tables(theta, EDGES), np.broadcast_to(np.exp(theta["mu"]), (EDGES, 3, 5)),
                                   rtol=1e-15, atol=0)


def test_unknown_family_is_refused_naming_the_choices():
    with pytest.raises(infer.InputError, match="homo"):
        variational.Family("gaussian")
    with pytest.raises(infer.InputError, match="model"):
        infer.FitJob(["x.png"], 0.2, model="gaussian")


def old_elbo(kind, theta, results, clip, prior_mu, prior_sigma, kl_weight, plan, prior_weight):
    """The Python trainer's ELBO assembly (FitJob.objective at dfbe31f) for reference."""
    n = len(results)
    data = 0.0
    grads = {k: np.zeros_like(v, dtype=float) for k, v in theta.items()}
    for d, g_bend, bend, noise, g_effect, inside, eps in results:
        data += d / n
        g_log = np.asarray(g_bend) * bend / n
        if kind == "bdp":
            grads["mu"] += g_log.sum(axis=0)
            grads["eta"] += (g_log * noise).sum(axis=0) * numpy_sigmoid(theta["eta"])
        else:
            grads["mu"] += g_log
        if plan is not None:
            g_e = np.where(inside, g_effect, 0.0) / n
            grads["effect_mu"] += g_e
            if kind == "bdp":
                grads["effect_eta"] += g_e * eps * numpy_sigmoid(theta["effect_eta"])
    grad_norm = float(np.sqrt(sum(float(np.sum(g * g)) for g in grads.values())))
    factor = 1.0
    if clip is not None and grad_norm > clip:
        factor = clip / grad_norm
        for g in grads.values():
            g *= factor
    if kind in ("homo", "heter"):
        dev = (theta["mu"] - prior_mu) / prior_sigma
        per = 1.0 / (dev.shape[0] if kind == "heter" else 1.0)
        kl = kl_weight * 0.5 * float(np.sum(dev ** 2)) * per
        grads["mu"] += kl_weight * dev / prior_sigma * per
    else:
        sigma = numpy_softplus(theta["eta"])
        kl = float(np.sum(np.log(prior_sigma / sigma) + (sigma ** 2 + (theta["mu"] - prior_mu) ** 2) / (2 * prior_sigma ** 2) - 0.5))
        kl *= kl_weight
        grads["mu"] += kl_weight * (theta["mu"] - prior_mu) / prior_sigma ** 2
        grads["eta"] += kl_weight * (-1.0 / sigma + sigma / prior_sigma ** 2) * numpy_sigmoid(theta["eta"])
    if plan is not None:
        off, scale = plan
        w = kl_weight * prior_weight
        if kind == "bdp":
            s = numpy_softplus(theta["effect_eta"])
            kl_e = float(np.sum(np.log(scale / s) + (s ** 2 + (theta["effect_mu"] - off) ** 2) / (2 * scale ** 2) - 0.5))
            grads["effect_eta"] += w * (-1.0 / s + s / scale ** 2) * numpy_sigmoid(theta["effect_eta"])
            d_mu = (theta["effect_mu"] - off) / scale ** 2
        else:
            dev = (theta["effect_mu"] - off) / scale
            kl_e, d_mu = 0.5 * float(np.sum(dev ** 2)), dev / scale
        kl += w * kl_e
        grads["effect_mu"] += w * d_mu
    return {"loss": data + kl, "data": data, "kl": kl, "grad_norm": grad_norm, "clip": factor}, grads


@pytest.mark.parametrize("kind", ["homo", "heter", "bdp"])
@pytest.mark.parametrize("effects", [False, True])
@pytest.mark.parametrize("clip_fraction", [None, 0.5])
def test_native_elbo_matches_the_python_trainer(kind, effects, clip_fraction):
    rng = np.random.default_rng(2)
    family = variational.Family(kind)
    theta = theta_of(kind, rng, effects=2 if effects else 0)
    off, lower, upper, scale = np.zeros(2), np.array([-0.5, -0.05]), np.array([0.5, 1.0]), np.array([0.15, 0.2])
    block = variational.EffectBlock(off, lower, upper, scale) if effects else None
    results, draws = [], []
    for s in range(3 if family.stochastic else 1):
        noise = rng.standard_normal((EDGES, 3, 5)) if family.stochastic else None
        bend = family.tables(theta, EDGES, noise)
        g_bend = rng.normal(0, 1e5, bend.shape)
        eps = rng.standard_normal(2) if effects and family.stochastic else None
        g_effect, inside = None, None
        if effects:
            _, inside = variational.effect_draw(block, theta, eps)
            g_effect = rng.normal(0, 3, 2)
        d = float(rng.uniform(1, 5))
        results.append((d, g_bend, bend, noise, g_effect, inside, eps))
        draws.append(variational.Draw(d, g_bend, bend, noise, g_effect, eps))
    prior_mu = theta["mu"].reshape(-1, 3, 5)[0] + 0.3
    ref, ref_grads = old_elbo(kind, theta, results, None, prior_mu, 0.8, 1.0, (off, scale) if effects else None, 0.1)
    clip = None if clip_fraction is None else clip_fraction * ref["grad_norm"]
    if clip is not None:
        ref, ref_grads = old_elbo(kind, theta, results, clip, prior_mu, 0.8, 1.0, (off, scale) if effects else None, 0.1)
    terms, grads = variational.assemble_elbo(family, block, theta, draws, clip, prior_mu, 0.8, 1.0, 0.1)
    for k in ref:
        assert terms[k] == pytest.approx(ref[k], rel=1e-13, abs=0), k
    assert set(grads) == set(ref_grads)
    for k in grads:
        assert grads[k].shape == theta[k].shape
        np.testing.assert_allclose(grads[k], ref_grads[k], rtol=1e-12, atol=1e-12 * np.max(np.abs(ref_grads[k])))


def test_adam_matches_the_python_trainer_and_projects_effect_means():
    rng = np.random.default_rng(3)
    theta = theta_of("bdp", rng, effects=2)
    theta["effect_mu"] = np.array([0.49, 0.2])
    lower, upper = np.array([-0.5, -1.0]), np.array([0.5, 1.0])
    block = variational.EffectBlock(np.zeros(2), lower, upper, np.ones(2))
    lrs = {"mu": 0.03, "eta": 0.05, "effect_mu": np.array([0.2, 0.1]), "effect_eta": 0.05}
    state = {k: {"m": np.zeros_like(v), "v": np.zeros_like(v)} for k, v in theta.items()}
    ref_theta = {k: v.copy() for k, v in theta.items()}
    ref_state = {k: {"m": np.zeros_like(v), "v": np.zeros_like(v)} for k, v in theta.items()}
    b1, b2, e = 0.9, 0.999, 1e-8
    for t in (1, 2, 3):
        grads = {k: rng.normal(0, 1, v.shape) for k, v in theta.items()}
        grads["effect_mu"] = np.array([-1.0, 0.5])  # pushes the first mean past its upper bound
        theta = variational.adam_step(theta, grads, state, t, lrs, 0.5, b1, b2, e, block)
        for k, g in grads.items():  # FitJob.adam_step at dfbe31f
            st = ref_state[k]
            st["m"] = b1 * st["m"] + (1 - b1) * g
            st["v"] = b2 * st["v"] + (1 - b2) * g * g
            ref_theta[k] = ref_theta[k] - 0.5 * lrs[k] * (st["m"] / (1 - b1 ** t)) / (np.sqrt(st["v"] / (1 - b2 ** t)) + e)
        ref_theta["effect_mu"] = np.clip(ref_theta["effect_mu"], lower, upper)
        for k in theta:
            np.testing.assert_allclose(theta[k], ref_theta[k], rtol=1e-15, atol=0)
            np.testing.assert_allclose(state[k]["m"], ref_state[k]["m"], rtol=1e-15, atol=0)
            assert theta[k].shape == ref_theta[k].shape
    assert theta["effect_mu"][0] == upper[0]


def test_kl_and_clip_threshold_match_the_python_trainer():
    rng = np.random.default_rng(4)
    mu, mu0 = rng.normal(0, 1, (3, 5)), rng.normal(0, 1, (3, 5))
    sigma = rng.uniform(0.1, 2, (3, 5))
    value, d_mu, d_sigma = infer.kl_divergence(mu, sigma, mu0, 0.7)
    old = np.log(0.7 / sigma) + (sigma ** 2 + (mu - mu0) ** 2) / (2 * 0.7 ** 2) - 0.5
    assert value == pytest.approx(float(np.sum(old)), rel=1e-14)
    np.testing.assert_allclose(d_mu, (mu - mu0) / 0.7 ** 2, rtol=1e-15)
    np.testing.assert_allclose(d_sigma, -1.0 / sigma + sigma / 0.7 ** 2, rtol=1e-15)
    norms = list(rng.uniform(1, 100, 12))
    for window, min_epochs in ((10, 3), (4, 3), (3, 5)):
        got = variational.clip_threshold(norms, 3.0, window, min_epochs)
        first = norms[:window]
        assert got == (None if len(first) < min_epochs else pytest.approx(3.0 * float(np.median(first)), rel=1e-15))
    assert variational.clip_threshold(norms, 0.0, 10, 3) is None


def test_bad_draws_and_parameters_are_clear_errors():
    family = variational.Family("bdp")
    theta = theta_of("bdp", np.random.default_rng(5))
    bend = family.tables(theta, EDGES)
    prior = np.zeros((3, 5))
    with pytest.raises(infer.InputError, match="shaped like its tables"):
        variational.assemble_elbo(family, None, theta, [variational.Draw(1.0, np.ones((2, 3, 5)), bend)], None,
                                  prior, 1.0, 1.0, 1.0)
    with pytest.raises(infer.InputError, match="not finite"):
        variational.assemble_elbo(family, None, theta, [variational.Draw(np.nan, np.ones_like(bend), bend)], None,
                                  prior, 1.0, 1.0, 1.0)
    with pytest.raises(infer.InputError, match="no draws"):
        variational.assemble_elbo(family, None, theta, [], None, prior, 1.0, 1.0, 1.0)
    with pytest.raises(infer.InputError, match="eta"):
        family.tables({"mu": theta["mu"]}, EDGES)
    with pytest.raises(infer.InputError, match="noise"):
        family.tables(theta, EDGES, np.zeros((EDGES + 1, 3, 5)))
    with pytest.raises(infer.InputError, match="bounds"):
        variational.EffectBlock(np.array([2.0]), np.array([-1.0]), np.array([1.0]), np.array([0.1]))
