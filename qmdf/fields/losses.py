"""Training losses as plugins, each with its weight in config (``train.optim.losses.NAME.weight``).

SDF from raw points, no normals: ``surface`` (|sdf| on the points), ``eikonal`` (|grad sdf| = 1 over the
volume too, so |sdf| is metric deep inside, where the medial terms read it), ``offsurface`` (pushes
|sdf| away from 0 off the points, against spurious surfaces; SIREN/DiGS); ``normal`` (off by default: the
gradient follows outward input normals, for inputs that have trustworthy ones). Medial field (DMF): ``mf_max``,
``mf_ortho``, ``mf_consis`` with the medial projection, and ``mf_maximal`` (see its doc: what pins mf).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import torch

from qmdf.registry import Registry
from qmdf.schema import param

LOSSES = Registry("loss", "qmdf.losses")


@dataclass
class Terms:
    """What every loss may read, computed once per step."""

    xs: torch.Tensor  # surface points (B, 3)
    xv: torch.Tensor  # volume points (B, 3)
    sdf_s: torch.Tensor
    sdf_v: torch.Tensor
    grad_s: torch.Tensor | None  # None unless an active term needs it (see register_loss's ``needs``)
    grad_v: torch.Tensor | None
    mf_v: torch.Tensor | None
    grad_mf_v: torch.Tensor | None
    sdf_fn: Callable[[torch.Tensor], torch.Tensor]
    progress: float  # 0 at the first step, 1 at the last
    normals_s: torch.Tensor | None = None  # outward unit normals at the surface points, when the input has them
    sdf_target_v: torch.Tensor | None = None  # signed distance at the volume points, NaN where unknown
    mf_target_v: torch.Tensor | None = None  # medial radius at the volume points (on medial rays), NaN elsewhere
    net: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]] | None = None  # x -> (sdf, mf)
    anchors: dict = field(default_factory=dict)  # named point sets beyond the batch (feature_retrain's)
    generator: Callable[[int], torch.Generator] | None = None  # salt -> this step's seeded generator
    cache: dict = field(default_factory=dict)

    def anchor(self, name: str) -> torch.Tensor | None:
        """The anchor set ``name`` (None when this training has none)."""
        value = self.anchors.get(name)
        return value if value is not None and len(value) else None


def register_loss(name: str, config: type, medial: bool = False, needs: tuple[str, ...] = ()):
    """``needs``: the gradients the term reads ("sdf", "mf"); a step computes them (with a double backward) only
    when an active term needs them, which is most of a step's cost on the CPU."""

    def deco(fn):
        fn.medial = medial
        fn.needs = needs
        return LOSSES.add(name, fn, config)

    return deco


@dataclass
class SurfaceConfig:
    weight: float = param(3000.0, ge=0, doc="mean |sdf| on the input points (SIREN/DiGS: 3e3)")


@register_loss("surface", SurfaceConfig)
def surface(t: Terms, cfg: SurfaceConfig) -> torch.Tensor:
    """The input points lie on the zero level set."""
    return t.sdf_s.abs().mean()


@dataclass
class EikonalConfig:
    weight: float = param(
        100.0,
        ge=0,
        doc="mean (|grad sdf| - 1)^2 over surface and volume samples (DiGS: 50; "
        "100 here: a more metric SDF inside, see bench field)",
    )


@register_loss("eikonal", EikonalConfig, needs=("sdf",))
def eikonal(t: Terms, cfg: EikonalConfig) -> torch.Tensor:
    """A metric SDF everywhere, deep inside included."""
    g = torch.cat([t.grad_s, t.grad_v])
    return ((g.norm(dim=-1) - 1.0) ** 2).mean()


@dataclass
class OffSurfaceConfig:
    weight: float = param(100.0, ge=0, doc="mean exp(-alpha |sdf|) on volume samples (SIREN: 1e2)")
    alpha: float = param(100.0, gt=0)


@register_loss("offsurface", OffSurfaceConfig)
def offsurface(t: Terms, cfg: OffSurfaceConfig) -> torch.Tensor:
    """No zero level set away from the points: on the volume samples without a distance target (a target says
    better, and near the surface this term would fight it)."""
    free = _unknown(t.sdf_target_v, t.sdf_v)
    if not free.any():
        return t.sdf_v.sum() * 0.0
    return torch.exp(-cfg.alpha * t.sdf_v[free].abs()).mean()


def _unknown(target: torch.Tensor | None, like: torch.Tensor) -> torch.Tensor:
    if target is None:
        return torch.ones_like(like, dtype=torch.bool)
    return ~torch.isfinite(target)


@dataclass
class SdfTargetConfig:
    weight: float = param(
        300.0,
        ge=0,
        doc="mean |sdf - d| at the volume samples with a signed distance target "
        "(the route's: winding-number sign times the distance to the input)",
    )


@register_loss("sdf_target", SdfTargetConfig)
def sdf_target(t: Terms, cfg: SdfTargetConfig) -> torch.Tensor:
    """Not in the paper: the sign and the metric inside come from the input (mesh or points), not from the
    eikonal term alone, which leaves cavities filled and |sdf| short of the depth."""
    return _l1_where_known(t.sdf_v, t.sdf_target_v)


def _l1_where_known(value: torch.Tensor, target: torch.Tensor | None) -> torch.Tensor:
    """mean |value - target| over the samples whose target is known (finite); 0 when none is."""
    known = ~_unknown(target, value)
    if not known.any():
        return value.sum() * 0.0
    return (value[known] - target[known]).abs().mean()


@dataclass
class MfTargetConfig:
    weight: float = param(
        300.0,
        ge=0,
        doc="mean |mf - r| on the medial rays (r: the radius of the medial ball behind the ray's surface point)",
    )


@register_loss("mf_target", MfTargetConfig, medial=True)
def mf_target(t: Terms, cfg: MfTargetConfig) -> torch.Tensor:
    """Not in the paper: along the ray from a surface point to its medial ball the medial field is that ball's
    radius, which pins mf where the DMF terms admit any value between |sdf| and r."""
    return _l1_where_known(t.mf_v, t.mf_target_v)


@dataclass
class NormalConfig:
    weight: float = param(
        0.0,
        ge=0,
        doc="mean (1 - cos(grad sdf, n)) at the input points with outward normals "
        "(SIREN: 1e2); 0: raw points, as the paper. Reads a mesh's face normals (turned "
        "outward) or a point file's; does nothing on points without normals",
    )


@register_loss("normal", NormalConfig, needs=("sdf",))
def normal(t: Terms, cfg: NormalConfig) -> torch.Tensor:
    """Not in the paper: the SDF's gradient follows the input's outward normals. Without them a thin plate's
    two faces, 0.02 apart, are fitted as one face of a slab ten times thicker (measured on ABC 00000329)."""
    if t.normals_s is None:
        return t.sdf_s.sum() * 0.0
    return (1.0 - torch.nn.functional.cosine_similarity(t.grad_s, t.normals_s, dim=-1)).mean()


@dataclass
class MfMaxConfig:
    weight: float = param(100.0, ge=0, doc="mean relu(|sdf| - mf)^2 (DMF: 100)")


@register_loss("mf_max", MfMaxConfig, medial=True)
def mf_max(t: Terms, cfg: MfMaxConfig) -> torch.Tensor:
    """mf >= |sdf| (paper Eq. 2)."""
    return torch.relu(t.sdf_v.abs() - t.mf_v).pow(2).mean()


@dataclass
class MfOrthoConfig:
    weight: float = param(0.03, ge=0, doc="mean (grad mf . grad sdf)^2 (DMF: 0.03)")


@register_loss("mf_ortho", MfOrthoConfig, medial=True, needs=("sdf", "mf"))
def mf_ortho(t: Terms, cfg: MfOrthoConfig) -> torch.Tensor:
    """mf is constant along the normal rays (paper Eq. 3)."""
    return (t.grad_mf_v * t.grad_v).sum(-1).pow(2).mean()


def medial_projection(t: Terms) -> torch.Tensor:
    """M_proj(x) = x + (max(mf, |sdf|) - |sdf|) * sign(sdf) grad sdf / |grad sdf| (no stop-gradient, as DMF)."""
    if "proj" not in t.cache:
        a = t.sdf_v.abs()
        direction = torch.sign(t.sdf_v)[:, None] * t.grad_v / t.grad_v.norm(dim=-1, keepdim=True).clamp_min(1e-8)
        t.cache["proj"] = t.xv + (torch.maximum(t.mf_v, a) - a)[:, None] * direction
    return t.cache["proj"]


@dataclass
class MfConsisConfig:
    weight: float = param(
        2000.0,
        ge=0,
        doc="mean (|sdf(M_proj(x))| - mf(x))^2 (DMF: 500; 2000 here ties mf to "
        "the maximal ball harder against mf_maximal's push, see bench field)",
    )


@register_loss("mf_consis", MfConsisConfig, medial=True, needs=("sdf",))
def mf_consis(t: Terms, cfg: MfConsisConfig) -> torch.Tensor:
    """mf is the radius at the projected medial point (paper Eq. 5)."""
    return (t.sdf_fn(medial_projection(t)).abs() - t.mf_v).pow(2).mean()


@dataclass
class MfMaximalConfig:
    weight: float = param(1.0, ge=0, doc="- mean(mf) inside; the consistency term caps it at the true radius")


@register_loss("mf_maximal", MfMaximalConfig, medial=True)
def mf_maximal(t: Terms, cfg: MfMaximalConfig) -> torch.Tensor:
    """Pins the medial field. Along a normal ray |sdf| grows linearly up to the medial axis, so every mf
    between |sdf| and the true radius r satisfies the three DMF terms; mf sags toward |sdf| and the minima
    of q drift off the axis. Past the axis |sdf| falls again, so consistency rises as 4 (mf - r)^2: pushing
    mf up with weight w settles at mf - r ~ w / (4 w_consis), i.e. the maximal ball, which is the definition."""
    inside = t.sdf_v < 0
    if not inside.any():
        return t.mf_v.sum() * 0.0
    return -t.mf_v[inside].mean()


@dataclass
class SharpSdfConfig:
    weight: float = param(0.0, ge=0, doc="L_sharp1: mean |sdf| at the feature points (feature_retrain sets it)")


@register_loss("sharp_sdf", SharpSdfConfig)
def sharp_sdf(t: Terms, cfg: SharpSdfConfig) -> torch.Tensor:
    """Paper Sec. 4.3, L_sharp1: the surface passes through the feature points."""
    p = t.anchor("feature_points")
    if p is None:
        return t.sdf_s.sum() * 0.0
    return _at(t, "feature_points")[0].abs().mean()


@dataclass
class SharpMfConfig:
    weight: float = param(0.0, ge=0, doc="L_sharp2: mean |mf| at the feature points (feature_retrain sets it)")


@register_loss("sharp_mf", SharpMfConfig)
def sharp_mf(t: Terms, cfg: SharpMfConfig) -> torch.Tensor:
    """Paper Sec. 4.3, L_sharp2: the medial radius vanishes at a sharp edge. |mf|, not mf: the heads are not
    sign-constrained, and a plain mean drove mf to -0.22 there (measured on the box)."""
    p = t.anchor("feature_points")
    if p is None:
        return t.sdf_s.sum() * 0.0
    return _at(t, "feature_points")[1].abs().mean()


@dataclass
class SharpMedialConfig:
    weight: float = param(
        0.0,
        ge=0,
        doc="sdf = -r and mf = r at known medial points (the sharp edges' inward bisectors; feature_retrain sets it)",
    )
    batch: int = param(4096, ge=1, doc="medial points drawn per step")


@register_loss("sharp_medial", SharpMedialConfig)
def sharp_medial(t: Terms, cfg: SharpMedialConfig) -> torch.Tensor:
    """Known medial points with their radii (not in the paper): the centre of the ball inscribed at a sharp edge
    lies on its inward bisector at depth r, with radius r."""
    p, r = t.anchor("medial_points"), t.anchor("medial_radii")
    if p is None or r is None:
        return t.sdf_s.sum() * 0.0
    pick = torch.randint(len(p), (min(cfg.batch, len(p)),), generator=t.generator(1)).to(p.device)
    sdf, mf = t.net(p[pick])
    return (sdf + r[pick]).abs().mean() + (mf - r[pick]).abs().mean()


def _at(t: Terms, name: str) -> tuple[torch.Tensor, torch.Tensor]:
    """(sdf, mf) at the anchor set ``name``, evaluated once per step."""
    if name not in t.cache:
        t.cache[name] = t.net(t.anchors[name])
    return t.cache[name]


#: The paper's route (raw points alone): the eikonal term makes the SDF metric and the DMF terms carry mf.
PAPER_TERMS = ("surface", "eikonal", "offsurface", "normal", "mf_max", "mf_ortho", "mf_consis", "mf_maximal")

#: The supervised routes (mesh, oriented or raw points): the targets carry sign, metric and mf; the terms that
#: differentiate the field (eikonal, mf_ortho, mf_consis), most of a step's cost, are off (see README: measured).
SUPERVISED_WEIGHTS = {
    "surface": 3000.0,
    "eikonal": 0.0,
    "offsurface": 100.0,
    "sdf_target": 300.0,
    "normal": 0.0,
    "mf_max": 100.0,
    "mf_ortho": 0.0,
    "mf_consis": 0.0,
    "mf_maximal": 0.0,
    "mf_target": 300.0,
}


def default_losses() -> dict:
    """train.optim.losses: the supervised routes' terms and weights."""
    return {name: {"weight": w} for name, w in SUPERVISED_WEIGHTS.items()}


def paper_losses() -> dict:
    """train.optim.paper_losses: the paper route's terms, with their configs' default weights."""
    return {name: {"weight": LOSSES.get(name).config().weight} for name in PAPER_TERMS}
