"""The sheet's refinement as registered steps: one keep-if-better rule, steps by config, one source of defaults,
a step added by a plugin without editing qmdf."""

from __future__ import annotations

import inspect
import json
import logging
import textwrap
from dataclasses import dataclass

import numpy as np
import pytest

from conftest import FAST, manifests
from qmdf.medial.refinement import MAT, SheetData, refine, sheet_step
from qmdf.registry import SHEET_STEPS
from qmdf.schema import param


class _JudgedByRadius(SheetData):
    """Data whose 'CD' is how far the largest radius lies from 0.06 (no envelope measured)."""

    def chamfer(self, mat):
        return abs(float(mat.radii.max()) - 0.06)


def _data(**kw):
    return _JudgedByRadius(
        None,
        None,
        lambda q: np.ones(len(q), bool),
        lambda: None,
        **{"target_vertices": 0, "tolerance": 1e-3, "tip_reach": 0.003, "compact_slack": 1.5, **kw},
    )


def _triangle(radius=0.05):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    return MAT(v, np.full(3, radius), np.zeros((0, 2), np.int64), np.array([[0, 1, 2]]))


@dataclass
class _Scale:
    by: float = param(1.0, gt=0)


@pytest.fixture
def scaling_steps():
    """Two throwaway steps that scale every radius: one judged by the keep rule, one not."""

    def scale(mat, data, cfg):
        return mat._replace(radii=mat.radii * cfg.by), {"scaled": cfg.by}

    def judged(mat, data, cfg):
        return scale(mat, data, cfg)

    sheet_step("test_judged_scale", _Scale, keep_if_better=True, needs_data=False, summary="x{scaled}")(judged)
    sheet_step("test_plain_scale", _Scale, needs_data=False)(scale)
    yield {n: SHEET_STEPS.get(n).obj.sheet_step for n in ("test_judged_scale", "test_plain_scale")}
    SHEET_STEPS.remove("test_judged_scale")
    SHEET_STEPS.remove("test_plain_scale")


def test_a_judged_step_is_kept_only_where_the_fit_is_no_worse(scaling_steps, caplog):
    judged, plain = scaling_steps["test_judged_scale"], scaling_steps["test_plain_scale"]
    caplog.set_level(logging.INFO)
    mat, stats, cd = refine(_triangle(), _data(), [(judged, _Scale(1.2))])  # 0.05 -> 0.06: better
    assert np.allclose(mat.radii, 0.06) and stats["test_judged_scale"]["kept"] and cd == pytest.approx(0.0)
    assert "test_judged_scale: x1.2" in caplog.text and "kept" in caplog.text
    mat, stats, cd = refine(_triangle(), _data(), [(judged, _Scale(2.0))])  # 0.05 -> 0.10: worse, undone
    s = stats["test_judged_scale"]
    assert np.allclose(mat.radii, 0.05) and s["kept"] is False and cd == pytest.approx(0.01)
    assert s["cd_before"] == pytest.approx(0.01) and s["cd_after"] == pytest.approx(0.04)
    # a step not judged is kept whatever it does, and the CD is unknown after it
    mat, stats, cd = refine(_triangle(), _data(), [(plain, _Scale(2.0))])
    assert np.allclose(mat.radii, 0.1) and "kept" not in stats["test_plain_scale"] and cd is None
    # in order: the plain step's result is what the judged one is compared with
    mat, stats, cd = refine(_triangle(), _data(), [(plain, _Scale(2.0)), (judged, _Scale(0.6))])
    assert np.allclose(mat.radii, 0.06) and stats["test_judged_scale"]["cd_before"] == pytest.approx(0.04)


def test_the_keep_rule_keeps_ties_and_takes_a_slack():
    from qmdf.medial.coverage import keeps

    assert keeps(1.0, 1.0) and keeps(0.9, 1.0) and not keeps(1.1, 1.0)
    assert keeps(2.9, 1.0, slack=3.0) and not keeps(3.1, 1.0, slack=3.0)


def test_steps_that_need_the_data_are_left_out_where_the_radii_come_from_the_field():
    from qmdf.medial.steps import resolve_steps

    names = ["simplify", "centre", "coverage", "rims", "fit"]
    assert [s.name for s, _ in resolve_steps(names, {}, True)] == names
    assert [s.name for s, _ in resolve_steps(names, {}, False)] == ["simplify"]
    (_, fit), *_ = resolve_steps(["fit"], {"fit": {"iterations": 9}}, True)
    assert fit.iterations == 9 and fit.damping == 0.12


def test_the_sheets_config_names_a_wrong_step_or_setting_by_its_key_path(compose_cfg):
    from qmdf.config import validate

    problems = {
        p.key: p.message
        for p in validate(compose_cfg("sheet.steps=[simplify,centr]", "sheet.step.fit.damping=-1", "sheet.tolerance=0"))
    }
    assert "did you mean 'centre'" in problems["sheet.steps[1]"]
    assert "must be > 0" in problems["sheet.step.fit.damping"] and "must be > 0" in problems["sheet.tolerance"]
    assert not validate(compose_cfg("sheet.steps=[simplify,fit]", "sheet.step.coverage.vertices=0"))


def test_a_step_that_does_not_run_leaves_the_sheets_cache_key_alone():
    from qmdf.stages.sheet import Sheet, SheetConfig
    from qmdf.schema import defaults_of

    section = defaults_of(SheetConfig)
    section["steps"] = ["simplify", "fit"]
    other = {**section, "step": {**section["step"], "coverage": {**section["step"]["coverage"], "vertices": 7}}}
    assert Sheet.cache_config(section) == Sheet.cache_config(other)
    fit = {**section, "step": {**section["step"], "fit": {**section["step"]["fit"], "iterations": 7}}}
    assert Sheet.cache_config(section) != Sheet.cache_config(fit)


def _default(fn, name):
    return inspect.signature(fn).parameters[name].default


def test_the_library_runs_with_the_settings_python_m_qmdf_runs():
    """One source for every default: each library function the stages call defaults to the settings the stage's
    config starts from, so the API, the benches and the tests run what ``python -m qmdf`` runs."""
    from qmdf.medial.coverage import TOLERANCE, refine_coverage
    from qmdf.medial.covering import build_covering
    from qmdf.medial.envelope_fit import fit_envelope_to_samples
    from qmdf.medial.rims import extend_rims
    from qmdf.medial.sheet import CollapseSettings, prepared_solid, single_sheet, thinned_sheet
    from qmdf.medial.simplify import simplify_medial_mesh
    from qmdf.schema import defaults_of
    from qmdf.stages.cover import CoverConfig
    from qmdf.stages.sheet import SheetConfig

    cover = defaults_of(CoverConfig)
    del cover["eps_from_field"]
    assert defaults_of(type(_default(build_covering, "settings"))) == cover
    sheet = defaults_of(SheetConfig)
    expert = {k: v for k, v in sheet["expert"].items() if k not in ("compact_slack", "tip_reach")}
    assert defaults_of(type(_default(thinned_sheet, "settings"))) == expert
    assert _default(single_sheet, "settings") == CollapseSettings() == _default(thinned_sheet, "settings")
    assert _default(prepared_solid, "settings") == CollapseSettings()
    step = sheet["step"]
    # (simplify's deviation is a share of sheet.tolerance, which the step turns into the library's max_deviation)
    shared = ("boundary_weight", "max_turn_deg")
    assert {k: _default(simplify_medial_mesh, k) for k in shared} == {k: step["simplify"][k] for k in shared}
    assert {k: _default(fit_envelope_to_samples, k) for k in step["fit"]} == step["fit"]
    coverage = {"spacing": "spacing", "overshoot": "overshoot", "rounds": "max_rounds"}
    assert {k: _default(refine_coverage, v) for k, v in coverage.items()} == {k: step["coverage"][k] for k in coverage}
    assert _default(refine_coverage, "tolerance") == TOLERANCE == sheet["tolerance"]
    assert defaults_of(type(_default(extend_rims, "settings"))) == step["rims"]


def test_every_stage_whose_library_takes_settings_starts_from_the_same_defaults():
    """The stages whose config is the library's settings plus a few keys of their own: cover, contract,
    feature_detect, train's groups."""
    from qmdf.fields.settings import SupervisionSettings
    from qmdf.fields.supervision import build_supervision
    from qmdf.medial.contraction import contract
    from qmdf.medial.features import field_feature_points
    from qmdf.schema import defaults_of
    from qmdf.stages.contract import ContractConfig
    from qmdf.stages.feature_detect import FeatureDetectConfig
    from qmdf.stages.train import TrainConfig

    for fn, config, own in (
        (contract, ContractConfig, {"volume"}),
        (field_feature_points, FeatureDetectConfig, {"source"}),
    ):
        stage = {k: v for k, v in defaults_of(config).items() if k not in own}
        assert defaults_of(type(_default(fn, "settings"))) == stage
    assert _default(build_supervision, "settings") == SupervisionSettings() == TrainConfig().supervision


def _plugin_step(site):
    """An installed distribution with a sheet step, laid down as pip would: it pins every radius to its mean."""
    (site / "qmdf_flat_radii").mkdir(parents=True)
    (site / "qmdf_flat_radii" / "__init__.py").write_text(
        textwrap.dedent("""
        from dataclasses import dataclass
        from qmdf.medial.refinement import sheet_step
        from qmdf.schema import param

        @dataclass
        class FlatConfig:
            scale: float = param(1.0, gt=0)

        @sheet_step("flat_radii", FlatConfig, needs_data=False, summary="radii set to {radius:.4f}")
        def flat_radii(mat, data, cfg):
            r = float(mat.radii.mean()) * cfg.scale
            return mat._replace(radii=mat.radii * 0 + r), {"radius": r}
    """)
    )
    info = site / "qmdf_flat_radii-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: qmdf-flat-radii\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[qmdf.sheet_steps]\nflat_radii = qmdf_flat_radii\n")
    return {"PYTHONPATH": str(site)}


@pytest.mark.slow
def test_a_plugin_adds_a_step_by_entry_point_and_config(cli):
    env = _plugin_step(cli.cwd / "site")
    listing = cli(env=env, module="qmdf.plugins")
    assert "flat_radii" in listing.stdout
    proc = cli(*FAST, "sheet.steps=[simplify,flat_radii]", "sheet.step.flat_radii.scale=2", env=env)
    assert proc.returncode == 0, proc.stderr
    assert "flat_radii: radii set to" in proc.stderr
    (m,) = manifests(cli.cwd / "runs")
    stats = json.loads(open(f"{m['run_dir']}/04_sheet/sheet_stats.json").read())
    assert list(stats["steps"]) == ["simplify", "flat_radii"] and stats["steps"]["flat_radii"]["radius"] > 0
    bad = cli(*FAST, "sheet.steps=[simplify,flat_radii]", "sheet.step.flat_radii.scale=-1", env=env)
    assert bad.returncode == 2 and "sheet.step.flat_radii.scale: must be > 0, got -1" in bad.stderr
