"""The covering's decimation: one MeshLab pass, or two halves in two processes welded along their cut."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from skimage.measure import marching_cubes

from qmdf.geometry.decimation import decimate, prepass, topology


def _genus_two_surface(n: int = 64) -> trimesh.Trimesh:
    """Marching cubes of two tori fused side by side (genus 2, chi -2): a closed surface like a covering."""
    t = np.linspace(-1.2, 1.2, n)
    x, y, z = np.meshgrid(t, t, t, indexing="ij")

    def torus(cx):
        return np.sqrt((np.sqrt((x - cx) ** 2 + y**2) - 0.45) ** 2 + z**2) - 0.18

    v, f, _, _ = marching_cubes(np.minimum(torus(-0.5), torus(0.5)), 0.0, spacing=(t[1] - t[0],) * 3)
    return trimesh.Trimesh(v + t[0], f, process=True)


@pytest.fixture(scope="module")
def surface():
    mesh = _genus_two_surface()
    assert mesh.is_watertight and mesh.euler_number == -2
    return mesh


@pytest.mark.parametrize("workers,prepass_faces", [(1, 0), (2, 0), (1, 5000)])
def test_decimation_keeps_the_topology_and_the_shape(surface, workers, prepass_faces):
    target = 2000
    v, f = decimate(surface.vertices, surface.faces, target, workers=workers, prepass_faces=prepass_faces)
    out = trimesh.Trimesh(v, f, process=True)
    assert len(surface.faces) > 4 * target
    assert target - 10 <= len(out.faces) <= target
    assert out.is_watertight and out.euler_number == -2 and len(out.split(only_watertight=False)) == 1
    assert abs(abs(out.volume) - surface.volume) < 0.01 * surface.volume
    _, dist, _ = trimesh.proximity.closest_point(surface, out.vertices)
    assert dist.max() < 0.02  # the grid step is 0.038


def test_two_halves_weld_without_a_seam(surface):
    """No vertex is left twice on the cut: a duplicate would open the surface (boundary edges) or leave two
    vertices at one place."""
    v, f = decimate(surface.vertices, surface.faces, 2000, workers=2)
    used = np.unique(f)
    assert len(used) == len(v)
    assert len(np.unique(np.round(v, 12), axis=0)) == len(v)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    assert np.all(count == 2)


def test_small_meshes_take_one_pass(surface):
    one = decimate(surface.vertices, surface.faces, len(surface.faces) // 2, workers=1)
    two = decimate(surface.vertices, surface.faces, len(surface.faces) // 2, workers=2)  # under 4x the target
    assert np.array_equal(one[1], two[1]) and np.array_equal(one[0], two[0])


def test_a_failed_second_process_falls_back_to_one_pass(surface, monkeypatch, caplog):
    import sys

    monkeypatch.setattr(sys, "executable", "/bin/false")
    v, f = decimate(surface.vertices, surface.faces, 2000, workers=2)
    assert "decimating in one pass" in caplog.text
    one = decimate(surface.vertices, surface.faces, 2000, workers=1)
    assert np.array_equal(f, one[1])


def test_topology_reads_chi_components_and_closedness(surface):
    f = np.asarray(surface.faces)
    assert topology(f) == (-2, 1, True)
    two = np.vstack([f, f + f.max() + 1])  # two disjoint copies
    assert topology(two) == (-4, 2, True)
    assert topology(f[1:]) == (-3, 1, False)  # one face less: a hole, one boundary loop
    fast = prepass(surface.vertices, f, 5000)  # this surface's fast collapse keeps it: the prepass is used
    assert fast is not None and len(fast[1]) <= 5000 and topology(fast[1]) == (-2, 1, True)


def test_a_prepass_that_changes_the_topology_is_not_kept(surface, monkeypatch, caplog):
    """The fast collapse has no link condition: where its result differs in chi, components or closedness, the
    MeshLab pass runs from the full mesh, as without it."""
    import logging

    import fast_simplification

    def holed(v, f, target_count):  # what a collapse that tore the surface would give
        return v, f[: target_count - 1]

    monkeypatch.setattr(fast_simplification, "simplify", holed)
    with caplog.at_level(logging.INFO):
        v, f = decimate(surface.vertices, surface.faces, 2000, prepass_faces=5000)
    assert "changed the topology" in caplog.text
    alone = decimate(surface.vertices, surface.faces, 2000)
    assert np.array_equal(f, alone[1]) and np.array_equal(v, alone[0])


def test_no_prepass_where_it_would_not_halve_the_mesh(surface, monkeypatch):
    import fast_simplification

    def never(*args, **kwargs):
        raise AssertionError("the prepass ran on a mesh under twice its target")

    monkeypatch.setattr(fast_simplification, "simplify", never)
    v, f = decimate(surface.vertices, surface.faces, 2000, prepass_faces=6000)  # 11,876 faces < 12,000
    assert np.array_equal(f, decimate(surface.vertices, surface.faces, 2000)[1])
