"""Training losses as plugins, each with its weight in config (``train.losses.NAME.weight``).

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
    grad_s: torch.Tensor
    grad_v: torch.Tensor
    mf_v: torch.Tensor | None
    grad_mf_v: torch.Tensor | None
    sdf_fn: Callable[[torch.Tensor], torch.Tensor]
    progress: float  # 0 at the first step, 1 at the last
    normals_s: torch.Tensor | None = None  # outward unit normals at the surface points, when the input has them
    cache: dict = field(default_factory=dict)


def register_loss(name: str, config: type, medial: bool = False):
    def deco(fn):
        fn.medial = medial
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
    weight: float = param(100.0, ge=0, doc="mean (|grad sdf| - 1)^2 over surface and volume samples (DiGS: 50; "
                                           "100 here: a more metric SDF inside, see bench field)")


@register_loss("eikonal", EikonalConfig)
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
    """No zero level set away from the points."""
    return torch.exp(-cfg.alpha * t.sdf_v.abs()).mean()


@dataclass
class NormalConfig:
    weight: float = param(0.0, ge=0, doc="mean (1 - cos(grad sdf, n)) at the input points with outward normals "
                                         "(SIREN: 1e2); 0: raw points, as the paper. Reads a mesh's face normals (turned "
                                         "outward) or a point file's; does nothing on points without normals")


@register_loss("normal", NormalConfig)
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


@register_loss("mf_ortho", MfOrthoConfig, medial=True)
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
    weight: float = param(2000.0, ge=0, doc="mean (|sdf(M_proj(x))| - mf(x))^2 (DMF: 500; 2000 here ties mf to "
                                            "the maximal ball harder against mf_maximal's push, see bench field)")


@register_loss("mf_consis", MfConsisConfig, medial=True)
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


def default_losses() -> dict:
    return {name: {"weight": LOSSES.get(name).config().weight} for name in
            ("surface", "eikonal", "offsurface", "normal", "mf_max", "mf_ortho", "mf_consis", "mf_maximal")}
