"""Typed configs: every problem listed by key path; defaults from the dataclasses; typed sections."""

from __future__ import annotations

import pytest

from qmdf import config as cfgmod
from qmdf.errors import ConfigError


def keys(problems):
    return sorted(p.key for p in problems)


def test_default_config_is_valid(compose_cfg):
    assert cfgmod.validate(compose_cfg()) == []


def test_defaults_come_from_the_schemas(compose_cfg):
    cfg = compose_cfg()
    assert cfg.sample.degradations == {}
    assert cfg.input.shape == "teacup"
    assert list(cfg.pipeline.stages) == cfgmod.DEFAULT_PIPELINE


def test_every_problem_is_listed_by_key_path(compose_cfg):
    cfg = compose_cfg(
        "sample.n_points=-5",
        "input.kind=foo",
        "seed=abc",
        "+bogus=1",
        "pipeline.stages=[sample,trian]",
        "+sample.degradations.noize.sigma=1",
        "+sample.degradations.noise.sigma=-0.1",
        "cache.force=[cover]",
    )
    problems = cfgmod.validate(cfg)
    assert keys(problems) == sorted(
        [
            "bogus",
            "cache.force[0]",
            "input.kind",
            "pipeline.stages[1]",
            "sample.degradations.noise.sigma",
            "sample.degradations.noize",
            "sample.n_points",
            "seed",
        ]
    )
    text = "\n".join(map(str, problems))
    assert "did you mean 'noise'" in text and "did you mean 'train'" in text
    assert "must be >= 10, got -5" in text


def test_wrong_types_are_reported_not_coerced(compose_cfg):
    problems = cfgmod.validate(compose_cfg("sample.n_points=1.5", "cache.enabled=maybe", "input.min_points=true"))
    msgs = {p.key: p.message for p in problems}
    assert msgs["sample.n_points"].startswith("expected an integer")
    assert msgs["cache.enabled"].startswith("expected true/false")
    assert msgs["input.min_points"].startswith("expected an integer")


def test_missing_input_file_and_bad_suffix_are_reported(compose_cfg, tmp_path):
    problems = cfgmod.validate(compose_cfg(f"input.path={tmp_path}/mesh.dwg"))
    assert keys(problems) == ["input.path"] and "unsupported file type" in problems[0].message


def test_missing_input_file_is_a_config_problem(compose_cfg, tmp_path):
    problems = cfgmod.validate(compose_cfg("input.path=nowhere/scan.ply", "sample.n_points=0"), base_dir=tmp_path)
    assert {p.key: p.message for p in problems} == {
        "input.path": f"file not found: {tmp_path / 'nowhere' / 'scan.ply'}",
        "sample.n_points": "must be >= 10, got 0",
    }
    (tmp_path / "nowhere" / "scan.ply").mkdir(parents=True)
    problems = cfgmod.validate(compose_cfg("input.path=nowhere/scan.ply"), base_dir=tmp_path)
    assert [p.message for p in problems] == [f"not a file: {tmp_path / 'nowhere' / 'scan.ply'}"]


def test_check_raises_config_error_with_all_lines(compose_cfg):
    with pytest.raises(ConfigError) as err:
        cfgmod.check(compose_cfg("sample.n_points=0", "input.shape=cube"))
    msg = str(err.value)
    assert msg.startswith("invalid configuration (2 problems)")
    assert "input.shape: unknown shape 'cube'" in msg and "sample.n_points" in msg


def test_typed_sections(compose_cfg):
    cfg = compose_cfg("+sample.degradations.noise.sigma=0.01", "seed=3")
    root = cfgmod.typed_root(cfg)
    assert root.seed == 3 and root.input.shape == "teacup"
    sample = cfgmod.typed_section(cfg, "sample")
    assert sample.n_points == 2000 and sample.degradations == {"noise": {"sigma": 0.01}}


def test_stop_after_must_name_a_configured_stage(compose_cfg):
    problems = cfgmod.validate(compose_cfg("pipeline.stop_after=cover", "pipeline.stages=[sample]"))
    assert keys(problems) == ["pipeline.stop_after"]
