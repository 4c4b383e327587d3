"""sim.parse_effects_arg: the command-line effects syntax NAME[=VALUE][,NAME.PARAM[=VALUE]...] shared by synth and fit
(a bare NAME.PARAM, fitting that parameter, only in fit)."""
import pytest

from drapelab import sim

# A registry of two effects in the shape sim.effects() returns (only the fields the parser reads), so that these
# tests do not depend on which effects are registered today.
REGISTRY = [
    {"name": "tilt", "parameters": [
        {"name": "angle_rad", "off": 0.0, "moderate": 0.15},
        {"name": "azimuth_rad", "off": 0.0, "moderate": 0.7}]},
    {"name": "prestrain", "parameters": [
        {"name": "strain", "off": 0.0, "moderate": 0.03},
        {"name": "warp_minus_weft", "off": 0.0, "moderate": 0.01}]},
]


def parse(text, bare="moderate"):
    return sim.parse_effects_arg(text, bare=bare, registry=REGISTRY)


def test_empty_text_is_no_effect():
    assert parse(None) == {} and parse("") == {} and parse("  ") == {}


def test_bare_name_sets_the_primary_to_the_bare_value_and_the_rest_off():
    assert parse("tilt") == {"tilt": {"angle_rad": 0.15, "azimuth_rad": 0.0}}
    assert parse("tilt", bare="off") == {"tilt": {"angle_rad": 0.0, "azimuth_rad": 0.0}}
    assert parse("tilt", bare=None) == {"tilt": {}}


def test_name_value_sets_the_primary_and_name_param_value_any_one():
    assert parse("tilt=0.07") == {"tilt": {"angle_rad": 0.07, "azimuth_rad": 0.0}}
    assert parse(" tilt = 0.07 , tilt.azimuth_rad = -1.5 ,prestrain.warp_minus_weft=0.02") == {
        "tilt": {"angle_rad": 0.07, "azimuth_rad": -1.5},
        "prestrain": {"strain": 0.03, "warp_minus_weft": 0.02}}
    # An effect named only through a secondary parameter still gets its primary from `bare`.
    assert parse("tilt.azimuth_rad=1") == {"tilt": {"angle_rad": 0.15, "azimuth_rad": 1.0}}
    assert parse("tilt.azimuth_rad=1", bare="off") == {"tilt": {"angle_rad": 0.0, "azimuth_rad": 1.0}}
    assert parse("tilt.azimuth_rad=1,prestrain", bare=None) == {"tilt": {"azimuth_rad": 1.0}, "prestrain": {}}
    # a bare NAME beside one of its parameters set: that one is held, the others are fitted (they used to stay off)
    assert parse("tilt,tilt.azimuth_rad=1", bare=None) == {"tilt": {"azimuth_rad": 1.0, "angle_rad": None}}
    assert parse("tilt.azimuth_rad=1,tilt", bare=None) == {"tilt": {"azimuth_rad": 1.0, "angle_rad": None}}


def test_bare_name_param_fits_that_parameter_only_in_fit():
    # fit --effects NAME.PARAM: that parameter comes back as None (fitted from its off value); with bare=None
    # the effect's other parameters are not filled in (fit holds them off unless given).
    assert parse("prestrain.strain", bare=None) == {"prestrain": {"strain": None}}
    assert parse(" tilt.azimuth_rad , tilt=0.07,prestrain.warp_minus_weft ", bare=None) == {
        "tilt": {"azimuth_rad": None, "angle_rad": 0.07}, "prestrain": {"warp_minus_weft": None}}
    assert parse("tilt.angle_rad,tilt.azimuth_rad", bare=None) == {"tilt": {"angle_rad": None, "azimuth_rad": None}}
    # A bare NAME fits the whole effect: next to NAME.PARAM its other parameters are fitted too.
    assert parse("tilt,tilt.angle_rad", bare=None) == {"tilt": {"angle_rad": None, "azimuth_rad": None}}


@pytest.mark.parametrize("text, bare, message", [
    ("tilt.azimuth_rad", "moderate", r"without a value \(write tilt.azimuth_rad=VALUE; a bare tilt.azimuth_rad fits"),
    ("tilt.azimuth_rad", "off", "without a value"),
    ("tilt.angle_rad,tilt.angle_rad", None, "tilt.angle_rad is set twice"),
    ("tilt=0.1,tilt.angle_rad", None, "tilt.angle_rad is set twice"),
    ("tilt.angle_rad,tilt.angle_rad=0.1", None, "tilt.angle_rad is set twice"),
    ("tilt.angle", None, "no parameter 'angle'.*angle_rad, azimuth_rad"),
    ("tlt.angle_rad", None, "unknown effect 'tlt'"),
])
def test_bare_name_param_errors(text, bare, message):
    with pytest.raises(sim.InputError, match=message):
        parse(text, bare=bare)


def test_a_structural_parameter_cannot_be_fitted_bare():
    registry = [{"name": "disk_contact", "parameters": [
        {"name": "clamp_radius_m", "off": 0.0, "moderate": 0.02, "structural": True},
        {"name": "friction", "off": 0.0, "moderate": 0.3}]}]
    with pytest.raises(sim.InputError, match="disk_contact.clamp_radius_m is structural"):
        sim.parse_effects_arg("disk_contact.clamp_radius_m", bare=None, registry=registry)
    assert sim.parse_effects_arg("disk_contact.friction,disk_contact.clamp_radius_m=0.03", bare=None,
                                 registry=registry) == {"disk_contact": {"friction": None, "clamp_radius_m": 0.03}}


@pytest.mark.parametrize("text, message", [
    ("tlt=0.1", "unknown effect 'tlt'.*registered: tilt, prestrain"),
    ("tilt.angle=0.1", "no parameter 'angle'.*angle_rad, azimuth_rad"),
    ("tilt=abc", "tilt.angle_rad: expected a number, got 'abc'"),
    ("tilt=", "tilt.angle_rad: expected a number"),
    ("tilt=nan", "tilt.angle_rad: must be finite"),
    ("tilt.azimuth_rad=inf", "tilt.azimuth_rad: must be finite"),
    ("tilt=0.1,tilt.angle_rad=0.2", "tilt.angle_rad is set twice"),
    ("tilt.azimuth_rad", "without a value"),
    ("tilt,,prestrain", "empty item"),
])
def test_bad_text_is_an_error_naming_the_item(text, message):
    with pytest.raises(sim.InputError, match=message):
        parse(text)


def test_bad_bare_and_bad_type_are_errors():
    with pytest.raises(sim.InputError, match="bare"):
        parse("tilt", bare="strong")
    with pytest.raises(sim.InputError, match="expected text"):
        sim.parse_effects_arg({"tilt": {}})


def test_the_real_registry_and_the_model_accept_the_result():
    registry = sim.effects()
    first = registry[0]
    values = sim.parse_effects_arg(first["name"])
    assert values == {first["name"]: {q["name"]: (q["moderate"] if i == 0 else q["off"])
                                      for i, q in enumerate(first["parameters"])}}
    model = sim.ClothModel(sim.cusick_specimen(vertices=40), effects=values)
    assert model.active_effects == [first["name"]]
    # Ranges are the native registry's to check, naming the field.
    primary = first["parameters"][0]
    with pytest.raises(sim.InputError, match=f"{first['name']}.{primary['name']}"):
        sim.ClothModel(sim.cusick_specimen(vertices=40),
                       effects=sim.parse_effects_arg(f"{first['name']}={primary['upper'] + 1}"))
