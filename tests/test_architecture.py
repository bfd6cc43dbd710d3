"""Imports run one way: the library layer (geometry, medial, fields: plain functions over arrays) never imports
the stages, the pipeline, the benchmarks or plugin discovery that sit on top of it, and the registry is a leaf.
Read from the source (every import, inside functions too), so a lazy upward import cannot hide."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "qmdf"
LIBRARY = ("qmdf.geometry", "qmdf.medial", "qmdf.fields")
ABOVE_THE_LIBRARY = (
    "qmdf.stages",
    "qmdf.stage",
    "qmdf.pipeline",
    "qmdf.bench",
    "qmdf.api",
    "qmdf.plugins",
    "qmdf.config",
    "qmdf.__main__",
    "qmdf.sweep",
    "qmdf.evaluate",
    "qmdf.view",
)


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return {m for m in out if m == "qmdf" or m.startswith("qmdf.")}


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


MODULES = {_module_name(p): _imports(p) for p in PACKAGE.rglob("*.py")}


def test_the_library_layer_imports_nothing_above_it():
    bad = {
        m: sorted(i for i in imps if _within(i, ABOVE_THE_LIBRARY))
        for m, imps in MODULES.items()
        if _within(m, LIBRARY)
    }
    assert not {m: i for m, i in bad.items() if i}, "library modules importing the layers above them"


def test_the_registry_is_a_leaf():
    assert MODULES["qmdf.registry"] <= {"qmdf.errors", "qmdf.errors.PipelineError"}
    assert MODULES["qmdf.errors"] == set()


def test_every_module_was_read():
    assert {"qmdf.medial.contraction", "qmdf.medial.covering", "qmdf.fields.fitting", "qmdf.stages.contract"} <= set(
        MODULES
    )


def test_the_import_graph_command_shows_no_upward_import(tmp_path):
    from qmdf.plugins.__main__ import import_graph, imports_listing

    assert imports_listing(PACKAGE).splitlines()[-1].endswith(": none")
    # a library module that reaches a stage is reported
    (tmp_path / "qmdf" / "geometry").mkdir(parents=True)
    (tmp_path / "qmdf" / "geometry" / "bad.py").write_text("def f():\n    from qmdf.stages.sample import Sample\n")
    assert import_graph(tmp_path / "qmdf") == {"geometry": {"stages": 1}}
    assert imports_listing(tmp_path / "qmdf").splitlines()[-1].endswith("geometry -> stages (1)")


def _resolved(imports: set[str]) -> set[str]:
    """Each import as the module it reads (``qmdf.geometry.metrics.unique_edges`` -> ``qmdf.geometry.metrics``)."""
    out = set()
    for name in imports:
        while name not in MODULES and "." in name:
            name = name.rsplit(".", 1)[0]
        if name in MODULES:
            out.add(name)
    return out


def import_cycles(modules: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan), packages' ``__init__`` left out: importing
    ``qmdf.x`` runs ``qmdf/__init__`` first whoever asks, so a package that re-exports its members is no circle."""
    graph = {m: {i for i in _resolved(imps) if i != m and i in modules} for m, imps in modules.items()}
    packages = {m for m in graph if (PACKAGE.parent / m.replace(".", "/") / "__init__.py").exists()}
    graph = {m: deps - packages for m, deps in graph.items() if m not in packages}
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return groups


def test_no_import_circles():
    assert import_cycles(MODULES) == []
    # a circle through a function-local import is found
    assert import_cycles({"qmdf.stage": {"qmdf.pipeline"}, "qmdf.pipeline": {"qmdf.stage.Stage"}}) == [
        ["qmdf.pipeline", "qmdf.stage"]
    ]


def test_the_report_reads_the_papers_table_without_the_benchmarks():
    assert not any(_within(i, ("qmdf.bench",)) for i in MODULES["qmdf.report"])


def _functions(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef):
            a = node.args
            count = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + bool(a.vararg) + bool(a.kwarg)
            count -= bool(a.args) and a.args[0].arg in ("self", "cls")
            yield node.name, count, node.end_lineno - node.lineno + 1


def test_the_house_stays_small():
    """Every stage module at most 150 lines, no library function with more than 12 parameters (settings travel
    as one dataclass), no function in qmdf/medial over 80 lines."""
    stages = {p.name: len(p.read_text().splitlines()) for p in (PACKAGE / "stages").glob("*.py")}
    assert {k: n for k, n in stages.items() if n > 150} == {}
    library = [p for prefix in LIBRARY for p in (PACKAGE / prefix.split(".")[1]).rglob("*.py")]
    wide = {f"{p.name}:{name}": n for p in library for name, n, _ in _functions(p) if n > 12}
    assert wide == {}
    long = {f"{p.name}:{name}": n for p in (PACKAGE / "medial").glob("*.py") for name, _, n in _functions(p) if n > 80}
    assert long == {}
