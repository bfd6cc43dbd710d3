"""Unique rows of non-negative integer arrays (edges, faces, grid nodes) through one integer key per row.

``np.unique(a, axis=0)`` sorts the rows as opaque byte strings, about 30x slower than sorting one int64 per row
(the teacup's sheet, 400k edges: 1.1 s against 0.04 s). The key is the row's index in C order over the
columns' ranges, so the result, its order included, is the same as ``np.unique(a, axis=0)``'s."""

from __future__ import annotations

import numpy as np


def unique_rows(a: np.ndarray, return_inverse: bool = False, return_counts: bool = False):
    """``np.unique(a, axis=0, return_inverse=..., return_counts=...)`` for a 2-D array of non-negative integers."""
    a = np.asarray(a)
    if a.ndim != 2 or not np.issubdtype(a.dtype, np.integer):
        raise ValueError("unique_rows expects a 2-D array of integers")
    if len(a) == 0 or a.shape[1] == 0:
        return np.unique(a, axis=0, return_inverse=return_inverse, return_counts=return_counts)
    a = a.astype(np.int64, copy=False)
    dims = a.max(0) + 1
    if a.min() < 0 or np.log2(dims.astype(np.float64)).sum() >= 62:
        return np.unique(a, axis=0, return_inverse=return_inverse, return_counts=return_counts)
    key = np.ravel_multi_index(tuple(a.T), tuple(int(d) for d in dims))
    out = np.unique(key, return_inverse=return_inverse, return_counts=return_counts)
    keys, extra = (out[0], out[1:]) if isinstance(out, tuple) else (out, ())
    rows = np.column_stack(np.unravel_index(keys, tuple(int(d) for d in dims))).astype(np.int64)
    if not extra:
        return rows
    extra = tuple(e.reshape(-1) for e in extra)
    return (rows, *extra)
