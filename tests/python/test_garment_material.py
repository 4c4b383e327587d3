"""Tests of drapelab.garment.material: per-element tables drawn from a preset's posterior onto a garment, their
summaries and their round trip through Blender attribute arrays."""
import copy
import os

import numpy as np
import pytest

from drapelab import infer, sim
from drapelab.garment import InputError, material as gmat, skirt as gskirt

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
WOOL = os.path.join(ROOT, "assets", "presets", "fabric_05_wool_red_bdp.json")


@pytest.fixture(scope="module")
def garment():
    return gskirt.make_skirt("flared", vertices=1500)


@pytest.fixture(scope="module")
def preset():
    return infer.load_preset(WOOL)


@pytest.fixture(scope="module")
def draws(garment):
    return gmat.sample_garment_material(WOOL, garment, seed=7, samples=60)


def test_shapes_and_native_order(garment, draws):
    m = draws[0]
    model = sim.ClothModel((garment.positions, garment.faces, garment.uv), heterogeneous=True, support_radius=10.0)
    E, F = model.num_bending_edges, garment.num_faces
    assert m.stretch.shape == (F, 6, 4) and m.bend.shape == (E, 3, 5)
    assert m.bending_edges.shape == (E, 2) and m.bending_edges.dtype == np.int32
    assert np.array_equal(m.bending_stencils, model.bending_edges)          # the native model's order
    assert np.array_equal(m.bending_edges, model.bending_edges[:, :2])
    p = m.native_parameters(model)
    blocks = model.split(p)
    assert np.array_equal(blocks["bend"], m.bend) and np.array_equal(blocks["stretch"], m.stretch)
    assert blocks["density"] == m.density == pytest.approx(0.274, abs=0.05)
    assert np.isfinite(model.energy(garment.positions, p))
    assert np.isfinite(model.gradient(garment.positions, p)).all()


def test_values_finite_positive_and_stretch_is_the_presets(preset, draws):
    for m in draws[:5]:
        assert np.isfinite(m.bend).all() and (m.bend > 0).all()
        assert np.array_equal(m.stretch, np.broadcast_to(np.asarray(preset["stretch_N_m"]), m.stretch.shape))
        assert m.density == preset["density_kg_m2"] and m.preset_name == "fabric_05_wool_red_bdp"
        assert m.effects == {}                                               # the shipped presets have none


def test_deterministic_per_seed_and_samples_differ(garment, draws):
    again = gmat.sample_garment_material(WOOL, garment, seed=7, samples=60)
    assert all(np.array_equal(a.bend, b.bend) for a, b in zip(draws, again))
    assert not np.array_equal(draws[0].bend, draws[1].bend)
    other = gmat.sample_garment_material(WOOL, garment, seed=8, samples=1)[0]
    assert not np.array_equal(other.bend, draws[0].bend)


def test_draws_follow_the_posterior(preset, draws, garment):
    """Within one draw the per-edge log spread is the posterior's log_std; across draws, the per-draw mean moves
    by the calibration's global_log_std around log_mean; the same as infer.preset_bend_samples."""
    bend = preset["posterior"]["bend"]
    mu, sd, g = np.asarray(bend["log_mean"]), np.asarray(bend["log_std"]), bend["global_log_std"]
    logs = np.log(np.stack([m.bend for m in draws]))                         # (K, E, 3, 5)
    within = logs.std(axis=1).mean(axis=0)                                   # (3, 5)
    assert np.allclose(within, sd, rtol=0.05)
    draw_means = logs.mean(axis=1)                                           # (K, 3, 5): mu + g z_k
    assert np.allclose(draw_means.mean(axis=0), mu, atol=4 * g / np.sqrt(len(draws)))
    spread = (draw_means - mu).mean(axis=(1, 2)).std()
    assert spread == pytest.approx(g, rel=0.3)
    ref = infer.preset_bend_samples(preset, draws[0].bend.shape[0], np.random.default_rng(7), 60)
    assert np.array_equal(ref[3], draws[3].bend)                             # exactly evaluate's draws


def test_homo_preset_gives_identical_elements(preset, garment):
    homo = copy.deepcopy(preset)
    homo["model"] = "homo"
    homo["posterior"]["bend"]["log_std"] = np.zeros((3, 5)).tolist()
    homo["posterior"]["bend"]["global_log_std"] = 0.0
    m = gmat.sample_garment_material(homo, garment, seed=1, samples=2)
    for draw in m:
        assert np.array_equal(draw.bend, np.broadcast_to(np.exp(np.asarray(homo["posterior"]["bend"]["log_mean"])),
                                                         draw.bend.shape))
    assert np.array_equal(m[0].bend, m[1].bend)
    for values in list(m[0].face_scalars.values()) + list(m[0].edge_scalars.values()):
        assert np.ptp(values) == 0


def test_summaries_read_the_tables(draws):
    m = draws[0]
    assert set(m.face_scalars) == {"drapelab_stretch_warp", "drapelab_stretch_weft", "drapelab_stretch_shear"}
    assert set(m.edge_scalars) == {"drapelab_bend_warp", "drapelab_bend_weft", "drapelab_bend_bias"}
    assert np.array_equal(m.face_scalars["drapelab_stretch_weft"], m.stretch[:, 0, 0])   # c11, small strain
    assert np.array_equal(m.face_scalars["drapelab_stretch_warp"], m.stretch[:, 0, 2])   # c22
    assert np.array_equal(m.face_scalars["drapelab_stretch_shear"], m.stretch[:, 0, 3])  # c33
    assert np.array_equal(m.edge_scalars["drapelab_bend_warp"], m.bend[:, 0, 0])         # beta = 0
    assert np.array_equal(m.edge_scalars["drapelab_bend_bias"], m.bend[:, 1, 0])         # beta = 45
    assert np.array_equal(m.edge_scalars["drapelab_bend_weft"], m.bend[:, 2, 0])         # beta = 90


def test_attributes_round_trip(draws, garment):
    m = draws[2]
    attrs = gmat.material_attributes(m)
    assert set(attrs) == set(gmat.ATTRIBUTE_DOMAINS)
    assert all(name.startswith("drapelab_") for name in attrs)
    F, E = garment.num_faces, m.bend.shape[0]
    for name, values in attrs.items():
        assert values.shape == ((F,) if gmat.ATTRIBUTE_DOMAINS[name] == "FACE" else (E,)), name
    assert np.array_equal(attrs["drapelab_stretch_06"], m.stretch[:, 1, 2])   # entry 4 row + column
    assert np.array_equal(attrs["drapelab_bend_07"], m.bend[:, 1, 2])         # entry 5 row + column
    # Blender stores FLOAT attributes in float32: the round trip through float32 keeps 7 digits
    back = gmat.material_from_attributes({k: v.astype(np.float32) for k, v in attrs.items()}, garment)
    assert np.allclose(back.bend, m.bend, rtol=1e-6) and np.allclose(back.stretch, m.stretch, rtol=1e-6)
    exact = gmat.material_from_attributes(attrs, garment)
    assert np.array_equal(exact.bend, m.bend) and np.array_equal(exact.stretch, m.stretch)
    assert exact.density == m.density and np.array_equal(exact.bending_edges, m.bending_edges)
    for k in m.edge_scalars:
        assert np.array_equal(exact.edge_scalars[k], m.edge_scalars[k])


def test_attribute_errors(draws, garment):
    attrs = gmat.material_attributes(draws[0])
    missing = dict(attrs)
    del missing["drapelab_bend_14"]
    with pytest.raises(InputError, match="drapelab_bend_14 is missing"):
        gmat.material_from_attributes(missing, garment)
    short = dict(attrs, drapelab_stretch_03=attrs["drapelab_stretch_03"][:-1])
    with pytest.raises(InputError, match="drapelab_stretch_03 has .* values, the garment has .* faces"):
        gmat.material_from_attributes(short, garment)
    nan = dict(attrs, drapelab_bend_02=np.where(np.arange(len(attrs["drapelab_bend_02"])) == 5, np.nan,
                                                attrs["drapelab_bend_02"]))
    with pytest.raises(InputError, match="drapelab_bend_02 has a non-finite value at element 5"):
        gmat.material_from_attributes(nan, garment)
    zero = dict(attrs, drapelab_bend_00=np.zeros_like(attrs["drapelab_bend_00"]))
    with pytest.raises(InputError, match="non-positive bending stiffness on bending edge 0"):
        gmat.material_from_attributes(zero, garment)


def test_bad_arguments(garment, preset):
    with pytest.raises(InputError, match="seed"):
        gmat.sample_garment_material(WOOL, garment, seed=-1)
    with pytest.raises(InputError, match="samples"):
        gmat.sample_garment_material(WOOL, garment, samples=0)
    with pytest.raises(InputError, match="garment"):
        gmat.sample_garment_material(WOOL, "skirt")
    with pytest.raises(InputError, match="shipped: fabric_01"):
        gmat.sample_garment_material("no_such_fabric", garment)
    assert gmat.resolve_preset("fabric_03")[1] == "fabric_03_viscose_white_bdp"   # a unique prefix
    broken = copy.deepcopy(preset)
    broken["posterior"]["bend"]["log_std"] = [[-1] * 5] * 3
    with pytest.raises(InputError, match="log_std must be >= 0"):
        gmat.sample_garment_material(broken, garment)


def test_fabrics_differ_more_than_draws(garment):
    """Stiff wool (fabric 5) and soft viscose (fabric 3) differ in bending by more than draws of one fabric."""
    wool = gmat.sample_garment_material(WOOL, garment, seed=0, samples=8)
    viscose = gmat.sample_garment_material("fabric_03", garment, seed=0, samples=8)
    level = lambda ms: np.array([np.log(m.bend).mean() for m in ms])  # noqa: E731
    w, v = level(wool), level(viscose)
    assert w.mean() - v.mean() > 2 * max(w.std(), v.std())
