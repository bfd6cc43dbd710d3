"""The single sheet: the collapse keeps the solid's topology, the placement puts it on the axis, the SQEM
simplification keeps topology and envelope. Known answers: a disc (chi 1, a rim), a circle (chi 0, no faces),
three half-planes meeting along a line (a seam), an annulus, a triangle of lone edges."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from qmdf.geometry.metrics import euler_medial_mesh, seam_edges, single_face_edges
from qmdf.medial.sheet import single_sheet
from qmdf.medial.simplify import simplify_medial_mesh, slab_planes
from qmdf.medial.thinning import collapse_to_sheet

N = 48
AX = np.linspace(-0.55, 0.55, N)
H = AX[1] - AX[0]
X, Y, Z = np.meshgrid(AX, AX, AX, indexing="ij")
R = np.hypot(X, Y)
LO, SPACING = np.full(3, AX[0]), np.full(3, H)


def _disc_membrane(radius: float):
    """A 96-gon fan in z = 0: where a contracted disc's membrane lies."""
    t = np.linspace(0, 2 * np.pi, 97)[:-1]
    v = np.vstack([[0, 0, 0], np.column_stack([radius * np.cos(t), radius * np.sin(t), 0 * t])])
    f = np.array([[0, 1 + k, 1 + (k + 1) % 96] for k in range(96)])
    return v, f


def test_collapse_keeps_the_topology_of_discs_tubes_and_seams():
    disc = np.abs(Z) + np.maximum(R - 0.4, 0)  # q of a disc of radius 0.4 in z = 0
    for eps in (0.03, 0.06):  # two and four node layers thick
        cx = collapse_to_sheet(disc < eps, disc, 0.5 * eps)
        assert cx.euler == 1 and cx.cubes == 0 and len(cx.squares) > 0
    tube = np.hypot(R - 0.3, Z)  # q of a torus's circle
    assert collapse_to_sheet(tube < 0.05, tube, 0.025).euler == 0
    planes = (
        np.min(
            [
                np.abs(-np.sin(a) * X + np.cos(a) * Y) + np.maximum(-(np.cos(a) * X + np.sin(a) * Y), 0)
                for a in (0, 2.1, 4.2)
            ],
            axis=0,
        )
        + np.maximum(np.abs(Z) - 0.3, 0)
        + np.maximum(R - 0.4, 0)
    )
    assert collapse_to_sheet(planes < 0.05, planes, 0.025).euler == 1


def test_disc_sheet_is_one_layer_on_the_axis_reaching_the_rim():
    q = np.abs(Z) + np.maximum(R - 0.4, 0)
    v, f = _disc_membrane(0.4)
    sheet = single_sheet(q < 0.03, q, LO, SPACING, v, f, eps=0.03)
    assert sheet.euler == 1 and len(sheet.edges) == 0
    assert np.abs(sheet.vertices[:, 2]).max() < 1e-9  # placed on the membrane
    # one layer: the placed faces cover the disc once (area of the disc, not twice it)
    tri = sheet.vertices[sheet.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    true_area = np.pi * 0.4**2 * (96 / (2 * np.pi)) * np.sin(2 * np.pi / 96)  # the 96-gon
    assert abs(area - true_area) < 0.05 * true_area
    rim = np.unique(single_face_edges(sheet.faces))
    assert np.hypot(*sheet.vertices[rim, :2].T).min() > 0.4 - 3 * H  # its rim is the disc's rim


def test_circle_sheet_is_a_closed_polyline():
    q = np.hypot(R - 0.3, Z)
    tube = trimesh.creation.torus(major_radius=0.3, minor_radius=1e-4, major_sections=128, minor_sections=6)
    sheet = single_sheet(q < 0.05, q, LO, SPACING, np.asarray(tube.vertices), np.asarray(tube.faces), eps=0.05)
    assert len(sheet.faces) == 0 and sheet.euler == 0
    assert np.bincount(sheet.edges.ravel()).tolist() == [2] * len(sheet.vertices)
    assert np.abs(np.hypot(np.hypot(*sheet.vertices[:, :2].T) - 0.3, sheet.vertices[:, 2])).max() < 1e-3  # h = 0.023


def test_slab_planes_touch_all_three_spheres():
    rng = np.random.default_rng(0)
    c = rng.uniform(-1, 1, (200, 3, 3))
    r = rng.uniform(0.05, 0.2, (200, 3))
    n, d, ok = slab_planes(c, r)
    assert ok.mean() > 0.9
    assert np.allclose(np.linalg.norm(n[ok], axis=2), 1)
    for side in (0, 1):
        assert np.allclose((n[ok, side, None, :] * c[ok]).sum(2) + r[ok], d[ok, side][:, None], atol=1e-9)
    # three equal spheres in z = 0: the planes z = +-r
    n, d, ok = slab_planes(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]]), np.array([[0.3, 0.3, 0.3]]))
    assert ok[0] and np.allclose(sorted(n[0, :, 2]), [-1, 1]) and np.allclose(d[0], 0.3)


def _grid_sheet(nx: int, ny: int, z=lambda x, y: 0 * x):
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), z(x, y).ravel()])
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def test_simplify_a_flat_sheet_keeps_its_rim_and_envelope():
    v, f = _grid_sheet(30, 30)
    res = simplify_medial_mesh(v, np.full(len(v), 0.1), np.zeros((0, 2)), f, 60)
    assert len(res.vertices) == 60 and euler_medial_mesh(60, res.edges, res.faces) == 1
    assert np.abs(res.vertices[:, 2]).max() < 1e-9 and np.allclose(res.radii, 0.1, atol=1e-9)
    assert np.allclose(res.vertices.min(0)[:2], 0, atol=1e-4) and np.allclose(res.vertices.max(0)[:2], 1, atol=1e-4)


def test_simplify_keeps_seams_holes_and_cycles():
    # three unit squares meeting along the z axis (a Y-junction), radius growing away from the seam
    sheets = []
    for a in (0.0, 2.1, 4.2):
        v, f = _grid_sheet(12, 12)
        d = np.array([np.cos(a), np.sin(a), 0])
        sheets.append((v[:, :1] * d + v[:, 1:2] * [0, 0, 1], f))
    v = np.vstack([s[0] for s in sheets])
    f = np.vstack([s[1] + 144 * k for k, s in enumerate(sheets)])
    _, index, inverse = np.unique(np.round(v, 9), axis=0, return_index=True, return_inverse=True)
    v, f = v[index], inverse.ravel()[f]
    r = 0.05 + 0.1 * np.linalg.norm(v[:, :2], axis=1)
    res = simplify_medial_mesh(v, r, np.zeros((0, 2)), f, 30)
    assert euler_medial_mesh(len(res.vertices), res.edges, res.faces) == 1
    assert len(seam_edges(res.faces)) >= 1 and len(res.edges) == 0
    # an annulus stays an annulus
    t = np.linspace(0, 2 * np.pi, 41)[:-1]
    ring = np.vstack([np.column_stack([rad * np.cos(t), rad * np.sin(t), 0 * t]) for rad in (0.3, 0.35, 0.4)])
    faces = []
    for k in range(2):
        for j in range(40):
            a, b, c, d = 40 * k + j, 40 * k + (j + 1) % 40, 40 * (k + 1) + (j + 1) % 40, 40 * (k + 1) + j
            faces += [[a, b, c], [a, c, d]]
    res = simplify_medial_mesh(ring, np.full(len(ring), 0.05), np.zeros((0, 2)), np.array(faces), 30)
    assert euler_medial_mesh(len(res.vertices), res.edges, res.faces) == 0 and len(res.faces) > 0
    # pushed to 3 vertices the annulus may thin to its core circle (same homotopy type), never to a disc
    res = simplify_medial_mesh(ring, np.full(len(ring), 0.05), np.zeros((0, 2)), np.array(faces), 3)
    assert euler_medial_mesh(len(res.vertices), res.edges, res.faces) == 0 and len(res.vertices) >= 3
    # a triangle of lone edges: no collapse may shrink the cycle to a double edge
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    res = simplify_medial_mesh(tri, np.full(3, 0.1), np.array([[0, 1], [1, 2], [2, 0]]), np.zeros((0, 3)), 1)
    assert len(res.vertices) == 3 and len(res.edges) == 3


@pytest.mark.parametrize("target", [40, 200])
def test_simplify_a_curved_sheet_keeps_its_envelope_close(target):
    from qmdf.geometry.envelope import EnvelopeUnion
    from qmdf.geometry.ma_format import MedialMesh

    v, f = _grid_sheet(25, 25, lambda x, y: 0.2 * np.sin(2 * x) * np.cos(y))
    r = 0.05 + 0.05 * v[:, 0]
    res = simplify_medial_mesh(v, r, np.zeros((0, 2)), f, target)
    assert euler_medial_mesh(len(res.vertices), res.edges, res.faces) == 1
    # every simplified sphere lies on the original envelope's surface to within a few per cent of its radius
    union = EnvelopeUnion.from_mat(MedialMesh(v, r, np.zeros((0, 2)), f).with_face_edges())
    tops = res.vertices + res.radii[:, None] * np.array([0, 0, 1.0])
    assert np.abs(union.sdf(tops)).max() < 0.1 * r.max()


def test_simplify_under_a_deviation_goes_as_far_as_the_shape_allows():
    """With max_deviation, the vertex count follows the shape: a flat sheet of constant radius (its envelope two
    planes, moved by no collapse) goes down to its corners' few vertices; a curved one stops where a collapse
    would move the envelope by more than the deviation, the more vertices the smaller it is, every original
    point of the original envelope within the deviation of the simplified one (root mean square), within three
    of them at most."""
    from qmdf.geometry.envelope import EnvelopeUnion, sample_union_surface
    from qmdf.geometry.ma_format import MedialMesh

    v, f = _grid_sheet(30, 30)
    flat = simplify_medial_mesh(v, np.full(len(v), 0.1), np.zeros((0, 2)), f, 1, max_deviation=1e-4)
    assert len(flat.vertices) <= 12 and euler_medial_mesh(len(flat.vertices), flat.edges, flat.faces) == 1
    v, f = _grid_sheet(30, 30, lambda x, y: 0.2 * np.sin(2 * x) * np.cos(y))
    r = 0.05 + 0.05 * v[:, 0]
    original = EnvelopeUnion.from_mat(MedialMesh(v, r, np.zeros((0, 2)), f).with_face_edges())
    on_original = sample_union_surface(original, 5000, np.random.default_rng(0))
    counts = []
    for deviation in (3e-3, 1e-3, 1e-4):
        res = simplify_medial_mesh(v, r, np.zeros((0, 2)), f, 1, max_deviation=deviation)
        counts.append(len(res.vertices))
        assert res.stats["over_deviation"] > 0
        union = EnvelopeUnion.from_mat(MedialMesh(res.vertices, res.radii, res.edges, res.faces).with_face_edges())
        moved = np.abs(union.sdf(on_original))
        assert np.sqrt(np.mean(moved**2)) < deviation and moved.max() < 3 * deviation
    assert counts[0] < counts[1] < counts[2] < len(v)


def test_the_collapse_takes_every_kth_node_within_the_node_budget():
    from qmdf.medial.sheet import node_stride

    inside = np.zeros((40, 40, 40), bool)
    inside[:20, :20, :20] = True  # 8,000 nodes inside; every 2nd: 1,000; every 3rd: 343
    assert node_stride(inside, 8000) == 1
    assert node_stride(inside, 7999) == 2 and node_stride(inside, 1000) == 2
    assert node_stride(inside, 999) == 3


def test_a_collapse_after_softening_starts_only_from_the_softened_cells():
    """After a run, only a pair whose coface was softened can have become collapsible: seeding the heap with
    the softened cells' faces leaves what a scan of every cell leaves."""
    from qmdf.medial.thinning import Collapse

    q = np.abs(Z) + np.maximum(R - 0.4, 0)
    results = []
    for full_scan in (False, True):
        col = Collapse(q < 0.06, q, 0.03)
        cx = col.run()
        rng = np.random.default_rng(0)
        col.soften(cx, rng.random(len(cx.squares)) < 0.3, rng.random(len(cx.edges)) < 0.3)
        if full_scan:
            col.softened = None
        results.append(col.run())
    seeded, scanned = results
    assert len(seeded.squares) < len(cx.squares)  # the softening released something
    for name in ("nodes", "edges", "squares"):
        assert np.array_equal(getattr(seeded, name), getattr(scanned, name))


def test_covered_squares_against_the_plain_greedy_loop():
    from scipy.spatial import cKDTree

    from qmdf.medial.sheet import _covered_squares

    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (400, 3))
    squares = rng.integers(0, 400, (300, 4))
    proper = rng.random(300) < 0.8
    node_q = rng.random(400)
    got = _covered_squares(x, squares, proper, node_q, 0.08)
    # the rule spelled out: by increasing q, a square is covered when a square taken before lies within radius
    idx = np.flatnonzero(proper)
    centre = x[squares[idx]].mean(1)
    near = cKDTree(centre).query_ball_point(centre, 0.08)
    taken, want = np.zeros(len(idx), bool), np.zeros(300, bool)
    for k in np.argsort(node_q[squares[idx]].mean(1), kind="stable"):
        if any(taken[j] for j in near[k] if j != k):
            want[idx[k]] = True
        else:
            taken[k] = True
    assert 0 < want.sum() < proper.sum() and np.array_equal(got, want)


def test_redundant_edges_against_the_plain_loops():
    from scipy.spatial import cKDTree

    from qmdf.geometry.metrics import edges_off_polygons
    from qmdf.medial.sheet import _redundant_edges

    rng = np.random.default_rng(5)
    x = rng.uniform(0, 1, (300, 3))
    edges = np.unique(np.sort(rng.integers(0, 300, (500, 2)), axis=1), axis=0)
    edges = edges[edges[:, 0] != edges[:, 1]]
    squares = rng.integers(0, 300, (40, 4))
    node_q = rng.random(300)
    short, reach = 0.05, 0.09
    got = _redundant_edges(x, edges, squares, node_q, short, reach)
    # each rule spelled out, edge by edge
    lone = edges_off_polygons(edges, squares)
    mid, eq = x[edges].mean(1), node_q[edges].mean(1)
    want = lone & (np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1) < short)
    want |= lone & (cKDTree(x[squares].mean(1)).query(mid)[0] < reach)
    for i in np.flatnonzero(lone & ~want):
        near = cKDTree(mid).query_ball_point(mid[i], 0.5 * reach)
        want[i] = any(j != i and (eq[j] < eq[i] or (eq[j] == eq[i] and j < i)) for j in near)
    degree = np.bincount(edges.ravel(), minlength=len(x))
    for i in np.flatnonzero(lone & ~want):
        for v, w in ((edges[i, 0], edges[i, 1]), (edges[i, 1], edges[i, 0])):
            near = cKDTree(x).query_ball_point(x[v], reach)
            want[i] |= bool(degree[v] == 1 and any(u != v and u != w for u in near))
    assert 0 < want.sum() < lone.sum() and np.array_equal(got, want)


def test_valley_squares_and_edges_are_where_q_is_lowest_across_them():
    """A slab five nodes thick with q lowest on one node layer: the cubes collapse onto that layer, leaving walls
    across the slab (squares facing x or y) that only the keep level held; a wall is a valley only where q is
    lowest across it, and an edge only on the line where q is lowest across both other axes."""
    from qmdf.medial.sheet import _valley_edges, _valley_squares

    k = 24  # the node layer of the valley
    slab = (np.abs(np.arange(N) - k) <= 2)[None, None, :] & (R < 0.3)
    q = np.abs(Z - AX[k]) + 1e-3 * np.hypot(X - AX[20], Y - AX[20])  # one valley layer; one lowest line in it
    cx = collapse_to_sheet(slab, q, 1.0)  # nothing but the cubes collapses
    valley = _valley_squares(cx, q)
    facing_z = cx.square_cells[:, 2] % 2 == 0
    assert facing_z.sum() > 100 and np.all(cx.nodes[cx.squares[facing_z], 2] == k) and valley[facing_z].all()
    facing_x = cx.square_cells[:, 0] % 2 == 0
    at_low_x = np.all(cx.nodes[cx.squares, 0] == 20, axis=1)
    assert facing_x.sum() > 100 and (facing_x & at_low_x).sum() > 0
    assert np.array_equal(valley[facing_x], at_low_x[facing_x])
    edges = _valley_edges(cx, q)
    along_x = cx.edge_cells[:, 0] % 2 == 1
    ends = cx.nodes[cx.edges[edges & along_x]]  # (M, 2, 3)
    assert len(ends) > 5 and np.all(ends[..., 1] == 20) and np.all(ends[..., 2] == k)
    assert (~edges[along_x]).sum() > 10 * len(ends)


@pytest.mark.parametrize("hollow", [False, True])
def test_a_void_of_the_covering_is_filled_unless_the_shape_has_it(hollow):
    """A disc's covering six node layers thick with an island of nodes left out in its middle (q above eps
    there, as around a junction of sheets): kept, the collapse would close a pocket around it (chi 2). The void
    is filled where the sdf reads inside all over it; where the shape is hollow there (sdf > 0), it stays."""
    from qmdf.medial.sheet import fill_voids, sheet_counts

    q = np.abs(Z) + np.maximum(R - 0.4, 0)
    island = np.sqrt(X**2 + Y**2 + Z**2) < H  # the 2 x 2 x 2 nodes around the grid's middle
    inside = (q < 0.06) & ~island
    assert island.sum() == 8 and not inside[island].any()
    sdf_at = lambda p: np.where(np.linalg.norm(p, axis=1) < 2 * H, 1.0 if hollow else -0.1, -0.1)  # noqa: E731
    filled, stats = fill_voids(inside, lambda nodes: sdf_at(LO + nodes * SPACING) > 0)
    assert stats["voids"] == 1 and stats["filled"] == (0 if hollow else 1)
    assert np.array_equal(filled, inside | (island & (not hollow)))
    v, f = _disc_membrane(0.4)
    mat, stats = _thin(
        {"inside": inside, "lo": LO, "spacing": SPACING, "eps": 0.06},
        lambda p: {"q": np.abs(p[:, 2]) + np.maximum(np.hypot(p[:, 0], p[:, 1]) - 0.4, 0), "sdf": sdf_at(p)},
        v,
        f,
        lambda x: np.full(len(x), 0.05),
    )
    assert stats["voids"]["filled"] == (0 if hollow else 1)
    assert sheet_counts(mat)["chi"] == (2 if hollow else 1)


def test_cubical_euler_against_known_solids_and_the_complex_itself():
    from qmdf.medial.thinning import _fill_cells, _read_complex, cubical_euler

    ball = np.zeros((8, 8, 8), bool)
    ball[1:7, 1:7, 1:7] = True
    shell = ball.copy()
    shell[3:5, 3:5, 3:5] = False  # an enclosed void: b2 = 1
    ring = ball.copy()
    ring[3:5, 3:5, :] = False  # a hole through: b1 = 1
    assert [cubical_euler(m) for m in (ball, shell, ring)] == [1, 2, 0]
    rng = np.random.default_rng(0)
    for _ in range(4):  # brute force: every cell of the complex built and counted
        m = rng.random((7, 8, 6)) < 0.6
        cells = np.zeros(tuple(2 * np.array(m.shape) - 1), np.uint8)
        _fill_cells(m, cells)
        assert cubical_euler(m) == _read_complex(cells, np.zeros(3, np.int64)).euler


def _thin(grid, evaluate, v, f, radii_of, settings=None, target_chi=None):
    """``thinned_sheet`` of a covering's grid, its solid prepared first (``prepared_solid``)."""
    from qmdf.medial.sheet import CollapseSettings, prepared_solid, thinned_sheet

    settings = settings or CollapseSettings()
    return thinned_sheet(prepared_solid(grid, evaluate, settings, target_chi), v, f, radii_of, settings)


def _ring_with_bar():
    """q of a circle (radius 0.3 in z = 0) and of a bar across its hole whose valley reads 0.04: the nodes below
    a level under 0.04 are a ring (chi 0), above it a theta (chi -1)."""
    ring = np.hypot(R - 0.3, Z)
    bar = np.hypot(Y, Z) + np.maximum(np.abs(X) - 0.3, 0) + 0.04
    return np.minimum(ring, bar)


def _ring_with_bar_sheet_args(q):
    """``_thin``'s first five arguments for ``_ring_with_bar``'s covering at 0.07, placed on a thin
    ring's surface."""
    tube = trimesh.creation.torus(major_radius=0.3, minor_radius=1e-4, major_sections=128, minor_sections=6)
    grid = {"inside": q < 0.07, "lo": LO, "spacing": SPACING, "eps": 0.07}

    def evaluate(p):
        x, y, z = p.T
        ring = np.hypot(np.hypot(x, y) - 0.3, z)
        bar = np.hypot(y, z) + np.maximum(np.abs(x) - 0.3, 0) + 0.04
        return {"q": np.minimum(ring, bar), "sdf": np.full(len(p), -0.1)}

    return grid, evaluate, np.asarray(tube.vertices), np.asarray(tube.faces), lambda x: np.full(len(x), 0.05)


def test_the_level_with_the_shapes_topology_is_the_highest_one_below_a_bridge():
    from qmdf.medial.sheet import level_with_topology

    q = _ring_with_bar()
    level, mask, scan = level_with_topology(q, 0.07, 0, lambda m: m)
    assert scan[0] == (0.07, -1) and scan[-1][1] == 0
    assert 0.04 - 0.005 < level < 0.04 + H and np.array_equal(mask, q < level)  # the first level past the bar's
    assert all(c == -1 for _, c in scan[:-1])
    level, mask, scan = level_with_topology(q, 0.07, 5, lambda m: m)  # no level has it
    assert level is None and mask is None and len(scan) == 15


def test_the_sheet_takes_the_level_of_the_shapes_topology():
    from qmdf.medial.sheet import sheet_counts

    q = _ring_with_bar()
    args = _ring_with_bar_sheet_args(q)
    plain_mat, plain = _thin(*args)
    assert sheet_counts(plain_mat)["chi"] == -1 and plain["level"] is None
    matched_mat, matched = _thin(*args, target_chi=0)
    assert sheet_counts(matched_mat)["chi"] == 0 and matched["level"]["eps"] < 0.04 + H
    assert len(matched_mat.faces) == 0  # the ring's polyline, the bar gone


def test_the_solid_euler_characteristic_of_a_closed_mesh_and_none_of_an_open_one():
    from qmdf.geometry.metrics import solid_euler

    assert solid_euler(trimesh.creation.icosphere(2).faces) == 1
    assert solid_euler(trimesh.creation.torus(0.3, 0.1).faces) == 0
    two = trimesh.util.concatenate([trimesh.creation.icosphere(2), trimesh.creation.torus(0.3, 0.1)])
    assert solid_euler(two.faces) == 1  # a ball and a solid torus
    cut = trimesh.creation.icosphere(2)
    assert solid_euler(cut.faces[4:]) is None


def test_where_no_level_has_the_shapes_topology_the_solid_is_grown_with_it():
    from qmdf.medial.sheet import CollapseSettings, sheet_counts

    q = _ring_with_bar()  # every level from 0.07 down to 0.021 has chi -1 or 0, none the ball's 1
    args = _ring_with_bar_sheet_args(q)
    kept_mat, kept = _thin(*args, CollapseSettings(grow_topology=False), target_chi=1)
    assert kept["level"]["eps"] is None and sheet_counts(kept_mat)["chi"] == -1  # the covering's nodes as they are
    mat, grown = _thin(*args, target_chi=1)
    assert sheet_counts(mat)["chi"] == 1 and grown["level"]["grown"]["chi"] == 1
    assert grown["level"]["grown"]["refused"] > 0
    assert len(mat.faces) == 0  # a tree of polylines: both loops cut
    # the tree still follows the ring: most of the circle's length is kept
    on_ring = np.abs(np.hypot(mat.vertices[:, 0], mat.vertices[:, 1]) - 0.3) < 2 * H
    assert on_ring.sum() > 0.8 * (2 * np.pi * 0.3 / H)


def test_pick_sheet_prefers_compact_then_the_shapes_chi_then_the_better_fit():
    """Of several sheets of one shape, a compact one beats a better-fitting one that is not; then the input's
    chi; then the fit (here a fake fit: the largest radius)."""
    from qmdf.medial.refinement import MAT
    from qmdf.medial.sheet import pick_sheet

    def sheet(radius, compact, chi):
        v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
        mat = MAT(v, np.full(3, radius), np.zeros((0, 2), int), np.array([[0, 1, 2]]))
        return mat, {"compact": compact, "after": {"chi": chi}, "cd": None}

    def fit(mat):
        return float(mat.radii.max())

    loose, wrong_chi, right, worse = sheet(0.1, False, 1), sheet(0.2, True, 0), sheet(0.3, True, 1), sheet(0.4, True, 1)
    kept, rows = pick_sheet([loose, wrong_chi, worse, right], fit, target_chi=1)
    assert kept == 3 and [r["cd"] for r in rows] == [0.1, 0.2, 0.4, 0.3]
    assert pick_sheet([loose, wrong_chi, worse, right], fit)[0] == 1  # no known chi: the best compact fit
    assert pick_sheet([loose], fit, target_chi=0)[0] == 0  # nothing better: the only one
    # a sheet whose CD the refinement measured already is not measured again
    measured = (worse[0], {**worse[1], "cd": 0.05})
    kept, rows = pick_sheet([right, measured], fit, target_chi=1)
    assert kept == 1 and rows[1]["cd"] == 0.05


def test_a_sphere_is_one_ball_and_an_ellipsoid_is_not():
    import logging

    import trimesh

    from qmdf.medial.coverage import surface_balls
    from qmdf.medial.refinement import SheetData
    from qmdf.medial.sheet import one_ball
    from qmdf.geometry.sampling import sample_surface

    from qmdf.geometry.even_mesh_distance import EvenlyMeshedSurface

    def data_of(mesh):
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        s = sample_surface(v, f, 2000, np.random.default_rng(0))
        even = EvenlyMeshedSurface((v, f))  # a sphere's centre: the AABB tree's worst case
        return SheetData(
            even,
            None,
            None,
            lambda: surface_balls(s.points, s.normals, even),
            target_vertices=3000,
            tolerance=1e-3,
            tip_reach=0.0,
            compact_slack=1.0,
            log=logging.getLogger("t"),
        )

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.4)
    sphere.apply_translation([0.05, -0.02, 0.01])
    mat, cd = one_ball(data_of(sphere))
    assert len(mat.vertices) == 1 and not len(mat.edges) and not len(mat.faces)
    assert np.allclose(mat.vertices[0], [0.05, -0.02, 0.01], atol=1e-3) and abs(mat.radii[0] - 0.4) < 1e-3
    assert cd <= 1e-3
    ellipsoid = trimesh.creation.icosphere(subdivisions=4, radius=0.4)
    ellipsoid.apply_scale([1.0, 0.97, 0.94])  # 2.4e-2 from round at most: a disc's MAT, not a point
    assert one_ball(data_of(ellipsoid)) is None


def test_the_two_off_axis_sheets_are_built_side_by_side_and_logged_one_after_the_other(caplog):
    import logging
    import threading
    import time

    from qmdf.medial.refinement import SheetData
    from qmdf.medial.sheet import _side_by_side

    data = SheetData(
        None,
        np.zeros((1, 3)),
        lambda q: q[:, 0] < 0,
        lambda: None,
        target_vertices=10,
        tolerance=1e-3,
        tip_reach=0.0,
        compact_slack=1.5,
        log=logging.getLogger("qmdf.test_sheet"),
    )
    running = []

    def build(rule, data):
        running.append(threading.get_ident())
        data.log.info("building %s", rule)
        time.sleep(0.2 if rule == 0.75 else 0.0)  # the second finishes first, its lines still come second
        data.log.info("built %s", rule)
        return rule, {"threads_seen": len(set(running))}

    with caplog.at_level(logging.INFO, logger="qmdf.test_sheet"):
        out = _side_by_side(build, data, 0.75, 3.0)
    assert [rule for rule, _ in out] == [0.75, 3.0] and len(set(running)) == 2
    assert [r.getMessage() for r in caplog.records] == ["building 0.75", "built 0.75", "building 3.0", "built 3.0"]
