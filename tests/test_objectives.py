"""The stage-2 objectives' values against their formulas (spc3d.reconstruct.objectives).

Each loss is checked against an independent float64 evaluation of its definition, at values where
every term matters, so that a changed sign, weight, clamp or branch shows as a wrong number rather
than only as a slower or a different fit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spc3d.evaluation.metrics import ssim_loss
from spc3d.pixels import linear_to_srgb
from spc3d.reconstruct.objectives import LN2, BernoulliObjective, JointConfig, JointObjective, RGBObjective

G = torch.Generator().manual_seed(0)
PRED = torch.rand(2, 24, 20, 3, generator=G, dtype=torch.float64)
TARGET = torch.rand(2, 24, 20, 3, generator=G, dtype=torch.float64)


def test_rgb_losses_are_mean_absolute_and_mean_squared_error():
    diff = (PRED - TARGET).numpy()
    assert float(RGBObjective("l1").loss(PRED, TARGET)) == pytest.approx(np.abs(diff).mean(), rel=1e-12)
    assert float(RGBObjective().loss(PRED, TARGET)) == pytest.approx(np.abs(diff).mean(), rel=1e-12)  # L1 by default
    assert float(RGBObjective("mse").loss(PRED, TARGET)) == pytest.approx(np.square(diff).mean(), rel=1e-12)


@pytest.mark.parametrize("kind", ["l1", "mse"])
def test_rgb_ssim_mix_is_one_minus_w_error_plus_w_dssim(kind):
    w = 0.2
    err = RGBObjective(kind).loss(PRED, TARGET)
    dssim = ssim_loss(PRED.permute(0, 3, 1, 2), TARGET.permute(0, 3, 1, 2))
    got = RGBObjective(kind, w).loss(PRED, TARGET)
    assert float(got) == pytest.approx(float((1 - w) * err + w * dssim), rel=1e-6)
    single = RGBObjective(kind, w).loss(PRED[0], TARGET[0])  # one (H, W, 3) image: a batch of one
    assert float(single) == pytest.approx(float(RGBObjective(kind, w).loss(PRED[:1], TARGET[:1])), rel=1e-9)


def test_objectives_say_whether_a_plateau_can_stop_them_and_how_they_are_shown():
    assert RGBObjective().stops_on_plateau and RGBObjective().name == "rgb"
    bern = BernoulliObjective(1.0, 0.5, 1.0, 0.0)
    assert not bern.stops_on_plateau and not JointObjective(bern).stops_on_plateau
    x = torch.tensor([-0.5, 0.001, 0.3, 1.7])
    assert torch.equal(RGBObjective().to_srgb(x), x.clamp(0, 1))
    assert torch.equal(bern.to_srgb(x), linear_to_srgb(x)) and torch.equal(
        JointObjective(bern).to_srgb(x), linear_to_srgb(x)
    )


def nll(linear: np.ndarray, f: np.ndarray, flux: float, q: float, T: float, dcr: float) -> float:
    """The Bernoulli negative log-likelihood per value, in float64: x = λT, P(1) = 1 - exp(-x)."""
    x = np.maximum((q * flux * np.maximum(linear, 0.0) + dcr) * T, 1e-12)
    return float(-(f * np.log(-np.expm1(-x)) - (1 - f) * x).mean())


@pytest.mark.parametrize("dcr", [0.0, 3.0e3])
def test_bernoulli_loss_is_the_likelihood_of_the_bit_fractions(dcr):
    obj = BernoulliObjective(flux_scale=2.0e4, q=0.4, exposure_s=1.0e-4, dark_count_rate=dcr)
    linear = np.linspace(-0.2, 3.0, 40)  # negative renders count as dark (only dark counts fire)
    f = np.linspace(0.0, 1.0, 40) ** 1.5
    got = obj.loss(torch.as_tensor(linear), torch.as_tensor(f))
    assert float(got) == pytest.approx(nll(linear, f, 2.0e4, 0.4, 1.0e-4, dcr), rel=1e-10)
    lam = obj.lam_t(torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64))
    expected = [dcr * 1e-4 or 1e-12, dcr * 1e-4 or 1e-12, (0.4 * 2.0e4 + dcr) * 1e-4]
    np.testing.assert_allclose(lam.numpy(), expected, rtol=1e-12)


def test_bernoulli_branches_meet_at_ln2_in_value_and_gradient():
    obj = BernoulliObjective(flux_scale=1.0, q=1.0, exposure_s=1.0, dark_count_rate=0.0)
    for x0 in (LN2 * (1 - 1e-9), LN2 * (1 + 1e-9), 0.01, 5.0):
        x = torch.tensor([x0], dtype=torch.float64, requires_grad=True)
        loss = obj.loss(x, torch.tensor([0.7], dtype=torch.float64))
        (g,) = torch.autograd.grad(loss, x)
        p = -math.expm1(-x0)
        assert loss.item() == pytest.approx(-(0.7 * math.log(p) - 0.3 * x0), rel=1e-9)
        assert g.item() == pytest.approx(-(0.7 * math.exp(-x0) / p - 0.3), rel=1e-7)


def test_joint_loss_is_the_likelihood_plus_w_times_the_image_loss():
    bern = BernoulliObjective(flux_scale=3.0, q=0.5, exposure_s=1.0, dark_count_rate=0.1)
    image = RGBObjective("l1")
    joint = JointObjective(bern, JointConfig(weight=0.7, weight_final=0.2, decay_until=0.5), image)
    bits, stage1 = torch.rand(2, 8, 6, 3, generator=G), torch.rand(2, 8, 6, 3, generator=G)
    pred = torch.rand(2, 8, 6, 3, generator=G)
    target = torch.cat([bits, stage1], -1)
    like, prior = bern.loss(pred, bits), image.loss(linear_to_srgb(pred), stage1)
    for t, w in ((0.0, 0.7), (0.25, 0.45), (0.5, 0.2), (0.9, 0.2)):
        joint.at(t)
        assert joint.weight == pytest.approx(w)
        assert float(joint.loss(pred, target)) == pytest.approx(float(like + w * prior), rel=1e-6)
    off = JointObjective(bern, JointConfig(likelihood=False), image)
    assert float(off.loss(pred, target)) == pytest.approx(float(prior), rel=1e-6)
    assert isinstance(JointObjective(bern, JointConfig(penalty="l1")).image, RGBObjective)


def test_objectives_are_immutable_values():
    """A trainer, its checkpoint and a joint row share one objective: none may change it in place
    (the joint row's schedule changes only its own weight, through ``at``)."""
    import dataclasses

    for objective in (RGBObjective("l1"), BernoulliObjective(100.0, 0.4, 1e-3, 10.0)):
        with pytest.raises(dataclasses.FrozenInstanceError):
            objective.name = "changed"


def test_joint_config_accepts_its_closed_ranges_and_names_the_key_first_when_it_refuses():
    JointConfig(decay_until=0.0)
    JointConfig(decay_until=1.0)  # decay over the whole run: valid
    JointConfig(weight=0.0, weight_final=0.0)  # no prior term: the likelihood row's objective
    with pytest.raises(ValueError, match=r"^stage2\.joint\.decay_until = 1\.5: a fraction of the run, in \[0, 1\]$"):
        JointConfig(decay_until=1.5)
    with pytest.raises(ValueError, match=r"^stage2\.joint\.penalty = 'l2': use one of \['own', 'l1'\]$"):
        JointConfig(penalty="l2")
    for key in ("weight", "weight_final"):
        with pytest.raises(ValueError, match=rf"^stage2\.joint\.{key} = -0\.1: the prior term's weight must be >= 0$"):
            JointConfig(**{key: -0.1})


def test_the_l1_penalty_pulls_with_the_mean_absolute_error_whatever_the_model():
    """``penalty: l1`` (for NeRF, whose own loss is MSE) makes the prior term L1 on the sRGB render."""
    bern = BernoulliObjective(100.0, 0.4, 1e-3, 10.0)
    joint = JointObjective(bern, JointConfig(weight=1.0, weight_final=1.0, likelihood=False, penalty="l1"))
    pred = PRED.clamp(0.05, 0.95)
    target = torch.cat([torch.zeros_like(pred), TARGET], dim=-1)
    expected = (linear_to_srgb(pred) - TARGET).abs().mean()
    assert float(joint.loss(pred, target)) == pytest.approx(float(expected), rel=1e-12)
