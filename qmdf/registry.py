"""Name -> component registries, filled by decorators (built-ins) and by entry points (third parties).

A third-party package exposes components through entry-point groups in its own pyproject, e.g.::

    [project.entry-points."qmdf.stages"]
    smooth = "my_pkg.stages:SmoothStage"

The entry point may name the object itself or a module whose decorators register it. A plugin that fails to
import is recorded with its real error and traceback, and reported by name when something asks for it;
it never hides behind a generic "not found".
"""

from __future__ import annotations

import contextvars
import difflib
import importlib.metadata as metadata
import logging
import traceback
import types
from dataclasses import dataclass
from typing import Any, Callable, Iterator

from qmdf.errors import PipelineError

log = logging.getLogger(__name__)

#: Where the component currently being registered comes from (set while an entry point loads).
_origin: contextvars.ContextVar[str | None] = contextvars.ContextVar("qmdf_origin", default=None)


@dataclass(frozen=True)
class Entry:
    name: str
    obj: Any
    origin: str
    config: type | None = None
    doc: str = ""


@dataclass(frozen=True)
class BrokenPlugin:
    name: str
    origin: str
    error: str
    details: str


def _first_doc_line(obj: Any) -> str:
    """The docstring's first sentence, joined across its wrapped lines (its first paragraph if it has no stop)."""
    doc = (getattr(obj, "__doc__", None) or "").strip()
    paragraph = " ".join(line.strip() for line in doc.split("\n\n")[0].splitlines())
    end = paragraph.find(". ")
    return paragraph[: end + 1] if end >= 0 else paragraph


class Registry:
    """One kind of component (stage, degradation, shape...) and the entry-point group that extends it."""

    def __init__(self, kind: str, group: str, reserved: frozenset[str] = frozenset()):
        self.kind = kind
        self.group = group
        self.reserved = reserved
        self._entries: dict[str, Entry] = {}
        self._broken: dict[str, BrokenPlugin] = {}
        self._entry_points_loaded = False

    # -- registration -------------------------------------------------------------------------
    def add(self, name: str, obj: Any, config: type | None = None, origin: str | None = None) -> Any:
        if name in self.reserved:
            raise PipelineError(f"cannot register {self.kind} '{name}': the name is reserved")
        origin = origin or _origin.get() or f"{getattr(obj, '__module__', '?')} (built-in)"
        old = self._entries.get(name)
        if old is not None and old.obj is not obj:
            raise PipelineError(f"{self.kind} '{name}' is registered twice: by {old.origin} and by {origin}")
        self._entries[name] = Entry(name, obj, origin, config, _first_doc_line(obj))
        return obj

    def register(self, name: str, config: type | None = None) -> Callable[[Any], Any]:
        """Decorator: ``@STAGES.register("cover")``."""

        def deco(obj: Any) -> Any:
            return self.add(name, obj, config if config is not None else getattr(obj, "Config", None))

        return deco

    def remove(self, name: str) -> None:
        """Forget a component (tests and interactive sessions)."""
        self._entries.pop(name, None)
        self._broken.pop(name, None)

    # -- entry points -------------------------------------------------------------------------
    def load_entry_points(self, force: bool = False) -> None:
        if self._entry_points_loaded and not force:
            return
        self._entry_points_loaded = True
        for ep in metadata.entry_points(group=self.group):
            dist = getattr(ep, "dist", None)
            where = f"entry point '{ep.name} = {ep.value}'"
            if dist is not None:
                where += f" of {dist.metadata['Name']} {dist.version}"
            token = _origin.set(where)
            try:
                obj = ep.load()
            except Exception as exc:  # a plugin's own bug must not take qmdf down, but must be visible
                self._broken[ep.name] = BrokenPlugin(
                    ep.name, where, f"{type(exc).__name__}: {exc}", traceback.format_exc()
                )
                log.debug("plugin %s failed to load", ep.name, exc_info=True)
                continue
            finally:
                _origin.reset(token)
            if not isinstance(obj, types.ModuleType) and ep.name not in self._entries:
                self.add(ep.name, obj, getattr(obj, "Config", None), origin=where)

    # -- lookup ------------------------------------------------------------------------------
    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def get(self, name: str) -> Entry:
        if name in self._entries:
            return self._entries[name]
        raise PipelineError(self.why_missing(name))

    def why_missing(self, name: str) -> str:
        if name in self._broken:
            b = self._broken[name]
            return f"{self.kind} plugin '{name}' ({b.origin}) failed to load: {b.error}"
        close = difflib.get_close_matches(name, list(self._entries), n=1)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        known = ", ".join(sorted(self._entries)) or "none"
        return f"unknown {self.kind} '{name}'{hint} (registered: {known})"

    def names(self) -> list[str]:
        return sorted(self._entries)

    def entries(self) -> Iterator[Entry]:
        return iter(sorted(self._entries.values(), key=lambda e: e.name))

    def broken(self) -> list[BrokenPlugin]:
        return sorted(self._broken.values(), key=lambda b: b.name)


RESERVED = frozenset({"seed", "input", "pipeline", "cache", "hydra", "run"})

STAGES = Registry("stage", "qmdf.stages", reserved=RESERVED)
DEGRADATIONS = Registry("degradation", "qmdf.degradations")
SHAPES = Registry("shape", "qmdf.shapes")
SHEET_STEPS = Registry("sheet step", "qmdf.sheet_steps")
