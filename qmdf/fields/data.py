"""Training samples: batches of input points (the paper's 4096) plus volume samples, drawn per step from a
generator seeded by (seed, step), so a resumed run draws exactly what an uninterrupted one would."""
from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset


def local_spacing(points: np.ndarray, k: int = 50) -> np.ndarray:
    """Distance to the k-th neighbour (IGR's per-point Gaussian scale), clipped to a sane range."""
    from scipy.spatial import cKDTree

    k = int(min(k, len(points) - 1))
    d, _ = cKDTree(points).query(points, k=k + 1)
    return np.clip(d[:, -1], 2e-3, 0.1)


class StepBatches(Dataset):
    """Item i is the batch of step i: (surface points, volume points), plus the surface points' normals when
    ``normals`` is given."""

    def __init__(self, points: np.ndarray, steps: int, surface_batch: int, volume_batch: int,
                 uniform_fraction: float, seed: int, box: float = 0.6, start: int = 0, normals: np.ndarray | None = None):
        self.points = torch.as_tensor(points, dtype=torch.float32)
        self.normals = None if normals is None else torch.as_tensor(normals, dtype=torch.float32)
        self.sigma = torch.as_tensor(local_spacing(points), dtype=torch.float32)
        self.steps, self.bs, self.bv = steps, surface_batch, volume_batch
        self.n_uniform = int(round(volume_batch * uniform_fraction))
        self.seed, self.box = seed, box
        self.start = start  # a resumed run continues with the batches of the steps it has not done

    def __len__(self) -> int:
        return self.steps - self.start

    def __getitem__(self, index: int):
        step = self.start + index
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + step)
        n = len(self.points)
        pick = torch.randint(n, (self.bs,), generator=g)
        xs = self.points[pick]
        near_idx = torch.randint(n, (self.bv - self.n_uniform,), generator=g)
        near = self.points[near_idx] + torch.randn(len(near_idx), 3, generator=g) * self.sigma[near_idx, None]
        uniform = (torch.rand(self.n_uniform, 3, generator=g) * 2 - 1) * self.box
        if self.normals is None:
            return xs, torch.cat([near, uniform])
        return xs, torch.cat([near, uniform]), self.normals[pick]


def loader(ds: StepBatches) -> DataLoader:
    return DataLoader(ds, batch_size=None, shuffle=False, num_workers=0)
