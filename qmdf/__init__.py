"""qmdf: medial axis transforms of meshes and point clouds through a neural Quasi-Medial Distance Field."""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__", "medial_axis", "run"]


def __getattr__(name: str):
    # The API pulls in Hydra and the stages; keep `import qmdf` itself light.
    if name in ("medial_axis", "run", "MedialAxis"):
        from qmdf import api

        return getattr(api, name)
    raise AttributeError(name)
