"""The LightningModule: one optimisation step of the joint SDF + medial field."""
from __future__ import annotations

import math

import lightning as L
import torch

from qmdf import schema
from qmdf.fields.data import StepSampler
from qmdf.fields.losses import LOSSES, Terms
from qmdf.fields.network import MedialFieldNet


class Diverged(RuntimeError):
    """The loss became NaN or infinite."""


class FieldModule(L.LightningModule):
    """Each step draws its batch from ``sampler`` at the module's own global step (the data loader only counts),
    so an interrupted and resumed training is the same training."""

    def __init__(self, backbone: str, backbone_params: dict, losses: dict, medial_field: bool, lr: float,
                 lr_final: float, steps: int, sampler: StepSampler, ridge_every: int = 0, ridge_start: float = 0.3,
                 feature_points=None, sharp_weights: tuple[float, float] = (0.0, 0.0),
                 medial_points=None, medial_radii=None, medial_weight: float = 0.0, medial_batch: int = 4096):
        super().__init__()
        # feature-retrain (paper Sec. 4.3): L_sharp1 = mean |sdf(p_i)|, L_sharp2 = mean |mf(p_i)| at feature points
        # (|mf|: our heads are not sign-constrained, and a plain mean drove mf to -0.22 there, measured on the box)
        self.register_buffer("feature_points", None if feature_points is None else torch.as_tensor(feature_points, dtype=torch.float32))
        self.sharp_weights = sharp_weights
        # known medial points with their radii (bisectors of sharp edges): sdf = -r and mf = r there
        self.register_buffer("medial_points", None if medial_points is None else torch.as_tensor(medial_points, dtype=torch.float32))
        self.register_buffer("medial_radii", None if medial_radii is None else torch.as_tensor(medial_radii, dtype=torch.float32))
        self.medial_weight, self.medial_batch = medial_weight, medial_batch
        entry = __import__("qmdf.fields.backbones", fromlist=["BACKBONES"]).BACKBONES.get(backbone)
        self.net = MedialFieldNet(backbone, schema.build(entry.config, backbone_params))
        self.medial_field = medial_field
        self.terms = []
        for name, params in losses.items():
            e = LOSSES.get(name)
            if getattr(e.obj, "medial", False) and not medial_field:
                continue
            cfg = schema.build(e.config, params)
            if cfg.weight > 0:
                self.terms.append((name, e.obj, cfg))
        self.needs = {need for _, fn, _ in self.terms for need in getattr(fn, "needs", ())}
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
        grad = grad_mf = None
        with torch.enable_grad():
            sdf, mf = self.net(x)
            if "sdf" in self.needs:
                grad = torch.autograd.grad(sdf.sum(), x, create_graph=True)[0]
            if "mf" in self.needs and self.medial_field:
                grad_mf = torch.autograd.grad(mf.sum(), x, create_graph=True)[0]
        b = len(xs)
        t = Terms(
            xs=xs, xv=x[b:], sdf_s=sdf[:b], sdf_v=sdf[b:], grad_s=None if grad is None else grad[:b],
            grad_v=None if grad is None else grad[b:], mf_v=mf[b:] if self.medial_field else None,
            grad_mf_v=grad_mf[b:] if grad_mf is not None else None,
            sdf_fn=self.net.sdf_only, progress=self.global_step / max(1, self.steps - 1),
            normals_s=data["normals"], sdf_target_v=data["sdf_target"], mf_target_v=data["mf_target"],
        )
        values = {name: fn(t, cfg) for name, fn, cfg in self.terms}
        total = sum(cfg.weight * values[name] for name, _, cfg in self.terms)
        if self.feature_points is not None and len(self.feature_points):
            sdf_f, mf_f = self.net(self.feature_points)
            values["sharp_sdf"], values["sharp_mf"] = sdf_f.abs().mean(), mf_f.abs().mean()
            total = total + self.sharp_weights[0] * values["sharp_sdf"] + self.sharp_weights[1] * values["sharp_mf"]
        if self.medial_points is not None and len(self.medial_points) and self.medial_weight > 0:
            pick = torch.randint(len(self.medial_points), (min(self.medial_batch, len(self.medial_points)),),
                                 generator=self.sampler.generator(int(self.global_step), salt=1))
            pick = pick.to(self.medial_points.device)
            sdf_m, mf_m = self.net(self.medial_points[pick])
            r = self.medial_radii[pick]
            values["sharp_medial"] = (sdf_m + r).abs().mean() + (mf_m - r).abs().mean()
            total = total + self.medial_weight * values["sharp_medial"]
        if not torch.isfinite(total):
            raise Diverged(f"the loss became {total.item()} at step {self.global_step}")
        logs = {f"loss/{k}": v.detach() for k, v in values.items()}
        logs["loss/total"] = total.detach()
        self.log_dict(logs, on_step=True, on_epoch=False, prog_bar=False)
        if self.global_step % 10 == 0:
            self.history.append({"step": int(self.global_step), **{k: float(v) for k, v in logs.items()}})
        return total

    def configure_optimizers(self):
        opt = torch.optim.Adam(self.net.parameters(), lr=self.lr)
        final = self.lr_final / self.lr

        def cosine(step: int) -> float:
            t = min(step / max(1, self.steps), 1.0)
            return final + (1 - final) * 0.5 * (1 + math.cos(math.pi * t))

        return {"optimizer": opt, "lr_scheduler": {"scheduler": torch.optim.lr_scheduler.LambdaLR(opt, cosine), "interval": "step"}}
