"""The single-sheet medial mesh: the covering's solid collapsed to one layer (``qmdf.medial.thinning``), its
vertices placed on the contracted membrane, which lies on the axis.

The collapse fixes the topology (chi of the solid, seams where sheets meet, free rims, curves); the membrane
fixes the geometry. The cubes collapse in q's order; squares and edges then only where they are redundant:
off the axis (the covering's outer shell), in q's upper band (``valley_share``), flat once placed (a fin
around a curve, a step across a sheet), or covering a spot another square of lower q already covers (the node
layers beside a sheet). Whatever the rules release, the collapse only removes what keeps the homotopy type.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from qmdf.geometry.metrics import edges_off_polygons
from qmdf.medial.thinning import Collapse, CubicalComplex, cubical_euler


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


@njit(cache=True)
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
    valley_share: float = 0.5,
    off_axis: float = 0.75,
    fin_area: float = 0.25,
    valley_only: bool = True,
) -> Sheet:
    """The single sheet of the grid nodes ``inside`` the covering (q at them), placed on the membrane.

    The cubes collapse first, in q's order. Then squares and edges may collapse where they are off the axis
    (their corners, on average, farther than ``off_axis`` grid steps from the membrane: what the cubes left
    on the covering's outer shell), where they are flat once placed (smaller than ``fin_area`` of a grid square:
    a fin around a curve-like axis, a step across a sheet), or where a square of lower q already covers their
    placed spot (the other node layers beside a sheet); lone edges likewise (``_redundant_edges``). With
    ``valley_only``, squares and edges across which q has no valley are released too (``_valley_squares``,
    ``_valley_edges``). Each release can expose more, so release and collapse repeat until nothing changes."""
    from qmdf.geometry.inside import mesh_distance

    lo, spacing = np.asarray(lo, np.float64), np.asarray(spacing, np.float64)
    h = float(spacing.max())
    col = Collapse(inside, q, _keep_levels(inside, q, eps, valley_share))
    cx = col.run()
    first = {"vertices": len(cx.nodes), "squares": len(cx.squares), "edges": len(cx.edges), "chi": cx.euler}
    dist, x = mesh_distance(membrane_vertices, membrane_faces, lo + cx.nodes * spacing)
    # masks over this first complex's cells, so applied in the first round only (later rounds only remove cells)
    off_valley = (~_valley_squares(cx, q), ~_valley_edges(cx, q)) if valley_only else None
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


def pick_sheet(candidates: list, fit_of, target_chi: int | None = None) -> tuple[int, list[dict]]:
    """Which of several ``(MedialMesh, stats)`` sheets of one shape to keep: a compact one before one that is not,
    then one with ``target_chi``, then the one whose envelope fits the data best (``fit_of(vertices, radii, lone
    edges, faces) -> CD``; a sheet's own ``stats["cd"]`` where ``simplified_sheet`` measured it already). Returns its
    index and, per candidate, what decided."""
    rows = [
        {
            "compact": bool(stats["compact"]),
            "chi": int(stats["after"]["chi"]),
            "vertices": len(mat.vertices),
            "cd": float(stats["cd"] if "cd" in stats else fit_of(mat.vertices, mat.radii, mat.lone_edges(), mat.faces)),
        }
        for mat, stats in candidates
    ]
    ranks = [(not r["compact"], target_chi is not None and r["chi"] != target_chi, r["cd"]) for r in rows]
    return min(range(len(rows)), key=ranks.__getitem__), rows


def simplified_sheet(
    grid: dict,
    evaluate,
    membrane_vertices: np.ndarray,
    membrane_faces: np.ndarray,
    radii_of,
    *,
    max_nodes: int = 1_000_000,
    speck_fraction: float = 0.01,
    valley_share: float = 0.5,
    off_axis: float = 0.75,
    fin_area: float = 0.25,
    valley_only: bool = True,
    fill_pockets: bool = True,
    target_chi: int | None = None,
    grow_topology: bool = True,
    target_vertices: int = 3000,
    compact_slack: float = 1.5,
    boundary_weight: float = 1.0,
    max_turn_deg: float = 60.0,
    tips: np.ndarray | None = None,
    tip_reach: float = 0.01,
    centre_of=None,
    refine_of=None,
    refine_vertices: int = 0,
    fit_of=None,
    extend_of=None,
    fit_envelope_of=None,
):
    """The compact single-layer MAT of a covering: its grid (``inside``, ``lo``, ``spacing``, ``eps``, as
    ``covering.build_covering`` gives it) on every k-th node within ``max_nodes`` (``node_stride``), pieces below
    ``speck_fraction`` of the largest dropped, with ``fill_pockets`` its voids inside the shape filled
    (``fill_voids``), q and sdf from ``evaluate(points)``, with ``target_chi`` the nodes below the highest level
    whose solid has that Euler characteristic (``level_with_topology``; none: with ``grow_topology`` and
    ``target_chi`` <= 1 a solid grown in the covering with it, ``topology_growth``, else the covering's nodes),
    collapsed onto the membrane (``single_sheet``), radii from ``radii_of(vertices)``, then simplified to
    ``target_vertices`` (compact: at most ``compact_slack`` times as many left; 0: not) under the spherical quadric
    error, and last, with ``centre_of(vertices) -> (vertices, radii)``, each vertex moved onto the axis; vertices
    within ``tip_reach`` of the ``tips`` (feature points) stay in place through both. Last, ``refine_of(vertices,
    radii, lone edges, faces, max_added) -> (same four, stats)`` adds up to ``refine_vertices`` where the envelope
    falls short of the surface (``medial.coverage``), and a second simplification, the added vertices fixed, brings
    the MAT back to ``target_vertices`` (then centred again): on the bunny 3,000 + 1,000 -> 3,000 vertices kept CD
    1.04e-3 of the 4,000's 0.97e-3. With ``fit_of(vertices, radii, lone edges, faces) -> CD`` against the data, the
    MAT before coverage is kept where coverage and the second simplification made it worse (the exact ellipsoid's
    sheet, already within 1e-3 of its surface everywhere: CD 1.06e-4 before, 1.40e-4 after). Last, with
    ``extend_of(vertices, radii, lone edges, faces, fixed) -> (vertices, radii, stats)``, the rims are carried out
    to the axis's end (``medial.rims``), the tips fixed. Then, with ``fit_envelope_of(vertices, radii, lone
    edges, faces, fixed) -> (vertices, radii, stats)``, the spheres are fitted to the data's surface
    (``medial.envelope_fit``), the tips fixed, kept only where ``fit_of`` says the fit improved. Returns the
    ``MedialMesh`` and its stats (before and after simplification)."""
    from qmdf.geometry.ma_format import MedialMesh
    from qmdf.geometry.metrics import euler_medial_mesh, seam_edges, single_face_edges
    from qmdf.medial.simplify import simplify_medial_mesh

    stride = node_stride(grid["inside"], max_nodes)
    spacing = np.asarray(grid["spacing"]) * stride
    inside = keep_large_pieces(grid["inside"][::stride, ::stride, ::stride], speck_fraction)
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
    voids: list[dict] = []

    def prepare(mask):
        mask = keep_large_pieces(mask, speck_fraction)
        if fill_pockets:
            mask, filled = fill_voids(mask, lambda n: field_at(n)[1] > 0)
            voids.append(filled)
        return mask

    eps = float(grid["eps"])
    level = None
    if target_chi is not None:
        found, mask, scan = level_with_topology(np.where(inside, q, np.inf), eps, target_chi, prepare)
        level = {"target_chi": int(target_chi), "eps": found, "scan": scan}
        if found is not None:
            inside, eps = mask, found
        elif grow_topology and target_chi <= 1:
            from qmdf.medial.topology_growth import grow_with_topology

            allowed = prepare(inside)
            field_at(np.argwhere(allowed))
            inside, level["grown"] = grow_with_topology(allowed, np.where(allowed, q, np.inf), target_chi)
    if level is None or (level["eps"] is None and "grown" not in level):
        inside = prepare(inside)
    field_at(np.argwhere(inside))  # the filled voids' nodes too
    q = np.where(inside, q, np.inf)
    sheet = single_sheet(
        inside,
        q,
        lo,
        spacing,
        membrane_vertices,
        membrane_faces,
        eps,
        valley_share,
        off_axis,
        fin_area,
        valley_only,
    )
    radii = radii_of(sheet.vertices)
    stats = {
        "nodes_inside": int(inside.sum()),
        "grid_stride": stride,
        "voids": voids[-1] if voids else None,
        "level": level,
        "collapse": sheet.stats,
        "before": {
            "vertices": len(sheet.vertices),
            "edges": len(sheet.edges),
            "faces": len(sheet.faces),
            "chi": sheet.euler,
        },
    }
    v, e, f = sheet.vertices, sheet.edges, sheet.faces

    def near_tips(x):
        if tips is None:
            return None
        from scipy.spatial import cKDTree

        return cKDTree(tips).query(x)[0] < tip_reach

    def simplify(v, radii, e, f, fixed):
        res = simplify_medial_mesh(v, radii, e, f, target_vertices, boundary_weight, max_turn_deg, fixed)
        return res.vertices, res.radii, res.edges, res.faces, res.stats

    def centre(v, radii):
        moved, centred_radii = centre_of(v)
        fixed = near_tips(v)  # feature tips stay on their sharp edges, as in the simplification
        if fixed is not None:
            moved[fixed], centred_radii[fixed] = v[fixed], radii[fixed]
        step = np.linalg.norm(moved - v, axis=1)
        return moved, centred_radii, {"median_move": float(np.median(step)), "max_move": float(step.max())}

    if target_vertices and len(v) > target_vertices:
        v, radii, e, f, stats["simplify"] = simplify(v, radii, e, f, near_tips(v))
    if centre_of is not None:
        v, radii, stats["centred"] = centre(v, radii)

    def compact(n):
        return not target_vertices or n <= compact_slack * target_vertices

    if refine_of is not None and refine_vertices > 0:
        if not compact(len(v)):
            stats["coverage"] = {"added": 0, "skipped": "the sheet is not compact (simplification stopped early)"}
        else:
            n0, before = len(v), (v, radii, e, f)
            v, radii, e, f, stats["coverage"] = refine_of(v, radii, e, f, refine_vertices)
            if target_vertices and len(v) > target_vertices:
                # back to the budget: the added balls (and the tips) stay, the collapses take what matters least
                added = np.arange(len(v)) >= n0
                tips_now = near_tips(v)
                v, radii, e, f, stats["resimplify"] = simplify(
                    v, radii, e, f, added if tips_now is None else added | tips_now
                )
                if centre_of is not None:
                    v, radii, stats["recentred"] = centre(v, radii)
            if fit_of is not None and stats["coverage"].get("added"):
                cd_before, cd_after = fit_of(*before), fit_of(v, radii, e, f)
                stats["coverage"].update(cd_before=cd_before, cd_after=cd_after, kept=bool(cd_after <= cd_before))
                if cd_after > cd_before:
                    v, radii, e, f = before
    if extend_of is not None:
        v, radii, stats["rims"] = extend_of(v, radii, e, f, near_tips(v))
    if fit_envelope_of is not None:
        fitted, fitted_radii, fit_stats = fit_envelope_of(v, radii, e, f, near_tips(v))
        if fit_of is not None:
            cd_before, cd_after = fit_of(v, radii, e, f), fit_of(fitted, fitted_radii, e, f)
            fit_stats.update(cd_before=cd_before, cd_after=cd_after, kept=bool(cd_after < cd_before))
            stats["cd"] = min(cd_before, cd_after)  # the kept sheet's, for pick_sheet
        if fit_stats.get("kept", True):
            v, radii = fitted, fitted_radii
        stats["envelope_fit"] = fit_stats
    mat = MedialMesh(v, radii, e, f).with_face_edges()
    stats["compact"] = compact(len(v))
    stats["after"] = {
        "vertices": len(v),
        "edges": int(len(mat.edges)),
        "faces": len(f),
        "lone_edges": int(len(e)),
        "chi": euler_medial_mesh(len(v), e, f),
        "seam_edges": int(len(seam_edges(f))),
        "rim_edges": int(len(single_face_edges(f))),
    }
    return mat, stats
