"""The train stage on tiny settings: it learns, it saves a field that loads with weights_only=True, it
resumes, it stops cleanly on divergence, and the medial field can be switched off (the paper's ablation)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from qmdf.fields.field import Field
from qmdf.geometry.shapes import torus_sdf
from qmdf.pipeline import Pipeline
from qmdf.errors import QmdfError

TINY = [
    "input.shape=torus",
    "input.shape_resolution=64",
    "pipeline.stages=[sample,train]",
    "train.optim.surface_batch=512",
    "train.model.backbone=mlp",
    "train.supervision.volume_samples=20000",
    "train.optim.volume_batch=512",
    "train.model.backbones.mlp.width=48",
    "train.model.backbones.mlp.depth=3",
]


def run(compose_cfg, tmp_path, *more, name="run"):
    return Pipeline(compose_cfg(*TINY, *more), tmp_path / name, tmp_path).run()


def test_training_fits_the_torus_and_saves_a_loadable_field(compose_cfg, tmp_path):
    res = run(compose_cfg, tmp_path, "train.optim.steps=300", "train.trainer.picture=true")
    path = res.path("field")
    raw = torch.load(path, weights_only=True)  # plain containers only
    assert raw["format"] == "qmdf-field/1" and raw["backbone"] == "mlp"
    field = res.load("field")
    assert isinstance(field, Field)
    rng = np.random.default_rng(0)
    near = rng.uniform(-0.55, 0.55, (4000, 3))
    near = near[np.abs(torus_sdf(near)) < 0.1]
    out = field.evaluate(near, grad=True)
    # after 300 tiny steps the zero level set follows the torus and the sign is right away from it
    # (metric accuracy deep inside needs the full budget: python -m qmdf.bench field measures it)
    exact = torus_sdf(near)
    assert np.median(np.abs(out["sdf"] - exact)) < 0.03
    away = np.abs(exact) > 0.03
    assert np.mean(np.sign(out["sdf"][away]) == np.sign(exact[away])) > 0.98
    # near the surface the gradient points along the torus's normal
    rho = np.hypot(near[:, 0], near[:, 1])
    ring = np.c_[0.35 * near[:, 0] / rho, 0.35 * near[:, 1] / rho, np.zeros(len(near))]
    normal = (near - ring) / np.linalg.norm(near - ring, axis=1, keepdims=True)
    grad_dir = out["sdf_grad"] / np.linalg.norm(out["sdf_grad"], axis=1, keepdims=True)
    assert np.median((grad_dir * normal).sum(1)) > 0.95
    assert np.allclose(out["q"], out["mf"] - np.abs(out["sdf"]), atol=1e-6)
    training = res.load("training")
    first, last = training["history"][0], training["history"][-1]
    assert last["loss/surface"] < 0.2 * first["loss/surface"]
    for pic in ("slices.png", "losses.png"):
        assert (res.run_dir / "01_train" / pic).stat().st_size > 5000
    # the mesh route keeps its medial rays for coverage: every sample's ball, as deep as the torus's tube radius, 0.15
    rays = res.load("medial_rays")
    assert np.array_equal(rays["origins"], res.load("points").points)
    assert abs(np.median(rays["radii"]) - 0.15) < 3e-3 and rays["tol"] > 0
    assert (res.run_dir / "01_train" / "logs").exists()  # the CSV logger


def test_field_queries_are_chunked_consistently(compose_cfg, tmp_path):
    res = run(compose_cfg, tmp_path, "train.optim.steps=5")
    f = res.load("field")
    pts = np.random.default_rng(1).uniform(-0.5, 0.5, (5000, 3))
    whole = f.evaluate(pts)["q"]
    f.chunk = 777
    assert np.allclose(f.evaluate(pts)["q"], whole, atol=1e-6)


def test_without_medial_field_trains_the_sdf_only(compose_cfg, tmp_path):
    res = run(compose_cfg, tmp_path, "train.optim.steps=20", "train.model.medial_field=false")
    losses = res.load("training")["final_losses"]
    assert "loss/surface" in losses and not any(k.startswith("loss/mf_") for k in losses)


@pytest.mark.slow
def test_resume_trains_every_step_and_matches_an_uninterrupted_run(compose_cfg, tmp_path, caplog):
    """Interrupted at step 30 of 80 with a checkpoint every 20: the rerun resumes at 20, trains to step 80 (a bug
    once stopped it near 50 while training.json said 80, and cached the short field) and ends with the weights of
    a run that was never interrupted."""
    from qmdf.fields import module as module_mod

    caplog.set_level("INFO")
    original = module_mod.FieldModule.training_step

    def interrupt_at_30(self, batch, idx):
        if self.global_step == 30:
            raise RuntimeError("simulated crash")  # a crash (or Ctrl-C) in the middle of training
        return original(self, batch, idx)

    settings = ("train.optim.steps=80", "train.trainer.checkpoint_every=20")
    module_mod.FieldModule.training_step = interrupt_at_30
    try:
        with pytest.raises(RuntimeError, match="simulated crash"):
            run(compose_cfg, tmp_path, *settings, name="a")
    finally:
        module_mod.FieldModule.training_step = original
    works = list((tmp_path / "cache" / "train").glob("*.work/last.ckpt"))
    assert len(works) == 1
    assert torch.load(works[0], weights_only=True)["global_step"] == 20
    steps_seen = []

    def count(self, batch, idx):
        steps_seen.append(int(self.global_step))
        return original(self, batch, idx)

    module_mod.FieldModule.training_step = count
    try:
        res = run(compose_cfg, tmp_path, *settings, name="b")
    finally:
        module_mod.FieldModule.training_step = original
    assert "resuming from" in caplog.text
    assert steps_seen == list(range(20, 80))  # from the checkpoint to the last step, each once
    history = res.load("training")["history"]
    assert history[0]["step"] == 20 and history[-1]["step"] == 70
    assert not list((tmp_path / "cache" / "train").glob("*.work"))  # scratch removed after success
    whole = run(compose_cfg, tmp_path, *settings, f"cache.dir={tmp_path / 'other_cache'}", name="c")
    resumed = torch.load(res.path("field"), weights_only=True)["state_dict"]
    straight = torch.load(whole.path("field"), weights_only=True)["state_dict"]
    assert max((resumed[k] - straight[k]).abs().max().item() for k in straight) < 1e-5


def test_divergence_stops_with_a_clear_message(compose_cfg, tmp_path):
    with pytest.raises(QmdfError, match="training diverged: the loss became (nan|inf)"):
        run(compose_cfg, tmp_path, "train.optim.steps=50", "train.optim.lr=1e30", "train.optim.lr_final=1e29")


def test_bad_train_settings_are_listed(compose_cfg):
    from qmdf.config import validate

    problems = validate(
        compose_cfg(
            "train.model.backbone=hashgrid",
            "+train.optim.losses.smooth.weight=1",
            "train.optim.losses.surface.weight=-1",
        )
    )
    keys = sorted(p.key for p in problems)
    assert keys == ["train.model.backbone", "train.optim.losses.smooth", "train.optim.losses.surface.weight"]


def test_grid_backbone_is_twice_differentiable_and_smooth_across_cells():
    from qmdf.fields.backbones import Grid, GridConfig

    g = Grid(GridConfig(levels=3, base_resolution=4, finest_resolution=16, log2_table_size=8)).double()
    with torch.no_grad():
        g.table.normal_()
    x = (torch.rand(6, 3, dtype=torch.float64) - 0.5).requires_grad_(True)
    assert torch.autograd.gradcheck(g.encode, (x,)) and torch.autograd.gradgradcheck(g.encode, (x,))
    # C1: the gradient is continuous across a cell face (linear blending would jump there)
    face = -0.6 + 1.2 * 3 / 16  # a face of the finest level
    pts = torch.tensor(
        [[face - 1e-10, 0.013, -0.021], [face + 1e-10, 0.013, -0.021]], dtype=torch.float64, requires_grad=True
    )
    jac = torch.stack(
        [torch.autograd.grad(g.encode(pts)[:, k].sum(), pts)[0] for k in range(g.cfg.levels * g.cfg.features)]
    )
    assert torch.allclose(jac[:, 0], jac[:, 1], atol=1e-6) and jac.abs().max() > 1
    # the dense coarse level and the hashed fine level both index inside their part of the table
    assert bool(g.dense[0]) and not bool(g.dense[-1])


def test_grid_backbone_trains_through_the_pipeline(compose_cfg, tmp_path):
    res = run(
        compose_cfg,
        tmp_path,
        "train.optim.steps=150",
        "train.model.backbone=grid",
        "train.model.backbones.grid.width=32",
        "train.model.backbones.grid.finest_resolution=32",
        "train.trainer.picture=false",
    )
    assert res.load("field").meta["backbone"] == "grid"
    hist = res.load("training")["history"]
    assert hist[-1]["loss/surface"] < 0.3 * hist[0]["loss/surface"]


@pytest.mark.slow
def test_normal_loss_gets_a_thin_plate_right(compose_cfg, tmp_path):
    """A plate 0.03 thick: with its mesh's outward normals (train.optim.losses.normal) the learned inside is the plate,
    thin; from the points alone with the paper's losses it need not be (ABC 00000329 came out ten times thicker)."""
    import trimesh

    path = tmp_path / "plate.ply"
    trimesh.creation.box(extents=(1.0, 0.4, 0.03)).subdivide().export(path)
    res = run(
        compose_cfg, tmp_path, f"input.path={path}", "train.optim.steps=300", "train.optim.losses.normal.weight=100"
    )
    field = res.load("field")
    rng = np.random.default_rng(0)
    xy = rng.uniform([-0.4, -0.15], [0.4, 0.15], (2000, 2))
    mid = field.evaluate(np.c_[xy, np.zeros(len(xy))])["sdf"]
    above = field.evaluate(np.c_[xy, np.full(len(xy), 0.06)])["sdf"]
    below = field.evaluate(np.c_[xy, np.full(len(xy), -0.06)])["sdf"]
    assert np.mean(mid < 0) > 0.95 and np.mean(above > 0.02) > 0.95 and np.mean(below > 0.02) > 0.95
    history = res.load("training")["history"]
    assert history[-1]["loss/normal"] < 0.1 < history[0]["loss/normal"]  # 1 - cos: the gradients turned to the normals
    # a point file without normals: they are estimated and oriented (the raw-points route), and the plate stays thin
    pts = tmp_path / "plate.xyz"
    np.savetxt(pts, res.load("points").points)
    cloud = run(
        compose_cfg,
        tmp_path,
        f"input.path={pts}",
        "train.optim.steps=300",
        "train.optim.losses.normal.weight=100",
        name="cloud",
    )
    assert cloud.load("training")["supervision"]["route"] == "raw_points"
    # WNNC orients the plate's two sides apart (propagation turned a third of them over, and the Poisson surface
    # did not close): the targets come from its closed Poisson surface
    sup = cloud.load("training")["supervision"]
    assert sup["orientation"]["method"] == "wnnc" and sup["proxy"] == "poisson", sup
    # The plate stays thin: the space 0.06 above it is outside.
    field = cloud.load("field")
    above = field.evaluate(np.c_[xy, np.full(len(xy), 0.06)])["sdf"]
    assert np.mean(above > 0.02) > 0.9


@pytest.mark.slow
def test_same_seed_same_field(compose_cfg, tmp_path):
    """The initial weights are seeded too: two trainings with one seed give the same field, another seed another."""
    fields = {}
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        res = run(compose_cfg, tmp_path, "train.optim.steps=5", "cache.enabled=false", f"seed={seed}", name=name)
        fields[name] = torch.load(res.path("field"), weights_only=True)["state_dict"]
    diff = {k: max((fields[k][p] - fields["a"][p]).abs().max().item() for p in fields["a"]) for k in "bc"}
    assert diff["b"] == 0.0 and diff["c"] > 1e-3, diff


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(2, 130), (15, 143)])
def test_a_signal_saves_a_checkpoint_and_the_rerun_ends_with_the_uninterrupted_field(
    compose_cfg, tmp_path, signum, code
):
    """Ctrl-C (SIGINT) or a scheduler's SIGTERM at step 30 of 80 with checkpoints only every 50: the run ends as
    interrupted with 128 + the signal, keeps a checkpoint of step 30 (it once lost all work since the last periodic
    one and exited 1 with "SystemExit: 1" in the manifest), and the rerun resumes there and ends with the weights
    of a run that was never interrupted."""
    import json
    import os

    from qmdf.errors import Interrupted
    from qmdf.fields import module as module_mod

    original = module_mod.FieldModule.optimizer_step
    sent = []

    def signal_after_the_update(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        if self.global_step >= 30 and not sent:
            # a real signal, delivered to this process's main thread right after the weights moved and before
            # the step is counted done: a checkpoint written here resumed into another field (bench faults)
            sent.append(self.global_step)
            os.kill(os.getpid(), signum)
        return out

    settings = ("train.optim.steps=80", "train.trainer.checkpoint_every=50")
    module_mod.FieldModule.optimizer_step = signal_after_the_update
    try:
        with pytest.raises(Interrupted, match="at training step 31 of 80: checkpoint saved") as info:
            run(compose_cfg, tmp_path, *settings, name="a")
    finally:
        module_mod.FieldModule.optimizer_step = original
    assert info.value.exit_code == code
    assert json.loads((tmp_path / "a" / "manifest.json").read_text())["status"] == "interrupted"
    (work,) = (tmp_path / "cache" / "train").glob("*.work/last.ckpt")
    assert torch.load(work, weights_only=True)["global_step"] == 31  # the step under way finished first
    res = run(compose_cfg, tmp_path, *settings, name="b")
    assert res.load("training")["history"][-1]["step"] == 70
    whole = run(compose_cfg, tmp_path, *settings, f"cache.dir={tmp_path / 'other_cache'}", name="c")
    resumed = torch.load(res.path("field"), weights_only=True)["state_dict"]
    straight = torch.load(whole.path("field"), weights_only=True)["state_dict"]
    assert max((resumed[k] - straight[k]).abs().max().item() for k in straight) < 1e-5


def test_another_backbones_settings_do_not_retrain(compose_cfg, tmp_path):
    """The cache key holds only the chosen backbone's settings: a change to grid's leaves an mlp training cached;
    a change to mlp's retrains it."""
    from qmdf.pipeline import Pipeline

    base = ["input.shape=torus", "pipeline.stages=[sample,train]"]
    runs = [
        Pipeline(compose_cfg(*base, *extra), tmp_path / f"run{i}", tmp_path).run()
        for i, extra in enumerate(([], ["train.model.backbones.grid.levels=4"], ["train.model.backbones.mlp.width=16"]))
    ]
    status = [[s["status"] for s in r.manifest["stages"] if s["name"] == "train"][0] for r in runs]
    assert status == ["ran", "cached", "ran"]
    # a finished run opens from its folder alone, as a later script would
    from qmdf.pipeline import RunResult

    opened = RunResult.open(runs[2].run_dir)
    assert opened.complete and opened.load("training")["steps"] == runs[2].load("training")["steps"]
    assert opened.path("field") == runs[2].path("field")


def test_medial_levels_feed_the_grids_coarse_levels_to_mf_only():
    from qmdf.fields.module import build_net

    torch.manual_seed(0)
    net = build_net("grid", {"levels": 4, "finest_resolution": 32, "log2_table_size": 12, "medial_levels": 2})
    assert net.medial_features == 2 * 2
    with torch.no_grad():
        net.trunk.mlp.layers[0].weight.normal_()  # the geometric init leaves the sdf deaf to the grid at first
    x = torch.rand(64, 3) - 0.5
    sdf0, mf0 = net(x)
    levels = net.trunk.offset.tolist() + [len(net.trunk.table)]
    with torch.no_grad():  # change the finest level only: the sdf follows it, mf (reading two levels) does not
        net.trunk.table[levels[3] :] += torch.randn_like(net.trunk.table[levels[3] :])
    sdf1, mf1 = net(x)
    same_side = (sdf0 < 0) == (sdf1 < 0)  # mf is the inner head's inside, the outer head's outside
    assert not torch.allclose(sdf0, sdf1) and same_side.sum() > 10
    assert torch.allclose(mf0[same_side], mf1[same_side])
    with torch.no_grad():  # a coarse level moves both
        net.trunk.table[: levels[1]] += torch.randn_like(net.trunk.table[: levels[1]])
    sdf2, mf2 = net(x)
    assert not torch.allclose(mf1, mf2)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_compiled_grid_encoding_is_the_torch_encoding(dtype):
    """Field queries (no autograd, CPU) take the compiled loop; it must give what the differentiable torch
    encoding gives, on dense and hashed levels, at cell faces and beyond the grid's bound (clamped)."""
    from qmdf.fields.backbones import Grid, GridConfig

    g = Grid(GridConfig(levels=4, base_resolution=4, finest_resolution=40, log2_table_size=10)).to(dtype)
    with torch.no_grad():
        g.table.normal_()
    assert bool(g.dense[0]) and not bool(g.dense[-1])
    x = torch.rand(2000, 3, dtype=dtype) * 1.6 - 0.8
    x[:5] = -0.6 + 1.2 * torch.tensor([0, 1, 3, 7, 40], dtype=dtype)[:, None] / 40  # faces of the finest level
    with torch.no_grad():
        compiled = g.encode(x)
    reference = g.encode(x.clone().requires_grad_(True)).detach()  # autograd on: the torch path
    assert compiled.dtype == dtype and compiled.shape == reference.shape
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    assert (compiled - reference).abs().max() < tol * max(1.0, float(reference.abs().max()))


def test_compiled_grid_encodings_table_gradient_is_the_torch_one():
    """A training step whose loss reads no gradient in x takes the compiled encoding with its own backward to the
    table; it must be autograd's gradient of the torch encoding, on dense and hashed levels and beyond the bound."""
    from qmdf.fields.backbones import Grid, GridConfig

    g = Grid(GridConfig(levels=4, base_resolution=4, finest_resolution=40, log2_table_size=10)).double()
    with torch.no_grad():
        g.table.normal_()
    assert bool(g.dense[0]) and not bool(g.dense[-1])
    x = torch.rand(3000, 3, dtype=torch.float64) * 1.6 - 0.8
    upstream = torch.randn(3000, g.cfg.levels * g.cfg.features, dtype=torch.float64)
    (g.encode(x) * upstream).sum().backward()
    compiled = g.table.grad.clone()
    g.table.grad = None
    (g.encode(x.clone().requires_grad_(True)) * upstream).sum().backward()  # x needs a gradient: the torch path
    assert compiled.abs().max() > 1.0  # the scatter reached the table
    assert torch.allclose(compiled, g.table.grad, rtol=0, atol=1e-10)


def test_the_medial_field_of_the_volume_rows_only_is_the_same_function_and_gradient():
    """A training step asks for mf of its volume samples only (``medial_from``), each point through its own head:
    the values and every parameter's gradient must be those of the whole batch's mf restricted to those rows."""
    from qmdf.fields.module import build_net

    net = build_net("grid", {"finest_resolution": 16, "log2_table_size": 12}).double()
    x = torch.rand(400, 3, dtype=torch.float64) - 0.5
    sdf_all, mf_all = net(x)
    sdf, mf = net(x, medial_from=150)
    assert mf.shape == (250,) and torch.equal(sdf, sdf_all)
    assert (sdf[150:] < 0).any() and (sdf[150:] > 0).any()  # both heads are exercised
    assert torch.allclose(mf, mf_all[150:], rtol=0, atol=1e-14)
    weights = torch.randn(250, dtype=torch.float64)
    grads = []
    for out in (mf, mf_all[150:]):
        net.zero_grad()
        (out * weights).sum().backward(retain_graph=True)
        grads.append([p.grad.clone() for p in net.parameters() if p.grad is not None])
    assert len(grads[0]) == len(grads[1]) > 0
    assert all(torch.allclose(a, b, rtol=0, atol=1e-12) for a, b in zip(*grads))


@pytest.mark.slow
def test_a_clouds_poisson_surface_is_handed_on_as_the_data_the_radii_are_measured_to(compose_cfg, tmp_path):
    from qmdf.geometry.inside import mesh_distance
    from qmdf.geometry.sampling import sample_surface
    from qmdf.geometry.shapes import get_shape
    from qmdf.stages.inputs import radius_data

    torus = get_shape("torus").mesh(96)
    v, f = np.asarray(torus.vertices), np.asarray(torus.faces)
    cloud = sample_surface(v, f, 3000, np.random.default_rng(0))
    np.savetxt(tmp_path / "torus.xyz", np.hstack([cloud.points, cloud.normals]))
    cloud_run = [o for o in TINY if not o.startswith("input.shape")] + [f"input.path={tmp_path / 'torus.xyz'}"]
    runs = {
        flag: Pipeline(
            compose_cfg(*cloud_run, "train.optim.steps=5", f"train.supervision.point_surface_as_data={flag}"),
            tmp_path / flag,
            tmp_path,
        ).run()
        for flag in ("true", "false")
    }
    res = runs["true"]
    mesh, points = radius_data(
        res.load("input_info"), None, lambda: res.load("points"), lambda: res.load("point_surface")
    )
    assert points is None and len(mesh[1]) > 1000
    # the closed Poisson surface of the cloud, not the points: close to the torus everywhere, between the points too
    surface = trimesh.Trimesh(*mesh, process=False)
    assert surface.is_watertight and surface.euler_number == 0
    between = sample_surface(v, f, 2000, np.random.default_rng(1)).points
    norm = res.load("normalization")
    assert np.median(mesh_distance(*mesh, norm.to_unit(between))[0]) < 2e-3
    assert "point_surface" not in runs["false"].artifacts
    mesh, points = radius_data(runs["false"].load("input_info"), None, lambda: runs["false"].load("points"))
    assert mesh is None and len(points) == 3000


def test_lightnings_logger_is_named_by_target(tmp_path, compose_cfg):
    """train.trainer.logger: any Lightning logger class by ``_target_``, its other keys its arguments; a wrong
    target stops with its key path, at start where the config can tell and at the stage otherwise."""
    from lightning.pytorch import loggers

    from qmdf.config import validate
    from qmdf.errors import QmdfError
    from qmdf.stages.training import lightning_logger

    csv, on_end = lightning_logger({"_target_": "lightning.pytorch.loggers.CSVLogger", "name": "logs"}, tmp_path)
    assert isinstance(csv, loggers.CSVLogger) and csv.name == "logs" and on_end is None
    assert csv.save_dir == str(tmp_path)
    with pytest.raises(
        QmdfError, match="train.trainer.logger._target_: cannot import 'lightning.pytorch.loggers.Nope'"
    ):
        lightning_logger({"_target_": "lightning.pytorch.loggers.Nope"}, tmp_path)
    (problem,) = validate(compose_cfg("train.trainer.logger._target_=csv"))
    assert problem.key == "train.trainer.logger._target_" and "logger class" in problem.message
