"""The physics prior of the stage-1 networks (spc3d.translate.prior) and the translators built on it:
the estimate against the Bernoulli physics (exact on constant images, Monte-Carlo on sampled ones),
finite at the extremes, the gain fitted from marginal means, and residual translators that start at
the prior, keep its level and save its gain."""

import copy

import numpy as np
import pytest
import torch

from spc3d.physics import spc
from spc3d.pixels import linear_to_srgb
from spc3d.translate import MODULES
from spc3d.translate.prior import P_MAX, PhysicsPrior, gaussian_kernel

from conftest import TINY_TRANSLATORS

CPU = torch.device("cpu")
TINY = TINY_TRANSLATORS  # tiny networks of every method, with the default physics prior (sigma 2 px)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def build(method: str, **over):
    module = MODULES[method]
    torch.manual_seed(0)
    return module.Translator(module.Config(**{**TINY[method], **over}), CPU)


def bits(*shape, p=0.4, seed=1):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(*shape, generator=g) < p).float()


def test_kernel_is_normalised_and_symmetric():
    for sigma in (0.5, 2.0, 3.3):
        k = gaussian_kernel(sigma)
        assert k.numel() == 2 * int(np.ceil(3 * sigma)) + 1
        assert float(k.sum()) == pytest.approx(1.0, abs=1e-6)
        assert torch.equal(k, k.flip(0))


@pytest.mark.parametrize("p", [0.0, 0.1, 0.5, 0.9, 1.0])
def test_constant_detection_rate_gives_the_exact_mle(p):
    """On a constant image the blur changes nothing: the rate is -log(1 - p) (p capped at P_MAX)."""
    prior = PhysicsPrior(2.0)
    prior.gain.copy_(torch.tensor([0.2, 0.3, 0.4]))
    x = torch.full((1, 3, 9, 13), p)
    want_rate = -np.log1p(-min(p, P_MAX))
    torch.testing.assert_close(prior.rate(x), torch.full_like(x, want_rate), rtol=1e-5, atol=1e-6)
    want = linear_to_srgb(torch.tensor([0.2, 0.3, 0.4]).view(1, 3, 1, 1) * want_rate).expand_as(x)
    torch.testing.assert_close(prior(x), want, rtol=1e-5, atol=1e-6)


def test_rate_matches_monte_carlo_bernoulli_frames():
    """Bits drawn at a known photon rate per frame (the simulator's exact model): the blurred
    detection rate is an unbiased estimate of p = 1 - exp(-lam) (within the Monte-Carlo error), and
    the rate -log(1 - blurred p) recovers lam at low and moderate flux; at high flux it lies above
    lam (Jensen: -log(1 - p) is convex), which is why the gain is fitted rather than assumed."""
    rng = np.random.default_rng(0)
    params = spc.SPCParams(q=1.0, exposure_s=1.0, dark_count_rate=0.0, frames=1)
    prior = PhysicsPrior(1.0)
    for lam, rel in ((0.05, 0.1), (0.7, 0.1), (2.0, None)):
        srgb = np.full((96, 128, 3), float(linear_to_srgb(torch.tensor(0.5))), dtype=np.float32)
        frames = spc.simulate_frames(srgb, 2 * lam, params, rng)  # flux_scale * 0.5 linear = lam per frame
        x = torch.from_numpy(frames[0].astype(np.float32)).permute(2, 0, 1)[None]
        p = -np.expm1(-lam)
        blurred = prior.blur(x)[..., 8:-8, 8:-8]
        assert float(blurred.mean()) == pytest.approx(p, abs=4 * np.sqrt(p * (1 - p) / blurred.numel()))
        rate = float(prior.rate(x)[..., 8:-8, 8:-8].mean())
        if rel is not None:
            assert rate == pytest.approx(lam, rel=rel)
        else:
            assert lam < rate < -np.log1p(-P_MAX)


def test_extremes_are_finite_with_finite_gradients():
    prior = PhysicsPrior(2.0)
    for x in (torch.zeros(1, 3, 8, 8), torch.ones(1, 3, 8, 8), bits(2, 3, 5, 3)):  # thinner than the kernel
        x = x.clone().requires_grad_(True)
        y = prior(x)
        y.sum().backward()
        assert torch.isfinite(y).all() and torch.isfinite(x.grad).all()
        assert y.shape == x.shape and y.min() >= 0 and y.max() <= 1


def test_fit_recovers_the_gain_from_marginal_means():
    """sRGB targets whose linear mean is g times the mean rate of the inputs: fit returns g, also
    from unrelated (unpaired) images and from batches."""
    prior = PhysicsPrior(1.5)
    x = bits(4, 3, 16, 16, p=0.3)
    g = torch.tensor([0.15, 0.25, 0.35])
    linear = prior.rate(x) * g.view(1, 3, 1, 1)
    target = linear_to_srgb(linear.flip(0))  # other images than the inputs: only the means matter
    got = prior.fit([(x[:2], target[:2]), (x[2:], target[2:])])
    torch.testing.assert_close(got, g, rtol=2e-3, atol=0)
    assert torch.equal(prior.gain, got)


def test_fit_errors_name_the_problem():
    prior = PhysicsPrior(2.0)
    with pytest.raises(ValueError, match="no training images"):
        prior.fit([])
    with pytest.raises(ValueError, match="no detections"):
        prior.fit([(torch.zeros(3, 8, 8), torch.rand(3, 8, 8))])
    with pytest.raises(ValueError, match="prior_sigma = 0"):
        PhysicsPrior(0)


def test_relevel_moves_the_target_mean_to_the_prior_mean():
    prior = PhysicsPrior(2.0)
    prior.gain.fill_(0.3)
    x, y = bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16)
    z = prior.relevel(x, y)
    torch.testing.assert_close(z.mean((-2, -1)), prior(x).mean((-2, -1)))
    torch.testing.assert_close(z - z.mean((-2, -1), keepdim=True), y - y.mean((-2, -1), keepdim=True))


@pytest.mark.parametrize("method", ["pix2pix", "pix2pixhd", "cyclegan", "restormer"])
def test_residual_translators_start_at_the_prior(method):
    """The residual's last convolution starts at zero: an untrained translator outputs the prior."""
    model = build(method)
    model.prior.gain.fill_(0.25)
    x = bits(2, 3, 24, 32)
    torch.testing.assert_close(model.translate(x), model.prior(x).clamp(0, 1), rtol=0, atol=1e-6)


@pytest.mark.parametrize("method", sorted(TINY))
def test_residual_keeps_the_prior_level_after_training(method):
    """Trained a few steps, a translator's output (before clamping) still has the prior's mean per
    image and channel: the residual carries structure, not brightness."""
    model = build(method)
    model.prior.gain.fill_(0.25)
    for step in range(3):
        torch.manual_seed(step)
        x = bits(2, 3, 16, 16, seed=10 + step)
        model.train_step(x, model.prior.relevel(x, torch.rand(2, 3, 16, 16)))
    x = bits(1, 3, 32, 32, seed=99)
    model.train(False)
    with torch.no_grad():
        raw = model.forward_image(x) if method != "diffusion" else None
    if raw is None:  # diffusion clamps inside; compare its output with the prior where nothing clips
        out, base = model.translate(x), model.prior(x)
        # x0 is clamped to [-1, 1] and then loses its mean: the residual stays within 1 / residual_scale
        assert float((out - base).abs().max()) <= 1.0 / model.cfg.residual_scale + 1e-6
        return
    torch.testing.assert_close(raw.mean((-2, -1)), model.prior(x).mean((-2, -1)), rtol=0, atol=1e-5)


@pytest.mark.parametrize("method", sorted(TINY))
def test_the_fitted_gain_is_saved_and_loaded_with_the_networks(method):
    model = build(method)
    assert "prior" in model.modules() and model.parameter_count()["prior"] == 0
    model.prior.gain.copy_(torch.tensor([0.11, 0.22, 0.33]))
    other = build(method)
    other.load(copy.deepcopy(model.state()))
    assert torch.equal(other.prior.gain, model.prior.gain)
    x = bits(1, 3, 16, 16)
    assert torch.equal(other.translate(x), model.translate(x))


@pytest.mark.parametrize("method", sorted(TINY))
def test_paper_presets_are_the_published_networks_without_prior(method):
    module = MODULES[method]
    assert module.PAPER["prior_sigma"] == 0.0
    assert build(method, prior_sigma=0.0).prior is None
    assert "prior" not in build(method, prior_sigma=0.0).modules()


def test_published_restormer_weights_need_the_published_design(tmp_path):
    model = build("restormer")
    path = tmp_path / "real_denoising.pth"
    torch.save({"params": model.net.state_dict()}, path)
    with pytest.raises(ValueError, match=r"real_denoising\.pth.*prior_sigma: 0"):
        model.load_pretrained(path)
