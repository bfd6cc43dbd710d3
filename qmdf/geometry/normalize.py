"""The unit-box normalisation of the paper (Sec. 5.1), kept so outputs can go back to the input's units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Normalization:
    """``unit = (x - center) * scale``: the bounding box is centred at the origin, its longest side is 1."""

    center: tuple[float, float, float]
    scale: float

    @classmethod
    def fit(cls, points: np.ndarray) -> "Normalization":
        lo, hi = points.min(axis=0), points.max(axis=0)
        extent = float((hi - lo).max())
        if not extent > 0:
            raise ValueError("cannot normalise a point set with zero extent")
        return cls(tuple(float(c) for c in (lo + hi) / 2), 1.0 / extent)

    @classmethod
    def identity(cls) -> "Normalization":
        return cls((0.0, 0.0, 0.0), 1.0)

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - np.asarray(self.center)) * self.scale

    def to_input(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) / self.scale + np.asarray(self.center)

    def length_to_input(self, lengths: np.ndarray | float) -> np.ndarray | float:
        """Radii and distances scale by 1/scale; they do not shift."""
        return np.asarray(lengths) / self.scale if not np.isscalar(lengths) else lengths / self.scale

    def to_dict(self) -> dict:
        return {
            "center": list(self.center),
            "scale": self.scale,
            "convention": "unit = (input - center) * scale; input = unit / scale + center",
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Normalization":
        return cls(tuple(float(c) for c in d["center"]), float(d["scale"]))
