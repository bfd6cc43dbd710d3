"""Input degradations, composable by config under ``sample.degradations`` (applied in the order listed).

Each one takes the clean point set and a seeded generator and returns a degraded point set. Distances are
fractions of the bounding-box diagonal of the normalised input, so settings transfer between shapes.

    python -m qmdf +sample.degradations.subsample.n=2000 +sample.degradations.noise.sigma=0.0025
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from qmdf.geometry.pointset import PointSet
from qmdf.registry import DEGRADATIONS
from qmdf.schema import param

Degradation = Callable[[PointSet, object, np.random.Generator], PointSet]


def register_degradation(name: str, config: type):
    def deco(fn: Degradation) -> Degradation:
        return DEGRADATIONS.add(name, fn, config)

    return deco


def _unit(v: list[float], what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    n = np.linalg.norm(a)
    if a.shape != (3,) or not n > 0:
        raise ValueError(f"{what} must be a non-zero 3-vector")
    return a / n


def _check_vec3(v: Optional[list[float]], key: str) -> list[tuple[str, str]]:
    if v is None:
        return []
    if len(v) != 3 or not np.linalg.norm(np.asarray(v, float)) > 0:
        return [(key, f"must be a non-zero 3-vector, got {v}")]
    return []


@dataclass
class SubsampleConfig:
    n: int = param(2000, ge=1, doc="keep this many points, drawn uniformly without replacement")


@register_degradation("subsample", SubsampleConfig)
def subsample(points: PointSet, cfg: SubsampleConfig, rng: np.random.Generator) -> PointSet:
    """Sparse input: keep n points chosen uniformly at random."""
    if cfg.n >= len(points):
        return points
    return points.subset(np.sort(rng.choice(len(points), size=cfg.n, replace=False)))


@dataclass
class NonUniformConfig:
    axis: list[float] = param(factory=lambda: [1.0, 0.0, 0.0], doc="density grows along this direction")
    min_keep: float = param(0.1, gt=0, le=1, doc="keep probability at the sparse end (1 at the dense end)")
    power: float = param(1.0, gt=0, doc="shape of the ramp between the ends")

    def check(self) -> list[tuple[str, str]]:
        return _check_vec3(self.axis, "axis")


@register_degradation("nonuniform", NonUniformConfig)
def nonuniform(points: PointSet, cfg: NonUniformConfig, rng: np.random.Generator) -> PointSet:
    """Non-uniform density: keep probability ramps from min_keep to 1 along an axis."""
    t = points.points @ _unit(cfg.axis, "axis")
    t = (t - t.min()) / max(float(np.ptp(t)), 1e-12)
    keep_p = cfg.min_keep + (1.0 - cfg.min_keep) * t**cfg.power
    return points.subset(rng.random(len(points)) < keep_p)


@dataclass
class NoiseConfig:
    sigma: float = param(0.0025, ge=0, doc="Gaussian noise std as a fraction of the bbox diagonal (paper: 0.001-0.005)")


@register_degradation("noise", NoiseConfig)
def noise(points: PointSet, cfg: NoiseConfig, rng: np.random.Generator) -> PointSet:
    """Gaussian noise on every coordinate; each point keeps its normal (the clean surface's: add drop_normals
    to simulate a raw scan)."""
    sigma = cfg.sigma * points.bbox_diagonal
    return points.with_points(points.points + rng.normal(0.0, sigma, size=points.points.shape))


@dataclass
class MissingRegionConfig:
    mode: str = param("ball", choices=("ball", "halfspace"), doc="cut balls around surface points, or a half-space")
    count: int = param(1, ge=1, doc="ball mode: number of holes")
    radius: float = param(0.1, gt=0, doc="ball mode: hole radius as a fraction of the bbox diagonal")
    centers: Optional[list[list[float]]] = param(
        None, doc="ball mode: hole centres (normalised frame); default: random input points"
    )
    normal: list[float] = param(
        factory=lambda: [0.0, 0.0, 1.0], doc="halfspace mode: remove points with x.normal > offset"
    )
    offset: float = param(0.25, doc="halfspace mode: offset along the normal (normalised frame)")

    def check(self) -> list[tuple[str, str]]:
        problems = _check_vec3(self.normal, "normal")
        for i, c in enumerate(self.centers or []):
            if len(c) != 3:
                problems.append((f"centers[{i}]", f"must be a 3-vector, got {c}"))
        return problems


@register_degradation("missing_region", MissingRegionConfig)
def missing_region(points: PointSet, cfg: MissingRegionConfig, rng: np.random.Generator) -> PointSet:
    """Incomplete input: remove balls around surface points, or everything beyond a plane."""
    p = points.points
    if cfg.mode == "halfspace":
        return points.subset(p @ _unit(cfg.normal, "normal") <= cfg.offset)
    centers = np.asarray(cfg.centers, float) if cfg.centers else p[rng.choice(len(p), size=cfg.count, replace=False)]
    r = cfg.radius * points.bbox_diagonal
    keep = np.ones(len(p), dtype=bool)
    for c in centers:
        keep &= np.linalg.norm(p - c, axis=1) > r
    return points.subset(keep)


@dataclass
class DropNormalsConfig:
    enabled: bool = param(True, doc="forget the points' normals: a raw scan (train then estimates and orients them)")


@register_degradation("drop_normals", DropNormalsConfig)
def drop_normals(points: PointSet, cfg: DropNormalsConfig, rng: np.random.Generator) -> PointSet:
    """Raw input: the points without their normals."""
    return PointSet(points.points) if cfg.enabled else points
