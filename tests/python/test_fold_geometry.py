"""tools/fold_geometry.py: its hinge angles follow the bend term's convention, its fold profile counts and measures
folds (synthetic shapes; the real-mesh comparison itself needs the dataset and is a lab run, docs/lab/fold-depth.md)."""
import importlib.util
import math
import os

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def fg():
    spec = importlib.util.spec_from_file_location("fold_geometry", os.path.join(ROOT, "tools", "fold_geometry.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_dihedral_angle_of_a_folded_hinge(fg):
    """One hinge (a, b) on the x axis, c on +y, d on -y folded by angle t about the hinge: the angle's magnitude is
    t, folding the other way flips its sign (the statistics use magnitudes)."""
    for t in (0.3, -0.7, 1.2):
        x = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -math.cos(t), math.sin(t)]], dtype=float)
        a = fg.dihedral_angles(x, np.array([[0, 1, 2, 3]]))[0]
        assert abs(abs(a) - abs(t)) < 1e-12
        x2 = x.copy()
        x2[3] = [0.5, -math.cos(t), -math.sin(t)]
        assert abs(fg.dihedral_angles(x2, np.array([[0, 1, 2, 3]]))[0] + a) < 1e-12  # the other way: opposite sign


def test_profile_counts_eight_folds_and_their_amplitude(fg):
    phi = np.linspace(-math.pi, math.pi, 400, endpoint=False)
    r = 0.12 + 0.008 * np.cos(8 * phi + 0.3) + 0.001 * np.cos(3 * phi)
    prof = fg.smooth_profile(phi, r)
    hi, lo = fg.peaks(prof)
    assert len(hi) == 8 and len(lo) == 8
    amp = 0.5 * (prof[hi].mean() - prof[lo].mean())
    assert abs(amp - 0.008) < 3e-4


def test_ring_stats_of_a_flat_specimen_are_zero(fg):
    from drapelab import sim
    model = sim.ClothModel(sim.cusick_specimen(3))
    rest = np.asarray(model.rest_positions)
    s = fg.ring_stats(rest.copy(), rest, np.asarray(model.bending_edges))
    assert all(abs(ring["z"]) < 1e-12 and ring["amplitude"] < 1e-9 for ring in s["rings"])
    assert all(abs(ring["R"] - ring["r0"]) <= 0.005 for ring in s["rings"])  # the band's mean radius
    assert all(b["crest_p99"] < 1e-9 and b["hoop_p95"] < 1e-9 for b in s["bands"])
