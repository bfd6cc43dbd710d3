"""The Python API: the same pipeline and configs as the CLI, for scripts and notebooks.

import qmdf
mat = qmdf.medial_axis("bunny.off", overrides=["cover.eps=0.01"])
mat.vertices, mat.radii, mat.edges, mat.faces, mat.metrics

run = qmdf.run(points_array, overrides=["pipeline.stop_after=sample"])
run.load("points")
"""

from __future__ import annotations

import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from qmdf.errors import InputError, PipelineError
from qmdf.rundir import conf_dir, new_run_name

log = logging.getLogger("qmdf")


def compose(overrides: Sequence[str] = ()) -> Any:
    """The composed (not yet validated) config for ``overrides``, exactly as the CLI would compose it."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from qmdf.config import register_configs

    register_configs()
    gh = GlobalHydra.instance()
    outer = gh.hydra if gh.is_initialized() else None  # called from inside someone's Hydra app
    gh.clear()
    try:
        with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
            return hydra_compose(config_name="config", overrides=list(overrides))
    finally:
        if outer is not None:
            GlobalHydra.instance().initialize(outer)


def _stage_input(source: Any, run_dir: Path) -> list[str]:
    """Overrides that point the pipeline at ``source`` (arrays and meshes are written into the run dir)."""
    if source is None:
        return []
    if isinstance(source, (str, os.PathLike)):
        return [f"input.path={_quote(os.path.abspath(source))}"]
    if not isinstance(source, np.ndarray) and not (hasattr(source, "vertices") and hasattr(source, "faces")):
        raise InputError(
            f"cannot use a {type(source).__name__} as input: pass a path, an (N, 3) array or a trimesh.Trimesh"
        )
    run_dir.mkdir(parents=True, exist_ok=True)
    if isinstance(source, np.ndarray):
        path = run_dir / "input.npy"
        np.save(path, np.asarray(source, dtype=np.float64))
        return [f"input.path={_quote(str(path))}", "input.kind=points"]
    path = run_dir / "input.ply"
    path.write_bytes(source.export(file_type="ply"))
    return [f"input.path={_quote(str(path))}", "input.kind=mesh"]


def _quote(path: str) -> str:
    return "'" + path.replace("\\", "\\\\").replace("'", "\\'") + "'"


def run(
    source: Any = None,
    overrides: Sequence[str] = (),
    run_dir: str | os.PathLike | None = None,
    base_dir: str | os.PathLike | None = None,
):
    """Run the configured pipeline on ``source`` (a path, an (N, 3) array, a trimesh, or None for the
    default shape). Returns the RunResult (run directory, manifest, artifacts)."""
    from qmdf.pipeline import Pipeline
    from qmdf.report import report_finished_run

    base = Path(base_dir or os.getcwd()).resolve()
    out = Path(run_dir) if run_dir is not None else base / "runs" / new_run_name()
    created = not out.exists()
    handler = None
    try:
        cfg = compose(list(overrides) + _stage_input(source, out))
        if run_dir is None:  # the caller did not choose: say where the files go
            log.info(
                "qmdf writes this run to %s and its cache to %s (run_dir= and cache.dir=... choose)",
                out,
                base / cfg.cache.dir if cfg.cache.enabled else "nowhere",
            )
        out.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(out / "qmdf.log")
        handler.setFormatter(logging.Formatter("[%(asctime)s][%(name)s][%(levelname)s] %(message)s"))
        logging.getLogger().addHandler(handler)
        if logging.getLogger().level > logging.INFO:
            logging.getLogger("qmdf").setLevel(logging.INFO)
        result = Pipeline(cfg, out, base).run()
        report_finished_run(out, cfg)
        return result
    except BaseException:
        if handler is not None:
            handler.close()
        if created and not (out / "manifest.json").exists():  # refused before the run began: no empty folder
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        if handler is not None:
            logging.getLogger().removeHandler(handler)
            handler.close()


@dataclass
class MedialAxis:
    """A medial axis transform in the unit box of the input (see ``normalization`` for its own units)."""

    vertices: np.ndarray
    radii: np.ndarray
    edges: np.ndarray
    faces: np.ndarray
    metrics: dict
    normalization: Any
    run_dir: Path

    def in_input_units(self) -> "MedialAxis":
        n = self.normalization
        return MedialAxis(
            n.to_input(self.vertices),
            n.length_to_input(self.radii),
            self.edges,
            self.faces,
            self.metrics,
            n,
            self.run_dir,
        )


def medial_axis(
    source: Any = None, overrides: Sequence[str] = (), run_dir: str | os.PathLike | None = None
) -> MedialAxis:
    """The MAT of ``source``: vertices, radii, edges, faces (unit-box frame) and the run's metrics."""
    result = run(source, overrides, run_dir)
    if "mat" not in result.artifacts:
        m = result.manifest
        why = (
            f"stages not available in this version: {', '.join(m['unavailable_stages'])}"
            if m["unavailable_stages"]
            else f"stages not run: {', '.join(m['not_run']) or 'none'}"
        )
        raise PipelineError(f"the run made no medial axis ({why}); see {result.run_dir}")
    from qmdf.geometry.ma_format import read_ma

    mat = read_ma(result.path("mat"))
    metrics = result.load("metrics") if "metrics" in result.artifacts else {}
    return MedialAxis(
        mat.vertices, mat.radii, mat.edges, mat.faces, metrics, result.load("normalization"), result.run_dir
    )
