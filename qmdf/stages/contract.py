"""``contract``: collapse the covering's volume onto the medial axis (paper Sec. 4.2, Fig. 8).

Energy over vertex positions, connectivity kept:
    mean over surface vertices of q(v)  +  lambda_volume * max(Vol, 0) / A0  +  lambda_laplacian * mean_i w_i |L v_i|^2
with Vol the enclosed volume (of the tets, or of the closed surface), A0 the initial surface area (so the
volume term is a mean thickness, comparable to q), L the uniform umbrella Laplacian and w_i inversely
proportional to the area around v_i (DCUDF). Steps: a per-vertex ("vector") Adam with cosine decay.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MESH, TETS
from qmdf.errors import QmdfError
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class ContractConfig:
    iterations: int = param(3000, ge=1, doc="optimisation steps (paper: about 3k)")
    lr: float = param(5e-4, gt=0, doc="step length in the unit box (DCUDF: 5e-4), cosine-decayed")
    lr_final: float = param(1e-6, gt=0)
    lambda_volume: float = param(1.0, ge=0, doc="weight of the enclosed volume (per initial area)")
    lambda_laplacian: float = param(100.0, ge=0, doc="weight of the area-weighted Laplacian smoothness")
    volume: str = param("surface", choices=("surface", "tets"), doc="enclosed volume of the surface (default, measured better) or of the tets")
    log_every: int = param(25, ge=1)


def umbrella(n_vertices: int, faces: np.ndarray):
    """Sparse uniform Laplacian L = I - D^-1 A of a triangle mesh, as a torch sparse matrix."""
    import torch

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    rows = np.concatenate([e[:, 0], e[:, 1]])
    cols = np.concatenate([e[:, 1], e[:, 0]])
    deg = np.bincount(rows, minlength=n_vertices).astype(np.float64)
    vals = -1.0 / np.maximum(deg[rows], 1)
    idx = np.vstack([np.r_[rows, np.arange(n_vertices)], np.r_[cols, np.arange(n_vertices)]])
    data = np.r_[vals, (deg > 0).astype(np.float64)]
    return torch.sparse_coo_tensor(torch.as_tensor(idx), torch.as_tensor(data), (n_vertices, n_vertices),
                                   check_invariants=True).coalesce()


def area_weights(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """w_i = max_j sqrt(A_j) / sqrt(A_i), A_i the area of the faces around vertex i (DCUDF)."""
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    a = np.bincount(faces.ravel(), np.repeat(area, 3), minlength=len(v))
    a = np.maximum(a, 1e-20)
    return np.sqrt(a.max()) / np.sqrt(a)


def contract(field, vertices: np.ndarray, faces: np.ndarray, tets: np.ndarray | None, cfg: ContractConfig):
    """The contracted vertices and the per-iteration log of the energy terms and the volume."""
    import math

    import torch

    from qmdf.geometry.tets import signed_volumes

    x = torch.tensor(vertices, dtype=torch.float64, requires_grad=True)
    surf = np.unique(faces)
    F = torch.as_tensor(faces, dtype=torch.int64)
    T = None if tets is None else torch.as_tensor(tets, dtype=torch.int64)
    if tets is not None and signed_volumes(vertices, tets).sum() < 0:
        T = T[:, [0, 2, 1, 3]]
    L = umbrella(len(vertices), faces)
    tri = vertices[faces]
    area0 = float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    w = torch.as_tensor(area_weights(vertices, faces))
    m = torch.zeros_like(x)
    s = torch.zeros(len(vertices), dtype=torch.float64)
    b1, b2 = 0.9, 0.999
    history = []

    def volume(xx):
        if T is not None:
            a, b, c, d = (xx[T[:, k]] for k in range(4))
            return (torch.cross(b - a, c - a, dim=1) * (d - a)).sum(1).sum() / 6.0
        v0, v1, v2 = xx[F[:, 0]], xx[F[:, 1]], xx[F[:, 2]]
        return (v0 * torch.cross(v1, v2, dim=1)).sum() / 6.0

    vol0 = float(volume(x.detach()))
    for it in range(cfg.iterations):
        out = field.evaluate(x.detach().numpy()[surf], grad=True)
        q_grad = np.zeros_like(vertices)
        q_grad[surf] = out["q_grad"] / len(surf)
        vol = volume(x)
        lap = torch.sparse.mm(L, x)
        e_lap = (w[:, None] * lap.pow(2)).sum(1).mean()
        # max(Vol, 0): the signed volume has no minimum at zero; once the layers meet it would keep pushing
        # them through each other (measured: the box's covering diverged to -2e3 without the clamp)
        geom = cfg.lambda_volume * torch.clamp(vol, min=0.0) / area0 + cfg.lambda_laplacian * e_lap
        (g,) = torch.autograd.grad(geom, x)
        g = g + torch.as_tensor(q_grad)
        with torch.no_grad():
            m.mul_(b1).add_(g, alpha=1 - b1)
            s.mul_(b2).add_(g.pow(2).sum(1), alpha=1 - b2)  # one second moment per vertex: isotropic steps
            t = it + 1
            lr = cfg.lr_final + (cfg.lr - cfg.lr_final) * 0.5 * (1 + math.cos(math.pi * it / cfg.iterations))
            step = (m / (1 - b1 ** t)) / (torch.sqrt(s / (1 - b2 ** t))[:, None] + 1e-16)
            x.sub_(lr * step)
        if it % cfg.log_every == 0 or it == cfg.iterations - 1:
            rec = {"iteration": it, "q_mean": float(out["q"].mean()), "volume": vol.item(), "laplacian": e_lap.item(),
                   "energy": float(out["q"].mean()) + geom.item(), "lr": lr}
            history.append(rec)
            if not np.isfinite(rec["energy"]):
                raise QmdfError(f"contraction diverged at iteration {it}; lower contract.lr")
    return x.detach().numpy(), history, vol0


@register_stage("contract")
class Contract(Stage):
    """Optimise the covering's vertices onto the minima of Q-MDF while its volume goes to zero."""

    Config = ContractConfig
    inputs = {"covering": MESH, "field": FIELD}
    optional_inputs = {"covering_tets": TETS}
    outputs = {"membrane": MESH, "contraction": JSON}
    optional_outputs = {"contracted_tets": TETS}

    def run(self, ctx: StageContext) -> None:
        import trimesh

        from qmdf.geometry.tets import boundary_faces

        cfg: ContractConfig = ctx.cfg
        field = ctx.load("field")
        use_tets = cfg.volume == "tets"
        if use_tets:
            if not ctx.has("covering_tets"):
                raise QmdfError("contract.volume=tets needs the tetrahedralize stage before contract")
            v, t = ctx.load("covering_tets")
            faces = boundary_faces(t, v)
        else:
            mesh = ctx.load("covering")
            v, t, faces = np.asarray(mesh.vertices), None, np.asarray(mesh.faces)
        x, history, vol0 = contract(field, v, faces, t, cfg)
        used = np.unique(faces)
        remap = np.full(len(x), -1)
        remap[used] = np.arange(len(used))
        membrane = trimesh.Trimesh(x[used], remap[faces], process=False)
        ctx.save("membrane", membrane)
        if t is not None:
            ctx.save("contracted_tets", (x, t))
        final = history[-1]
        ctx.save("contraction", {"initial_volume": vol0, "final_volume": final["volume"],
                                 "volume_ratio": final["volume"] / vol0 if vol0 else None,
                                 "volume_mode": "tets" if use_tets else "surface", "history": history})
        ctx.log.info("contracted (%s volume): volume %.3g -> %.3g (%.2f%%), mean q %.2e", "tet" if use_tets else "surface",
                     vol0, final["volume"], 100 * final["volume"] / vol0 if vol0 else float("nan"), final["q_mean"])
