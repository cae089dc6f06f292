"""GAN translators (pix2pixHD, pix2pix, CycleGAN) and their shared networks, at tiny sizes."""

import dataclasses
import io
import math

import numpy as np
import pytest
import torch

from spc3d.evaluation import lpips_specs
from spc3d.translate import cyclegan, pix2pix, pix2pixhd
from spc3d.translate.networks import (
    GANLoss,
    ImagePool,
    MultiscaleDiscriminator,
    NLayerDiscriminator,
    ResnetBlock,
    ResnetGenerator,
    UnetGenerator,
)
from spc3d.translate.vgg import VGGFeatures, VGGLoss

from conftest import TINY_TRANSLATORS

CPU = torch.device("cpu")
# The published networks at tiny sizes, without the physics prior (tested with it in test_translate_prior.py).
TINY = {
    m: (module, {**TINY_TRANSLATORS[m], "prior_sigma": 0.0})
    for m, module in (("pix2pix", pix2pix), ("pix2pixhd", pix2pixhd), ("cyclegan", cyclegan))
}
METHODS = sorted(TINY)
COLOUR = torch.tensor([0.85, 0.25, 0.55]).view(1, 3, 1, 1)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def make(method: str, seed: int = 0, vgg_weights=None, **over):
    module, tiny = TINY[method]
    torch.manual_seed(seed)
    return module.Translator(module.Config(**{**tiny, **over}), CPU, vgg_weights=vgg_weights)


def bits(*shape, p=0.4, seed=1):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(*shape, generator=g) < p).float()


def random_vgg_weights(seed: int = 0) -> dict[str, np.ndarray]:
    """He-initialised arrays with the shapes of the LPIPS VGG16 weights (keeps activations O(1))."""
    rng = np.random.default_rng(seed)
    out = {}
    for key, shape in lpips_specs.expected_shapes("vgg").items():
        fan_in = int(np.prod(shape[1:])) if len(shape) > 1 else 1
        scale = math.sqrt(2.0 / fan_in) if key.endswith("weight") else 0.01
        out[key] = (rng.standard_normal(shape) * scale).astype(np.float32)
    return out


def generator_params(model) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.G.parameters()]


# ---------------------------------------------------------------------------------------------
# Models
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
def test_translate_keeps_odd_sizes_and_range(method):
    model = make(method)
    out = model.translate(bits(2, 3, 37, 53))
    assert out.shape == (2, 3, 37, 53)
    assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1


@pytest.mark.parametrize("method", METHODS)
def test_train_step_finite_losses_and_updates_generator(method):
    model = make(method)
    before = generator_params(model)
    losses = model.train_step(bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16))
    assert "loss" in losses and all(isinstance(v, float) and math.isfinite(v) for v in losses.values())
    assert any(not torch.equal(a, b) for a, b in zip(before, model.G.parameters()))


def test_pix2pix_without_its_adversarial_term_is_an_l1_regressor():
    """lambda_gan 0: the discriminator is neither trained nor consulted; G's loss is lambda_L1 * L1."""
    model = make("pix2pix", lambda_gan=0.0)
    d_before = [p.detach().clone() for p in model.D.parameters()]
    binary, rgb = bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16)
    losses = model.train_step(binary, rgb)
    assert all(torch.equal(a, b) for a, b in zip(d_before, model.D.parameters()))
    assert losses["G_GAN"] == 0.0 and losses["loss"] == pytest.approx(model.cfg.lambda_L1 * losses["G_L1"])
    assert "D_real" not in losses and not any(k.startswith("D_") for k in losses)


def test_pix2pixhd_pixel_term_is_lambda_times_l1_and_off_by_default():
    binary, rgb = bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16)
    assert "G_L1" not in make("pix2pixhd", vgg_loss=False).train_step(binary, rgb)
    losses = make("pix2pixhd", vgg_loss=False, lambda_L1=100.0).train_step(binary, rgb)
    terms = sum(v for k, v in losses.items() if k.startswith("G_"))
    assert losses["G_L1"] > 0 and losses["loss"] == pytest.approx(terms, rel=1e-5)


def test_cyclegan_pixel_term_pairs_the_batches_and_is_off_by_default():
    """lambda_pixel 0: unpaired, no pixel term (the published CycleGAN); > 0: the sampler is asked
    for aligned pairs and G's objective gains lambda_pixel * |G(a) - b|_1 beside its own terms."""
    binary, rgb = bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16)
    plain = make("cyclegan")
    assert not plain.paired and "G_pixel" not in plain.train_step(binary, rgb)
    model = make("cyclegan", lambda_pixel=10.0)
    with torch.no_grad():
        expected = 10.0 * torch.nn.functional.l1_loss(model.g(binary * 2 - 1), rgb * 2 - 1)
    losses = model.train_step(binary, rgb)
    terms = sum(v for k, v in losses.items() if not k.startswith("D_") and k != "loss")
    assert model.paired and losses["G_pixel"] == pytest.approx(float(expected), rel=1e-5)
    assert losses["loss"] == pytest.approx(terms, rel=1e-5)


@pytest.mark.parametrize("method", METHODS)
def test_learns_constant_colour(method):
    """Random bits -> one constant colour: a few dozen steps must cut the output's L1 error."""
    model = make(method, lr=1e-3)
    test = bits(2, 3, 16, 16, seed=7)

    def error():
        return float((model.translate(test) - COLOUR).abs().mean())

    before = error()
    for step in range(25):
        model.train_step(bits(2, 3, 16, 16, seed=100 + step), COLOUR.expand(2, 3, 16, 16).clone())
    after = error()
    assert after < 0.75 * before, (before, after)  # measured ratios: pix2pix 0.59, others < 0.3


@pytest.mark.parametrize("method", METHODS)
def test_state_round_trip(method):
    model = make(method)
    model.train_step(bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16))
    buffer = io.BytesIO()
    torch.save(model.state(), buffer)
    buffer.seek(0)
    clone = make(method, seed=123)
    clone.load(torch.load(buffer, weights_only=False))
    x = bits(1, 3, 21, 18, seed=3)
    assert torch.equal(model.translate(x), clone.translate(x))


@pytest.mark.parametrize("method", METHODS)
def test_same_seed_same_losses(method):
    def run():
        model = make(method, seed=5)
        return [model.train_step(bits(2, 3, 16, 16, seed=s), torch.rand(2, 3, 16, 16)) for s in range(2)]

    torch.manual_seed(9)
    first = run()
    torch.manual_seed(9)
    assert run() == first


def test_flags_and_multiples():
    assert make("pix2pix").multiple == 8 and make("pix2pix").paired
    assert not make("cyclegan").paired and make("cyclegan").multiple == 2
    assert make("pix2pixhd").multiple == 4
    assert make("pix2pixhd", n_local_enhancers=1).multiple == 8


@pytest.mark.parametrize("module", [pix2pix, pix2pixhd, cyclegan])
def test_paper_configs_are_valid(module):
    cfg = module.Config(**module.PAPER)
    assert cfg.lr == 2e-4 and cfg.beta1 == 0.5
    assert dataclasses.asdict(cfg)  # frozen dataclass, every field set


def test_pix2pixhd_local_enhancer_trains_and_keeps_size():
    model = make("pix2pixhd", n_local_enhancers=1)
    assert math.isfinite(model.train_step(bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16))["loss"])
    assert model.translate(bits(1, 3, 19, 30)).shape == (1, 3, 19, 30)


def test_pix2pixhd_vgg_loss_with_weights():
    model = make("pix2pixhd", vgg_weights=random_vgg_weights(), vgg_loss=True)
    losses = model.train_step(bits(2, 3, 16, 16), torch.rand(2, 3, 16, 16))
    assert {"G_GAN", "G_feat", "G_VGG", "D"} <= set(losses) and losses["G_VGG"] > 0


def test_pix2pixhd_missing_vgg_weights_is_an_error():
    with pytest.raises(ValueError, match=r"vgg_loss.*lpips_weights\('vgg'\)"):
        make("pix2pixhd", vgg_loss=True)
    with pytest.raises(ValueError, match="ngf"):
        pix2pixhd.Config(ngf=6, n_local_enhancers=2)


# ---------------------------------------------------------------------------------------------
# Networks
# ---------------------------------------------------------------------------------------------
def test_resnet_generator_shape():
    net = ResnetGenerator(3, 2, ngf=4, n_down=2, n_blocks=2)
    out = net(torch.randn(2, 3, 12, 20))
    assert out.shape == (2, 2, 12, 20) and out.abs().max() <= 1


@pytest.mark.parametrize("num_downs", [3, 6])
def test_unet_shape_and_dropout_levels(num_downs):
    net = UnetGenerator(3, 3, num_downs=num_downs, ngf=4)
    side = 2**num_downs
    assert net(torch.randn(2, 3, side, 2 * side)).shape == (2, 3, side, 2 * side)
    dropouts = sum(isinstance(m, torch.nn.Dropout) for m in net.modules())
    assert dropouts == max(0, num_downs - 5)  # unet_256 (8 halvings) has 3


def test_discriminator_feature_lists():
    d = NLayerDiscriminator(6, ndf=4, n_layers=3)
    x = torch.randn(1, 6, 64, 64)
    feats = d(x, features=True)
    assert len(feats) == 5 and feats[-1].shape == (1, 1, 6, 6)  # n_layers + 2 stages; 70x70 patches
    assert torch.equal(d(x), feats[-1])
    md = MultiscaleDiscriminator(6, ndf=4, n_layers=2, num_D=3)
    outs = md(torch.randn(1, 6, 32, 32), features=True)
    assert len(outs) == 3 and all(len(f) == 4 for f in outs)
    assert outs[1][-1].shape[-1] < outs[0][-1].shape[-1]


def test_image_pool():
    images = torch.randn(3, 2, 4, 4)
    assert torch.equal(ImagePool(0).query(images), images)
    torch.manual_seed(0)
    pool = ImagePool(4)
    zeros = torch.zeros(4, 1, 2, 2)
    assert torch.equal(pool.query(zeros), zeros)  # filling: returns the queries
    mixed = torch.cat([pool.query(torch.ones(4, 1, 2, 2)) for _ in range(10)])
    assert set(mixed.flatten().tolist()) == {0.0, 1.0}  # stored zeros come back, mixed with ones
    assert 0 < (mixed == 0).all(dim=(1, 2, 3)).sum() <= 4


def test_image_pool_repeats_under_seed():
    def draw():
        torch.manual_seed(3)
        pool = ImagePool(2)
        return torch.cat([pool.query(torch.full((2, 1, 1, 1), float(i))) for i in range(6)])

    assert torch.equal(draw(), draw())


def test_gan_loss_values():
    ones, zeros = torch.ones(2, 1, 3, 3), torch.zeros(2, 1, 3, 3)
    lsgan, vanilla = GANLoss("lsgan"), GANLoss("vanilla")
    assert float(lsgan(ones, True)) == 0.0 and float(lsgan(zeros, True)) == 1.0
    assert float(lsgan(ones, False)) == 1.0
    assert float(vanilla(zeros, True)) == pytest.approx(math.log(2))
    assert float(lsgan([[zeros, ones], [ones, zeros]], True)) == pytest.approx(1.0)  # last map per scale
    with pytest.raises(ValueError, match="wgan"):
        GANLoss("wgan")


def test_vgg_features_taps_and_loss():
    weights = random_vgg_weights()
    vgg = VGGFeatures(weights)
    taps = vgg(torch.rand(2, 3, 32, 48) * 2 - 1)
    assert [t.shape for t in taps] == [
        (2, 64, 32, 48),
        (2, 128, 16, 24),
        (2, 256, 8, 12),
        (2, 512, 4, 6),
        (2, 512, 2, 3),
    ]
    assert not list(vgg.parameters()) and not vgg.state_dict()  # frozen, kept out of checkpoints
    loss = VGGLoss(weights)
    x = torch.rand(1, 3, 16, 16) * 2 - 1
    assert float(loss(x, x)) == 0.0 and float(loss(x, -x)) > 0
    bad = dict(weights, **{"conv3.weight": weights["conv3.weight"][:, :5]})
    with pytest.raises(ValueError, match="conv3.weight"):
        VGGFeatures(bad)


def test_gradcheck_resnet_block():
    torch.manual_seed(0)
    block = ResnetBlock(2, norm="instance").double()
    x = torch.randn(1, 2, 5, 5, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(block, (x,), eps=1e-6, atol=1e-5)


def test_gradcheck_vgg_loss():
    loss = VGGLoss(random_vgg_weights()).double()
    target = torch.rand(1, 3, 16, 16, dtype=torch.float64) * 2 - 1
    small = torch.rand(1, 3, 2, 2, dtype=torch.float64, requires_grad=True)

    def f(s):  # a 2x2 image upsampled to the 16 px VGG needs keeps gradcheck cheap
        return loss(torch.nn.functional.interpolate(s, size=16, mode="bilinear", align_corners=False), target)

    assert torch.autograd.gradcheck(f, (small,), eps=1e-6, atol=1e-5, fast_mode=True)


@pytest.mark.parametrize("method", METHODS)
def test_train_step_rejects_unaligned_crops(method):
    model = make(method)
    with pytest.raises(ValueError, match=rf"{method}: .*multiple of {model.multiple}"):
        model.train_step(bits(2, 3, 17, 17), torch.rand(2, 3, 17, 17))
