"""``python -m qmdf.plugins``: every registered stage and component, and where it came from."""

from __future__ import annotations

import sys

from qmdf.config import BUILTIN_STAGES
from qmdf.plugins.registry import all_registries, load_all
from qmdf.registry import STAGES


def listing() -> str:
    load_all()
    lines = []
    for reg in all_registries():
        plural = reg.kind + ("es" if reg.kind.endswith("s") else "s")
        lines.append(f"{plural} (entry-point group '{reg.group}'):")
        for e in reg.entries():
            io = ""
            if reg is STAGES:
                ins = ", ".join(list(e.obj.inputs) + [f"{n}?" for n in e.obj.optional_inputs]) or "-"
                outs = ", ".join(list(e.obj.outputs) + [f"{n}?" for n in e.obj.optional_outputs])
                io = f"  [{ins} -> {outs}]"
            lines.append(f"  {e.name:<16} {e.doc}{io}")
            lines.append(f"  {'':<16} from {e.origin}")
        for b in reg.broken():
            lines.append(f"  {b.name:<16} BROKEN: {b.error}")
            lines.append(f"  {'':<16} from {b.origin}")
        if reg is STAGES:
            missing = [n for n in BUILTIN_STAGES if n not in STAGES]
            if missing:
                lines.append(f"  not available in this version: {', '.join(missing)}")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.stdout.write(listing())
