"""Tests of the simulation facade drapelab.sim (and the physics bindings under it), on circle1 (297 vertices)."""
import threading
import time

import numpy as np
import pytest

from drapelab import sim, tables
from drapelab._native import native


@pytest.fixture(scope="module")
def circle1():
    return sim.cusick_specimen(1)


@pytest.fixture(scope="module")
def model(circle1):
    return sim.ClothModel(circle1)


@pytest.fixture(scope="module")
def small_heterogeneous():
    return sim.ClothModel(sim.cusick_specimen(vertices=60), heterogeneous=True)


def unit_direction(model, name, index=None):
    blocks = model.split(np.zeros(model.num_parameters))
    if index is None:
        blocks[name] = 1.0
    else:
        blocks[name][index] = 1.0
    return model.join(blocks)


# ---------------------------------------------------------------- shapes and layout
def test_specimen_levels_and_generated(tmp_path):
    # The bundled templates: the dataset's circle1..5, exactly.
    for level, count in zip(sim.TEMPLATE_LEVELS, (297, 1205, 2699, 4766, 7496)):
        assert sim.cusick_template_path(level) is not None, "bundled template missing from assets/"
        assert sim.cusick_specimen(level).num_vertices == count
    # A folder without templates: an error naming the file, never a silently generated stand-in.
    with pytest.raises(ValueError, match="circle1.obj"):
        sim.cusick_specimen(1, template_dir=tmp_path)
    assert sim.cusick_template_path(1, template_dir=tmp_path) is None
    small = sim.cusick_specimen(vertices=40)
    assert 30 <= small.num_vertices <= 60
    with pytest.raises(ValueError, match="level"):
        sim.cusick_specimen(6)
    with pytest.raises(ValueError, match="vertices"):
        sim.cusick_specimen(vertices=3)


def test_model_shapes_and_layout(model):
    assert model.num_vertices == 297
    assert model.rest_positions.shape == (297, 3)
    assert model.faces.shape == (model.num_faces, 3) and model.faces.dtype == np.int32
    assert model.bending_edges.shape == (model.num_bending_edges, 4)
    assert [b["name"] for b in model.layout] == ["stretch", "bend", "density", "handle_stiffness"]
    assert {b["name"]: b["unit"] for b in model.layout}["bend"] == "N m"
    radii = np.linalg.norm(model.uv[model.handle_vertices], axis=1)
    assert len(radii) > 0 and radii.max() < 0.09
    p = model.parameters()
    assert p.shape == (model.num_parameters,) == (24 + 15 + 2,)
    blocks = model.split(p)
    np.testing.assert_array_equal(blocks["stretch"], tables.COTTON_BLUE.stretch)
    np.testing.assert_array_equal(blocks["bend"], tables.COTTON_BLUE.bend)
    assert blocks["density"] == pytest.approx(0.192) and blocks["handle_stiffness"] == pytest.approx(1e3)
    np.testing.assert_array_equal(model.join(blocks), p)
    masses = model.masses(p)
    assert masses.shape == (297,)
    assert masses.sum() == pytest.approx(0.192 * np.pi * 0.15 ** 2, rel=0.02)


def test_heterogeneous_per_element_tables(small_heterogeneous):
    m = small_heterogeneous
    F, E = m.num_faces, m.num_bending_edges
    assert m.block_shape("stretch") == (F, 6, 4) and m.block_shape("bend") == (E, 3, 5)
    stretch = np.broadcast_to(tables.WOOL_RED.stretch, (F, 6, 4)) * np.linspace(0.5, 1.5, F)[:, None, None]
    p = m.parameters(stretch=stretch, bend=tables.WOOL_RED.bend, density=0.274)
    blocks = m.split(p)
    np.testing.assert_allclose(blocks["stretch"], stretch)
    assert blocks["bend"].shape == (E, 3, 5)
    np.testing.assert_array_equal(blocks["bend"][-1], tables.WOOL_RED.bend)
    bad = np.array(stretch)
    bad[7, 2, 3] = -1.0
    with pytest.raises(ValueError, match="stretch: stiffness must be >= 0.*row 2 c33 of face 7"):
        m.parameters(stretch=bad)
    with pytest.raises(ValueError, match=r"bend: expected shape \(3, 5\) or \(%d, 3, 5\)" % E):
        m.parameters(bend=np.ones((E + 1, 3, 5)))


def test_presets():
    for preset in tables.PRESETS.values():
        assert preset.stretch.shape == (6, 4) and preset.bend.shape == (3, 5) and preset.density > 0
        assert not preset.stretch.flags.writeable
    assert tables.preset("Cotton Blue") is tables.COTTON_BLUE
    with pytest.raises(ValueError, match="unknown material"):
        tables.preset("silk")


def test_parameters_from_material(model):
    blocks = model.split(model.parameters(material=tables.WOOL_RED, handle_stiffness=500.0))
    np.testing.assert_array_equal(blocks["stretch"], tables.WOOL_RED.stretch)
    assert blocks["density"] == pytest.approx(0.274) and blocks["handle_stiffness"] == 500.0
    assert model.split(model.parameters(material="cotton_pink"))["density"] == pytest.approx(0.114)


def test_model_from_obj_path_and_arrays(tmp_path, model):
    path = tmp_path / "flat.obj"
    sim.write_obj(path, model.rest_positions, model.faces)
    from_path = sim.ClothModel(str(path))
    assert from_path.num_vertices == model.num_vertices and from_path.num_faces == model.num_faces
    from_arrays = sim.ClothModel((model.rest_positions, model.faces))
    assert from_arrays.num_bending_edges == model.num_bending_edges


# ---------------------------------------------------------------- errors
@pytest.mark.parametrize("kwargs, pattern", [
    ({"stretch": np.ones((6, 3))}, r"stretch: expected shape \(6, 4\)"),
    ({"stretch": np.ones((535, 6, 4))}, "homogeneous"),
    ({"bend": np.ones(15)}, r"bend: expected shape \(3, 5\)"),
    ({"bend": np.full((3, 5), np.nan)}, "bend: non-finite"),
    ({"stretch": np.full((6, 4), np.inf)}, "stretch: non-finite"),
    ({"stretch": -np.ones((6, 4))}, r"stretch: stiffness must be >= 0.*row 0 c11"),
    ({"bend": -np.ones((3, 5))}, "bend: stiffness must be >= 0"),
    ({"density": 0.0}, "density: must be > 0"),
    ({"density": -0.1}, "density: must be > 0"),
    ({"density": float("nan")}, "density: must be finite"),
    ({"handle_stiffness": -1.0}, "handle_stiffness: must be >= 0"),
    ({"stretch": np.array([["a"] * 4] * 6)}, "stretch: expected real numbers"),
])
def test_parameter_errors_name_the_argument(model, kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        model.parameters(**kwargs)


def test_negative_poisson_coupling_is_allowed(model):
    t = np.array(tables.COTTON_BLUE.stretch)
    t[:, 1] = -0.1
    model.parameters(stretch=t)


def test_parameter_vector_errors(model):
    p = model.parameters()
    with pytest.raises(ValueError, match="params: expected 41 values"):
        model.simulate(p[:-1], steps=1)
    bad = p.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="params: non-finite"):
        model.simulate(bad, steps=1)
    bad = p.copy()
    bad[unit_direction(model, "density").astype(bool)] = -1.0
    with pytest.raises(ValueError, match="params:.*density"):
        model.simulate(bad, steps=1)
    bad = p.copy()
    bad[0] = -5.0
    with pytest.raises(ValueError, match="params:.*stretch.*negative"):
        model.simulate(bad, steps=1)


def test_model_and_simulate_argument_errors(circle1, model):
    with pytest.raises(ValueError, match="density"):
        sim.ClothModel(circle1, density=0)
    with pytest.raises(ValueError, match="handle_stiffness"):
        sim.ClothModel(circle1, handle_stiffness=-1)
    with pytest.raises(ValueError, match="mesh_or_path"):
        sim.ClothModel(42)
    p = model.parameters()
    with pytest.raises(ValueError, match="mode"):
        model.simulate(p, mode="quasi")
    with pytest.raises(ValueError, match="steps"):
        model.simulate(p, steps=0)
    with pytest.raises(ValueError, match="time_step"):
        model.simulate(p, steps=1, time_step=-0.05)
    with pytest.raises(ValueError, match="progress"):
        model.simulate(p, steps=1, progress=3)
    with pytest.raises(ValueError, match=r"positions0: expected shape \(297, 3\)"):
        model.simulate(p, steps=1, positions0=np.zeros((10, 3)))


def test_backward_errors():
    m = sim.ClothModel(sim.cusick_specimen(1))
    with pytest.raises(ValueError, match="simulate"):
        m.backward(np.zeros((297, 3)))
    m.simulate(m.parameters(), steps=2)
    with pytest.raises(ValueError, match=r"dL_dpositions: expected shape \(297, 3\)"):
        m.backward(np.zeros((297, 2)))
    bad = np.zeros((297, 3))
    bad[5, 1] = np.nan
    with pytest.raises(ValueError, match="dL_dpositions: non-finite"):
        m.backward(bad)
    m.simulate(m.parameters(), steps=2, record=False)
    with pytest.raises(ValueError, match="record=True"):
        m.backward(np.zeros((297, 3)))



def test_backward_alternatives_score_a_turned_tilt_from_one_adjoint():
    # the diagnosis's second direction: the tilt's angle off, its azimuth turned by 90 degrees; the rollout is the
    # same, so one adjoint gives the gradient at both (against a rollout of its own at the turned azimuth)
    m = sim.ClothModel(sim.cusick_specimen(1), effects={"tilt": {}, "offset": {}, "camera": {}})
    p = m.parameters()
    q = m.parameters(effects={"tilt": {"azimuth_rad": np.pi / 2}})
    v0 = 0.05 * np.random.default_rng(3).standard_normal((m.num_vertices, 3))
    seed = np.random.default_rng(4).standard_normal((m.num_vertices, 3))
    x = m.simulate(p, steps=8, velocities0=v0)
    plain = m.backward(seed, flat=True)
    at_p, at_q = m.backward(seed, flat=True, alternatives=[q])
    assert np.array_equal(at_p, plain)
    assert np.array_equal(m.simulate(q, steps=8, velocities0=v0), x)
    direct = m.backward(seed, flat=True)
    assert np.abs(at_q - direct).max() <= 1e-10 * np.abs(direct).max()
    turned = m.split(at_q)["tilt.angle_rad"]
    assert abs(float(turned) - float(m.split(plain)["tilt.angle_rad"])) > 1e-3 * abs(float(turned))
    # split dicts unless flat; a changed density, a wrong size and a static drape are clear errors
    m.simulate(p, steps=8, velocities0=v0)
    blocks = m.backward(seed, alternatives=[q])
    assert isinstance(blocks, list) and len(blocks) == 2 and "tilt.angle_rad" in blocks[1]
    with pytest.raises(ValueError, match="density"):
        m.backward(seed, alternatives=[m.parameters(density=0.2, effects={"tilt": {"azimuth_rad": 1.0}})])
    with pytest.raises(ValueError, match="alternatives"):
        m.backward(seed, alternatives=[p[:-1]])
    m.simulate(p, mode="static")
    with pytest.raises(ValueError, match="dynamic"):
        m.backward(seed, alternatives=[q])


# ---------------------------------------------------------------- physics sanity
def test_energy_gradient_matches_differences(model):
    p = model.parameters()
    rng = np.random.default_rng(1)
    x = model.rest_positions + 0.003 * rng.standard_normal((model.num_vertices, 3))
    d = rng.standard_normal(x.shape)
    g = model.gradient(x, p)
    assert g.shape == x.shape
    eps = 1e-7
    fd = (model.energy(x + eps * d, p) - model.energy(x - eps * d, p)) / (2 * eps)
    assert fd == pytest.approx(float((g * d).sum()), rel=1e-5)


def test_dynamic_drape_hangs_down_and_stays_on_the_disk(model):
    p = model.parameters()
    x = model.simulate(p, steps=20)
    assert x.shape == (297, 3) and np.isfinite(x).all()
    held = model.handle_vertices
    assert np.abs(x[held] - model.rest_positions[held]).max() < 1e-3
    outer = np.linalg.norm(model.uv, axis=1) > 0.14
    assert x[outer, 2].mean() < -0.01
    assert model.last_result["mode"] == "dynamic" and model.last_result["steps"] == 20


def test_the_backward_split_is_reported_with_contact(circle1):
    # last_result["timing"] gains the backward's split (seconds) after backward; a contact rollout's adjoint
    # works iteration by iteration (its solves and the terms' adjoint passes)
    effects = {"disk_contact": {"clamp_radius_m": 0.02}, "self_contact": {"thickness_m": 1e-3}}
    m = sim.ClothModel(circle1, density=tables.COTTON_BLUE.density, effects=effects)
    x = m.simulate(m.parameters(material=tables.COTTON_BLUE), steps=10)
    assert m.last_result["timing"]["backward_terms"] == 0
    m.backward(np.ones_like(x))
    t = m.last_result["timing"]
    assert t["newton_iterations"] >= 10 and t["backward_solve"] > 0 and t["backward_terms"] > 0
    assert t["backward_refactorizations"] == 0  # 10 circle1 factors fit in the default budget


# ---------------------------------------------------------------- gradients vs central differences
DIRECTIONS = [("bend", (1, 2)), ("bend", (0, 0)), ("stretch", (0, 3)), ("density", None), ("handle_stiffness", None)]


def check_gradient(model, mode, relative_step, rtol, **options):
    p = model.parameters()
    weights = np.random.default_rng(0).standard_normal((model.num_vertices, 3))
    x = model.simulate(p, mode=mode, **options)
    grads = model.backward(weights)
    assert set(grads) == {"stretch", "bend", "density", "handle_stiffness"}
    assert grads["stretch"].shape == (6, 4) and grads["bend"].shape == (3, 5)
    flat = model.join(grads)
    start = x if mode == "static" else None  # warm start keeps the static solve on the same equilibrium
    for name, index in DIRECTIONS:
        d = unit_direction(model, name, index)
        eps = relative_step * float(p @ d)
        plus = model.simulate(p + eps * d, mode=mode, positions0=start, **options)
        minus = model.simulate(p - eps * d, mode=mode, positions0=start, **options)
        fd = float((weights * (plus - minus)).sum()) / (2 * eps)
        assert float(flat @ d) == pytest.approx(fd, rel=rtol, abs=1e-9), (name, index)


def test_dynamic_gradient_matches_central_differences(model):
    # 10 steps of 0.05 s; the rollout is strongly nonlinear in the tables, hence the small relative step.
    check_gradient(model, "dynamic", 1e-6, 1e-4, steps=10, time_step=0.05)


def test_static_gradient_matches_central_differences():
    m = sim.ClothModel(sim.cusick_specimen(1))
    check_gradient(m, "static", 1e-5, 1e-3, force_tolerance=1e-10)
    assert m.last_result["mode"] == "static" and m.last_result["residual"] < 1e-10


def test_module_level_simulate_and_backward(model):
    p = model.parameters()
    x = sim.simulate(model, p, steps=3)
    g = sim.backward(model, np.ones_like(x), flat=True)
    assert g.shape == p.shape
    with pytest.raises(ValueError, match="ClothModel"):
        sim.simulate("not a model", p)


# ---------------------------------------------------------------- progress and cancel
def test_progress_is_called_every_step(model):
    calls = []
    model.simulate(model.parameters(), steps=5, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(i, 5) for i in range(1, 6)]
    back = []
    model.backward(np.ones((297, 3)), progress=lambda done, total: back.append((done, total)))
    assert back[-1] == (5, 5) and len(back) == 5


def test_cancel_event_from_another_thread_stops_the_rollout(model):
    cancel, started = threading.Event(), threading.Event()
    calls = []

    def progress(done, total):
        calls.append(done)
        started.set()

    def canceller():
        started.wait(10)
        cancel.set()

    t = threading.Thread(target=canceller)
    t.start()
    with pytest.raises(sim.Cancelled):
        model.simulate(model.parameters(), steps=100, progress=progress, cancel_event=cancel)
    t.join()
    assert 0 < len(calls) < 100
    # The model stays usable, and backward refuses the cancelled rollout.
    with pytest.raises(ValueError, match="simulate"):
        model.backward(np.zeros((297, 3)))
    model.simulate(model.parameters(), steps=2)


def test_cancel_event_set_before_start(model):
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(sim.Cancelled):
        model.simulate(model.parameters(), steps=5, cancel_event=cancel)


def test_native_progress_cancel_while_gil_released(model):
    # No Python callback: the rollout runs without the GIL, so this thread can cancel it mid-way.
    solver = native.ImplicitEuler(model.native)
    progress = native.Progress()
    errors = []

    def run():
        try:
            solver.forward(model.parameters(), steps=100000, record=False, progress=progress)
        except native.Cancelled as e:
            errors.append(e)

    t = threading.Thread(target=run)
    t.start()
    time.sleep(0.2)
    assert t.is_alive()
    progress.cancel()
    t.join(10)
    assert not t.is_alive() and len(errors) == 1 and progress.cancelled


def test_static_solve_cancel():
    m = sim.ClothModel(sim.cusick_specimen(1))
    cancel = threading.Event()

    def progress(done, total):
        if done == 3:
            cancel.set()

    with pytest.raises(sim.Cancelled):
        m.simulate(m.parameters(), mode="static", progress=progress, cancel_event=cancel)


def test_progress_callback_exception_propagates(model):
    def progress(done, total):
        raise ZeroDivisionError("from the callback")

    with pytest.raises(ZeroDivisionError, match="from the callback"):
        model.simulate(model.parameters(), steps=3, progress=progress)


def test_factor_memory_budget_gives_the_same_gradient(model):
    p = model.parameters()
    weights = np.random.default_rng(2).standard_normal((model.num_vertices, 3))
    x_kept = model.simulate(p, steps=6)
    g_kept = model.backward(weights, flat=True)
    x_refactorised = model.simulate(p, steps=6, factor_memory_mb=0)
    g_refactorised = model.backward(weights, flat=True)
    np.testing.assert_array_equal(x_kept, x_refactorised)
    np.testing.assert_allclose(g_refactorised, g_kept, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="factor_memory_mb"):
        model.simulate(p, steps=1, factor_memory_mb=-1)
