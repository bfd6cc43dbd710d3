"""medial.topology_growth: a solid with the prescribed topology grown in q's order, against known answers and a
brute-force check of the simple-point test."""

import numpy as np
from scipy import ndimage

from qmdf.medial.thinning import cubical_euler
from qmdf.medial.topology_growth import _joining, grow_with_topology

CUBE = np.ones((3, 3, 3), bool)


def _pieces(mask):
    return ndimage.label(mask)[1]  # 6-connected, as the cubical complex's inside


def _voids(mask):
    outside = np.pad(~mask, 1, constant_values=True)
    return ndimage.label(outside, structure=CUBE)[1] - 1  # 26-connected, the border's piece not a void


def _torus(n=40, tube=0.25, centre=(0.0, 0.0)):
    x, y, z = (np.mgrid[:n, :n, :n] - n / 2 + 0.5) / (n / 2)
    d = np.sqrt((np.sqrt((x - centre[0]) ** 2 + (y - centre[1]) ** 2) - 0.55) ** 2 + z**2)
    return d < tube, d


def test_simple_points_keep_every_betti_number():
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(40):
        mask = ndimage.binary_opening(rng.random((7, 7, 7)) < 0.55)
        mask[[0, -1], :, :] = mask[:, [0, -1], :] = mask[:, :, [0, -1]] = False
        for i, j, k in np.argwhere(~mask[1:-1, 1:-1, 1:-1]) + 1:
            t6, t26, change = _joining(mask, i, j, k)
            after = mask.copy()
            after[i, j, k] = True
            assert cubical_euler(after) - cubical_euler(mask) == change
            if t6 == 1 and t26 == 1:
                assert change == 0
                assert _pieces(after) == _pieces(mask)
                assert _voids(after) == _voids(mask)
                checked += 1
            elif t6 == 0:
                assert _pieces(after) == _pieces(mask) + 1
    assert checked > 150


def test_a_torus_grows_into_a_ball_or_keeps_its_handle():
    allowed, d = _torus()
    assert cubical_euler(allowed) == 0
    ball, stats = grow_with_topology(allowed, d, target_chi=1)
    assert (cubical_euler(ball), _pieces(ball), _voids(ball)) == (1, 1, 0)
    assert 0 < stats["refused"] < 0.05 * allowed.sum()  # one thin cut across the tube
    assert not (ball & ~allowed).any()
    ring, stats = grow_with_topology(allowed, d, target_chi=0)
    assert (cubical_euler(ring), _pieces(ring), _voids(ring)) == (0, 1, 0)
    assert len(stats["closures_q"]) == 1 and stats["chi"] == 0


def test_the_low_valley_handle_closes_before_a_high_bridge():
    # a solid torus whose q is low along its core, plus a bar across its hole at high q: genus 2
    allowed, d = _torus(n=44)
    x, y, z = (np.mgrid[:44, :44, :44] - 21.5) / 22
    bar = (np.abs(y) < 0.1) & (np.abs(z) < 0.1) & (np.abs(x) < 0.7)
    allowed |= bar
    q = np.where(bar & (d >= 0.25), 0.6, d)
    assert cubical_euler(allowed) == -1
    grown, stats = grow_with_topology(allowed, q, target_chi=0)
    assert cubical_euler(grown) == 0 and _pieces(grown) == 1
    assert stats["closures_q"][0] < 0.25  # the torus's own loop, not the bar's
    # the loop around the torus's core is whole: every node of its core circle is in
    core = d < 0.06
    assert grown[core].all()
