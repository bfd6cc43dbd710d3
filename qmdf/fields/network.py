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

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(sdf, mf), each (N,)."""
        if self.medial_features:
            encoding = self.trunk.encode(x)
            h = self.trunk.mlp(x, encoding)
            hm = self.medial_trunk(x, encoding[:, : self.medial_features])
        else:
            h = self.trunk(x)
            hm = h if self.medial_trunk is None else self.medial_trunk(x)
        sdf = self.sdf_head(h).squeeze(-1)
        inside = sdf < 0
        if torch.is_grad_enabled():
            mf = torch.where(inside, self.mf_inner(hm).squeeze(-1), self.mf_outer(hm).squeeze(-1))
        else:  # queries: each point through its own head only (a fifth of the forward pass)
            mf = torch.empty_like(sdf)
            mf[inside] = self.mf_inner(hm[inside]).squeeze(-1)
            mf[~inside] = self.mf_outer(hm[~inside]).squeeze(-1)
        return sdf, mf

    def sdf_only(self, x: torch.Tensor) -> torch.Tensor:
        return self.sdf_head(self.trunk(x)).squeeze(-1)
