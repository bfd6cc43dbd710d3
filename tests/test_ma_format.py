"""The .ma format: round trip, face edges completed, extended variants, broken files refused."""

from __future__ import annotations

import numpy as np
import pytest

from qmdf.errors import InputError
from qmdf.geometry.ma_format import MedialMesh, read_ma, write_ma


def test_round_trip_adds_face_edges(tmp_path):
    mat = MedialMesh(np.eye(4, 3), [0.1, 0.2, 0.3, 0.4], edges=[[0, 3]], faces=[[0, 1, 2]])
    write_ma(tmp_path / "a.ma", mat)
    text = (tmp_path / "a.ma").read_text().splitlines()
    assert text[0] == "4 4 1"
    back = read_ma(tmp_path / "a.ma")
    assert np.allclose(back.vertices, mat.vertices) and np.allclose(back.radii, mat.radii)
    assert sorted(map(tuple, back.edges)) == [(0, 1), (0, 2), (0, 3), (1, 2)]
    assert back.faces.tolist() == [[0, 1, 2]]


def test_extended_variant_fields_are_ignored(tmp_path):
    (tmp_path / "b.ma").write_text("3 1 1\nv 0 0 0 0.5 1\nv 1 0 0 0.25 0\nv 0 1 0 0.1 0\ne 0 1 0\nf 0 1 2 0 1\n")
    mat = read_ma(tmp_path / "b.ma")
    assert mat.radii.tolist() == [0.5, 0.25, 0.1] and mat.faces.tolist() == [[0, 1, 2]]


@pytest.mark.parametrize(
    "text, message",
    [
        ("2 0 0\nv 0 0 0 1\n", "header says 2 0 0"),
        ("1 1 0\nv 0 0 0 1\ne 0 5\n", "outside 0..0"),
        ("x y z\n", "not a valid .ma file"),
    ],
)
def test_broken_files_are_refused(tmp_path, text, message):
    (tmp_path / "c.ma").write_text(text)
    with pytest.raises(InputError, match=message):
        read_ma(tmp_path / "c.ma")


def test_the_shared_data_ma_file_reads_if_present():
    from conftest import DATA

    files = sorted(DATA.rglob("*.ma")) if DATA.exists() else []
    if not files:
        pytest.skip("no .ma file in ../shared/data")
    mat = read_ma(files[0])
    assert len(mat.vertices) > 0 and np.all(mat.radii >= 0)


def test_obj_and_ply_of_a_medial_mesh_with_a_curve_read_back(tmp_path):
    """The sheet's OBJ and PLY: faces, the lone edges of a curve-like axis, and the radii, readable by trimesh and
    by qmdf's own reader (the OBJ once had inline '# r' comments on its v lines, which neither could read)."""
    import trimesh

    from qmdf.geometry.io import Limits, load_geometry
    from qmdf.geometry.ma_format import write_obj, write_ply_with_radius

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 1], [3, 1, 0.5]])
    mat = MedialMesh(v, [0.1, 0.2, 0.3, 0.4, 0.5], edges=[[3, 4]], faces=[[0, 1, 2], [1, 3, 2]]).with_face_edges()
    assert mat.lone_edges().tolist() == [[3, 4]]
    write_obj(tmp_path / "m.obj", mat)
    text = (tmp_path / "m.obj").read_text()
    assert "l 4 5" in text and "# radius 5 0.5" in text
    assert all("#" not in line for line in text.splitlines() if line.startswith("v "))
    back = trimesh.load(tmp_path / "m.obj", process=False, force="mesh")
    assert np.allclose(back.vertices[:4], v[:4]) and back.faces.tolist() == [[0, 1, 2], [1, 3, 2]]
    assert len(load_geometry(tmp_path / "m.obj", limits=Limits(min_points=3)).points.points) == 4
    write_ply_with_radius(tmp_path / "m.ply", mat)
    ply = trimesh.load(tmp_path / "m.ply", process=False)
    raw = ply.metadata["_ply_raw"]
    assert np.allclose(raw["vertex"]["data"]["radius"], mat.radii)
    edges = raw["edge"]["data"]
    assert [[int(a), int(b)] for a, b in zip(edges["vertex1"], edges["vertex2"])] == [[3, 4]]
