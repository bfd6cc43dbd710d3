"""The joint network: a backbone trunk and three heads, sdf, mf_inner and mf_outer (paper Sec. 4.1.3)."""

from __future__ import annotations

import math

import torch
from torch import nn

from qmdf.fields.backbones import BACKBONES, MLP, MLPConfig


class MedialFieldNet(nn.Module):
    """sdf(x) and the medial field, picked by the sign of sdf: mf = mf_inner inside, mf_outer outside."""

    def __init__(self, backbone: str, backbone_cfg, head_width: int = 64, init_radius: float = 0.3):
        super().__init__()
        entry = BACKBONES.get(backbone)
        self.trunk = entry.obj(backbone_cfg)
        w = self.trunk.out_dim
        self.sdf_head = nn.Linear(w, 1)
        if getattr(backbone_cfg, "geometric_init", False):
            # SAL's geometric initialisation: the trunk + sdf head start close to |x| - init_radius
            nn.init.normal_(self.sdf_head.weight, math.sqrt(math.pi) / math.sqrt(w), 1e-4)
            nn.init.constant_(self.sdf_head.bias, -init_radius)
        medial_width = int(getattr(backbone_cfg, "medial_width", 0) or 0)
        self.medial_trunk = None
        self.medial_features = 0  # grid features the medial trunk reads (its coarsest levels')
        if medial_width:  # a smooth trunk of its own for mf (see GridConfig.medial_width)
            self.medial_features = int(getattr(backbone_cfg, "medial_levels", 0)) * backbone_cfg.features
            medial_cfg = MLPConfig(width=medial_width, depth=3, geometric_init=False)
            self.medial_trunk = MLP(medial_cfg, extra_dim=self.medial_features)
            w = medial_width
        self.mf_inner = self._head(w, head_width)
        self.mf_outer = self._head(w, head_width)

    @staticmethod
    def _head(w: int, hw: int) -> nn.Module:
        head = nn.Sequential(
            nn.Linear(w, hw), nn.Softplus(beta=100), nn.Linear(hw, hw), nn.Softplus(beta=100), nn.Linear(hw, 1)
        )
        nn.init.constant_(head[-1].bias, 0.1)  # a positive radius to start from
        return head

    def forward(self, x: torch.Tensor, medial_from: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
        """(sdf (N,), mf (N - medial_from,)): mf of ``x[medial_from:]`` only, so a training step whose first
        rows are surface samples (no medial term reads their mf) does not pay for it there."""
        if self.medial_features:
            encoding = self.trunk.encode(x)
            h = self.trunk.mlp(x, encoding)
            hm = self.medial_trunk(x[medial_from:], encoding[medial_from:, : self.medial_features])
        else:
            h = self.trunk(x)
            hm = h[medial_from:] if self.medial_trunk is None else self.medial_trunk(x[medial_from:])
        sdf = self.sdf_head(h).squeeze(-1)
        # each point through its own head only: a point's mf does not depend on the other head, so this is the
        # same function and gradient as choosing between both heads' outputs, at half the heads' cost
        inside = (sdf[medial_from:] < 0).detach()
        rows_in, rows_out = inside.nonzero().squeeze(1), (~inside).nonzero().squeeze(1)
        parts = torch.cat([self.mf_inner(hm[rows_in]).squeeze(-1), self.mf_outer(hm[rows_out]).squeeze(-1)])
        where = rows_in.new_empty(len(hm))  # each row's place in parts
        where[torch.cat([rows_in, rows_out])] = torch.arange(len(hm), device=hm.device)
        return sdf, parts[where]

    def sdf_only(self, x: torch.Tensor) -> torch.Tensor:
        return self.sdf_head(self.trunk(x)).squeeze(-1)
