"""The effect registry through the facade: sim.effects(), ClothModel(effects=...), parameters/split, the CLI."""
import json
import subprocess
import sys

import numpy as np
import pytest

from drapelab import sim, tables


def test_registry_lists_every_effect_with_units_and_explanations():
    registry = sim.effects()
    assert registry, "no effect registered"
    assert "tilt" in [e["name"] for e in registry]
    for e in registry:
        assert e["explanation"] and e["signature"], e["name"]
        for q in e["parameters"]:
            assert q["unit"] and q["lower"] <= q["off"] <= q["upper"], (e["name"], q["name"])
            assert q["lower"] <= q["moderate"] <= q["upper"] and q["prior_scale"] > 0, (e["name"], q["name"])


@pytest.mark.parametrize("name", [e["name"] for e in sim.effects()])
def test_every_effect_at_its_off_value_drapes_exactly_as_the_base_model(name):
    base = sim.ClothModel(sim.cusick_specimen(1))
    off = sim.ClothModel(sim.cusick_specimen(1), effects={name: {}})
    assert off.active_effects == [name] and base.active_effects == []
    pb = base.parameters(material=tables.COTTON_BLUE)
    po = off.parameters(material=tables.COTTON_BLUE)
    blocks = off.split(po)
    for q in next(e for e in sim.effects() if e["name"] == name)["parameters"]:
        assert blocks[f"{name}.{q['name']}"] == q["off"]
    xb = base.simulate(pb, steps=10)
    xo = off.simulate(po, steps=10)
    assert np.array_equal(xb, xo)


def test_tilt_moves_the_drape_downhill_and_its_gradient_is_reported():
    model = sim.ClothModel(sim.cusick_specimen(1), effects={"tilt": {"angle_rad": 0.15, "azimuth_rad": 0.0}})
    p = model.parameters(material=tables.COTTON_BLUE)
    x = model.simulate(p, steps=40)
    level = sim.ClothModel(sim.cusick_specimen(1))
    x0 = level.simulate(level.parameters(material=tables.COTTON_BLUE), steps=40)
    rim = np.linalg.norm(model.rest_positions[:, :2], axis=1) > 0.14
    # Gravity leans towards +x: the rim shifts towards +x (a 1-fold signature), against the level drape.
    shift = x[rim, 0].mean() - x0[rim, 0].mean()
    assert shift > 1e-3, shift
    grads = model.backward(np.tile([1.0, 0.0, 0.0], (model.num_vertices, 1)) / model.num_vertices)
    assert grads["tilt.angle_rad"] > 0  # more tilt, further downhill
    # parameters(effects=) sets a value; split reads it back
    p2 = model.parameters(material=tables.COTTON_BLUE, effects={"tilt": {"angle_rad": 0.05}})
    assert model.split(p2)["tilt.angle_rad"] == 0.05


@pytest.mark.parametrize("effects, message", [
    ({"no_such": {}}, "no_such"),
    ({"tilt": {"angle": 0.1}}, "angle"),
    ({"tilt": {"angle_rad": 3.0}}, "tilt.angle_rad"),
    ({"tilt": {"angle_rad": float("nan")}}, "tilt.angle_rad"),
    ("tilt", "expected a dict"),
])
def test_bad_effects_are_errors_naming_the_field(effects, message):
    with pytest.raises(ValueError, match=message):
        sim.ClothModel(sim.cusick_specimen(vertices=40), effects=effects)


def test_parameters_refuse_an_inactive_effect():
    model = sim.ClothModel(sim.cusick_specimen(vertices=40))
    with pytest.raises(ValueError, match="not active"):
        model.parameters(effects={"tilt": {"angle_rad": 0.1}})


def test_cli_effects_prints_and_writes_the_registry(tmp_path):
    out = tmp_path / "effects.json"
    r = subprocess.run([sys.executable, "-m", "drapelab.cli", "effects", "--json", str(out)],
                       capture_output=True, text=True, check=True)
    assert "tilt:" in r.stdout and "angle_rad (primary)" in r.stdout
    data = json.loads(out.read_text())
    assert [e["name"] for e in data["effects"]] == [e["name"] for e in sim.effects()]
