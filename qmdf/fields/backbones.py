"""Backbones: coordinates (N, 3) in the unit box -> features (N, out_dim). Swappable by ``train.model.backbone``.

Each one must be twice differentiable (the eikonal and orthogonality terms differentiate its gradient).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from qmdf.registry import Registry
from qmdf.schema import param

BACKBONES = Registry("backbone", "qmdf.backbones")


def register_backbone(name: str, config: type):
    def deco(cls):
        return BACKBONES.add(name, cls, config)

    return deco


@dataclass
class MLPConfig:
    width: int = param(128, ge=8, doc="hidden width")
    depth: int = param(4, ge=1, doc="hidden layers")
    softplus_beta: float = param(100.0, gt=0, doc="softplus sharpness (DMF: 100)")
    fourier_features: int = param(
        0, ge=0, doc="Gaussian Fourier features of the input (0: none, keeps geometric init exact)"
    )
    fourier_scale: float = param(2.0, gt=0, doc="std of the Fourier frequencies (cycles per unit)")
    geometric_init: bool = param(
        True, doc="start from the SDF of a sphere (SAL), so training begins from a valid shape"
    )


@register_backbone("mlp", MLPConfig)
class MLP(nn.Module):
    """DMF-style softplus MLP (smaller, for a CPU), optionally with Fourier features of the input.

    ``extra_dim`` more input features (a grid encoding's) may follow the coordinates: their weights start
    at zero, so the geometric initialisation holds and training adds detail where the data asks for it."""

    def __init__(self, cfg: MLPConfig, extra_dim: int = 0):
        super().__init__()
        self.cfg = cfg
        in_dim = 3
        if cfg.fourier_features:
            self.register_buffer("B", torch.randn(3, cfg.fourier_features) * cfg.fourier_scale * 2 * math.pi)
            in_dim = 3 + 2 * cfg.fourier_features
        self.extra_dim = extra_dim
        dims = [in_dim + extra_dim] + [cfg.width] * cfg.depth
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.act = nn.Softplus(beta=cfg.softplus_beta)
        self.out_dim = cfg.width
        if cfg.geometric_init:
            for i, layer in enumerate(self.layers):
                nn.init.normal_(layer.weight, 0.0, math.sqrt(2) / math.sqrt(layer.out_features))
                nn.init.zeros_(layer.bias)
                if i == 0 and (cfg.fourier_features or extra_dim):
                    nn.init.zeros_(layer.weight[:, 3:])  # Fourier / grid features start silent, as DMF damps them

    def forward(self, x: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        h = x
        if self.cfg.fourier_features:
            proj = x @ self.B
            h = torch.cat([x, torch.sin(proj), torch.cos(proj)], dim=-1)
        if extra is not None:
            h = torch.cat([h, extra], dim=-1)
        for layer in self.layers:
            h = self.act(layer(h))
        return h


@dataclass
class GridConfig:
    levels: int = param(8, ge=1, le=16, doc="resolution levels of the encoding")
    features: int = param(2, ge=1, le=8, doc="features per level")
    base_resolution: int = param(8, ge=2, doc="cells per side at the coarsest level")
    finest_resolution: int = param(
        127,
        ge=2,
        doc="cells per side at the finest level. 127 (128^3 corners = 2^21, every level dense) puts the box's "
        "q minima within 0.93e-3 of its axis (1.20e-3 at 80) and abc_00000329's |grad sdf| at 0.98 (0.72 at 80); "
        "train 20-30% longer on the CPU (teacup 72 -> 88 s)",
    )
    log2_table_size: int = param(
        21,
        ge=8,
        le=24,
        doc="entries per level; finer levels are hashed into it. 2^21 keeps every level dense up to 127 cells: "
        "hash collisions were the teacup's q noise (genus of the covering 555 at 2^17 and 96 cells, 12 dense "
        "at 80). The 128-cell level hashed in 2^21 centred the box at 0.79e-3, but collisions are a risk dense is not",
    )
    bound: float = param(0.6, gt=0, doc="the grid covers [-bound, bound]^3 (volume samples reach 0.6)")
    width: int = param(64, ge=8, doc="hidden width of the MLP after the encoding")
    depth: int = param(2, ge=1, doc="hidden layers of that MLP")
    softplus_beta: float = param(100.0, gt=0)
    geometric_init: bool = param(True, doc="the MLP reads the coordinates too and starts from a sphere's SDF")
    medial_width: int = param(
        64,
        ge=0,
        doc="the medial field from its own smooth MLP of the coordinates (this width, 3 "
        "layers) instead of the grid's features: the grid follows every bump's medial branch, and "
        "on the bunny its mf was blocks and q a maze (covering genus ~1500); 0: from the grid",
    )
    medial_levels: int = param(
        0,
        ge=0,
        doc="the medial MLP also reads the grid's coarsest this many levels (0: the coordinates alone). On the "
        "bunny 4 levels lower q on the axis (p50 / p90 / p99 2.8e-3 / 11e-3 / 34e-3 against 4.5e-3 / 19e-3 / "
        "48e-3) but the covering gets genus 9, the MAT chi -11 and CD 7.6e-3 (5.2e-3 with 0)",
    )


#: Spatial-hash primes of Instant-NGP (the first is 1 so that a dense level needs no hashing).
_PRIMES = (1, 2654435761, 805459861)


@register_backbone("grid", GridConfig)
class Grid(nn.Module):
    """Instant-NGP-style multiresolution grid encoding plus a small softplus MLP, in plain PyTorch.

    Corners are blended with smoothstep weights 3t^2 - 2t^3 instead of linear ones: trilinear blending has
    a gradient that jumps across cell faces and a zero Hessian inside cells, so the eikonal and
    orthogonality terms (which differentiate the gradient) would see nothing; smoothstep is C1. Every
    operation is a gather or an elementwise product, so double backward runs on the CPU with no custom
    kernel. Coarse levels are dense tables, fine ones hashed."""

    def __init__(self, cfg: GridConfig):
        super().__init__()
        self.cfg = cfg
        growth = (cfg.finest_resolution / cfg.base_resolution) ** (1 / max(1, cfg.levels - 1))
        res = [int(math.floor(cfg.base_resolution * growth**i)) for i in range(cfg.levels)]
        table = 1 << cfg.log2_table_size
        sizes = [min((r + 1) ** 3, table) for r in res]
        offsets = [0]
        for n in sizes[:-1]:
            offsets.append(offsets[-1] + n)
        self.register_buffer("res", torch.tensor(res, dtype=torch.float32), persistent=False)
        self.register_buffer("res_int", torch.tensor(res, dtype=torch.int64), persistent=False)
        self.register_buffer("size", torch.tensor(sizes, dtype=torch.int64), persistent=False)
        self.register_buffer("offset", torch.tensor(offsets, dtype=torch.int64), persistent=False)
        self.register_buffer("dense", torch.tensor([(r + 1) ** 3 <= table for r in res]), persistent=False)
        self.all_dense = all((r + 1) ** 3 <= table for r in res)
        self.register_buffer(
            "corners", torch.tensor([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)]), persistent=False
        )
        self.table = nn.Parameter(torch.empty(sum(sizes), cfg.features).uniform_(-1e-4, 1e-4))
        mlp_cfg = MLPConfig(
            width=cfg.width,
            depth=cfg.depth,
            softplus_beta=cfg.softplus_beta,
            fourier_features=0,
            geometric_init=cfg.geometric_init,
        )
        self.mlp = MLP(mlp_cfg, extra_dim=cfg.levels * cfg.features)
        self.out_dim = cfg.width

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) -> (N, levels * features)."""
        if x.device.type == "cpu" and not (torch.is_grad_enabled() and x.requires_grad):
            return self._encode_compiled(x)
        u = ((x.clamp(-self.cfg.bound, self.cfg.bound) + self.cfg.bound) / (2 * self.cfg.bound))[:, None, :] * self.res[
            None, :, None
        ]
        cell = torch.minimum(
            u.detach().floor(), (self.res - 1)[None, :, None]
        )  # (N, L, 3); the far face stays in the last cell
        t = u - cell
        w1 = t * t * (3 - 2 * t)  # smoothstep: C1 across cell faces
        idx = cell.long()[:, :, None, :] + self.corners[None, None]  # (N, L, 8, 3)
        stride = (self.res_int + 1)[None, :, None]
        flat = idx[..., 0] + stride * (idx[..., 1] + stride * idx[..., 2])
        if not self.all_dense:  # the default grid's levels all fit their tables: no hash to compute
            hashed = (idx[..., 0] * _PRIMES[0]) ^ (idx[..., 1] * _PRIMES[1]) ^ (idx[..., 2] * _PRIMES[2])
            flat = torch.where(self.dense[None, :, None], flat, hashed % self.size[None, :, None])
        flat = flat + self.offset[None, :, None]
        w = torch.stack([1 - w1, w1], -1)  # (N, L, 3, 2): weights of the near and far corner per axis
        weight = (w[:, :, 0, :, None, None] * w[:, :, 1, None, :, None] * w[:, :, 2, None, None, :]).reshape(
            *w.shape[:2], 8
        )
        feats = self.table[flat]  # (N, L, 8, F)
        return (weight[..., None] * feats).sum(2).reshape(len(x), -1)

    def _encode_compiled(self, x: torch.Tensor) -> torch.Tensor:
        """``encode`` on the CPU in one compiled loop (``qmdf.fields._grid_kernels``): 3.5x faster on field
        queries, where the encoding was 80% of the forward pass. Differentiable to the table only."""
        if torch.is_grad_enabled() and self.table.requires_grad:
            return _CompiledEncoding.apply(x, self.table, self)
        return torch.from_numpy(self._compiled_forward(x, self.table))

    def _kernel_args(self, x: torch.Tensor) -> tuple:
        return (
            x.detach().numpy().astype(np.float64, copy=False),
            self.res_int.numpy(),
            self.size.numpy(),
            self.offset.numpy(),
            self.dense.numpy(),
            float(self.cfg.bound),
        )

    def _compiled_forward(self, x: torch.Tensor, table: torch.Tensor) -> np.ndarray:
        from qmdf.fields._grid_kernels import encode_grid

        table = table.detach().numpy()
        out = np.empty((len(x), int(self.res_int.numel()) * self.cfg.features), table.dtype)
        xs, res, size, offset, dense, bound = self._kernel_args(x)
        encode_grid(xs, table, res, size, offset, dense, bound, out)
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.mlp(x, self.encode(x))


class _CompiledEncoding(torch.autograd.Function):
    """The compiled encoding with its gradient to the table: a training step whose loss reads no gradient of
    the field (the supervised route) spends 4x less on the encoding than autograd's gathers and scatter. Not
    differentiable in x; ``Grid.encode`` keeps the torch path when x needs a gradient."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, table: torch.Tensor, grid: Grid) -> torch.Tensor:
        ctx.grid = grid
        ctx.save_for_backward(x)
        return torch.from_numpy(grid._compiled_forward(x, table))

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out: torch.Tensor):
        from qmdf.fields._grid_kernels import encode_grid_backward

        (x,) = ctx.saved_tensors
        grid = ctx.grid
        grad_table = torch.zeros_like(grid.table)
        xs, res, size, offset, dense, bound = grid._kernel_args(x)
        encode_grid_backward(xs, grad_out.contiguous().numpy(), res, size, offset, dense, bound, grad_table.numpy())
        return None, grad_table, None
