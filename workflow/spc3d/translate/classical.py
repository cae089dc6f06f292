"""The strongest non-learned denoiser of the binary frame as a stage-1 method (``classical``).

A denoising comparison is owed its classical baseline. Per image, from the input x = k / K (the
mean of K binary frames, each pixel k detections of K):

1. a variance-stabilising transform for binomial counts (Anscombe 1948),
   y = arcsin(sqrt((k + 3/8) / (K + 3/4))), whose noise has a known std σ_K ≈ 1 / (2 sqrt(K + 1/2));
2. a denoiser of additive noise of that known σ_K (non-local means, wavelet shrinkage, total
   variation; BM3D where its package is installed);
3. the algebraic inverse, p̂ = ((K + 3/4) sin²(y) − 3/8) / K, clamped to [0, P_MAX] (:mod:`.prior`);
4. the MLE rate λ = −log1p(−p̂), a per-channel gain and the sRGB display: the physics prior's own
   code (:class:`Classical` is a :class:`.prior.PhysicsPrior` whose blur is steps 1–3), so the gain
   is fitted on the training data exactly as the prior's is.

At K = 1 (the default) the VST stabilises nothing: a bit takes two values and the VST maps
them to two values (0.481 and 1.090, σ_1 = 0.408), an affine map of the bits. What it still does is
hand the denoisers their noise level in their own terms; its inverse, applied to a local average of
the mapped bits, bends it by at most ±0.012 (S-shaped), which the fitted gain partly absorbs. The
``gaussian`` family skips the VST: it blurs the fractions themselves, i.e. it *is* the physics prior
(the ``prior`` method at its σ), so the search can never do worse than the prior on the data it
selects on (up to the calibration subset, below).

"Training" is a selection on the training scenes only (:meth:`Translator.fit_untrained`): every
candidate of :data:`GRID` in the searched families gets its gain fitted on every
``calibration_every``-th training pair and is scored on the training scenes' held-out views (the
validator's score; without validation, on those training pairs themselves, recorded as such); the
best PSNR is kept and its gain refitted on every training pair. The choice (an index into
:data:`GRID`, checked against the grid on load) and the gain are buffers of the module, saved in
model.pt; the table of every candidate's score and time goes to train.json (``selection``).

K reaches the method through its Config's ``frames``, which the training job sets from
``stage1.frames`` (a sweep point's K; :func:`spc3d.specs.translators.model_config`) and model.pt
keeps, so the model translates at the K it was selected for. Inferring K from an input's distinct
values would be fragile (an image may not show every level) and is not done.
"""

from __future__ import annotations

import functools
import importlib.util
import itertools
import time
from collections.abc import Callable, Iterable

import numpy as np
import torch
from torch import Tensor, nn

from spc3d.evaluation.metrics import psnr
from spc3d.specs.translators.classical import (
    GRID,
    GRID_DIGEST,
    PAPER,  # noqa: F401 - the contract of spc3d.translate
    Config,
    label,
    pinned_index,
)
from spc3d.translate.base import TranslatorBase
from spc3d.translate.prior import P_MAX, PhysicsPrior

# --- the variance-stabilising transform -----------------------------------------------------------


def vst(x: np.ndarray, frames: int) -> np.ndarray:
    """Anscombe's binomial VST of the detection fraction x = k / K of K frames."""
    return np.arcsin(np.sqrt((x * frames + 0.375) / (frames + 0.75)))


def vst_sigma(frames: int) -> float:
    """The noise std of :func:`vst`'s output, 1 / (2 sqrt(K + 1/2))."""
    return 0.5 / np.sqrt(frames + 0.5)


def inverse_vst(y: np.ndarray, frames: int) -> np.ndarray:
    """The algebraic inverse of :func:`vst`: a detection probability in [0, P_MAX]."""
    k = (frames + 0.75) * np.sin(np.clip(y, 0.0, np.pi / 2)) ** 2 - 0.375
    return np.clip(k / frames, 0.0, P_MAX)


def stabilised(denoise: Callable) -> Callable:
    """``denoise(y, sigma, **params)`` of additive noise of known std, as a denoiser of K-frame
    fractions: VST, ``denoise`` at the VST's sigma, inverse VST."""

    @functools.wraps(denoise)
    def run(x: np.ndarray, frames: int, **params) -> np.ndarray:
        return inverse_vst(denoise(vst(x, frames), vst_sigma(frames), **params), frames)

    return run


# --- the denoisers: (H, W, 3) fractions of K frames -> detection probability ----------------------


@functools.lru_cache(maxsize=16)
def _prior_blur(sigma: float) -> PhysicsPrior:
    return PhysicsPrior(sigma)


def gaussian(x: np.ndarray, frames: int, sigma: float) -> np.ndarray:
    """The physics prior's blur of the fractions themselves (linear, so no VST: its mean is unbiased)."""
    del frames
    t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).permute(2, 0, 1)[None]
    return _prior_blur(float(sigma)).blur(t)[0].permute(1, 2, 0).double().numpy()


def nlm(y: np.ndarray, sigma: float, patch_size: int, patch_distance: int, h: float, subtract: bool) -> np.ndarray:
    """Non-local means (fast mode), filter strength ``h`` σ; ``subtract``: pass σ so the weights
    discount the noise's expected patch distance (at K = 1 that makes them all ~1: a box filter)."""
    from skimage.restoration import denoise_nl_means  # here: importing skimage costs every workflow parse 0.6 s

    return denoise_nl_means(
        y,
        patch_size=patch_size,
        patch_distance=patch_distance,
        h=h * sigma,
        sigma=sigma if subtract else 0.0,
        fast_mode=True,
        channel_axis=-1,
    )


def wavelet(y: np.ndarray, sigma: float, wavelet: str, method: str, levels: int) -> np.ndarray:
    """Soft wavelet shrinkage at the known σ (``levels`` capped by the image size)."""
    import pywt
    from skimage.restoration import denoise_wavelet

    most = pywt.dwt_max_level(min(y.shape[:2]), pywt.Wavelet(wavelet).dec_len)
    return denoise_wavelet(
        y,
        sigma=sigma,
        wavelet=wavelet,
        mode="soft",
        wavelet_levels=max(1, min(levels, most)),
        method=method,
        rescale_sigma=True,
        channel_axis=-1,
    )


def tv(y: np.ndarray, sigma: float, weight: float) -> np.ndarray:
    """Total-variation denoising (Chambolle), weight ``weight`` σ. Its default stopping tolerance
    (2e-4 of the energy) stops it after a few iterations on a VST'd binary frame, far from the
    minimum (non-monotone in the weight); 1e-5 converges at ~0.1 s per 168 × 126 image."""
    from skimage.restoration import denoise_tv_chambolle

    return denoise_tv_chambolle(y, weight=weight * sigma, eps=1e-5, max_num_iter=500, channel_axis=-1)


def bm3d_channels(y: np.ndarray, sigma: float, stage: str) -> np.ndarray:
    """BM3D per channel (the channels' noise is independent); needs the optional bm3d package."""
    import bm3d

    stages = {"all": bm3d.BM3DStages.ALL_STAGES, "hard": bm3d.BM3DStages.HARD_THRESHOLDING}
    return np.stack([bm3d.bm3d(y[..., c], sigma_psd=sigma, stage_arg=stages[stage]) for c in range(y.shape[-1])], -1)


# name -> fn(x: (H, W, 3) fractions of K frames, frames, **params) -> (H, W, 3) detection probability
DENOISERS: dict[str, Callable] = {
    "gaussian": gaussian,
    "nlm": stabilised(nlm),
    "wavelet": stabilised(wavelet),
    "tv": stabilised(tv),
    "bm3d": stabilised(bm3d_channels),
}
# Families that need a package the project does not depend on: the module and why it is absent.
OPTIONAL = {
    "wavelet": ("pywt", "PyWavelets is not installed (scikit-image's optional wavelet backend)"),
    "bm3d": ("bm3d", "the bm3d package is not installed (non-commercial licence: never a dependency)"),
}


@functools.cache
def unavailable(name: str) -> str | None:
    """Why family ``name`` cannot run here (its optional package is missing), else None."""
    module, why = OPTIONAL.get(name, (None, None))
    return why if module and importlib.util.find_spec(module) is None else None


def detection(x: Tensor, frames: int, index: int) -> Tensor:
    """(B, 3, H, W) fractions of K frames -> GRID[index]'s detection probability, in [0, P_MAX]."""
    name, params = GRID[index]
    if unavailable(name):
        raise ImportError(f"classical: the chosen denoiser {label(index)} cannot run: {unavailable(name)}")
    images = x.detach().cpu().double().permute(0, 2, 3, 1).numpy()
    out = np.stack([DENOISERS[name](im, frames, **params) for im in images])
    return torch.from_numpy(np.clip(out, 0.0, P_MAX)).permute(0, 3, 1, 2).to(x)


# --- the model --------------------------------------------------------------------------------------


class Classical(PhysicsPrior):
    """The physics prior with its blur replaced by ``GRID[choice]``'s denoiser of the fractions:
    same rate, gain fit and display. Buffers: ``gain``, ``choice`` (-1: none yet), ``grid``."""

    def __init__(self, frames: int):
        super().__init__(1.0)
        # PhysicsPrior's Gaussian kernel is never used (blur is replaced); fit() reads its device and dtype
        self.register_buffer("kernel", self.kernel, persistent=False)
        self.frames = frames
        self.register_buffer("choice", torch.tensor(-1))
        self.register_buffer("grid", torch.tensor(GRID_DIGEST))

    def blur(self, x: Tensor) -> Tensor:
        if int(self.choice) < 0:
            raise RuntimeError(
                "classical: no denoiser chosen yet (fit_untrained selects one; or pin stage1.classical.choice)"
            )
        return detection(x, self.frames, int(self.choice))

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        if int(state_dict["grid"]) != GRID_DIGEST:
            raise ValueError(
                "classical: this model's choice indexes another candidate grid (spc3d.specs.translators.classical.GRID "
                "has changed since it was selected); train it again"
            )
        return super().load_state_dict(state_dict, strict, assign)


class Translator(TranslatorBase):
    """:class:`Classical` with the candidate chosen on the training scenes and its fitted gain."""

    paired = True
    multiple = 1
    trainable = False  # nothing is optimised: "training" is the selection of fit_untrained

    def __init__(self, cfg: Config, device: torch.device, vgg_weights: dict | None = None):
        del vgg_weights  # nothing is trained, no perceptual loss
        self.cfg, self.device = cfg, torch.device(device)
        self.net = Classical(cfg.frames).to(self.device)
        if cfg.choice is not None:
            self.net.choice.fill_(pinned_index(cfg.choice, cfg.params))

    def modules(self) -> dict[str, nn.Module]:
        return {"classical": self.net}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {}

    def forward_image(self, binary: Tensor) -> Tensor:
        return self.net(binary.to(self.device))

    def train_step(self, binary: Tensor, rgb: Tensor) -> dict[str, float]:
        raise RuntimeError("classical has no network to train: its training is the selection of fit_untrained")

    def fit_untrained(
        self, pairs: Callable[[], Iterable[tuple[Tensor, Tensor]]], validate: Callable[[Callable], dict] | None
    ) -> dict:
        """The search (unless ``choice`` pins a candidate), then the chosen one's gain on every pair;
        returns the selection table for train.json."""
        start = time.perf_counter()
        skipped = {n: unavailable(n) for n in self.cfg.denoisers if unavailable(n)}
        table = {"frames": self.cfg.frames, "unavailable": skipped}
        if self.cfg.choice is None:
            table |= self.search(pairs, validate, [i for i, (n, _) in enumerate(GRID) if n in self.cfg.denoisers])
        gain = self.net.fit(pairs())
        chosen = int(self.net.choice)
        table |= {"chosen": label(chosen), "index": chosen, "pinned": self.cfg.choice is not None}
        return table | {"gain": gain.tolist(), "seconds": time.perf_counter() - start}

    def search(self, pairs, validate, indices: list[int]) -> dict:
        """Score every candidate of ``indices`` that can run here; choose the best val PSNR."""
        runnable = [i for i in indices if not unavailable(GRID[i][0])]
        if not runnable:
            raise ValueError(f"stage1.classical.denoisers = {list(self.cfg.denoisers)}: none can run here")
        subset = list(itertools.islice(pairs(), 0, None, self.cfg.calibration_every))
        judge = validate or functools.partial(pair_score, pairs=subset)
        rows = [self.trial(i, subset, judge) for i in runnable]
        best = max(rows, key=lambda r: r["val_psnr"])
        self.net.choice.fill_(best["index"])
        where = "the training scenes' held-out views" if validate else "the calibration pairs (no validation views)"
        calibration = f"1 training pair in {self.cfg.calibration_every} ({len(subset)} pairs)"
        return {"scored_on": where, "calibration": calibration, "candidates": rows}

    def trial(self, index: int, subset: list, judge: Callable[[Callable], dict]) -> dict:
        """Candidate ``index``: its gain on ``subset``, its score, its time."""
        start, clock = time.perf_counter(), []
        self.net.choice.fill_(index)
        gain = self.net.fit(subset)
        scores = judge(timed(self.translate, clock))
        images = sum(n for _, n in clock)
        per_image = 1000 * sum(t for t, _ in clock) / max(images, 1)
        row = {"index": index, "candidate": label(index), "denoiser": GRID[index][0], **scores}
        return row | {"gain": gain.tolist(), "ms_per_image": per_image, "seconds": time.perf_counter() - start}


def timed(translate: Callable[[Tensor], Tensor], clock: list) -> Callable[[Tensor], Tensor]:
    """``translate`` that appends (seconds, images) of every call to ``clock``."""

    def run(x: Tensor) -> Tensor:
        start = time.perf_counter()
        out = translate(x)
        clock.append((time.perf_counter() - start, len(x)))
        return out

    return run


def pair_score(translate: Callable[[Tensor], Tensor], pairs: list) -> dict[str, float]:
    """Mean PSNR and L1 of ``translate`` on (binary, target) pairs, in the translators' own domain
    (the fallback without validation views)."""
    psnrs, l1s = [], []
    for binary, target in pairs:
        binary, target = (t if t.ndim == 4 else t[None] for t in (binary, target))
        out = translate(binary).cpu()
        psnrs += [psnr(o, t) for o, t in zip(out, target)]
        l1s += [float((o - t).abs().mean()) for o, t in zip(out, target)]
    return {"val_psnr": float(np.mean(psnrs)), "val_l1": float(np.mean(l1s))}
