"""The grid encoding's forward pass and its gradient to the table compiled, for the CPU.

It mirrors ``Grid.encode`` in backbones.py (the tested reference, which autograd differentiates twice for
training): the same clamp, cells, smoothstep weights, dense and hashed indices. Torch builds the
(N, levels, 8, 3) index and weight tensors as separate temporaries; one loop here does the same gathers
without them, which is what the cover's and the contraction's millions of field queries cost, and what a
training step whose loss reads no gradient of the field (the supervised route's) spends on the encoding."""

from __future__ import annotations

import math

from numba import njit, prange

_P1, _P2 = 2654435761, 805459861  # Instant-NGP's spatial-hash primes (the first, 1, needs no product)


@njit(cache=True)
def _corner_cell(xk, bound, rl):
    """The cell index along one axis and the smoothstep weight of its far corner."""
    u = (min(max(xk, -bound), bound) + bound) / (2.0 * bound) * rl
    c = min(math.floor(u), rl - 1)
    t = u - c
    return c, t * t * (3.0 - 2.0 * t)


@njit(cache=True, inline="always")
def _corner_row(corner, ci, cj, ck, wx, wy, wz, stride, dense, size, offset):
    """The table row of one of a cell's 8 corners (dense index or spatial hash) and its smoothstep weight."""
    a, b, c = corner >> 2 & 1, corner >> 1 & 1, corner & 1
    i, j, k = ci + a, cj + b, ck + c
    weight = (wx if a else 1.0 - wx) * (wy if b else 1.0 - wy) * (wz if c else 1.0 - wz)
    flat = i + stride * (j + stride * k) if dense else (i ^ (j * _P1) ^ (k * _P2)) % size
    return offset + flat, weight


@njit(cache=True, parallel=True)
def encode_grid(x, table, res, size, offset, dense, bound, out):
    """out (N, levels * F) = the smoothstep-blended features of the 8 corners of each level's cell."""
    n_levels, n_feat = res.shape[0], table.shape[1]
    for n in prange(x.shape[0]):
        for lv in range(n_levels):
            rl = res[lv]
            ci, wx = _corner_cell(x[n, 0], bound, rl)
            cj, wy = _corner_cell(x[n, 1], bound, rl)
            ck, wz = _corner_cell(x[n, 2], bound, rl)
            stride = rl + 1
            base = lv * n_feat
            for f in range(n_feat):
                out[n, base + f] = 0.0
            for corner in range(8):
                row, weight = _corner_row(corner, ci, cj, ck, wx, wy, wz, stride, dense[lv], size[lv], offset[lv])
                for f in range(n_feat):
                    out[n, base + f] += weight * table[row, f]


@njit(cache=True, parallel=True)
def encode_grid_backward(x, grad_out, res, size, offset, dense, bound, grad_table):
    """grad_table += d(sum(out * grad_out)) / d table, ``out`` as ``encode_grid`` makes it. One thread a level:
    each level's rows of the table are its own, so the scatter needs no atomics."""
    n_levels, n_feat = res.shape[0], grad_table.shape[1]
    for lv in prange(n_levels):
        rl = res[lv]
        stride = rl + 1
        base = lv * n_feat
        for n in range(x.shape[0]):
            ci, wx = _corner_cell(x[n, 0], bound, rl)
            cj, wy = _corner_cell(x[n, 1], bound, rl)
            ck, wz = _corner_cell(x[n, 2], bound, rl)
            for corner in range(8):
                row, weight = _corner_row(corner, ci, cj, ck, wx, wy, wz, stride, dense[lv], size[lv], offset[lv])
                for f in range(n_feat):
                    grad_table[row, f] += weight * grad_out[n, base + f]
