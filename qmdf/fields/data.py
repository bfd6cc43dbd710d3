"""Training batches. Each step's batch is drawn from the supervision's pools (input points with their normals;
volume samples with their targets) by a generator seeded by (seed, step), and drawn by the module from its own
global step: a resumed run draws exactly what an uninterrupted one would, whatever the data loader replays."""

from __future__ import annotations

import torch
from torch.utils.data import DataLoader, Dataset

from qmdf.fields.supervision import Supervision


class StepSampler:
    """Batches of one step: surface points (+ normals), volume points with their sdf and mf targets (NaN where
    unknown). A sample on a medial ray takes the mf target of its ray, from ``heights`` when the module gives
    them (``axis_heights``). Tensors live on the module's device (``to``)."""

    def __init__(self, sup: Supervision, surface_batch: int, volume_batch: int, seed: int):
        f32 = torch.float32
        self.surface = torch.as_tensor(sup.surface, dtype=f32)
        self.normals = None if sup.normals is None else torch.as_tensor(sup.normals, dtype=f32)
        self.volume = torch.as_tensor(sup.volume, dtype=f32)
        self.sdf = torch.as_tensor(sup.sdf, dtype=f32)
        self.mf = torch.as_tensor(sup.mf, dtype=f32)
        self.radii = None if sup.radii is None else torch.as_tensor(sup.radii, dtype=f32)
        self.ray = None if sup.ray is None else torch.as_tensor(sup.ray, dtype=torch.int64)
        # where the medial rays start and their direction: the points and their normals, or samples of a proxy
        # surface and its normals (``Supervision.ray_origins``)
        self.origins = self.surface if sup.ray_origins is None else torch.as_tensor(sup.ray_origins, dtype=f32)
        self.ray_normals = self.normals if sup.ray_normals is None else torch.as_tensor(sup.ray_normals, dtype=f32)
        self.bs, self.bv, self.seed = surface_batch, volume_batch, seed

    @property
    def has_rays(self) -> bool:
        if self.radii is None or self.ray_normals is None or self.ray is None:
            return False
        return bool((self.ray >= 0).any())

    def to(self, device) -> "StepSampler":
        for name in ("surface", "normals", "volume", "sdf", "mf", "radii", "ray", "origins", "ray_normals"):
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, value.to(device))
        return self

    def generator(self, step: int, salt: int = 0) -> torch.Generator:
        return torch.Generator().manual_seed(self.seed * 1_000_003 + step + salt * 7_919_993)

    def batch(self, step: int, heights: torch.Tensor | None = None) -> dict:
        g = self.generator(step)
        ps = torch.randint(len(self.surface), (self.bs,), generator=g).to(self.surface.device)
        pv = torch.randint(len(self.volume), (self.bv,), generator=g).to(self.volume.device)
        mf = self.mf[pv]
        if heights is not None and self.ray is not None:
            ray = self.ray[pv]
            mf = torch.where(ray >= 0, heights[ray.clamp_min(0)], mf)
        return {
            "xs": self.surface[ps],
            "normals": None if self.normals is None else self.normals[ps],
            "xv": self.volume[pv],
            "sdf_target": self.sdf[pv],
            "mf_target": mf,
        }

    def _along_rays(self, fn, samples: int, reach: float, chunk: int) -> torch.Tensor:
        """fn(points (M * samples, 3), depths (M, samples)) -> (M,), over the depths 0 .. reach * r of each surface
        point's medial ray, in chunks."""
        t = torch.linspace(0.0, reach, samples, device=self.surface.device)
        out = torch.empty(len(self.origins), device=self.surface.device)
        per = max(1, chunk // samples)
        for s in range(0, len(self.origins), per):
            p, n, r = self.origins[s : s + per], self.ray_normals[s : s + per], self.radii[s : s + per]
            depth = r[:, None] * t[None, :]
            x = p[:, None, :] - depth[..., None] * n[:, None, :]
            out[s : s + per] = fn(x.reshape(-1, 3), depth)
        return out

    @torch.no_grad()
    def axis_q(self, net, samples: int = 48, reach: float = 1.3, chunk: int = 1 << 16) -> torch.Tensor:
        """The lowest q = mf - |sdf| inside along each medial ray: about 0 where the field's q has its valley on the
        axis, and how far above 0 it stays where it does not (the eps a covering needs to hold the axis there)."""

        def lowest(x, depth):
            sdf, mf = net(x)
            q = torch.where(sdf < 0, mf - sdf.abs(), torch.full_like(sdf, float("inf")))
            return q.reshape(depth.shape).amin(1)

        return self._along_rays(lowest, samples, reach, chunk)

    @torch.no_grad()
    def axis_heights(self, sdf_fn, chunk: int = 1 << 16) -> torch.Tensor:
        """The learned |sdf| at each ray's medial point p - r n (r from the data). A network rounds the |sdf| ridge
        at the axis (the teacup's walls: 1.5e-3 below the true radius), so with mf = r, q = mf - |sdf| stays above
        eps on the axis and the covering has holes; with mf = this height, q is 0 at the true medial point. (Not
        the field's own ridge along the ray: past a small ball's axis a ray can enter a thicker part where |sdf|
        keeps growing, more slowly, and a search for where it stops tracking the depth drifts with the field's
        small metric errors along long rays: both were tried on the bunny.)"""
        out = torch.empty(len(self.origins), device=self.surface.device)
        for s in range(0, len(self.origins), chunk):
            centre = self.origins[s : s + chunk] - self.radii[s : s + chunk, None] * self.ray_normals[s : s + chunk]
            out[s : s + chunk] = (-sdf_fn(centre)).clamp_min(0.0)
        return out


class Steps(Dataset):
    """Item i is just i: the module draws its batch from its global step (see the module doc)."""

    def __init__(self, steps: int):
        self.steps = steps

    def __len__(self) -> int:
        return self.steps

    def __getitem__(self, index: int) -> torch.Tensor:
        return torch.tensor(index)


def loader(steps: int) -> DataLoader:
    return DataLoader(Steps(steps), batch_size=None, shuffle=False, num_workers=0)
