"""``python -m qmdf.plugins``: every registered stage and component, and where it came from.
``python -m qmdf.plugins --imports [PACKAGE_DIR]``: the import graph between qmdf's layers, read from the source."""

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


#: qmdf's layers, bottom to top: each may import those before it, never those after
LAYERS = ("errors", "registry", "geometry", "fields", "medial", "stages", "pipeline", "bench", "api", "view")


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "qmdf"


def import_graph(package_dir) -> dict[str, dict[str, int]]:
    """{layer: {layer it imports: how many import statements}}, every import counted (inside functions too)."""
    import ast
    from pathlib import Path

    root = Path(package_dir)
    graph: dict[str, dict[str, int]] = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).with_suffix("")
        here = _layer(".".join(rel.parts))
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for name in names:
                if name.startswith("qmdf.") and _layer(name) != here:
                    edges = graph.setdefault(here, {})
                    edges[_layer(name)] = edges.get(_layer(name), 0) + 1
    return graph


def imports_listing(package_dir) -> str:
    """The graph as lines, and the imports that go up the layers (a library module reaching a stage, say)."""
    graph = import_graph(package_dir)
    rank = {name: i for i, name in enumerate(LAYERS)}
    lines, upward = [], []
    for here in sorted(graph, key=lambda n: (rank.get(n, len(LAYERS)), n)):
        targets = graph[here]
        lines.append(f"{here:<10} -> " + ", ".join(f"{t} ({n})" for t, n in sorted(targets.items())))
        upward += [f"{here} -> {t} ({n})" for t, n in targets.items() if rank.get(t, -1) > rank.get(here, len(LAYERS))]
    lines.append("upward imports (a lower layer reaching a higher one): " + (", ".join(upward) or "none"))
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--imports":
        from pathlib import Path

        sys.stdout.write(imports_listing(sys.argv[2] if len(sys.argv) > 2 else Path(__file__).resolve().parents[1]))
    else:
        sys.stdout.write(listing())
