"""sim.contact_report (the native contact diagnostics, bound): intersecting triangle pairs and the minimum
distance of a state, against the garment module's independent numpy check and hand-made geometry; obstacles;
bad input named."""
import numpy as np
import pytest

from drapelab import sim
from drapelab.garment.mesh import self_intersections


def sheet(n=6, size=0.1, z=0.0, shift=(0.0, 0.0)):
    u = np.linspace(0, size, n)
    xx, yy = np.meshgrid(u, u, indexing="ij")
    p = np.stack([xx.ravel() + shift[0], yy.ravel() + shift[1], np.full(n * n, z)], axis=1)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f += [(a, b, c), (a, c, d)]
    return p, np.array(f, dtype=np.int32)


def two_sheets(gap):
    p0, f0 = sheet()
    p1, f1 = sheet(z=gap, shift=(0.01, 0.013))
    return np.vstack([p0, p1]), np.vstack([f0, f1 + len(p0)])


def test_parallel_sheets_distance_and_no_intersection():
    p, f = two_sheets(0.002)
    r = sim.contact_report(f, p, search_radius=0.01)
    assert r["intersecting_pairs"] == 0 and r["first_pairs"] == []
    assert r["min_distance_m"] == pytest.approx(0.002, rel=1e-9)


def test_a_crossing_sheet_counts_the_same_pairs_as_the_numpy_check():
    p, f = two_sheets(0.0)
    p = p.copy()
    half = len(p) // 2
    p[half:, 2] = (p[half:, 0] - 0.055) * 0.5  # the second sheet tilted through the first
    r = sim.contact_report(f, p, max_listed=1000)
    reference = {tuple(sorted(q)) for q in self_intersections(p, f).tolist()}
    assert r["intersecting_pairs"] == len(reference) > 0
    assert {tuple(sorted(q)) for q in r["first_pairs"]} == reference


def test_an_obstacle_counts_cloth_obstacle_pairs_only():
    cloth, cf = sheet(z=0.001)
    body, bf = sheet(n=4, size=0.12, z=0.0, shift=(-0.01, -0.01))
    r = sim.contact_report(cf, cloth, obstacle=(body, bf), search_radius=0.01)
    assert r["intersecting_pairs"] == 0 and r["min_distance_m"] == pytest.approx(0.001, rel=1e-9)
    sunk = cloth.copy()
    sunk[:, 2] = (sunk[:, 0] - 0.05) * 0.2  # through the body plane
    r = sim.contact_report(cf, sunk, obstacle=(body, bf), max_listed=10000)
    assert r["intersecting_pairs"] > 0
    assert all(a < len(cf) <= b for a, b in (sorted(q) for q in r["first_pairs"]))


@pytest.mark.parametrize("kwargs, message", [
    (dict(faces=np.zeros((0, 3))), "no faces"),
    (dict(positions=np.zeros(7)), "3V"),
    (dict(faces=np.array([[0, 1, 99]])), "outside"),
    (dict(positions=np.full((36, 3), np.nan)), "non-finite"),
    (dict(search_radius=-1.0), "search_radius"),
])
def test_bad_input_is_named(kwargs, message):
    p, f = sheet()
    args = dict(faces=f, positions=p)
    args.update(kwargs)
    with pytest.raises(sim.InputError, match=message):
        sim.contact_report(**args)
