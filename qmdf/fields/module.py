"""The LightningModule: one optimisation step of the joint SDF + medial field."""

from __future__ import annotations

import math
from typing import Any, Callable

import lightning as L
import torch

from qmdf import schema
from qmdf.fields.data import StepSampler
from qmdf.fields.losses import LOSSES, Terms
from qmdf.fields.network import MedialFieldNet

#: the losses are logged (and kept in the history) every this many steps; ``fitting`` gives Lightning the same
LOG_EVERY = 10


def build_net(backbone: str, params: dict) -> MedialFieldNet:
    """The joint network with the registered ``backbone`` and its settings."""
    from qmdf.fields.backbones import BACKBONES

    return MedialFieldNet(backbone, schema.build(BACKBONES.get(backbone).config, params))


def build_terms(losses: dict, medial_field: bool = True) -> list[tuple[str, Callable, Any]]:
    """(name, function, typed config) of each registered loss in ``losses`` with a positive weight; the medial
    field's terms only when it is trained."""
    terms = []
    for name, params in losses.items():
        e = LOSSES.get(name)
        if getattr(e.obj, "medial", False) and not medial_field:
            continue
        cfg = schema.build(e.config, params)
        if cfg.weight > 0:
            terms.append((name, e.obj, cfg))
    return terms


class Diverged(RuntimeError):
    """The loss became NaN or infinite."""


class FieldModule(L.LightningModule):
    """Each step draws its batch from ``sampler`` at the module's own global step (the data loader only counts),
    so an interrupted and resumed training is the same training. The network and the loss terms are built
    outside (``build_net``, ``build_terms``); ``anchors`` are named point sets some terms read beyond the batch
    (feature_retrain's feature points, medial points and radii), kept as buffers so a checkpoint holds them."""

    def __init__(
        self,
        net: MedialFieldNet,
        terms: list[tuple[str, Callable, Any]],
        sampler: StepSampler,
        *,
        steps: int,
        lr: float = 1e-3,
        lr_final: float = 1e-4,
        medial_field: bool = True,
        ridge_every: int = 0,
        ridge_start: float = 0.3,
        anchors: dict | None = None,
    ):
        super().__init__()
        self.net = net
        self.medial_field = medial_field
        self.terms = terms
        self.needs = {need for _, fn, _ in self.terms for need in getattr(fn, "needs", ())}
        self.anchor_names = []
        for name, value in (anchors or {}).items():
            self.register_buffer(
                f"anchor_{name}", None if value is None else torch.as_tensor(value, dtype=torch.float32)
            )
            self.anchor_names.append(name)
        self.lr, self.lr_final, self.steps = lr, lr_final, steps
        self.sampler = sampler
        # mf targets on the medial rays: the rays' radii, then (every ridge_every steps from ridge_start of the
        # training on) the learned |sdf| at the rays' medial points; a buffer, so a checkpoint resumes with them
        self.ridge_every = ridge_every if sampler.has_rays and medial_field else 0
        self.ridge_start = int(ridge_start * steps)
        self.register_buffer("ray_heights", None if sampler.radii is None else sampler.radii.clone())
        self.history: list[dict] = []

    def on_fit_start(self) -> None:
        self.sampler.to(self.device)

    def training_step(self, batch, batch_idx):
        step = int(self.global_step)
        if self.ridge_every and step >= self.ridge_start and (step - self.ridge_start) % self.ridge_every == 0:
            self.ray_heights = self.sampler.axis_heights(self.net.sdf_only)
        data = self.sampler.batch(step, self.ray_heights)
        xs, xv = data["xs"], data["xv"]
        x = torch.cat([xs, xv]).requires_grad_(bool(self.needs))
        b = len(xs)
        grad = grad_mf = None
        with torch.enable_grad():
            # mf of the volume samples only: no term reads it on the surface (a quarter of a step's time)
            sdf, mf_v = self.net(x, medial_from=b if self.medial_field else len(x))
            if "sdf" in self.needs:
                grad = torch.autograd.grad(sdf.sum(), x, create_graph=True)[0]
            if "mf" in self.needs and self.medial_field:
                grad_mf = torch.autograd.grad(mf_v.sum(), x, create_graph=True)[0]
        t = Terms(
            xs=xs,
            xv=x[b:],
            sdf_s=sdf[:b],
            sdf_v=sdf[b:],
            grad_s=None if grad is None else grad[:b],
            grad_v=None if grad is None else grad[b:],
            mf_v=mf_v if self.medial_field else None,
            grad_mf_v=grad_mf[b:] if grad_mf is not None else None,
            sdf_fn=self.net.sdf_only,
            progress=self.global_step / max(1, self.steps - 1),
            normals_s=data["normals"],
            sdf_target_v=data["sdf_target"],
            mf_target_v=data["mf_target"],
            net=self.net,
            anchors={name: getattr(self, f"anchor_{name}") for name in self.anchor_names},
            generator=lambda salt: self.sampler.generator(step, salt),
        )
        values = {name: fn(t, cfg) for name, fn, cfg in self.terms}
        total = sum(cfg.weight * values[name] for name, _, cfg in self.terms)
        if not torch.isfinite(total):
            raise Diverged(f"the loss became {total.item()} at step {self.global_step}")
        if step % LOG_EVERY == 0:  # Lightning's logger writes every LOG_EVERY steps; log_dict costs 2 ms a call
            logs = {f"loss/{k}": v.detach() for k, v in values.items()}
            logs["loss/total"] = total.detach()
            self.log_dict(logs, on_step=True, on_epoch=False, prog_bar=False)
            self.history.append({"step": step, **{k: float(v) for k, v in logs.items()}})
        return total

    def configure_optimizers(self):
        # one fused kernel for every tensor: 6.9 -> 1.8 ms a step on 2 cores (the grid's 1.7M parameters), about 10 s
        # over 2,000 steps by that count
        try:
            opt = torch.optim.Adam(self.net.parameters(), lr=self.lr, fused=True)
        except (RuntimeError, ValueError):  # a device without the fused kernel
            opt = torch.optim.Adam(self.net.parameters(), lr=self.lr)
        final = self.lr_final / self.lr

        def cosine(step: int) -> float:
            t = min(step / max(1, self.steps), 1.0)
            return final + (1 - final) * 0.5 * (1 + math.cos(math.pi * t))

        return {
            "optimizer": opt,
            "lr_scheduler": {"scheduler": torch.optim.lr_scheduler.LambdaLR(opt, cosine), "interval": "step"},
        }
