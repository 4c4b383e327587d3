"""The physics of the effects rest_curvature and damping through the facade: damping is implicit Rayleigh damping
(a free fall follows (1 + h c) v' = v - h g exactly and approaches the terminal speed g / c), a static drape
ignores it and says so, and rest_curvature changes the drape while its off value does not."""
import warnings

import numpy as np
import pytest

from drapelab import sim


def _free_fall_velocities(c, steps, h=0.05):
    # No handle (stiffness 0): the specimen falls as a rigid body, every elastic force is zero.
    effects = {"damping": {"mass_per_s": c}}
    model = sim.ClothModel(sim.cusick_specimen(1), effects=effects)
    p = model.parameters(handle_stiffness=0.0, effects=effects)
    out = []
    for n in range(1, steps + 1):
        model.simulate(p, steps=n, time_step=h, record=False)
        out.append(model.velocities.copy())
    return out


def test_damping_free_fall_is_implicit_rayleigh_damping():
    h = 0.05
    (undamped,) = _free_fall_velocities(0.0, 1, h)
    g = -undamped[0, 2] / h  # the model's gravity
    assert g == pytest.approx(9.8, rel=1e-3)
    c = 4.0
    vz = 0.0
    for v in _free_fall_velocities(c, 5, h):
        vz = (vz - h * g) / (1 + h * c)
        np.testing.assert_allclose(v[:, 2], vz, rtol=1e-10)
        np.testing.assert_allclose(v[:, :2], 0.0, atol=1e-12)
    # and the terminal speed g / c after many steps (a 5 s fall)
    effects = {"damping": {"mass_per_s": c}}
    model = sim.ClothModel(sim.cusick_specimen(1), effects=effects)
    model.simulate(model.parameters(handle_stiffness=0.0, effects=effects), steps=100, time_step=h, record=False)
    np.testing.assert_allclose(model.velocities[:, 2], -g / c, rtol=1e-6)


def test_static_drape_ignores_damping_and_says_so():
    registry = {e["name"]: e for e in sim.effects()}
    assert registry["damping"]["dynamic_only"] and not registry["rest_curvature"]["dynamic_only"]
    mesh = sim.cusick_specimen(1)
    base = sim.ClothModel(mesh)
    effects = {"damping": {"mass_per_s": registry["damping"]["parameters"][0]["moderate"]}}
    damped = sim.ClothModel(mesh, effects=effects)
    x0 = base.simulate(base.parameters(), mode="static")
    with pytest.warns(UserWarning, match="damping has no effect on a static drape"):
        x1 = damped.simulate(damped.parameters(effects=effects), mode="static")
    np.testing.assert_array_equal(x0, x1)
    assert damped.last_result["ignored_effects"] == ["damping"]
    # its gradient there is exactly zero
    damped.backward(np.ones_like(x1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a dynamic drape does not warn
        damped.simulate(damped.parameters(effects=effects), steps=5)


@pytest.mark.parametrize("name", ["rest_curvature", "damping"])
def test_effect_moves_the_dynamic_drape_and_its_off_value_does_not(name):
    entry = {e["name"]: e for e in sim.effects()}[name]
    mesh = sim.cusick_specimen(1)
    base = sim.ClothModel(mesh)
    xb = base.simulate(base.parameters(), steps=20, record=False)
    for q in entry["parameters"]:
        off = {name: {q["name"]: q["off"]}}
        on = {name: {q["name"]: q["moderate"]}}
        model = sim.ClothModel(mesh, effects=on)
        np.testing.assert_array_equal(model.simulate(model.parameters(effects=off), steps=20, record=False), xb)
        x = model.simulate(model.parameters(effects=on), steps=20, record=False)
        assert np.abs(x - xb).max() > 1e-3, q["name"]  # millimetres after 1 s
