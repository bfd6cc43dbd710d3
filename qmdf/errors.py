"""Errors a user can cause. They end a run with one clear message and a non-zero exit, never a traceback."""

from __future__ import annotations

from dataclasses import dataclass


class QmdfError(Exception):
    """A problem with the user's input, configuration or plugins, explained in the message."""

    exit_code = 2


@dataclass(frozen=True)
class Problem:
    """One configuration problem, located by its key path (``sample.n_points``)."""

    key: str
    message: str

    def __str__(self) -> str:
        return f"{self.key}: {self.message}"


class ConfigError(QmdfError):
    """Every problem found in a configuration, listed by key path."""

    def __init__(self, problems: list[Problem]):
        self.problems = list(problems)
        lines = "\n".join(f"  - {p}" for p in self.problems)
        n = len(self.problems)
        super().__init__(f"invalid configuration ({n} problem{'s' if n != 1 else ''}):\n{lines}")


class InputError(QmdfError):
    """The input file or point set cannot be used."""


class PipelineError(QmdfError):
    """The configured pipeline cannot run (unknown stage, broken wiring, broken plugin)."""


class Interrupted(QmdfError):
    """The user (Ctrl-C: SIGINT) or a scheduler (SIGTERM) stopped the run; what could be kept was kept."""

    def __init__(self, message: str, signal_number: int):
        super().__init__(message)
        self.exit_code = 128 + signal_number  # the shell's convention: 130 for SIGINT, 143 for SIGTERM
