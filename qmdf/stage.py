"""What a stage is: a registered class that reads named artifacts and writes named artifacts.

Write one like this (third-party packages expose it through the ``qmdf.stages`` entry-point group)::

    @dataclass
    class SmoothConfig:
        iterations: int = param(10, ge=1)

    @register_stage("smooth")
    class Smooth(Stage):
        Config = SmoothConfig
        inputs = {"points": POINTS}
        outputs = {"smoothed": POINTS}

        def run(self, ctx):
            pts = ctx.load("points")
            ctx.save("smoothed", my_smoothing(pts, ctx.cfg.iterations))
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from qmdf.artifacts import ArtifactKind, write_atomic
from qmdf.errors import PipelineError
from qmdf.registry import STAGES


@dataclass
class NoConfig:
    """A stage without settings."""


@dataclass(frozen=True)
class RunSettings:
    """What every stage may read besides its own section: the seed, the input, and the caller's directory."""

    seed: int
    input: Any  # qmdf.config.InputConfig
    base_dir: Path  # relative paths in the config resolve against this (the caller's directory)
    run_dir: Path


class Stage:
    """Base class of every stage. Subclasses set the class attributes and implement ``run``."""

    name: ClassVar[str] = ""
    Config: ClassVar[type] = NoConfig
    inputs: ClassVar[Mapping[str, ArtifactKind]] = {}
    optional_inputs: ClassVar[Mapping[str, ArtifactKind]] = {}
    outputs: ClassVar[Mapping[str, ArtifactKind]] = {}
    optional_outputs: ClassVar[Mapping[str, ArtifactKind]] = {}
    #: Top-level config sections besides the stage's own that change its result (they enter the cache key).
    config_deps: ClassVar[tuple[str, ...]] = ("seed",)
    #: Bump when the stage's code changes its results, so that old cache entries are not reused.
    version: ClassVar[str] = "1"

    @classmethod
    def cache_config(cls, section: dict) -> dict:
        """The part of the stage's config section that its result depends on, for the cache key (all of it,
        unless a stage knows better: train hashes only the chosen backbone's settings)."""
        return section

    def fingerprint(self, ctx: "StageContext") -> str:
        """Extra cache-key material that the config does not capture (e.g. an input file's content)."""
        return ""

    def run(self, ctx: "StageContext") -> None:  # pragma: no cover - abstract
        raise NotImplementedError


def register_stage(name: str):
    """Class decorator: register a stage under ``name`` (the key of its config section too)."""

    def deco(cls: type[Stage]) -> type[Stage]:
        if not (isinstance(cls, type) and issubclass(cls, Stage)):
            raise TypeError(f"@register_stage('{name}') expects a Stage subclass, got {cls!r}")
        cls.name = name
        return STAGES.add(name, cls, cls.Config)

    return deco


@dataclass
class StageContext:
    """A stage's view of the run: its typed config, its input artifacts and the folder it writes into."""

    stage: Stage
    cfg: Any
    settings: RunSettings
    stage_dir: Path
    input_paths: Mapping[str, Path]
    log: logging.Logger
    #: Scratch that survives a failed or interrupted run of the same cache key (checkpoints to resume from);
    #: the pipeline removes it once the stage succeeds.
    work_dir: Path | None = None
    written: dict[str, Path] = field(default_factory=dict)
    #: typed settings of the other stages named in the stage's config_deps (feature_retrain reads train's)
    sections: Mapping[str, Any] = field(default_factory=dict)
    #: what the stage decided that a reader of the manifest should see (train's supervision route); stored as
    #: notes.json in the stage folder, so a cached result carries it too
    notes: dict = field(default_factory=dict)
    #: where the stage's outputs land once it succeeds (stage_dir is a scratch folder while it runs): the folder
    #: to name in a message
    output_dir: Path | None = None

    @property
    def seed(self) -> int:
        return self.settings.seed

    def rng(self, salt: str = "") -> np.random.Generator:
        """A generator seeded by the run seed and the stage name, so stages draw independent streams."""
        key = [self.settings.seed] + [ord(c) for c in f"{self.stage.name}/{salt}"]
        return np.random.default_rng(key)

    def has(self, name: str) -> bool:
        return name in self.input_paths

    def _kind(self, name: str, table: str) -> ArtifactKind:
        decl = getattr(self.stage, table)
        opt = getattr(self.stage, f"optional_{table}")
        if name in decl:
            return decl[name]
        if name in opt:
            return opt[name]
        raise PipelineError(f"stage '{self.stage.name}' did not declare {table[:-1]} artifact '{name}'")

    def load(self, name: str) -> Any:
        kind = self._kind(name, "inputs")
        if name not in self.input_paths:
            raise PipelineError(f"stage '{self.stage.name}': optional input '{name}' is not available")
        path = self.input_paths[name]
        return kind.load(path) if kind.load else path

    def path(self, name: str) -> Path:
        """Where to write output ``name`` yourself (for FILE artifacts); the pipeline records it."""
        kind = self._kind(name, "outputs")
        path = self.stage_dir / f"{name}{kind.suffix}"
        self.written[name] = path
        return path

    def save(self, name: str, value: Any) -> Path:
        kind = self._kind(name, "outputs")
        if kind.save is None:
            raise PipelineError(f"artifact '{name}' is written by the stage itself: write it at ctx.path('{name}')")
        path = self.stage_dir / f"{name}{kind.suffix}"
        write_atomic(path, lambda tmp: kind.save(value, tmp))
        self.written[name] = path
        return path
