"""Every benchmark file in ../shared/data loads with the counts its MANIFEST states (skipped without it)."""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest

from conftest import DATA
from qmdf.geometry.io import load_geometry

ROWS = list(csv.DictReader(open(DATA / "MANIFEST.tsv"), delimiter="\t")) if (DATA / "MANIFEST.tsv").exists() else []


def _counts(text: str) -> dict[str, int]:
    return {k: int(v) for k, v in re.findall(r"(\w+)=(-?\d+)(?=\s|$)", text)}


@pytest.mark.skipif(not ROWS, reason="../shared/data is not present")
@pytest.mark.parametrize("row", ROWS, ids=[r["file"] for r in ROWS])
def test_benchmark_file_loads_with_manifest_counts(row):
    g = load_geometry(DATA / row["file"])
    c = _counts(row["counts"])
    if row["kind"] == "mesh":
        import trimesh

        # coincident vertices are welded, as trimesh's own processing does: compare with that
        ref = trimesh.load(DATA / row["file"], process=False, force="mesh")
        ref.merge_vertices(merge_tex=True, merge_norm=True)
        ref.remove_unreferenced_vertices()
        assert g.is_mesh and (len(g.points), len(g.faces)) == (len(ref.vertices), c["F"])
        edges = np.unique(
            np.sort(np.concatenate([g.faces[:, [0, 1]], g.faces[:, [1, 2]], g.faces[:, [2, 0]]]), 1), axis=0
        )
        chi = len(g.points) - len(edges) + len(g.faces)
        assert chi == ref.euler_number
        if len(g.points) == c["V"]:
            assert chi == c["chi"]
    else:
        assert not g.is_mesh and len(g.points) == c["points"]
        has_normals = "nx" in row["counts"] or "cols=6" in row["counts"]
        assert (g.points.normals is not None) == has_normals
