"""Restormer and the conditional-diffusion stand-in for DiffBIR (stage-1 translators).

Tiny configurations throughout; the sampler is tested separately from the network with an
oracle noise predictor.
"""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import pytest
import torch

from spc3d.translate import diffusion as D
from spc3d.translate import restormer as R

CPU = torch.device("cpu")
# The published designs, without the physics prior (tested with it in test_translate_prior.py).
TINY_R = R.Config(dim=8, num_blocks=(1, 1, 1, 1), num_refinement_blocks=1, heads=(1, 1, 2, 2), prior_sigma=0.0)
TINY_D = D.Config(base_channels=8, channel_mults=(1, 2), groups=4, timesteps=50, sample_steps=4, prior_sigma=0.0)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def binary_batch(b: int, h: int, w: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(b, 3, h, w, generator=g) < 0.4).float()


# ---------------------------------------------------------------------------------- Restormer


@pytest.mark.parametrize("norm", ["BiasFree", "WithBias"])
def test_restormer_odd_size_through_translate(norm):
    torch.manual_seed(0)
    tr = R.Translator(replace(TINY_R, layernorm_type=norm), CPU)
    out = tr.translate(binary_batch(2, 37, 53))
    assert tr.multiple == 8 and tr.paired
    assert out.shape == (2, 3, 37, 53)
    assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1


def test_restormer_paper_size_matches_publication():
    # Restormer reports 26.13M parameters (official default: WithBias LayerNorm).
    net = R.Restormer(replace(R.Config(), **{**R.PAPER, "layernorm_type": "WithBias"}))
    assert round(sum(p.numel() for p in net.parameters()) / 1e6, 2) == 26.13


def test_mdta_shape_and_attention_rows_sum_to_one():
    torch.manual_seed(0)
    mdta = R.MDTA(dim=8, num_heads=2, bias=False)
    x = torch.randn(3, 8, 5, 7)
    attn, v = mdta.attention(x)
    assert attn.shape == (3, 2, 4, 4)  # channel attention: (C/h x C/h) per head
    assert v.shape == (3, 2, 4, 35)
    torch.testing.assert_close(attn.sum(-1), torch.ones(3, 2, 4))
    assert mdta(x).shape == x.shape


def test_biasfree_layernorm_matches_hand_computation():
    torch.manual_seed(0)
    x = torch.randn(2, 5, 3, 4) + 3.0  # a clear non-zero mean
    norm = R.ChannelLayerNorm(5, "BiasFree")
    out = norm(x)
    mean = x.mean(dim=1, keepdim=True)
    var = ((x - mean) ** 2).mean(dim=1, keepdim=True)  # population variance over channels
    torch.testing.assert_close(out, x / torch.sqrt(var + 1e-5))
    torch.testing.assert_close(out.var(dim=1, unbiased=False), torch.ones(2, 3, 4), atol=1e-3, rtol=0)
    assert out.mean(dim=1).abs().min() > 1.0  # the mean is not removed
    with_bias = R.ChannelLayerNorm(5, "WithBias")(x)
    torch.testing.assert_close(with_bias.mean(dim=1), torch.zeros(2, 3, 4), atol=1e-5, rtol=0)


@pytest.mark.parametrize("block", ["mdta", "gdfn"])
def test_gradcheck_blocks(block):
    torch.manual_seed(0)
    module = R.MDTA(4, 2, bias=True) if block == "mdta" else R.GDFN(4, 1.5, bias=True)
    module = module.double()
    x = torch.randn(1, 4, 3, 5, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(module, (x,), eps=1e-6, atol=1e-5)


def test_official_names_and_checkpoint_round_trip(tmp_path):
    torch.manual_seed(0)
    tr = R.Translator(TINY_R, CPU)
    sd = tr.net.state_dict()
    for name in (
        "patch_embed.proj.weight",
        "encoder_level1.0.norm1.body.weight",
        "encoder_level1.0.attn.temperature",
        "encoder_level1.0.attn.qkv.weight",
        "encoder_level1.0.attn.qkv_dwconv.weight",
        "encoder_level1.0.attn.project_out.weight",
        "encoder_level2.0.ffn.project_in.weight",
        "latent.0.ffn.dwconv.weight",
        "decoder_level1.0.ffn.project_out.weight",
        "down1_2.body.0.weight",
        "up2_1.body.0.weight",
        "reduce_chan_level2.weight",
        "reduce_chan_level3.weight",
        "refinement.0.norm2.body.weight",
        "output.weight",
    ):
        assert name in sd, name
    assert not any(k.startswith("reduce_chan_level1") for k in sd)
    path = tmp_path / "restormer.pth"
    torch.save({"params": sd}, path)
    loaded = R.load_official_checkpoint(path, TINY_R)
    x = binary_batch(1, 24, 32)
    assert torch.equal(loaded.translate(x), tr.translate(x))


def test_mismatched_checkpoint_names_keys(tmp_path):
    sd = R.Translator(TINY_R, CPU).net.state_dict()
    sd["skip_conv.weight"] = torch.zeros(16, 8, 1, 1)  # dual-pixel-only layer
    path = tmp_path / "other.pth"
    torch.save({"params": sd}, path)
    with pytest.raises(ValueError) as err:
        R.load_official_checkpoint(path, replace(TINY_R, num_blocks=(2, 1, 1, 1)))
    msg = str(err.value)
    assert str(path) in msg and "encoder_level1.1.attn.qkv.weight" in msg and "skip_conv.weight" in msg
    with pytest.raises(ValueError, match="shape"):
        R.load_official_checkpoint(path, replace(TINY_R, dim=12))


def test_restormer_learns_tiny_mapping():
    torch.manual_seed(0)
    tr = R.Translator(replace(TINY_R, lr=2e-3, grad_clip=0.0), CPU)
    binary = binary_batch(4, 16, 16)
    rgb = 0.2 + 0.6 * binary.flip(1)  # swap red and blue, shrink the range
    losses = [tr.train_step(binary, rgb)["loss"] for _ in range(40)]
    assert all(isinstance(v, float) for v in losses)
    assert sum(losses[-5:]) / 5 < 0.5 * sum(losses[:5]) / 5


def test_restormer_train_step_any_crop_and_load_pretrained(tmp_path):
    torch.manual_seed(0)
    tr = R.Translator(TINY_R, CPU)
    assert set(tr.train_step(binary_batch(2, 20, 12), torch.rand(2, 3, 20, 12))) >= {"loss"}
    path = tmp_path / "w.pth"
    torch.save({"params": tr.net.state_dict()}, path)
    other = R.Translator(TINY_R, CPU)
    other.load_pretrained(path)  # what stage1 settings' ``checkpoint`` calls
    x = binary_batch(1, 16, 16)
    assert torch.equal(other.translate(x), tr.translate(x))


def test_restormer_state_round_trip():
    torch.manual_seed(0)
    a, b = R.Translator(TINY_R, CPU), R.Translator(TINY_R, CPU)
    x, y = binary_batch(2, 16, 16), torch.rand(2, 3, 16, 16)
    a.train_step(x, y)
    b.load(copy.deepcopy(a.state()))  # as from disk: no optimiser tensors shared with a
    assert torch.equal(a.translate(x), b.translate(x))
    a.train_step(x, y), b.train_step(x, y)  # optimiser state came along too
    assert torch.equal(a.translate(x), b.translate(x))


# ---------------------------------------------------------------------------------- Diffusion


@pytest.mark.parametrize("kind", ["linear", "cosine"])
def test_noise_schedule(kind):
    sched = D.NoiseSchedule(D.make_betas(kind, 1000))
    ab = sched.alphas_cumprod
    assert ab.dtype == torch.float64
    assert ((sched.betas > 0) & (sched.betas < 1)).all()
    assert ((ab > 0) & (ab < 1)).all() and (ab[1:] < ab[:-1]).all()
    x0 = torch.rand(2, 3, 8, 8) * 2 - 1
    noise = torch.randn(x0.shape, generator=torch.Generator().manual_seed(0))
    xt = sched.q_sample(x0, torch.zeros(2, dtype=torch.long), noise)
    assert (xt - x0).abs().max() < 0.05  # t = 0 is almost clean


@pytest.mark.parametrize("prediction", ["v", "eps"])
def test_parameterisation_round_trip(prediction):
    sched = D.NoiseSchedule(D.make_betas("cosine", 1000))
    g = torch.Generator().manual_seed(1)
    x0 = torch.rand(4, 3, 5, 5, generator=g, dtype=torch.float64) * 2 - 1
    noise = torch.randn(4, 3, 5, 5, generator=g, dtype=torch.float64)
    t = torch.tensor([0, 10, 500, 900])
    xt = sched.q_sample(x0, t, noise)
    x0_hat, eps_hat = sched.to_x0_eps(xt, t, sched.target(x0, noise, t, prediction), prediction)
    torch.testing.assert_close(x0_hat, x0, atol=1e-10, rtol=0)
    torch.testing.assert_close(eps_hat, noise, atol=1e-10, rtol=0)


@pytest.mark.parametrize("prediction,eta", [("v", 0.0), ("eps", 0.0), ("v", 1.0)])
def test_ddim_with_oracle_recovers_x0(prediction, eta):
    sched = D.NoiseSchedule(D.make_betas("cosine", 1000))
    g = torch.Generator().manual_seed(2)
    x0 = torch.rand(2, 3, 6, 6, generator=g, dtype=torch.float64) * 2 - 1

    def oracle(x_t, t):  # the exact network output for this x0
        a, s = sched.coefs(t, x_t)
        eps = (x_t - a * x0) / s
        return eps if prediction == "eps" else a * eps - s * x0

    x_T = torch.randn(x0.shape, generator=g, dtype=torch.float64)
    out = D.ddim_sample(oracle, x_T, sched, steps=10, prediction=prediction, eta=eta, generator=g)
    torch.testing.assert_close(out, x0, atol=1e-9, rtol=0)


def test_window_attention_matches_per_tile_attention():
    g = torch.Generator().manual_seed(3)
    q, k, v = (torch.randn(2, 4, 5, 7, generator=g, dtype=torch.float64) for _ in range(3))
    out = D.window_attention(q, k, v, window=4)
    assert out.shape == (2, 4, 5, 7)
    for rows in (slice(0, 4), slice(4, 5)):  # tiles, the bottom/right ones cut by the image edge
        for cols in (slice(0, 4), slice(4, 7)):
            tq, tk, tv = (t[:, :, rows, cols].flatten(2).transpose(1, 2) for t in (q, k, v))
            ref = torch.softmax(tq @ tk.transpose(1, 2) / 2.0, dim=-1) @ tv  # scale 1/sqrt(C)
            torch.testing.assert_close(out[:, :, rows, cols].flatten(2).transpose(1, 2), ref)


def test_diffusion_odd_size_and_deterministic_sampling():
    torch.manual_seed(0)
    tr = D.Translator(TINY_D, CPU)
    tr.train_step(binary_batch(2, 8, 8), torch.rand(2, 3, 8, 8))  # non-zero output layer
    x = binary_batch(1, 37, 53)
    out1, out2 = tr.translate(x), tr.translate(x)
    assert tr.multiple == 2
    assert out1.shape == (1, 3, 37, 53) and torch.isfinite(out1).all()
    assert out1.min() >= 0 and out1.max() <= 1
    assert torch.equal(out1, out2)
    other = D.Translator(replace(TINY_D, sample_seed=1), CPU)
    other.load(tr.state())
    assert not torch.equal(other.translate(x), out1)


def test_diffusion_samples_average_their_own_draws(monkeypatch):
    """samples: 2 returns the mean of two outputs, each sampled from its own x_T of the seeded
    generator (the sampler replaced by one that returns x_T, the prior off: the output is x_T)."""
    monkeypatch.setattr(D, "ddim_sample", lambda predict, x_T, *a, **k: x_T)
    cfg = replace(TINY_D, samples=2, prior_sigma=0.0)
    x = binary_batch(1, 16, 16)
    out = D.Translator(cfg, CPU).forward_image(x)
    gen = torch.Generator().manual_seed(cfg.sample_seed)
    draws = [((torch.randn(x.shape, generator=gen) + 1) / 2).clamp(0, 1) for _ in range(2)]
    torch.testing.assert_close(out, (draws[0] + draws[1]) / 2)
    one = D.Translator(replace(cfg, samples=1), CPU).forward_image(x)
    torch.testing.assert_close(one, draws[0])  # one sample: the output as before the option


def test_diffusion_train_step_decreases_loss():
    torch.manual_seed(0)
    tr = D.Translator(replace(TINY_D, lr=5e-3), CPU)
    binary = binary_batch(4, 8, 8)
    rgb = torch.full((4, 3, 8, 8), 0.7)
    losses = []
    for step in range(40):
        torch.manual_seed(step % 5)  # the same 5 (t, noise) draws recur: comparable losses
        losses.append(tr.train_step(binary, rgb)["loss"])
    assert all(isinstance(v, float) and math.isfinite(v) for v in losses)
    assert sum(losses[-5:]) < 0.75 * sum(losses[:5])


def test_diffusion_state_round_trip():
    torch.manual_seed(0)
    a, b = D.Translator(TINY_D, CPU), D.Translator(TINY_D, CPU)
    a.train_step(binary_batch(2, 9, 11), torch.rand(2, 3, 9, 11))  # crops need not divide by 2
    b.load(copy.deepcopy(a.state()))
    assert int(b.ema.num_updates) == 1
    x = binary_batch(1, 12, 10)
    assert torch.equal(a.translate(x), b.translate(x))
