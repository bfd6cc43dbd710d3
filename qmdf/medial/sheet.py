"""The single-sheet medial mesh: the covering's solid collapsed to one layer (``qmdf.medial.thinning``), its
vertices placed on the contracted membrane, which lies on the axis.

The collapse fixes the topology (chi of the solid, seams where sheets meet, free rims, curves); the membrane
fixes the geometry. The cubes collapse in q's order; squares and edges then only where they are redundant:
off the axis (the covering's outer shell), in q's upper band (``valley_share``), flat once placed (a fin
around a curve, a step across a sheet), or covering a spot another square of lower q already covers (the node
layers beside a sheet). Whatever the rules release, the collapse only removes what keeps the homotopy type.
"""

from __future__ import annotations

import logging

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from qmdf.geometry.metrics import edges_off_polygons
from qmdf.medial.coverage import keeps
from qmdf.medial.thinning import Collapse, CubicalComplex, cubical_euler
from qmdf.schema import param


@dataclass
class CollapseSettings:
    """How the covering's solid collapses to one layer (``prepared_solid``, ``thinned_sheet``): the expert
    settings of the sheet stage (``sheet.expert``), each with what it was measured on."""

    valley_share: float = param(
        0.5,
        gt=0,
        le=1,
        doc="squares and edges whose q lies above this share of the way from q's local floor up to eps may "
        "collapse (the covering's outer shell)",
    )
    off_axis: float = param(
        0.75,
        gt=0,
        doc="squares whose corners lie farther than this many grid steps from the membrane are off the axis and "
        "may collapse",
    )
    off_axis_wide: float = param(
        3.0,
        ge=0,
        doc="the sheet stage, with radius=data: a second sheet with this off_axis, and the compact one with the "
        "input's chi whose envelope fits the data better is kept (0: only off_axis). Where a thin plate lies "
        "oblique to the grid, its middle collapses away at 0.75 steps (abc_00000125: CD 0.43e-3 -> 0.27e-3); on "
        "thick parts 3 steps keeps the covering's outer shell (the block 0.56e-3 -> 1.12e-3)",
    )
    match_topology: bool = param(
        True,
        doc="the sheet stage: where the input's solid has a known Euler characteristic (a closed mesh's, a "
        "cloud's Poisson surface's), collapse the nodes below the highest of 15 levels from the covering's eps "
        "down to 0.3 eps whose solid has it (the kitten at eps 0.047: chi -1, a bridge; at 0.040 chi 0 as its "
        "genus implies)",
    )
    fin_area: float = param(
        0.25,
        ge=0,
        lt=1,
        doc="placed squares below this share of a grid square's area are flat: a fin around a curve-like axis or "
        "a step across a sheet",
    )
    valley_only: bool = param(
        True,
        doc="also release squares whose q is not a valley across them (below both parallel squares one node "
        "away) and edges not a valley across both other axes: one layer of a wide flat valley stays (the block: "
        "43k vertices after simplification -> 9.7k, seams 56k -> 1k; the teacup's seams 669 -> 240)",
    )
    fill_pockets: bool = param(
        True,
        doc="fill the covering's enclosed voids where the learned sdf is inside everywhere in them before the "
        "collapse: a covering thick around a junction of sheets encloses islands of higher q, and each became a "
        "closed pocket of the sheet (b2 > 0); a void that reaches outside the shape (a hollow part) stays",
    )
    grow_topology: bool = param(
        True,
        doc="where no level of q has the input's Euler characteristic (at most 1: one piece of genus g), grow the "
        "solid in the covering from its lowest q, node by node in q's order, each joining only where it changes "
        "no topology, then the g lowest-q tunnels closed (medial.topology_growth; the sharp sphere's maze of "
        "genus 31); off, or chi above 1: the covering's nodes as they are, with a warning",
    )
    speck_fraction: float = param(
        0.01,
        ge=0,
        lt=1,
        doc="drop pieces of the covering's solid with fewer nodes than this share of the largest's (cover's rule "
        "for its specks)",
    )
    max_nodes: int = param(
        1_000_000,
        ge=1000,
        doc="collapse on every k-th grid node, k the smallest that leaves at most this many nodes inside the "
        "covering: a thick covering (the bunny's eps raised to 0.034: 2.2M nodes) took 370 s at every node; at "
        "eps 0.055 every second node (172k) gives chi 1 in 17 s; the teacup's 570k nodes keep every node",
    )


@dataclass
class Sheet:
    vertices: np.ndarray  # (V, 3)
    edges: np.ndarray  # (E, 2) edges that bound no face (curve-like parts of the axis)
    faces: np.ndarray  # (F, 3)
    stats: dict = field(default_factory=dict)

    @property
    def euler(self) -> int:
        from qmdf.geometry.metrics import euler_medial_mesh

        return euler_medial_mesh(len(self.vertices), self.edges, self.faces)


def keep_large_pieces(inside: np.ndarray, share: float) -> np.ndarray:
    """The inside nodes whose 6-connected piece has at least ``share`` of the largest piece's nodes."""
    from scipy import ndimage

    label, n = ndimage.label(inside)
    if n <= 1:
        return inside
    sizes = np.bincount(label.ravel())[1:]
    keep = np.flatnonzero(sizes >= share * sizes.max()) + 1
    return np.isin(label, keep)


def fill_voids(inside: np.ndarray, outside_at) -> tuple[np.ndarray, dict]:
    """The inside nodes with every void of the covering that the shape does not have filled in. A void is a
    piece of the outside nodes, 26-connected (the complement of a cubical complex of whole cells), that does
    not reach the grid's border; it is the shape's own (a hollow part) when ``outside_at(void's nodes)`` (a mask)
    holds at any of its nodes. Why: a covering thick around a junction of sheets can enclose an island of q
    above eps, and the collapse keeps the homotopy type, so each island would become a closed pocket of the sheet
    (b2 > 0, where the medial axis of a solid without cavities has none)."""
    from scipy import ndimage

    enclosed = ndimage.binary_fill_holes(inside, structure=np.ones((3, 3, 3), bool)) & ~inside
    stats = {"voids": 0, "filled": 0, "filled_nodes": 0}
    if not enclosed.any():
        return inside, stats
    label, n = ndimage.label(enclosed, structure=np.ones((3, 3, 3), bool))
    nodes = np.argwhere(label)
    own = outside_at(nodes)
    shape_void = np.zeros(n + 1, bool)
    shape_void[label[tuple(nodes[own].T)]] = True
    fill = ~shape_void
    fill[0] = False
    out = inside | fill[label]
    stats.update(voids=int(n), filled=int(fill.sum()), filled_nodes=int((out & ~inside).sum()))
    return out, stats


def level_with_topology(
    q: np.ndarray,
    eps: float,
    target_chi: int,
    prepare,
    levels: int = 15,
    lowest: float = 0.3,
) -> tuple[float | None, np.ndarray | None, list]:
    """The highest of ``levels`` levels from ``eps`` down to ``lowest * eps`` whose solid, the nodes with q below
    it after ``prepare(mask)`` (specks dropped, voids filled), has Euler characteristic ``target_chi`` (the
    shape's: the collapse and the simplification keep it): (level, its prepared mask, the scan as (level, chi)
    pairs); (None, None, scan) where none has. Why: eps raised to the field's noise floor on its axis is too thick
    where two parts of the axis come close (the kitten at 0.047: a bridge, chi -1 against 0; right from 0.040 to
    0.033, a handle broken below), and too thin where q's valley stays high on a branch (holes); the highest
    level of the right topology keeps the covering thick where it can be."""
    scan = []
    for level in eps * np.linspace(1.0, lowest, levels):
        mask = prepare(q < level)
        chi = cubical_euler(mask)
        scan.append((float(level), int(chi)))
        if chi == target_chi:
            return float(level), mask, scan
    return None, None, scan


def _crop(mask: np.ndarray) -> tuple[tuple[slice, ...], np.ndarray]:
    """The box around ``mask``'s true entries with one node of margin (a void inside stays enclosed in it), as
    slices and its lowest index."""
    idx = np.argwhere(mask)
    lo, hi = np.maximum(idx.min(0) - 1, 0), np.minimum(idx.max(0) + 2, np.array(mask.shape))
    return tuple(slice(a, b) for a, b in zip(lo, hi)), lo


def node_stride(inside: np.ndarray, max_nodes: int) -> int:
    """The smallest k with at most ``max_nodes`` of every k-th grid node inside (the collapse's cost follows the
    node count)."""
    stride = 1
    while inside[::stride, ::stride, ::stride].sum() > max_nodes:
        stride += 1
    return stride


def _centre_curves(x: np.ndarray, squares: np.ndarray, membrane_vertices: np.ndarray, reach: float) -> np.ndarray:
    """Vertices of no square (a curve-like axis) moved from the membrane's surface to the middle of it: the
    mean of the membrane's vertices within ``reach``. Around a curve the contracted membrane is a thin tube,
    and its surface is off the axis by the tube's radius."""
    from scipy.spatial import cKDTree

    curve = np.ones(len(x), bool)
    curve[np.unique(squares)] = False
    if not curve.any():
        return x
    tree = cKDTree(membrane_vertices)
    out = x.copy()
    for i in np.flatnonzero(curve):
        near = tree.query_ball_point(x[i], reach)
        if near:
            out[i] = membrane_vertices[near].mean(0)
    return out


def _quad_areas(x: np.ndarray, squares: np.ndarray) -> np.ndarray:
    a, b, c, d = (x[squares[:, k]] for k in range(4))
    return 0.5 * (np.linalg.norm(np.cross(b - a, c - a), axis=1) + np.linalg.norm(np.cross(c - a, d - a), axis=1))


def _triangulate(x: np.ndarray, squares: np.ndarray) -> np.ndarray:
    """Two triangles per square, split along its shorter placed diagonal."""
    a, b, c, d = squares.T
    short_ac = np.linalg.norm(x[a] - x[c], axis=1) <= np.linalg.norm(x[b] - x[d], axis=1)
    t1 = np.where(short_ac[:, None], np.column_stack([a, b, c]), np.column_stack([a, b, d]))
    t2 = np.where(short_ac[:, None], np.column_stack([a, c, d]), np.column_stack([b, c, d]))
    return np.concatenate([t1, t2]).astype(np.int64)


def _keep_levels(inside: np.ndarray, q: np.ndarray, eps: float, share: float, reach: int = 2) -> np.ndarray:
    """Per node, the q below which squares and edges stay: ``share`` of the way from q's local floor (the lowest
    q within ``reach`` nodes: the valley, whatever the grid's offset from it) up to eps (the covering)."""
    from scipy.ndimage import minimum_filter

    floor = minimum_filter(np.where(inside, q, np.inf), size=2 * reach + 1, mode="nearest")
    floor = np.minimum(floor, eps)
    return floor + share * (eps - floor)


def _covered_squares(
    x: np.ndarray, squares: np.ndarray, proper: np.ndarray, node_q: np.ndarray, radius: float
) -> np.ndarray:
    """Proper squares placed onto a spot that a square of lower q already covers (the node layers beside a
    sheet all land on it): taking squares by increasing q, each one whose placed centre lies within ``radius``
    of a square already taken is covered. Neighbours on one layer's staircase lie farther apart than half a
    grid step, so one layer is never covered by itself."""
    from scipy.spatial import cKDTree

    out = np.zeros(len(squares), bool)
    idx = np.flatnonzero(proper)
    if len(idx) < 2:
        return out
    centre = x[squares[idx]].mean(1)
    start, nbr = _neighbour_lists(cKDTree(centre), radius)
    taken = _take_uncovered(np.argsort(node_q[squares[idx]].mean(1), kind="stable"), start, nbr)
    out[idx[~taken]] = True
    return out


def _neighbour_lists(tree, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's neighbours within ``radius`` (itself excluded) as CSR lists: start (n + 1,), neighbours."""
    pairs = tree.query_pairs(radius, output_type="ndarray")
    both = np.concatenate([pairs, pairs[:, ::-1]])
    both = both[np.argsort(both[:, 0], kind="stable")]
    start = np.searchsorted(both[:, 0], np.arange(tree.n + 1))
    return start, both[:, 1].copy()


@njit(cache=True, nogil=True)
def _take_uncovered(order, start, nbr):
    """In ``order``, take each item none of whose neighbours was taken before it."""
    taken = np.zeros(len(order), np.bool_)
    for k in order:
        free = True
        for m in range(start[k], start[k + 1]):
            if taken[nbr[m]]:
                free = False
                break
        taken[k] = free
    return taken


def _redundant_edges(
    x: np.ndarray, edges: np.ndarray, squares: np.ndarray, node_q: np.ndarray, short: float, reach: float
) -> np.ndarray:
    """Edges bounding no square that are placed almost to a point (shorter than ``short``: across a sheet),
    onto a sheet (within ``reach`` of a square's placed centre: a removed layer's side), onto the same spot as
    another lone edge of lower q (within half of ``reach``), or dangling with the loose end within ``reach`` of
    another vertex (a spur beside a curve): they may collapse where they dangle. A curve-like axis away from any
    sheet keeps its edges, its loose ends included."""
    from scipy.spatial import cKDTree

    if not len(edges):
        return np.zeros(0, bool)
    lone = edges_off_polygons(edges, squares)
    length = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
    mid = x[edges].mean(1)
    out = lone & (length < short)
    check = np.flatnonzero(lone & ~out)
    if len(squares) and len(check):
        out[check[cKDTree(x[squares].mean(1)).query(mid[check])[0] < reach]] = True
    # another edge within half of reach that reads a lower q (ties: the lower index) covers this one's spot
    check = np.flatnonzero(lone & ~out)
    if len(check):
        eq = node_q[edges].mean(1)
        pairs = cKDTree(mid[check]).sparse_distance_matrix(cKDTree(mid), 0.5 * reach, output_type="ndarray")
        i, j = check[pairs["i"]], pairs["j"]
        lower = (j != i) & ((eq[j] < eq[i]) | ((eq[j] == eq[i]) & (j < i)))
        out[i[lower]] = True
    # a spur: a dangling edge whose loose end lands beside a vertex other than its own neighbour
    degree = np.bincount(edges.ravel(), minlength=len(x))
    check = np.flatnonzero(lone & ~out)
    if len(check):
        points = cKDTree(x)
        for end, other in ((0, 1), (1, 0)):
            v, w = edges[check, end], edges[check, other]
            dangling = degree[v] == 1
            if not dangling.any():
                continue
            # the three nearest within reach: one that is neither v nor w exists iff any does
            d, u = points.query(x[v[dangling]], k=min(3, len(x)), distance_upper_bound=reach)
            u = u.reshape(len(d), -1)
            other_near = (np.isfinite(d.reshape(len(u), -1)) & (u != v[dangling, None]) & (u != w[dangling, None])).any(
                1
            )
            out[check[dangling][other_near]] = True
    return out


def _mean_q(q: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """The mean q over each cell's corner nodes (C, K, 3); inf where a corner lies off the grid."""
    ok = np.all((corners >= 0) & (corners < np.array(q.shape)), axis=(1, 2))
    out = np.full(len(corners), np.inf)
    out[ok] = q[tuple(corners[ok].reshape(-1, 3).T)].reshape(ok.sum(), -1).mean(1)
    return out


def _valley_squares(cx: CubicalComplex, q: np.ndarray) -> np.ndarray:
    """Squares whose q (their corners' mean) is no higher than that of both parallel squares one node away
    along their normal: where q has its valley across them. A valley of q flat to within the keep level is
    several nodes wide (the block's eps raised to 0.021: 285k vertices left, a foam of walls); one layer of it
    is a valley, the others may collapse."""
    corners = cx.nodes[cx.squares]  # (S, 4, 3) grid nodes
    step = np.eye(3, dtype=np.int64)[np.argmin(cx.square_cells % 2, axis=1)][:, None, :]  # along the even axis
    return _mean_q(q, corners) <= np.minimum(_mean_q(q, corners + step), _mean_q(q, corners - step))


def _valley_edges(cx: CubicalComplex, q: np.ndarray) -> np.ndarray:
    """Edges whose q is no higher than that of the four parallel edges one node away across them: a curve-like
    axis runs along them (an edge on a sheet has a flat q beside it, within the sheet)."""
    ends = cx.nodes[cx.edges]  # (E, 2, 3)
    axis = np.argmax(cx.edge_cells % 2, axis=1)
    eye = np.eye(3, dtype=np.int64)
    beside = [_mean_q(q, ends + sign * eye[(axis + k) % 3][:, None, :]) for k in (1, 2) for sign in (1, -1)]
    return _mean_q(q, ends) <= np.min(beside, axis=0)


def _lone_edges(cx: CubicalComplex) -> np.ndarray:
    """The 1-cells that are no square's side."""
    return np.sort(cx.edges, axis=1)[edges_off_polygons(cx.edges, cx.squares)]


def single_sheet(
    inside: np.ndarray,
    q: np.ndarray,
    lo: np.ndarray,
    spacing: np.ndarray,
    membrane_vertices: np.ndarray,
    membrane_faces: np.ndarray,
    eps: float,
    settings: CollapseSettings = CollapseSettings(),
    keep_q: np.ndarray | None = None,
) -> Sheet:
    """The single sheet of the grid nodes ``inside`` the covering (q at them), placed on the membrane.

    The cubes collapse first, in q's order. Then squares and edges may collapse where they are off the axis
    (their corners, on average, farther than ``settings.off_axis`` grid steps from the membrane: what the cubes
    left on the covering's outer shell), where they are flat once placed (smaller than ``settings.fin_area`` of a
    grid square: a fin around a curve-like axis, a step across a sheet), or where a square of lower q already
    covers their placed spot (the other node layers beside a sheet); lone edges likewise (``_redundant_edges``).
    With ``valley_only``, squares and edges across which q has no valley are released too (``_valley_squares``,
    ``_valley_edges``). Each release can expose more, so release and collapse repeat until nothing changes.
    ``keep_q``: the per-node levels of ``_keep_levels`` where the caller has them (one solid, several rules)."""
    from qmdf.geometry.inside import mesh_distance

    lo, spacing = np.asarray(lo, np.float64), np.asarray(spacing, np.float64)
    off_axis, fin_area = settings.off_axis, settings.fin_area
    h = float(spacing.max())
    col = Collapse(inside, q, _keep_levels(inside, q, eps, settings.valley_share) if keep_q is None else keep_q)
    cx = col.run()
    first = {"vertices": len(cx.nodes), "squares": len(cx.squares), "edges": len(cx.edges), "chi": cx.euler}
    dist, x = mesh_distance(membrane_vertices, membrane_faces, lo + cx.nodes * spacing)
    # masks over this first complex's cells, so applied in the first round only (later rounds only remove cells)
    off_valley = (~_valley_squares(cx, q), ~_valley_edges(cx, q)) if settings.valley_only else None
    for _ in range(20):  # until nothing more is released (a released layer can expose the next)
        far = dist > off_axis * h
        s, e = cx.squares, cx.edges
        node_q = q[tuple(cx.nodes.T)]
        off_sq = far[s].mean(1) > 0.5 if len(s) else np.zeros(0, bool)
        off_edge = far[e].all(1) if len(e) else np.zeros(0, bool)
        off_edge |= _redundant_edges(x, e, s, node_q, fin_area * h, 0.75 * h)
        flat = _quad_areas(x, s) < fin_area * float(np.prod(np.sort(spacing)[:2]))
        soft_sq = off_sq | flat | _covered_squares(x, s, ~flat, node_q, 0.5 * h)
        if off_valley is not None:
            soft_sq, off_edge, off_valley = soft_sq | off_valley[0], off_edge | off_valley[1], None
        if not (soft_sq.any() or off_edge.any()):
            break
        col.soften(cx, soft_sq, off_edge)
        cells = len(cx.nodes) + len(cx.edges) + len(cx.squares)
        cx = col.run()
        if len(cx.nodes) + len(cx.edges) + len(cx.squares) == cells:
            break
        dist, x = mesh_distance(membrane_vertices, membrane_faces, lo + cx.nodes * spacing)
    x = _centre_curves(x, cx.squares, membrane_vertices, h)
    faces = _triangulate(x, cx.squares)
    stats = {"collapse_chi": cx.euler, "cubes_left": cx.cubes, "first_pass": first, "squares": int(len(cx.squares))}
    return Sheet(x, _lone_edges(cx), faces, stats)


def pick_sheet(candidates: list, chamfer, target_chi: int | None = None) -> tuple[int, list[dict]]:
    """Which of several ``(refinement.MAT, stats)`` sheets of one shape to keep: a compact one before one that is
    not, then one with ``target_chi``, then the one whose envelope fits the data best (``stats["cd"]`` where the
    refinement measured it, else ``chamfer(mat) -> CD``; ``refinement``'s measure). Returns its index and, per
    candidate, what decided."""
    rows = [
        {
            "compact": bool(stats["compact"]),
            "chi": int(stats["after"]["chi"]),
            "vertices": len(mat.vertices),
            "cd": float(stats["cd"] if stats.get("cd") is not None else chamfer(mat)),
        }
        for mat, stats in candidates
    ]
    # compact first, then the input's chi; between equals the one keep-if-better rule on the fit
    ranks = [(not r["compact"], target_chi is not None and r["chi"] != target_chi) for r in rows]
    kept = 0
    for i in range(1, len(rows)):
        if ranks[i] < ranks[kept] or (ranks[i] == ranks[kept] and keeps(rows[i]["cd"], rows[kept]["cd"])):
            kept = i
    return kept, rows


def refined_sheet(
    grid: dict,
    evaluate,
    membrane: tuple[np.ndarray, np.ndarray],
    radii_of,
    data,
    steps: list,
    settings: CollapseSettings = CollapseSettings(),
    target_chi: int | None = None,
    off_axis_wide: float = 0.0,
):
    """The sheet of a covering (its ``prepared_solid`` from ``grid``, ``evaluate``, ``settings`` and
    ``target_chi``, then ``thinned_sheet`` on the ``membrane``'s (vertices, faces)), refined by ``steps``
    on ``data`` (``refinement.refine``); with ``off_axis_wide`` (not 0, not ``settings.off_axis``) built twice,
    the second time under that off-axis rule, the better kept (``pick_sheet``). Returns the ``refinement.MAT`` and
    its stats: the collapse's, ``before`` and ``after`` refinement (``sheet_counts``), ``steps`` (each step's
    stats), ``cd`` (its envelope's, where a judged step measured it), ``compact`` and ``off_axis``."""
    import dataclasses

    from qmdf.medial.refinement import refine

    if any(step.needs_data for step, _ in steps):
        ball = one_ball(data)
        if ball is not None:
            counts = sheet_counts(ball[0])
            return ball[0], {
                "one_ball": True,
                "before": counts,
                "after": counts,
                "steps": {},
                "cd": ball[1],
                "compact": True,
            }
    solid = prepared_solid(grid, evaluate, settings, target_chi)  # the same for every off-axis rule
    if solid.stats["level"]:
        data.log.log(*describe_level(solid.stats["level"]))

    def build(off_axis: float, data=data):
        data.log.info("sheet: collapsing the covering with off_axis %s", off_axis)
        rule = dataclasses.replace(settings, off_axis=off_axis)
        mat, stats = thinned_sheet(solid, *membrane, radii_of, rule)
        stats["before"] = sheet_counts(mat)
        mat, stats["steps"], stats["cd"] = refine(mat, data, steps)
        stats.update(compact=data.is_compact(len(mat.vertices)), after=sheet_counts(mat))
        return mat, stats

    if not off_axis_wide or off_axis_wide == settings.off_axis:
        return build(settings.off_axis)
    candidates = _side_by_side(build, data, settings.off_axis, off_axis_wide)
    kept, rows = pick_sheet(candidates, data.chamfer, target_chi)
    mat, stats = candidates[kept]
    for row, off_axis in zip(rows, (settings.off_axis, off_axis_wide)):
        row["off_axis"] = off_axis
    stats["off_axis"] = {"tried": rows, "kept": rows[kept]["off_axis"]}
    data.log.info("sheet: off_axis %s kept (%s)", rows[kept]["off_axis"], "; ".join(map(_row_text, rows)))
    return mat, stats


def _side_by_side(build, data, *rules: float) -> list:
    """``build(rule, data)`` for each rule, in threads: the sheets of two off-axis rules are independent and
    each mostly one core's work (the collapse and simplification loops release the GIL), so on 2 cores the second
    costs little more wall time than the first (the teacup's sheet stage 42.7 s -> 31.0 s). The first logs as it goes,
    the others' lines follow it in order; the results are those of building them one after the other."""
    import dataclasses
    from concurrent.futures import ThreadPoolExecutor

    logs = [data.log] + [_DeferredLog() for _ in rules[1:]]
    with ThreadPoolExecutor(len(rules)) as pool:
        futures = [pool.submit(build, rule, dataclasses.replace(data, log=log)) for rule, log in zip(rules, logs)]
        try:
            return [f.result() for f in futures]
        finally:
            for log in logs[1:]:
                log.replay(data.log)


class _DeferredLog:
    """A logger's ``info`` / ``warning`` / ``log`` calls kept to be replayed on a real one."""

    def __init__(self):
        self.calls: list[tuple] = []

    def log(self, level, msg, *args):
        self.calls.append((level, msg, args))

    def info(self, msg, *args):
        self.log(logging.INFO, msg, *args)

    def warning(self, msg, *args):
        self.log(logging.WARNING, msg, *args)

    def replay(self, logger) -> None:
        for level, msg, args in self.calls:
            logger.log(level, msg, *args)


def one_ball(data):
    """``(MAT, CD)`` of one ball where the data is a sphere to within ``data.tolerance`` (its envelope's CD to the
    data, the sheet's own verdict), else None. A ball's MAT is its centre, but the covering of a learned field keeps
    a blob of nodes around it that no collapse thins to a point: a 3,000-point sphere's sheet came out as 3,000
    vertices of spikes and lone edges after 268 s of refinement, every one of its balls reaching the whole surface.
    The sphere is the least-squares one through the data's samples (|x|^2 = 2 c.x + r^2 - |c|^2, linear)."""
    from qmdf.medial.refinement import MAT

    x = data.balls.samples
    if len(x) < 4:
        return None
    solution = np.linalg.lstsq(np.c_[2.0 * x, np.ones(len(x))], np.einsum("ij,ij->i", x, x), rcond=None)[0]
    centre = solution[:3]
    radius = float(np.sqrt(max(solution[3] + centre @ centre, 0.0)))
    off = np.abs(np.linalg.norm(x - centre, axis=1) - radius)
    if not radius > 0 or off.mean() > data.tolerance:  # not a sphere: no envelope to measure
        return None
    mat = MAT(centre[None], np.array([radius]), np.zeros((0, 2), np.int64), np.zeros((0, 3), np.int64))
    cd = data.chamfer(mat)
    if cd > data.tolerance:
        return None
    data.log.info(
        "sheet: the data lies within %.2e (CD) of one ball, centre %s, radius %.4g: the MAT is that ball",
        cd,
        np.round(centre, 4).tolist(),
        radius,
    )
    return mat, cd


def _row_text(r: dict) -> str:
    compact = "" if r["compact"] else ", not compact"
    return f"{r['off_axis']}: CD {r['cd']:.3e} to the data, {r['vertices']} vertices, chi {r['chi']}{compact}"


def describe_level(level: dict) -> tuple[int, str]:
    """The log level and line that say which level of q the collapse took (``_solid``'s ``level`` stats)."""
    import logging

    scan = ", ".join(f"{e:.4f}: {c}" for e, c in level["scan"])
    head = (
        f"sheet: no level of q from eps {level['scan'][0][0]:.4g} down gives the solid the input's Euler "
        f"characteristic {level['target_chi']} (scan: {scan}); "
    )
    if level.get("grown"):
        g = level["grown"]
        return logging.INFO, head + (
            f"grown in q's order instead: {g['joined']} of the covering's {g['allowed']} nodes, "
            f"{len(g['closures_q'])} tunnels closed, chi {g['chi']} (sheet.expert.grow_topology)"
        )
    if level["eps"] is None:
        return logging.WARNING, head + "the covering's nodes are collapsed as they are"
    return logging.INFO, (
        f"sheet: the nodes below q = {level['eps']:.4g} collapsed, the highest level whose solid has the input's "
        f"Euler characteristic {level['target_chi']} (covering's eps {level['scan'][0][0]:.4g}; "
        "sheet.expert.match_topology)"
    )


@dataclass
class PreparedSolid:
    """The grid nodes a sheet collapses from, with q at them (inf outside), the box they lie in and the level
    they lie below: what every off-axis rule's sheet of one covering shares (``prepared_solid``)."""

    inside: np.ndarray
    q: np.ndarray
    lo: np.ndarray
    spacing: np.ndarray
    eps: float
    stats: dict
    keep_q: np.ndarray  # per node, the q below which squares and edges stay (``_keep_levels``)


def prepared_solid(
    grid: dict, evaluate, settings: CollapseSettings = CollapseSettings(), target_chi: int | None = None
) -> PreparedSolid:
    """A covering's grid (``inside``, ``lo``, ``spacing``, ``eps``, as ``covering.build_covering`` gives it) on
    every k-th node within ``settings.max_nodes`` (``node_stride``), its solid prepared (``_solid``: specks
    dropped, voids filled, with ``target_chi`` the level or the growth of the input's topology), q and sdf from
    ``evaluate(points)``, each node evaluated once."""
    stride = node_stride(grid["inside"], settings.max_nodes)
    spacing = np.asarray(grid["spacing"]) * stride
    inside = keep_large_pieces(grid["inside"][::stride, ::stride, ::stride], settings.speck_fraction)
    if not inside.any():
        from qmdf.errors import QmdfError

        raise QmdfError("no grid node lies inside the covering: nothing to collapse into a sheet")
    box, first = _crop(inside)
    inside, lo = inside[box], np.asarray(grid["lo"]) + first * spacing
    q, sdf = np.full(inside.shape, np.nan), np.full(inside.shape, np.nan)

    def field_at(n):
        """q and sdf at grid nodes n (M, 3), each node evaluated once; its point as the whole grid has it (a
        rounding off would break q's ties on exact fields)."""
        todo = n[np.isnan(q[tuple(n.T)])]
        if len(todo):
            out = evaluate(grid["lo"] + (todo + first) * spacing)
            q[tuple(todo.T)], sdf[tuple(todo.T)] = out["q"], out["sdf"]
        return q[tuple(n.T)], sdf[tuple(n.T)]

    field_at(np.argwhere(inside))
    inside, eps, stats = _solid(inside, q, float(grid["eps"]), field_at, settings, target_chi)
    field_at(np.argwhere(inside))  # the filled voids' nodes too
    stats.update(nodes_inside=int(inside.sum()), grid_stride=stride)
    q = np.where(inside, q, np.inf)
    return PreparedSolid(inside, q, lo, spacing, eps, stats, _keep_levels(inside, q, eps, settings.valley_share))


def thinned_sheet(
    solid: PreparedSolid,
    membrane_vertices: np.ndarray,
    membrane_faces: np.ndarray,
    radii_of,
    settings: CollapseSettings = CollapseSettings(),
):
    """The single-layer MAT of a covering before refinement: its ``prepared_solid`` collapsed onto the membrane
    under ``settings``' off-axis rule (``single_sheet``), radii from ``radii_of(vertices)``. Returns the
    ``refinement.MAT`` and its stats."""
    from qmdf.medial.refinement import MAT

    # read only (the collapse copies what it changes), so one solid serves each off-axis rule, side by side too
    sheet = single_sheet(
        solid.inside,
        solid.q,
        solid.lo,
        solid.spacing,
        membrane_vertices,
        membrane_faces,
        solid.eps,
        settings,
        solid.keep_q,
    )
    radii = radii_of(sheet.vertices)
    return MAT(sheet.vertices, radii, sheet.edges, sheet.faces), {**solid.stats, "collapse": sheet.stats}


def _solid(inside, q, eps: float, field_at, settings: CollapseSettings, target_chi: int | None):
    """The nodes to collapse, the level they lie below and stats: pieces below ``speck_fraction`` of the largest
    dropped, with ``fill_pockets`` the voids inside the shape filled (``fill_voids``, the sdf from
    ``field_at(nodes) -> (q, sdf)``); with ``target_chi`` the nodes below the highest level whose solid has that
    Euler characteristic (``level_with_topology``), none: with ``grow_topology`` and ``target_chi`` <= 1 a solid
    grown in the covering with it (``topology_growth``), else the covering's nodes."""
    voids: list[dict] = []

    def prepare(mask):
        mask = keep_large_pieces(mask, settings.speck_fraction)
        if settings.fill_pockets:
            mask, filled = fill_voids(mask, lambda n: field_at(n)[1] > 0)
            voids.append(filled)
        return mask

    level = None
    if target_chi is not None:
        found, mask, scan = level_with_topology(np.where(inside, q, np.inf), eps, target_chi, prepare)
        level = {"target_chi": int(target_chi), "eps": found, "scan": scan}
        if found is not None:
            inside, eps = mask, found
        elif settings.grow_topology and target_chi <= 1:
            from qmdf.medial.topology_growth import grow_with_topology

            allowed = prepare(inside)
            field_at(np.argwhere(allowed))
            inside, level["grown"] = grow_with_topology(allowed, np.where(allowed, q, np.inf), target_chi)
    if level is None or (level["eps"] is None and "grown" not in level):
        inside = prepare(inside)
    return inside, eps, {"voids": voids[-1] if voids else None, "level": level}


def sheet_counts(mat) -> dict:
    """A ``refinement.MAT``'s size and topology: vertices, edges (the faces' too), faces, lone edges, chi, seam
    and rim edges."""
    from qmdf.geometry.metrics import euler_medial_mesh, seam_edges, single_face_edges

    return {
        "vertices": len(mat.vertices),
        "edges": int(len(mat.medial_mesh().edges)),
        "faces": len(mat.faces),
        "lone_edges": int(len(mat.edges)),
        "chi": euler_medial_mesh(len(mat.vertices), mat.edges, mat.faces),
        "seam_edges": int(len(seam_edges(mat.faces))),
        "rim_edges": int(len(single_face_edges(mat.faces))),
    }


def sheet_verdict(mat, stats: dict, tolerance: float, target_vertices: int) -> str | None:
    """Whether the refined sheet is the MAT: sets ``stats["fits_data"]`` (its envelope within ``tolerance`` of the
    data, where the refinement measured it) and ``stats["compact"]``; returns why not (export then writes the
    membrane), None where it is."""
    # an undertrained field (no inside) thins to a point: no sheet, whatever its chi. But a sphere's MAT is one
    # ball: a point is the MAT where its ball lies within the tolerance of the data (export takes it as is)
    stats["fits_data"] = bool(stats.get("cd") is not None and stats["cd"] <= tolerance)
    v, e, f, r_max = len(mat.vertices), len(mat.edges), len(mat.faces), float(mat.radii.max(initial=0.0))
    if (not (f or e) and not stats["fits_data"]) or not r_max > 0:
        stats["compact"] = False
        return (
            f"the single sheet collapsed to {v} vertices, {e} lone edges, {f} faces, largest radius {r_max:.3g}: the "
            "field's inside is too thin for a MAT here (see the train stage's slices.png); export writes the membrane"
        )
    if not stats["compact"]:
        return (
            f"the single sheet is not compact: simplification stopped at {v} vertices (target {target_vertices}; "
            f"{stats['after']['seam_edges']} seam edges); export writes the membrane as the MAT"
        )
    return None
