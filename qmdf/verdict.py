"""A run's verdict on its own result: ``ok``, or ``suspect`` with the reasons, each a check of the result against
what the input says (the learned surface against the input points, the solid against the input's inside, the
MAT's topology against the solid's). A wrong result that calls itself complete is the worst thing a run can hand
a user: the sparse teacup with its normals oriented by propagation came out a solid lump (chi -1163) and said
nothing.

Plain values in, a dict out; the evaluate stage gathers the evidence, the pipeline and the report show it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class VerdictLimits:
    # The learned zero level set is fitted through the input points: a median distance of a hundredth of the box
    # is a field that did not learn the surface (good runs: under 2e-3, a 0.5% noisy cloud's 5e-3).
    zero_set_to_points: float = 0.01
    # Normals the cloud's own winding number contradicts (ahead of the point inside, behind it outside): a right
    # orientation of a clean cloud leaves under 1% (the sparse teacup by WNNC 0.07%; by propagation 5-8%), 0.5%
    # noise 3% (the noisy teacup, whose MAT has the right chi)
    inconsistent_normals: float = 0.05
    # The field's sign against a reference mesh, where the run has one (good runs: 99.5% and up; the lump 72%).
    sign_accuracy: float = 0.97
    # The MAT's reconstruction against the input's solid: its volume within this factor either way.
    volume_ratio: float = 1.3
    # |chi| of a MAT of V vertices beyond max(20, V / 100) is a foam, not a shape's axis (genus 10 at most here).
    chi_floor: int = 20
    chi_per_vertex: float = 0.01
    # The MAT's parts that contradict the shape (``qmdf.geometry.mat_structure``): vertices outside it, balls out
    # of it or of no radius inside it, edges and faces across a hole. A few at a sharp corner are the sheet's
    # rounding; a twentieth of the MAT is a wrong axis.
    structural_share: float = 0.05


@dataclass
class Evidence:
    """What a run knows about its result; None where it does not know it."""

    zero_set_distance: float | None = None  # median |learned sdf| at the input points
    orientation: dict | None = None  # train's stats of a raw cloud's orientation
    proxy: str | None = None  # how a cloud's inside was fitted ("poisson", or why not)
    proxy_pieces: int | None = None  # pieces of the closed surface fitted to a cloud
    proxy_euler: tuple[int, int] | None = None  # its solid chi, and as a grid of a quarter sampling gap sees it
    sign_accuracy: float | None = None
    volume: float | None = None  # the MAT's reconstruction's
    input_volume: float | None = None  # the input solid's (a closed mesh or a cloud's fitted surface)
    chi: int | None = None  # the MAT's
    input_chi: int | None = None  # the input solid's, where known
    vertices: int | None = None  # the MAT's
    structure: dict | None = None  # the MAT's structural defects (mat_structure.structural_defects)
    notes: list[str] = field(default_factory=list)


def verdict(e: Evidence, limits: VerdictLimits = VerdictLimits()) -> dict:
    """``{"quality": "ok" | "suspect", "reasons": [...]}``: every check that could be made and failed."""
    reasons: list[str] = []
    if e.zero_set_distance is not None and e.zero_set_distance > limits.zero_set_to_points:
        reasons.append(
            f"the learned surface passes a median {e.zero_set_distance:.3g} from the input points "
            f"(over {limits.zero_set_to_points:g} of the box): the field did not learn the input"
        )
    o = e.orientation or {}
    share = o.get("inconsistent_share")
    if share is not None and share > limits.inconsistent_normals:
        reasons.append(
            f"{100 * share:.1f}% of the estimated normals contradict the cloud's winding number "
            f"(orientation {o.get('method', '?')}): inside and outside are not settled"
        )
    if e.proxy is not None and e.proxy != "poisson" and e.proxy != "points":
        reasons.append(f"no closed surface could be fitted to the oriented points ({e.proxy})")
    if e.proxy_pieces is not None and e.proxy_pieces > 1:
        reasons.append(
            f"the solid fitted to the cloud has {e.proxy_pieces} pieces: walls thinner than the sampling gap, "
            "or holes the cloud leaves open"
        )
    if e.proxy_euler is not None and e.proxy_euler[0] != e.proxy_euler[1]:
        reasons.append(
            f"the solid fitted to the cloud has solid chi {e.proxy_euler[0]}, {e.proxy_euler[1]} at a quarter of the "
            "sampling gap: a tunnel or thread narrower than the samples can show"
        )
    if e.sign_accuracy is not None and e.sign_accuracy < limits.sign_accuracy:
        reasons.append(
            f"the field's inside agrees with the reference on {100 * e.sign_accuracy:.1f}% of the box "
            f"(under {100 * limits.sign_accuracy:.0f}%)"
        )
    if e.volume is not None and e.input_volume and e.input_volume > 0:
        ratio = e.volume / e.input_volume
        if not 1 / limits.volume_ratio <= ratio <= limits.volume_ratio:
            reasons.append(f"the MAT's solid has {ratio:.2f}x the volume of the input's")
    if e.chi is not None and e.vertices is not None:
        bound = max(limits.chi_floor, int(limits.chi_per_vertex * e.vertices))
        if abs(e.chi) > bound:
            reasons.append(f"the MAT's chi {e.chi} is absurd for {e.vertices} vertices (|chi| over {bound})")
        elif e.input_chi is not None and e.chi != e.input_chi:
            reasons.append(f"the MAT's chi {e.chi} differs from the input solid's {e.input_chi}")
    st = e.structure or {}
    if st:
        shares = {
            "vertices": st["defective_vertices"] / max(st["vertices"], 1),
            "edges": st["edges_outside"] / max(st["edges"], 1),
            "faces": st["faces_outside"] / max(st["faces"], 1),
        }
        worst = max(shares, key=shares.get)
        if shares[worst] > limits.structural_share:
            reasons.append(
                f"{100 * shares[worst]:.0f}% of the MAT's {worst} contradict the shape (outside it, balls out of it "
                f"or of no radius inside it; over {100 * limits.structural_share:.0f}%): {st}"
            )
    return {"quality": "suspect" if reasons else "ok", "reasons": reasons}


def zero_set_distance(sdf_at_points: np.ndarray) -> float:
    return float(np.median(np.abs(sdf_at_points))) if len(sdf_at_points) else 0.0
