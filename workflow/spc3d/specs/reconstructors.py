"""The settings of every built-in reconstructor (stage 2) and of the joint rows, torch-free.

``GaussianConfig`` (3DGS), ``NerfConfig`` with its presets (the paper's NeRF), ``GridConfig`` (the
grid NeRF) and ``JointConfig`` (the joint rows' prior weight and penalty), and the builders the
model specs name (``config_3dgs`` ...; :mod:`spc3d.specs`). The models of :mod:`spc3d.reconstruct`
import them; they live here so that the workflow builds and checks every job's settings when it
parses the configuration, without importing torch. Each field's comment gives its meaning and the
reference implementation's value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from spc3d import specs
from spc3d.specs.build import build_config, require_positive


@dataclass
class GaussianConfig:
    """3DGS settings; defaults are the reference implementation's (Kerbl et al. 2023, graphdeco-inria/
    gaussian-splatting ``arguments/__init__.py``); the workflow's CPU budgets override some (config.yaml)."""

    iterations: int = 30_000  # optimisation steps (one random training view each)
    sh_degree: int = 3  # highest SH degree
    sh_interval: int = 1000  # consider raising the active degree every this many iterations
    lr_means: float = 1.6e-4  # x scene extent, decays exponentially to lr_means_final
    lr_means_final: float = 1.6e-6  # x scene extent, the positions' learning rate at the last step
    lr_sh_dc: float = 2.5e-3  # Adam lr of the SH degree-0 (base colour) coefficients
    lr_sh_rest: float = 2.5e-3 / 20  # Adam lr of the higher SH coefficients (view-dependent colour)
    lr_opacity: float = 0.05  # Adam lr of the opacity logits
    lr_scales: float = 5e-3  # Adam lr of the log scales
    lr_quats: float = 1e-3  # Adam lr of the rotation quaternions
    ssim_weight: float = 0.2  # loss (1 - w) L1 + w (1 - SSIM)
    densify_from: int = 500  # first iteration of clone / split / prune
    densify_until: int = 15_000  # no density control after this iteration
    densify_every: int = 100  # iterations between density-control passes
    densify_grad: float = 2e-4  # view-space positional gradient threshold (NDC units, as 3DGS)
    percent_dense: float = 0.01  # clone below / split above this fraction of the scene extent
    opacity_reset_every: int = 3000  # opacities clamped down to 0.01 this often (while densifying)
    prune_opacity: float = 0.005  # prune Gaussians whose opacity falls below this
    max_screen_size: float = 20.0  # px; prune larger Gaussians after the first opacity reset
    max_gaussians: int = 200_000  # hard cap on capacity
    init_points: int = 5000  # random initialisation only
    pose_refine: bool = False  # learn a correction of every training camera (spc3d.reconstruct.pose_refine)
    pose_lr: float = 5e-4  # Adam lr of the corrections (radians; translation in scene extents), at pose_from
    pose_lr_final: float = 5e-6  # their lr at the last iteration (exponential decay: they settle, not drift)
    pose_from: int = 300  # iteration from which the corrections move (the Gaussians fit roughly first)
    plateau_window: int = 100  # steps averaged into one value of the stopping rule (spc3d.training.Plateau)
    plateau_patience: int = 0  # windows in a row without a gain of plateau_gain stop the training (0: never)
    plateau_gain: float = 0.01  # relative drop of the windowed training objective that counts as progress
    plateau_tol: float = 0.0  # ... and by at least this much (objective units): below it the fit is done
    plateau_views: int = 0  # training views held out of the fit whose objective judges the stop (0: the
    # training objective itself; spc3d.reconstruct.views.hold_out)
    backend: str = "native"  # rasterizer back-end
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)  # colour behind the last Gaussian (render space)

    def __post_init__(self):
        require_positive(
            self, "iterations", "sh_interval", "densify_every", "max_gaussians", "init_points", "plateau_window"
        )
        if not 0 <= self.sh_degree <= 3:
            raise ValueError(f"sh_degree = {self.sh_degree}: the rasterizer evaluates degrees 0..3")
        if self.densify_until > 0 and self.densify_from >= self.densify_until:
            raise ValueError(
                f"densify_from = {self.densify_from}, densify_until = {self.densify_until}: densification would "
                f"never run; set densify_until above densify_from (or densify_until: 0 for none)"
            )
        if self.max_gaussians < self.init_points:
            raise ValueError(
                f"max_gaussians = {self.max_gaussians} is below init_points = {self.init_points}: the cap would be "
                f"broken from the first step; raise max_gaussians or lower init_points"
            )


@dataclass(frozen=True)
class NerfConfig:
    depth: int = 8  # layers of the density trunk
    width: int = 256  # hidden units per trunk layer (the view branch has width // 2)
    skips: tuple[int, ...] = (4,)  # the input is concatenated again after these trunk layers
    freqs_xyz: int = 10  # positional-encoding frequencies 2^0..2^(L-1) for positions
    freqs_dir: int = 4  # positional-encoding frequencies for viewing directions
    use_viewdirs: bool = True  # colour depends on the viewing direction
    n_coarse: int = 64  # stratified samples per ray
    n_fine: int = 64  # importance samples per ray (the paper's LLFF config uses 128)
    perturb: bool = True  # jitter stratified samples during training
    raw_noise_std: float = 1.0  # std of noise added to raw density during training (regulariser)
    white_bkgd: bool = False  # composite onto white instead of black
    lr: float = 5e-4  # Adam learning rate at step 0
    lr_final: float = 5e-5  # learning rate reached at ``n_iters`` (exponential decay)
    n_iters: int = 200_000  # iteration budget the learning rate decays over
    batch_rays: int = 1024  # rays per training step (N_rand)
    chunk: int = 4096  # rays per forward pass when rendering whole images
    plateau_window: int = 50  # steps averaged into one value of the stopping rule (spc3d.training.Plateau)
    plateau_patience: int = 0  # windows in a row without a gain of plateau_gain stop the training (0: never)
    plateau_gain: float = 0.01  # relative drop of the windowed training objective that counts as progress
    plateau_tol: float = 0.0  # ... and by at least this much (objective units): below it the fit is done
    plateau_views: int = 0  # training views held out of the fit whose objective judges the stop (0: the
    # training objective itself; spc3d.reconstruct.views.hold_out)

    def __post_init__(self):
        require_positive(self, "depth", "width", "n_coarse", "n_iters", "batch_rays", "chunk", "plateau_window")


def nerf_preset(name: str) -> NerfConfig:
    """'paper' (original defaults), 'llff' (128 fine samples), 'cpu' (small, for 2-core budgets)."""
    presets = {
        "paper": NerfConfig(),
        "llff": NerfConfig(n_fine=128),
        "cpu": NerfConfig(
            depth=4,
            width=64,
            skips=(2,),
            freqs_xyz=8,
            freqs_dir=2,
            n_coarse=32,
            n_fine=32,
            n_iters=3000,
            batch_rays=1024,
        ),
    }
    if name not in presets:
        raise ValueError(f"unknown NeRF preset {name!r}; choose one of {sorted(presets)}")
    return presets[name]


@dataclass(frozen=True)
class GridConfig:
    channels: int = 12  # feature-grid channels fed to the colour MLP
    res_schedule: tuple[tuple[int, int], ...] = ((0, 32), (500, 64), (1500, 96))  # (iteration, grid R³)
    xy_extent: float = 1.3  # NDC x, y half-width of the box (off-centre views see past ±1)
    n_samples: int = 96  # uniform samples per ray in t ∈ [0, 1] (uniform in disparity)
    alpha_init: float = 1e-2  # initial α of one sample on a ray along the NDC z axis (DVGO fine stage)
    occupancy_thres: float = 1e-2  # cells whose max α (same reference step) is below are empty. At
    # alpha_init, cells that training has not raised above their initial density (never seen, behind
    # surfaces, or carved out) are skipped: ~45 % fewer cells at 64³, same held-out PSNR
    weight_thres: float = 1e-4  # samples with a smaller compositing weight skip the colour head
    min_trans: float = 1e-3  # a ray stops once its transmittance is this low (early termination)
    native: bool = True  # deferred model on the CPU: render with the numba marcher (volume.march_grid)
    deferred: bool = True  # composite features along the ray, then run the colour head once per ray
    # (deferred shading, as SNeRG: S× fewer head evaluations; False = head on every sample as DVGO)
    mlp_width: int = 64  # colour-head hidden units
    mlp_depth: int = 2  # colour-head hidden layers
    freqs_dir: int = 4  # positional-encoding frequencies of the viewing direction
    white_bkgd: bool = False  # composite onto white instead of black
    perturb: bool = True  # jitter samples within their bins during training
    lr_grid: float = 1.0  # Adam learning rate of both grids (DVGO: 0.1, tuned for ~20k iterations;
    # 1.0 fits 300-1200 iterations several dB better, benchmarks/nerf_grid_quality.py)
    lr_mlp: float = 1e-3  # Adam learning rate of the colour head (DVGO)
    lr_decay: float = 0.1  # learning rates are multiplied by this factor over ``n_iters``
    n_iters: int = 3000  # iteration budget (learning-rate decay horizon)
    batch_rays: int = 4096  # rays per training step
    tv_density: float = 1e-3  # weight of the density-grid total variation in ``tv_loss``
    tv_features: float = 1e-5  # weight of the feature-grid total variation in ``tv_loss``
    occupancy_every: int = 100  # trainer: call ``update_occupancy`` this often ...
    occupancy_warmup: int = 200  # ... from this iteration on (before it every cell is kept)
    chunk: int = 8192  # rays per forward pass when rendering whole images
    plateau_window: int = 50  # steps averaged into one value of the stopping rule (spc3d.training.Plateau)
    plateau_patience: int = 0  # windows in a row without a gain of plateau_gain stop the training (0: never)
    plateau_gain: float = 0.01  # relative drop of the windowed training objective that counts as progress
    plateau_tol: float = 0.0  # ... and by at least this much (objective units): below it the fit is done
    plateau_views: int = 0  # training views held out of the fit whose objective judges the stop (0: the
    # training objective itself; spc3d.reconstruct.views.hold_out)

    def __post_init__(self):
        require_positive(
            self, "channels", "n_samples", "n_iters", "batch_rays", "occupancy_every", "chunk", "plateau_window"
        )
        if not self.res_schedule or any(res < 2 for _, res in self.res_schedule):
            raise ValueError(f"res_schedule = {self.res_schedule}: needs (iteration, resolution >= 2) pairs")

    @property
    def step_ref(self) -> float:
        """Reference sample spacing: NDC distance between samples on the axial ray (z spans 2)."""
        return 2.0 / self.n_samples


@dataclass(frozen=True)
class JointConfig:
    """The prior term's weight schedule (over the fraction t of the run done) and penalty."""

    # A constant 0.1, chosen on the training scenes (benchmarks/joint_weight.py prints the candidates' scores;
    # docs/stage2.md#joint-rows): the best there, and every decaying schedule tried was worse.
    weight: float = 0.1  # w at t = 0
    weight_final: float = 0.1  # w from t = decay_until on
    decay_until: float = 0.5  # fraction of the run over which w falls linearly (0: weight_final throughout)
    likelihood: bool = True  # false: the prior term alone (= the two-stage row, for checks)
    penalty: str = "own"  # "own": the model's two-stage image loss; "l1": L1 on sRGB (robust, for NeRF's MSE)

    def __post_init__(self):
        if self.penalty not in PENALTIES:
            raise ValueError(f"stage2.joint.penalty = {self.penalty!r}: use one of {list(PENALTIES)}")
        if not 0.0 <= self.decay_until <= 1.0:
            raise ValueError(f"stage2.joint.decay_until = {self.decay_until}: a fraction of the run, in [0, 1]")
        for key in ("weight", "weight_final"):
            if not getattr(self, key) >= 0.0:
                raise ValueError(f"stage2.joint.{key} = {getattr(self, key)}: the prior term's weight must be >= 0")

    def weight_at(self, t: float) -> float:
        """w at the fraction ``t`` of the run."""
        if self.decay_until <= 0.0 or t >= self.decay_until:
            return self.weight_final
        return self.weight_final + (self.weight - self.weight_final) * (1.0 - max(t, 0.0) / self.decay_until)


PENALTIES = ("own", "l1")


def config_3dgs(settings: dict):
    return build_config(GaussianConfig, settings, "stage2.3dgs")


def config_nerf(settings: dict):
    settings = dict(settings)
    return build_config(NerfConfig, settings, "stage2.nerf-mlp", nerf_preset(settings.pop("preset", "paper")))


def config_nerf_grid(settings: dict):
    return build_config(GridConfig, settings, "stage2.nerf-grid")


def config_joint(settings: dict):
    """stage2.joint: the joint rows' prior weight schedule and penalty (:class:`JointConfig`)."""
    return build_config(JointConfig, settings, "stage2.joint")


def check_joint(joint: dict) -> None:
    """stage2.joint and each of its per-model entries, as :func:`config_joint` builds them."""
    from spc3d.names import joint_settings

    models, choose = joint.get("models") or {}, joint.get("choose") or {}
    for key, given in (("models", models), ("choose", choose)):
        unknown = sorted(set(given) - set(specs.RECONSTRUCTORS))
        if unknown:
            raise ValueError(
                f"stage2.joint.{key}: unknown model(s) {unknown}; use one of {sorted(specs.RECONSTRUCTORS)}"
            )
    for model in [None, *models]:
        config_joint(joint_settings(joint, model))
    for model, candidates in choose.items():
        check_candidates(candidates, f"stage2.joint.choose.{model}")


def check_candidates(candidates, where: str) -> list[float]:
    """Candidate prior weights of a fold's choice (spc3d.choices): distinct finite numbers >= 0."""
    values = [float(c) for c in candidates or ()]
    if not values or any(not math.isfinite(v) or v < 0 for v in values) or len(set(values)) != len(values):
        raise ValueError(f"{where} = {candidates}: need distinct finite weights >= 0, e.g. [0.1, 0.3, 1.0]")
    return values


def reconstructor_config(model: str, settings: dict):
    """Model ``model``'s settings dataclass built from its ``stage2`` block ``settings`` (its spec's
    ``config`` builder: for a plugin, a function of the plugin's own module)."""
    return specs.load(specs.RECONSTRUCTORS[model].config)(settings)
