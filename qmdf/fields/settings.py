"""The field's training settings in groups (``train.model``, ``train.supervision``, ``train.optim``,
``train.trainer``): the train stage's config and the defaults of the library functions that take them
(``supervision.build_supervision``), one source for both."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from qmdf import schema
from qmdf.geometry.orientation import ORIENTATIONS
from qmdf.schema import param


def _backbones():
    from qmdf.fields.backbones import BACKBONES

    return BACKBONES


def _default_losses() -> dict:
    from qmdf.fields.losses import default_losses

    return default_losses()


def _paper_losses() -> dict:
    from qmdf.fields.losses import paper_losses

    return paper_losses()


def _losses():
    from qmdf.fields.losses import LOSSES

    return LOSSES


@dataclass
class ModelSettings:
    backbone: str = param(
        "grid",
        doc="network trunk (python -m qmdf.plugins lists them); grid resolves the teacup's "
        "0.046-thick walls with |grad sdf| 1.00 inside where the 128x4 MLP reached 0.16-0.55 (same 2,000 steps)",
    )
    backbones: dict[str, Any] = param(
        factory=lambda: schema.registered_defaults(_backbones()),
        doc="each backbone's settings; the chosen one is used",
        schemas=lambda: schema.registered_schemas(_backbones()),
    )
    medial_field: bool = param(True, doc="train the medial field too; false: the paper's 'w/o MF' ablation")


@dataclass
class PoissonSettings:
    """A cloud's screened Poisson surface (``geometry.proxy_surface.poisson_surface``)."""

    depth: int = param(8, ge=5, le=11, doc="octree depth of the Poisson surface (8: cells of 1/256 of the box)")
    point_weight: float = param(4.0, ge=0, doc="screening weight: higher follows the points more closely, noise too")
    samples_per_node: float = param(
        0.25,
        gt=0,
        doc="the Poisson octree refines a node while it holds this many points: small follows a sparse clean "
        "cloud between its points (the 1,000-point block's sign 99.16% -> 99.59% against 1.5)",
    )
    coarse_samples_per_node: float = param(
        1.5,
        gt=0,
        doc="the same for the coarse surface taken instead where the fine one has other pieces or another "
        "solid Euler characteristic (it fits noise); equal to poisson_samples_per_node: no check",
    )


@dataclass
class DenoiseSettings:
    """A noisy cloud's points moved onto their local surface before the Poisson solve
    (``geometry.point_denoise``)."""

    mode: str = param(
        "auto",
        choices=("auto", "on", "off"),
        doc="auto: when the points' local quadric fits leave a residual above threshold sampling gaps (noise; a "
        "clean or sparse cloud's residual is its surface's curvature, a few percent of the gap); on: always; off",
    )
    threshold: float = param(
        0.2,
        gt=0,
        doc="auto's noise test, in sampling gaps (clean and sparse clouds of six bench shapes at most 0.045, the "
        "sparse block file 0.135, SRB scans 0.06 to 0.13; 0.5% noise 0.29 to 0.42, the noisy double torus files "
        "0.23 and 0.28)",
    )
    neighbours: int = param(
        48, ge=8, doc="points per quadric fit: the noise is averaged down by about the square root of this"
    )
    passes: int = param(2, ge=1, doc="projections in turn (each refits the quadrics to the moved points)")
    rounds: int = param(
        3,
        ge=1,
        doc="raw points: at most this many rounds of smoothing and orienting the smoothed points again (until a "
        "round turns under 0.1% of the normals); the noise is what misleads the orientation",
    )


@dataclass
class UpsampleSettings:
    """A sparse cloud given to the Poisson solve with new points on its local quadrics
    (``geometry.point_upsample``)."""

    mode: str = param(
        "auto",
        choices=("auto", "on", "off"),
        doc="auto: clouds of fewer than max_points points; on: always; off: never (the points as they are)",
    )
    max_points: int = param(
        10_000,
        ge=0,
        doc="auto's limit: sparse clouds (the bench's 1,000 and 2,000 points of 18 shapes: the Poisson surface's CD "
        "lower on 35 of 36, its solid chi right on 24 against 20); at 20k points it gains little (CD x0.73 to x1.09 "
        "on four models) and costs 5-11 s",
    )
    count: int = param(6, ge=1, doc="new points around each point, on a ring in its tangent plane")
    ring: float = param(
        0.35, gt=0, le=0.5, doc="the ring's radius in sampling gaps: inside the point's own neighbourhood"
    )
    neighbours: int = param(16, ge=8, doc="points per quadric fit (same-side neighbours only)")


@dataclass
class SupervisionSettings:
    route: str = param(
        "auto",
        choices=("auto", "mesh", "oriented_points", "raw_points", "paper"),
        doc="what the field learns from: auto picks mesh (an undegraded mesh input), oriented_points "
        "(points with normals) or raw_points; paper: the raw points alone, no normals or distances",
    )
    orientation: str = param(
        "wnnc",
        choices=ORIENTATIONS,
        doc="raw points: how their estimated normals are oriented. wnnc: the winding number's normal "
        "consistency (Lin et al. 2024), global, right where a wall is as thin as the sampling gap (the "
        "1,500-point teacup: 99.9% right); propagation: along a spanning tree, then winding checks (56% there)",
    )
    point_surface: str = param(
        "poisson",
        choices=("poisson", "points"),
        doc="on a point cloud (oriented_points, raw_points): poisson: a screened Poisson surface of the "
        "oriented points gives the sign, the distances and the medial rays (the sparse bunny's "
        "covering: genus 301 from the points alone); points: the points' winding number and distances",
    )
    zero_level: str = param(
        "input",
        choices=("input", "proxy"),
        doc="with a Poisson surface: the zero level set passes through the input points (input) or "
        "through samples of the Poisson surface (proxy: smooths a noisy cloud's noise away, "
        "loses the exactness of a clean sparse cloud's points)",
    )
    mesh_rays: str = param(
        "smooth",
        choices=("smooth", "face"),
        doc="on a mesh, the medial rays' directions: smooth (normals interpolated from the corners, tol 3e-4 + 8% "
        "of the median edge: the torus's radii within 3e-4) or face (the faces' normals, tol 1e-4: they meet the "
        "faceted mesh's own medial sheets, the torus's radii 0.055 short)",
    )
    point_surface_as_data: bool = param(
        True,
        doc="hand a cloud's closed Poisson surface on as the data later stages measure the MAT against (radii, "
        "centring, coverage, rims): distances to sparse points over-estimate the depth by about gap^2 / (8 r) "
        "between them (the 1,000-point block's MAT radii 5.6e-3 too large on average, against 1.3e-3 to the "
        "surface); false: the input points",
    )
    volume_samples: int = param(
        1_000_000, ge=1000, doc="volume samples with their targets, drawn once; each step picks volume_batch of them"
    )
    uniform_fraction: float = param(0.25, ge=0, le=1, doc="share of volume samples uniform in the box")
    ray_fraction: float = param(
        0.4,
        ge=0,
        le=1,
        doc="share of volume samples on the medial rays (inward from the surface "
        "samples to their medial balls, half by the axis); the rest near the points. Not for the paper route",
    )
    axis_band: str = param(
        "across",
        choices=("across", "inward"),
        doc="the ray samples by the axis: on both sides of it along the ray's line (where a mesh or a cloud's "
        "Poisson surface gives every sample its distance), so each side of the axis is sampled alike; inward: "
        "from the ray's own side only (before 2026-12-04: the torus's q valley 1.1e-3 inward of its axis, "
        "whose outer half sends 1.75x the rays)",
    )
    poisson: PoissonSettings = param(factory=PoissonSettings)
    denoise: DenoiseSettings = param(factory=DenoiseSettings)
    upsample: UpsampleSettings = param(factory=UpsampleSettings)


@dataclass
class OptimSettings:
    steps: int = param(
        1000,
        ge=1,
        doc="optimisation steps (the cosine schedule spans them); 1,000 held CD / HD within 1.2x of 2,000 on the "
        "teacup, bunny, kitten, block and three raw clouds at half the time (docs/results.md)",
    )
    lr: float = param(1e-3, gt=0)
    lr_final: float = param(1e-4, gt=0, doc="cosine decay down to this")
    surface_batch: int = param(4096, ge=16, doc="input points per step (paper: 4096)")
    volume_batch: int = param(4096, ge=16, doc="volume samples per step")
    ridge_every: int = param(
        200,
        ge=0,
        doc="every this many steps (from ridge_start on), the mf targets on the medial rays "
        "become the learned |sdf| at the rays' medial points, so q is 0 there although the network "
        "rounds the |sdf| ridge (0: the rays' radii from the data)",
    )
    ridge_start: float = param(0.3, ge=0, le=1, doc="share of the steps before the first ridge update")
    losses: dict[str, Any] = param(
        factory=_default_losses,
        schemas=lambda: schema.registered_schemas(_losses()),
        doc="loss name -> {weight, ...} for the supervised routes "
        "(mesh, oriented_points, raw_points); weight 0 disables",
    )
    paper_losses: dict[str, Any] = param(factory=_paper_losses, doc="the same for the paper route (raw points alone)")


#: Lightning's CSV logger in the stage's folder; any ``lightning.pytorch.loggers`` class (or a plugin's) by
#: ``_target_``, its other keys its arguments (``save_dir`` is the stage's folder)
CSV_LOGGER = {"_target_": "lightning.pytorch.loggers.CSVLogger", "name": "logs"}


@dataclass
class TrainerSettings:
    logger: dict[str, Any] = param(
        factory=lambda: dict(CSV_LOGGER),
        doc="Lightning's logger by _target_ and its arguments, e.g. {_target_: lightning.pytorch.loggers."
        "TensorBoardLogger} or WandbLogger (offline without WANDB_API_KEY)",
    )
    accelerator: str = param("auto", doc="Lightning accelerator: auto uses a GPU when there is one")
    checkpoint_every: int = param(
        250, ge=1, doc="steps between checkpoints (resume, and the last good state on divergence)"
    )
    resume: bool = param(True, doc="continue from the last checkpoint of an interrupted run with the same key")
    progress_bar: str = param("auto", choices=("auto", "on", "off"), doc="auto: only when stderr is a terminal")
    picture: bool = param(True, doc="cut-plane pictures of SDF, MF, Q-MDF and the loss curves")
