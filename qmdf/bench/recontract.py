"""Run a finished pipeline's last contraction again, from its saved field, covering and feature points, with
``contract.*`` overrides: an A/B of the contraction on identical inputs (training is not bit-reproducible,
so two full runs differ by more than many contraction settings do)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from qmdf.artifacts import FIELD, JSON, MESH, POINTS, write_json
from qmdf.errors import QmdfError


def _latest_before(stages: list[dict], artifact: str, index: int) -> str | None:
    """The path of ``artifact`` as the stage at ``index`` read it: the latest stage before it that made one."""
    made = [
        s["artifacts"][artifact]["path"] for s in stages if s["index"] < index and artifact in s.get("artifacts", {})
    ]
    return made[-1] if made else None


def _input_data(run_dir: Path, stages: list[dict], index: int):
    """(mesh, points) as export's ``input_data`` gives them, from the run's artifacts."""
    from qmdf.stages.inputs import radius_data

    path = {k: _latest_before(stages, k, index) for k in ("input_info", "surface", "points", "point_surface")}
    return radius_data(
        JSON.load(run_dir / path["input_info"]) if path["input_info"] else {},
        (lambda: MESH.load(run_dir / path["surface"])) if path["surface"] else None,
        (lambda: POINTS.load(run_dir / path["points"])) if path["points"] else None,
        (lambda: MESH.load(run_dir / path["point_surface"])) if path["point_surface"] else None,
    )


def recontract(run_dir: Path, out_dir: Path, overrides: list[str]) -> Path:
    """Contracts ``run_dir``'s last covering again under its own contract config plus ``overrides``
    (``contract.key=value``) and writes the MAT as the export stage does (``mat.ma``, ``reconstruction.ply``)
    and the contraction log into ``out_dir``, which it returns."""
    from omegaconf import OmegaConf

    from qmdf.geometry.envelope import EnvelopeUnion, reconstruct_mesh
    from qmdf.geometry.ma_format import write_ma
    from qmdf.schema import build, check_section
    from qmdf.medial.contraction import contract, surface_mesh
    from qmdf.medial.radii import membrane_to_mat
    from qmdf.stages.contract import ContractConfig
    from qmdf.stages.sheet import DEFAULT_STEPS

    bad = [o for o in overrides if not o.startswith("contract.") or "=" not in o]
    if bad:
        raise QmdfError(f"--recontract takes contract.key=value overrides only, got {' '.join(bad)}")
    if not (run_dir / "manifest.json").is_file():
        raise QmdfError(f"{run_dir} has no manifest.json: not a run folder")
    manifest = json.loads((run_dir / "manifest.json").read_text())
    stages = manifest["stages"]
    contracts = [s for s in stages if s["name"] == "contract"]
    if manifest.get("status") != "complete" or not contracts:
        raise QmdfError(f"{run_dir} is not a complete run with a contract stage")
    last = contracts[-1]
    sources = {k: _latest_before(stages, k, last["index"]) for k in ("field", "covering", "feature_points")}
    if sources["field"] is None or sources["covering"] is None:
        raise QmdfError(f"{run_dir}'s manifest names no field or covering before its last contract")
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    node = OmegaConf.merge(
        OmegaConf.create(config["contract"]), OmegaConf.from_dotlist([o.removeprefix("contract.") for o in overrides])
    )
    problems = check_section(ContractConfig, node, "contract")
    if problems:
        raise QmdfError("; ".join(map(str, problems)))
    cfg = build(ContractConfig, node)
    if cfg.volume != "surface":
        raise QmdfError("--recontract replays contractions with contract.volume=surface only")
    field = FIELD.load(run_dir / sources["field"])
    covering = MESH.load(run_dir / sources["covering"])
    features = None if sources["feature_points"] is None else POINTS.load(run_dir / sources["feature_points"]).points
    faces = np.asarray(covering.faces)
    x, history, vol0, _ = contract(field, np.asarray(covering.vertices), faces, None, features=features, settings=cfg)
    # the membrane as the run's export made it, with the sheet's settings: its radii, centred on the input's axis
    # where the sheet centres, covered where it covers
    sheet = config.get("sheet", {})
    radius, steps = sheet.get("radius", "data"), sheet.get("steps", list(DEFAULT_STEPS))
    mesh, points = _input_data(run_dir, stages, last["index"]) if radius == "data" else (None, None)
    mat = membrane_to_mat(surface_mesh(x, faces), field, radius, mesh, points, centre="centre" in steps)
    budget = int(((sheet.get("step") or {}).get("coverage") or {}).get("vertices", 1000)) if "coverage" in steps else 0
    if radius == "data" and budget:  # export's coverage of a membrane MAT
        from qmdf.medial.coverage import cover_mat
        from qmdf.stages.inputs import is_input_mesh, surface_balls_of

        sampled = _latest_before(stages, "points", last["index"])
        info = _latest_before(stages, "input_info", last["index"])
        # the run's points sample an input mesh, not a cloud's Poisson surface (sampled afresh then)
        own = is_input_mesh(
            JSON.load(run_dir / info) if info else {}, _latest_before(stages, "surface", last["index"]) is not None
        )
        load = (lambda: POINTS.load(run_dir / sampled)) if sampled and own else None
        mat, _ = cover_mat(mat, surface_balls_of(field, mesh, points, load), budget, int(config.get("seed", 0)))
    out_dir.mkdir(parents=True, exist_ok=True)
    write_ma(out_dir / "mat.ma", mat)
    resolution = int(config.get("export", {}).get("reconstruction_resolution", 128))
    recon = reconstruct_mesh(EnvelopeUnion.from_mat(mat), resolution)
    if recon is not None:
        MESH.save(recon, out_dir / "reconstruction.ply")
    write_json(
        out_dir / "contraction.json",
        {"run": str(run_dir), "overrides": overrides, "initial_volume": vol0, "history": history},
    )
    return out_dir
