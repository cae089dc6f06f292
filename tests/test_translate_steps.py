"""The faster training steps do the same maths as the plain ones they replace.

Each translator is built twice from one seed. The reference copy gets plain single-tensor Adam
optimisers (no fused kernel) and, for pix2pixHD and CycleGAN, the step as it was written before
passes were shared or batched (pix2pixHD: D frozen for G, four D passes; CycleGAN: six separate
generator and four separate discriminator calls). Both take the same steps on the same batches:
their losses and parameters must agree to float rounding.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from spc3d.evaluation import lpips_specs
from spc3d.translate import MODULES
from spc3d.translate.base import to_signed
from spc3d.translate.networks import conditional_d_step, set_requires_grad

CPU = torch.device("cpu")
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def vgg_weights(seed: int = 0) -> dict[str, np.ndarray]:
    """He-initialised arrays with the LPIPS VGG16 shapes (activations O(1), so the loss matters)."""
    rng = np.random.default_rng(seed)
    out = {}
    for key, shape in lpips_specs.expected_shapes("vgg").items():
        scale = math.sqrt(2.0 / int(np.prod(shape[1:]))) if key.endswith("weight") else 0.01
        out[key] = (rng.standard_normal(shape) * scale).astype(np.float32)
    return out


def build(method: str, **over):
    module = MODULES[method]
    torch.manual_seed(0)
    return module.Translator(module.Config(**over), CPU, vgg_weights())


def plain_optimisers(model) -> None:
    """Replace every optimiser of ``model`` by the same one without the fused kernel."""
    for opt in model.optimizers().values():
        params = [p for group in opt.param_groups for p in group["params"]]
        options = {k: v for k, v in opt.defaults.items() if k in ("lr", "betas", "eps", "weight_decay", "amsgrad")}
        plain = type(opt)(params, **options, foreach=False)
        name = next(k for k, v in vars(model).items() if v is opt)
        setattr(model, name, plain)


def pix2pixhd_reference_step(t, binary, rgb) -> dict[str, float]:
    """The pix2pixHD step before D's passes were shared."""
    t.train(True)
    x, y = to_signed(binary), to_signed(rgb)
    fake = t.generate(x)  # G, as a residual over the physics prior
    set_requires_grad([t.D], False)
    pred_fake = t.D(torch.cat([x, fake], 1), features=True)
    terms = {"G_GAN": t.gan(pred_fake, True)}
    with torch.no_grad():
        pred_real = t.D(torch.cat([x, y], 1), features=True)
    weight = t.cfg.lambda_feat * 4.0 / (t.cfg.n_layers_D + 1) / t.cfg.num_D
    terms["G_feat"] = weight * sum(
        F.l1_loss(f, r) for pf, pr in zip(pred_fake, pred_real) for f, r in zip(pf[:-1], pr[:-1])
    )
    terms["G_VGG"] = t.cfg.lambda_feat * t.vgg(fake, y)
    set_requires_grad([t.D], True)
    loss_g = sum(terms.values())
    t.opt_G.zero_grad(set_to_none=True)
    loss_g.backward()
    t.opt_G.step()
    d_terms = conditional_d_step(t.D, t.opt_D, t.gan, t.pool, x, y, fake)
    return {"loss": float(loss_g.detach()), **{k: float(v.detach()) for k, v in terms.items()}, **d_terms}


def cyclegan_reference_step(t, binary, rgb) -> dict[str, float]:
    """The CycleGAN step before generator and discriminator calls were batched."""
    t.train(True)
    cfg, a, b = t.cfg, to_signed(binary), to_signed(rgb)
    fake_b, fake_a = t.g(a), t.F(b)  # t.g: G as a residual over the physics prior
    set_requires_grad([t.D_A, t.D_B], False)
    terms = {
        "G_GAN": t.gan(t.D_B(fake_b), True),
        "F_GAN": t.gan(t.D_A(fake_a), True),
        "cycle_A": cfg.lambda_A * F.l1_loss(t.F(fake_b), a),
        "cycle_B": cfg.lambda_B * F.l1_loss(t.g(fake_a), b),
        "idt_G": cfg.lambda_identity * cfg.lambda_B * F.l1_loss(t.g(b), b),
        "idt_F": cfg.lambda_identity * cfg.lambda_A * F.l1_loss(t.F(a), a),
    }
    set_requires_grad([t.D_A, t.D_B], True)
    loss_g = sum(terms.values())
    t.opt_G.zero_grad(set_to_none=True)
    loss_g.backward()
    t.opt_G.step()
    fa, fb = fake_a.detach(), fake_b.detach()
    loss_a = 0.5 * (t.gan(t.D_A(a), True) + t.gan(t.D_A(t.pool_A.query(fa)), False))
    loss_b = 0.5 * (t.gan(t.D_B(b), True) + t.gan(t.D_B(t.pool_B.query(fb)), False))
    t.opt_D.zero_grad(set_to_none=True)
    (loss_a + loss_b).backward()
    t.opt_D.step()
    return {
        "loss": float(loss_g.detach()),
        **{k: float(v.detach()) for k, v in terms.items()},
        "D_A": float(loss_a.detach()),
        "D_B": float(loss_b.detach()),
    }


REFERENCE_STEPS = {"pix2pixhd": pix2pixhd_reference_step, "cyclegan": cyclegan_reference_step}


def batches(n: int, size: int, seed: int = 3):
    g = torch.Generator().manual_seed(seed)
    for _ in range(n):
        rgb = torch.rand(2, 3, size, size, generator=g)
        yield torch.bernoulli(0.2 + 0.6 * rgb, generator=g), rgb


def outputs(model, x: torch.Tensor) -> dict[str, torch.Tensor]:
    """Every network of ``model`` in eval mode on the binary batch ``x`` (B, 3, h, w) in [0, 1]."""
    out = {}
    for name, net in model.modules().items():
        was = net.training
        net.eval()
        with torch.no_grad():
            if name == "prior":
                y = net(x)
            elif name == "G":  # as it translates: with the prior, the residual's mean (and G's last bias) drop out
                y = model.forward_image(x)
            elif hasattr(model, "ema"):  # the diffusion UNet and its EMA copy: (x_t, binary, cleaned) at two t
                net = net.model if name == "ema" else net
                y = net(torch.cat([x, x, x], 1), torch.tensor([10, 500][: len(x)]))
            elif name.startswith("D"):
                y = net(torch.cat([x, x], 1) if model.paired else x)
                y = torch.cat([t.flatten() for t in y]) if isinstance(y, list) else y
            else:
                y = net(x)
        net.train(was)
        out[name] = y
    return out


def compare(method: str, size: int = 64, steps: int = 3, fused: bool = True, exact: bool = False, **over) -> None:
    """``steps`` steps of the translator and of its reference on the same batches: equal losses (to
    float rounding), and after the first step (same parameters, same gradients up to rounding)
    networks that compute the same. Later steps are compared by their losses only: Adam moves a
    parameter whose gradient is rounding noise (a bias before an instance norm) by ~lr either
    way, so rounding-level differences grow into lr-sized ones in parameters without effect.
    ``fused=False``: both take plain optimisers; ``exact``: then every step must agree bit for bit
    (parameters too)."""
    fast, ref = build(method, **over), build(method, **over)
    plain_optimisers(ref)
    if not fused:
        plain_optimisers(fast)
    reference_step = REFERENCE_STEPS.get(method, type(ref).train_step)
    probe = next(batches(1, size, seed=9))[0]
    for i, (binary, rgb) in enumerate(batches(steps, size)):
        torch.manual_seed(100 + i)  # the diffusion step draws t and the noise from the global generator
        got = fast.train_step(binary, rgb)
        torch.manual_seed(100 + i)
        want = reference_step(ref, binary, rgb)
        assert got.keys() == want.keys()
        for k in want:
            assert got[k] == (want[k] if exact else pytest.approx(want[k], rel=1e-4, abs=1e-6)), (method, i, k)
        if i == 0 or exact:
            a, b = outputs(fast, probe), outputs(ref, probe)
            for name in b:
                scale = float(b[name].abs().max())
                tol = {"rtol": 0, "atol": 0} if exact else {"rtol": 1e-5, "atol": 1e-5 * scale}
                torch.testing.assert_close(a[name], b[name], **tol, msg=f"{method} {name} after step {i + 1}")
    if exact:
        for name, net in fast.modules().items():
            for p, q in zip(net.parameters(), ref.modules()[name].parameters()):
                assert torch.equal(p, q), (method, name)


@pytest.mark.parametrize("method", sorted(m for m, module in MODULES.items() if module.Translator.trainable))
def test_default_step_matches_the_plain_step(method):
    """The configured (CPU-sized) models, as the default run trains them, fused Adam included."""
    compare(method)


def test_pix2pixhd_shared_discriminator_passes_are_exact():
    """Sharing D's passes between the G and D updates changes no bit (same optimisers on both)."""
    compare("pix2pixhd", fused=False, exact=True)


def test_pix2pixhd_with_an_image_pool_matches():
    """With a pool D's fake loss takes pooled images: its own pass, not the generator's."""
    compare("pix2pixhd", size=32, steps=4, fused=False, exact=True, pool_size=3, ngf=8, ndf=8, n_blocks_global=1)


@pytest.mark.parametrize("norm", ["batch", "none"])
def test_cyclegan_other_norms_match(norm):
    """Batch norm pools statistics over a call, so its calls stay separate; no norm batches them."""
    compare("cyclegan", size=32, norm=norm, ngf=8, ndf=8)


def test_optimisers_are_fused_on_this_cpu():
    """torch >= 2.4 has fused Adam / AdamW kernels for the CPU: every translator uses them."""
    version = tuple(int(v) for v in torch.__version__.split("+")[0].split(".")[:2])
    if version < (2, 4):
        pytest.skip("no fused CPU optimisers before torch 2.4")
    for method in MODULES:
        assert all(o.defaults.get("fused") for o in build(method).optimizers().values()), method
