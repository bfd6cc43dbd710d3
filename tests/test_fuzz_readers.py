"""Fuzzing every reader: whatever bytes a file holds, ``load_geometry`` returns checked geometry or raises one
``InputError`` (exit 2, one line), never another exception (a traceback). Inputs are random bytes, and valid
files of each format with bytes flipped, cut short or lines shuffled, so the parsers get past their first line.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

pytest.importorskip("hypothesis", reason="the dev extra installs hypothesis (make test does)")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from qmdf.errors import InputError
from qmdf.geometry.io import load_geometry


def _valid(suffix: str) -> bytes:
    mesh = trimesh.creation.icosphere(subdivisions=1)
    if suffix == ".ply binary":
        return mesh.export(file_type="ply", encoding="binary")
    if suffix == ".xyz":
        return "\n".join(" ".join(f"{c:.5f}" for c in p) for p in mesh.vertices).encode()
    if suffix == ".npy":
        buf = io.BytesIO()
        np.save(buf, np.asarray(mesh.vertices))
        return buf.getvalue()
    file_type = suffix[1:]
    out = mesh.export(file_type=file_type, **({"encoding": "ascii"} if file_type == "ply" else {}))
    return out if isinstance(out, bytes) else out.encode()


SUFFIXES = (".xyz", ".npy", ".ply", ".ply binary", ".obj", ".off", ".stl")
SETTINGS = settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def _load(tmp_path, suffix: str, data: bytes) -> None:
    path = tmp_path / f"fuzz{suffix.split()[0]}"
    path.write_bytes(data)
    try:
        load_geometry(path)
    except InputError as exc:
        assert "\n" not in str(exc).strip(), str(exc)  # one line


@pytest.mark.parametrize("suffix", SUFFIXES)
@SETTINGS
@given(data=st.binary(min_size=1, max_size=400))
def test_random_bytes(tmp_path, suffix, data):
    _load(tmp_path, suffix, data)


@pytest.mark.parametrize("suffix", SUFFIXES)
@SETTINGS
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=6))
def test_damaged_valid_files(tmp_path, suffix, cut, flips):
    data = bytearray(_valid(suffix))
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    data = bytes(data[: max(1, int(cut * len(data)))])
    _load(tmp_path, suffix, data)


@pytest.mark.parametrize("suffix", (".xyz", ".obj", ".off", ".ply"))
@SETTINGS
@given(seed=st.integers(0, 2**16), token=st.sampled_from(["nan", "inf", "-1", "1e400", "x", "", "0 0", "3 0 1 99999"]))
def test_text_formats_with_bad_tokens(tmp_path, suffix, seed, token):
    lines = _valid(suffix).decode(errors="replace").splitlines()
    rng = np.random.default_rng(seed)
    for i in rng.integers(0, len(lines), size=3):
        words = lines[i].split()
        if words:
            words[int(rng.integers(len(words)))] = token
            lines[i] = " ".join(words)
    _load(tmp_path, suffix, "\n".join(lines).encode())
