"""The pixel values every stage shares (spc3d.pixels): the sRGB transfer on arrays and tensors
alike, clipped to [0, 1], and PSNR."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spc3d import pixels

# below 0, the linear toe (both knees), the curve, 1 and above
KNEES = [0.0031308, 0.04045]
GRID = np.concatenate([[-0.5, 0.0], np.linspace(0.0, 0.05, 501), KNEES, np.linspace(0.05, 1.0, 96), [1.5]])


@pytest.mark.parametrize("curve", [pixels.srgb_to_linear, pixels.linear_to_srgb], ids=["decode", "encode"])
def test_arrays_and_tensors_take_one_curve_clipped_to_the_unit_range(curve):
    on_array = curve(GRID)
    on_tensor = curve(torch.from_numpy(GRID))
    assert isinstance(on_array, np.ndarray) and torch.is_tensor(on_tensor)
    np.testing.assert_allclose(on_tensor.numpy(), on_array, rtol=0, atol=1e-12)
    assert on_array[0] == 0.0 and on_array[-1] == pytest.approx(1.0, abs=1e-15)  # clipped (and on the tensor, above)


def test_the_linear_toe_and_its_inverse():
    toe = np.array([0.0, 0.001, 0.003])
    np.testing.assert_allclose(pixels.linear_to_srgb(torch.from_numpy(toe)).numpy(), 12.92 * toe, rtol=1e-15)
    np.testing.assert_allclose(pixels.srgb_to_linear(12.92 * toe), toe, rtol=1e-12)


def test_the_tensor_encoding_has_a_finite_gradient_at_black():
    x = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    pixels.linear_to_srgb(x).sum().backward()
    assert torch.isfinite(x.grad).all() and torch.equal(x.grad, torch.full((3,), 12.92, dtype=torch.float64))


def test_psnr_of_arrays_and_tensors_and_its_edges():
    rng = np.random.default_rng(0)
    a, b = rng.random((4, 5, 3)), rng.random((4, 5, 3))
    expected = 10.0 * math.log10(1.0 / np.mean((a - b) ** 2))
    assert pixels.psnr(a, b) == pytest.approx(expected, rel=1e-15)
    assert pixels.psnr(torch.from_numpy(a), torch.from_numpy(b)) == pytest.approx(expected, rel=1e-15)
    assert pixels.psnr(a, a.copy()) == math.inf
    with pytest.raises(ValueError, match=r"^expected two arrays of one shape, got \(4, 5, 3\) and \(4, 5\)$"):
        pixels.psnr(a, b[..., 0])
