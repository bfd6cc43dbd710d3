"""The stage registry: decorators, duplicates, broken plugins reported with their real error."""

from __future__ import annotations

import textwrap

import pytest

from qmdf.errors import PipelineError
from qmdf.registry import Registry


def _write_dist(site, dist, module_src, entry_points):
    """A minimal installed distribution (dist-info + module) that importlib.metadata discovers on sys.path."""
    pkg = site / dist
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(textwrap.dedent(module_src))
    info = site / f"{dist}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
    lines = "\n".join(f"{k} = {v}" for k, v in entry_points.items())
    (info / "entry_points.txt").write_text(f"[qmdf.test_components]\n{lines}\n")


def test_decorator_and_lookup():
    reg = Registry("widget", "qmdf.test_components")

    @reg.register("a")
    def make_a():
        """Makes an a."""

    assert reg.get("a").obj is make_a and reg.get("a").doc == "Makes an a."
    assert "built-in" in reg.get("a").origin
    with pytest.raises(PipelineError, match="unknown widget 'b'"):
        reg.get("b")


def test_duplicate_names_are_refused():
    reg = Registry("widget", "qmdf.test_components")
    reg.add("a", object())
    with pytest.raises(PipelineError, match="registered twice"):
        reg.add("a", object())


def test_reserved_names_are_refused():
    from qmdf.registry import RESERVED

    reg = Registry("stage", "qmdf.test_components", reserved=RESERVED)
    with pytest.raises(PipelineError, match="reserved"):
        reg.add("input", object())


def test_entry_points_good_and_broken(tmp_path, monkeypatch):
    site = tmp_path / "site"
    _write_dist(site, "good_plugin", "def thing():\n    '''A good thing.'''\n", {"good": "good_plugin:thing"})
    _write_dist(site, "bad_plugin", "import a_dependency_that_is_not_installed\n", {"bad": "bad_plugin:thing"})
    monkeypatch.syspath_prepend(str(site))
    reg = Registry("widget", "qmdf.test_components")
    reg.load_entry_points()
    good = reg.get("good")
    assert good.doc == "A good thing." and "good_plugin 0.1" in good.origin
    with pytest.raises(PipelineError) as err:
        reg.get("bad")
    msg = str(err.value)
    assert "widget plugin 'bad'" in msg and "bad_plugin 0.1" in msg
    assert "ModuleNotFoundError: No module named 'a_dependency_that_is_not_installed'" in msg
    assert reg.broken()[0].details.startswith("Traceback")
