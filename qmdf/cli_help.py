"""``python -m qmdf --help``: how to call it, the config groups, and every setting with its type, default and
the schema's doc, by key path (Hydra's own help, ``--hydra-help``, dumps the config without the docs)."""

from __future__ import annotations

import dataclasses
import textwrap
from pathlib import Path

from qmdf import schema

USAGE = """usage: python -m qmdf [KEY=VALUE ...] [+experiment=NAME] [+debug=fast] [-m KEY=A,B ...]

Computes the medial axis transform of the input (a mesh or point-cloud file, input.path=..., or an embedded
shape, input.shape=...) through a neural Quasi-Medial Distance Field, one stage after another; each run writes
its own folder (hydra.run.dir=... chooses it). --cfg job prints the composed config and runs nothing;
--hydra-help shows Hydra's own options; python -m qmdf.plugins lists the stages, backbones, losses,
degradations and shapes installed."""


def _rows(cls: type, prefix: str) -> list[tuple[str, str, str]]:
    out = []
    nested = {f.name: f.metadata.get("schemas") for f in dataclasses.fields(cls)}
    for name, typ, default, doc in schema.describe(cls):
        if dataclasses.is_dataclass(default):
            out += _rows(type(default), f"{prefix}{name}.")
            continue
        if nested.get(name):  # one group per registered component, each with its own settings
            for key, settings in nested[name]().items():
                out += _rows(settings, f"{prefix}{name}.{key}.")
            continue
        shown = "{...}" if isinstance(default, dict) and default else repr(default)
        out.append((f"{prefix}{name}", f"{typ} = {shown}", doc))
    return out


def settings_rows() -> list[tuple[str, str, str]]:
    """(key path, type = default, doc) of the root settings and of every registered stage's."""
    from qmdf.config import RootConfig
    from qmdf.plugins.registry import load_all
    from qmdf.registry import STAGES

    load_all()
    rows = _rows(RootConfig, "")
    for entry in STAGES.entries():
        rows += _rows(entry.config, f"{entry.name}.")
    return rows


def config_groups(conf: Path) -> dict[str, list[str]]:
    return {
        d.name: sorted(p.stem for p in d.glob("*.yaml"))
        for d in sorted(conf.iterdir())
        if d.is_dir() and d.name != "hydra"
    }


def help_text(conf: Path, width: int = 118, expert: bool = False) -> str:
    """The help; the tuned constants of a stage's ``expert`` group as one line each unless ``expert``."""
    lines = [USAGE, "", "config groups (add with +GROUP=NAME):"]
    lines += [f"  +{group}=  {', '.join(names)}" for group, names in config_groups(conf).items()]
    lines += ["", "settings (KEY=VALUE; python -m qmdf --cfg job shows the composed values):"]
    rows = settings_rows()
    folded: set[str] = set()
    for key, typed, doc in rows:
        group = key.split(".expert.")[0] + ".expert" if ".expert." in key else None
        if group and not expert:
            if group not in folded:
                folded.add(group)
                n = sum(k.startswith(group + ".") for k, _, _ in rows)
                lines.append(f"  {group}.*  ({n} tuned constants, each with its measurement: --help-expert lists them)")
            continue
        lines.append(f"  {key}  ({typed})")
        if doc:
            lines += textwrap.wrap(doc, width, initial_indent="      ", subsequent_indent="      ")
    return "\n".join(lines) + "\n"
