"""Backbones: coordinates (N, 3) in the unit box -> features (N, out_dim). Swappable by ``train.backbone``.

Each one must be twice differentiable (the eikonal and orthogonality terms differentiate its gradient).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

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
    fourier_features: int = param(0, ge=0, doc="Gaussian Fourier features of the input (0: none, keeps geometric init exact)")
    fourier_scale: float = param(2.0, gt=0, doc="std of the Fourier frequencies (cycles per unit)")
    geometric_init: bool = param(True, doc="start from the SDF of a sphere (SAL), so training begins from a valid shape")


@register_backbone("mlp", MLPConfig)
class MLP(nn.Module):
    """DMF-style softplus MLP (smaller, for a CPU), optionally with Fourier features of the input."""

    def __init__(self, cfg: MLPConfig):
        super().__init__()
        self.cfg = cfg
        in_dim = 3
        if cfg.fourier_features:
            self.register_buffer("B", torch.randn(3, cfg.fourier_features) * cfg.fourier_scale * 2 * math.pi)
            in_dim = 3 + 2 * cfg.fourier_features
        dims = [in_dim] + [cfg.width] * cfg.depth
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.act = nn.Softplus(beta=cfg.softplus_beta)
        self.out_dim = cfg.width
        if cfg.geometric_init:
            for i, layer in enumerate(self.layers):
                nn.init.normal_(layer.weight, 0.0, math.sqrt(2) / math.sqrt(layer.out_features))
                nn.init.zeros_(layer.bias)
                if i == 0 and cfg.fourier_features:
                    nn.init.zeros_(layer.weight[:, 3:])  # Fourier features start silent, as DMF damps them

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x
        if self.cfg.fourier_features:
            proj = x @ self.B
            h = torch.cat([x, torch.sin(proj), torch.cos(proj)], dim=-1)
        for layer in self.layers:
            h = self.act(layer(h))
        return h
