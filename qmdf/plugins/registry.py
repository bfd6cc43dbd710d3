"""Discovery: the built-in components and every installed plugin's, imported into the registries once
(``qmdf.registry`` holds the registries themselves and imports nothing of qmdf's)."""

from __future__ import annotations

from qmdf.registry import DEGRADATIONS, SHAPES, SHEET_STEPS, STAGES, Registry

_BUILTIN_MODULES = (
    "qmdf.geometry.shapes",
    "qmdf.geometry.degradations",
    "qmdf.fields.backbones",
    "qmdf.fields.losses",
    "qmdf.medial.steps",
    "qmdf.stages.sample",
    "qmdf.stages.train",
    "qmdf.stages.analytic_field",
    "qmdf.stages.cover",
    "qmdf.stages.tetrahedralize",
    "qmdf.stages.contract",
    "qmdf.stages.sheet",
    "qmdf.stages.export",
    "qmdf.stages.evaluate",
    "qmdf.stages.feature_detect",
    "qmdf.stages.feature_retrain",
)

_loaded = False


def load_all() -> None:
    """Import the built-in components and every installed plugin (once)."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    import importlib

    for mod in _BUILTIN_MODULES:
        importlib.import_module(mod)
    for reg in all_registries():
        reg.load_entry_points()


def all_registries() -> tuple[Registry, ...]:
    """Every registry, the field's too (they live beside the torch code that fills them)."""
    from qmdf.fields.backbones import BACKBONES
    from qmdf.fields.losses import LOSSES

    return (STAGES, DEGRADATIONS, SHAPES, BACKBONES, LOSSES, SHEET_STEPS)
