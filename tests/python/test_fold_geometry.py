"""drapelab.fold_geometry (and tools/fold_geometry.py on it): hinge angles, fold profiles, ring statistics and the
3D comparison's words, on synthetic shapes (the real-mesh comparison needs the dataset: docs/lab/fold-depth.md)."""
import math

import numpy as np
import pytest

from drapelab import fold_geometry as fg
from drapelab import sim


@pytest.fixture(scope="module")
def specimen():
    model = sim.ClothModel(sim.cusick_specimen(3))
    return np.asarray(model.rest_positions), np.asarray(model.bending_edges)


def test_dihedral_angle_of_a_folded_hinge():
    """One hinge (a, b) on the x axis, c on +y, d on -y folded by angle t about the hinge: the angle's magnitude is
    t, folding the other way flips its sign (the statistics use magnitudes)."""
    for t in (0.3, -0.7, 1.2):
        x = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -math.cos(t), math.sin(t)]], dtype=float)
        a = fg.dihedral_angles(x, np.array([[0, 1, 2, 3]]))[0]
        assert abs(abs(a) - abs(t)) < 1e-12
        x2 = x.copy()
        x2[3] = [0.5, -math.cos(t), -math.sin(t)]
        assert abs(fg.dihedral_angles(x2, np.array([[0, 1, 2, 3]]))[0] + a) < 1e-12


def test_profile_counts_eight_folds_and_their_amplitude():
    phi = np.linspace(-math.pi, math.pi, 400, endpoint=False)
    r = 0.12 + 0.008 * np.cos(8 * phi + 0.3) + 0.001 * np.cos(3 * phi)
    prof = fg.smooth_profile(phi, r)
    hi, lo = fg.peaks(prof)
    assert len(hi) == 8 and len(lo) == 8
    assert abs(0.5 * (prof[hi].mean() - prof[lo].mean()) - 0.008) < 3e-4


def test_ring_stats_of_a_flat_specimen_are_zero(specimen):
    rest, edges = specimen
    s = fg.ring_stats(rest.copy(), rest, edges)
    assert all(abs(ring["z"]) < 1e-12 and ring["amplitude"] < 1e-9 for ring in s["rings"])
    assert all(abs(ring["R"] - ring["r0"]) <= fg.RING_HALF_WIDTH for ring in s["rings"])
    assert all(b["crest_p99"] < 1e-9 and b["hoop_p95"] < 1e-9 for b in s["bands"])


def _skirt(rest, folds, amplitude, sharpness, phase=0.0):
    """A synthetic drape: the annulus hangs down a cone, its radius modulated by `folds` folds of `amplitude` at
    the hem (growing linearly from the edge); sharpness > 1 narrows the crests (|cos|^(1/sharpness) profile)."""
    r0 = np.hypot(rest[:, 0], rest[:, 1])
    phi = np.arctan2(rest[:, 1], rest[:, 0])
    s = np.clip((r0 - 0.09) / 0.06, 0.0, 1.0)
    wave = np.cos(folds * phi + phase)
    wave = np.sign(wave) * np.abs(wave) ** (1.0 / sharpness)
    R = np.where(r0 < 0.09, r0, 0.09 + 0.6 * (r0 - 0.09) + amplitude * s * wave)
    z = np.where(r0 < 0.09, 0.0, -0.75 * (r0 - 0.09))
    return np.stack([R * np.cos(phi), R * np.sin(phi), z], 1)


def test_compare_is_silent_on_its_own_drapes_and_names_sharper_crests(specimen):
    rest, edges = specimen
    drapes = [_skirt(rest, 8, 0.008, 1.0, phase=p) for p in np.linspace(0, 0.7, 8)]
    same = fg.compare(drapes[:4], drapes, rest, edges, noise_m=0.0)
    assert same["words"] == []
    assert len(same["rings"]) == len(fg.RINGS) and len(same["bands"]) == len(fg.BANDS)
    hem = same["rings"][-1]["amplitude"]
    assert hem["interval90"][0] <= hem["measured"] <= hem["interval90"][1]
    assert abs(hem["model"] - 0.008) < 0.001  # the hem ring (r0 14.5 cm) carries about the full amplitude
    sharp = [_skirt(rest, 8, 0.008, 4.0, phase=p) for p in (0.1, 0.3)]
    g = fg.compare(sharp, drapes, rest, edges, noise_m=0.0)
    crest = [b["crest_p99"] for b in g["bands"][2:]]
    assert all(q["measured"] > q["interval90"][1] for q in crest)
    assert any("crests are sharper" in w and "high_curvature_bending with log_factor < 0" in w for w in g["words"])
    # cloth moved in by 3 mm everywhere beyond the edge: named with its size
    inward = [x * np.where(np.hypot(x[:, 0], x[:, 1]) > 0.09, 1 - 0.003 / np.maximum(np.hypot(x[:, 0], x[:, 1]), 1e-9),
                           1.0)[:, None] * [1, 1, 0] + x * [0, 0, 1] for x in drapes[:2]]
    g = fg.compare(inward, drapes, rest, edges, noise_m=0.0)
    assert any("further in than the model's" in w and "3.0 mm" in w for w in g["words"])


def test_compare_needs_meshes(specimen):
    rest, edges = specimen
    with pytest.raises(ValueError, match="at least one measured mesh"):
        fg.compare([], [rest], rest, edges)
