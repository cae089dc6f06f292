"""Gaussian splatting math: projection, SH colour, and native (numba) vs reference rasterizers.

Float64 finite-difference checks use ``torch.autograd.gradcheck``; the native back-end computes
in float64 internally, so it is checked directly against its own finite differences in float64.
"""

import math

import numpy as np
import pytest
import torch

from spc3d.reconstruct.splat import (
    BACKENDS,
    eval_sh,
    project_gaussians,
    project_gaussians_native,
    rasterize,
    rasterize_dense,
    rasterize_native,
    rasterize_reference,
)
from spc3d.reconstruct.splat.native_sh import eval_sh_native
from spc3d.reconstruct.splat.project import SH_C0

RASTERIZERS = {"native": rasterize_native, "reference": rasterize_reference}
PROJECTORS = {"torch": project_gaussians, "native": project_gaussians_native}


def screen_scene(n, height, width, seed=0, dtype=torch.float32, sigma=(0.5, 3.0)):
    """Random screen-space Gaussians: the positional rasterizer arguments, background last."""
    g = torch.Generator().manual_seed(seed)
    means2d = torch.rand(n, 2, generator=g, dtype=dtype) * torch.tensor([width, height], dtype=dtype)
    s = sigma[0] + (sigma[1] - sigma[0]) * torch.rand(n, 2, generator=g, dtype=dtype)
    angle = math.pi * torch.rand(n, generator=g, dtype=dtype)
    cos, sin = torch.cos(angle), torch.sin(angle)
    a = (cos * s[:, 0]) ** 2 + (sin * s[:, 1]) ** 2
    c = (sin * s[:, 0]) ** 2 + (cos * s[:, 1]) ** 2
    b = cos * sin * (s[:, 0] ** 2 - s[:, 1] ** 2)
    det = a * c - b * b
    conics = torch.stack([c / det, -b / det, a / det], -1)
    radii = torch.ceil(3 * s.max(1).values).int()
    opacities = 0.05 + 0.9 * torch.rand(n, generator=g, dtype=dtype)
    colors = torch.rand(n, 3, generator=g, dtype=dtype)
    depths = torch.rand(n, generator=g, dtype=dtype)
    background = torch.rand(3, generator=g, dtype=dtype)
    return [means2d, conics, opacities, colors, depths, radii, height, width, background]


def grads(fn, args, seed=1):
    """Gradients of a random linear loss of (image, alpha) w.r.t. means2d, conics, opacities,
    colors and background (the loss weights are drawn in float64: the same for any dtype)."""
    leaves = [args[i].detach().clone().requires_grad_() for i in (0, 1, 2, 3, 8)]
    full = list(args)
    for i, t in zip((0, 1, 2, 3, 8), leaves):
        full[i] = t
    image, alpha = fn(*full)
    g = torch.Generator().manual_seed(seed)
    w_img = torch.randn(image.shape, generator=g, dtype=torch.float64).to(image.dtype)
    w_alpha = torch.randn(alpha.shape, generator=g, dtype=torch.float64).to(alpha.dtype)
    ((image * w_img).sum() + (alpha * w_alpha).sum()).backward()
    return [t.grad for t in leaves]


# ---------------------------------------------------------------- rasterizers: forward agreement


@pytest.mark.parametrize("n, height, width", [(200, 24, 32), (2000, 48, 64)])
def test_native_forward_matches_reference(n, height, width):
    args = screen_scene(n, height, width, seed=n)
    img_n, alpha_n = rasterize_native(*args)
    img_r, alpha_r = rasterize_reference(*args)
    assert img_n.shape == (height, width, 3) and alpha_n.shape == (height, width)
    assert img_n.dtype == torch.float32
    assert (img_n - img_r).abs().max() < 1e-5
    assert (alpha_n - alpha_r).abs().max() < 1e-5


def test_native_boxes_are_the_reference_boxes_tightened_to_visible_pixels():
    """native_prep's boxes lie inside the 3-sigma squares of ``pixel_boxes`` and leave out only
    pixels that no rasterizer composites (alpha < 1/255 or power > 0)."""
    from spc3d.reconstruct.splat.native_prep import prepare_tiles
    from spc3d.reconstruct.splat.reference import _pair_alpha, pixel_boxes

    means2d, conics, opacities, _, depths, radii, *_ = screen_scene(500, 24, 32, seed=8)
    means2d, radii = means2d * 1.5 - 8, radii.clone()  # many partly or fully off-image
    means2d[0], radii[1], opacities[2] = torch.tensor([1e12, -1e12]), 0, 0.001  # far off, culled, invisible
    _, boxes, *_ = prepare_tiles(
        means2d.numpy(), conics.numpy(), opacities.numpy(), depths.numpy(), radii.numpy(), 24, 32, np.float32
    )
    ref = pixel_boxes(means2d, radii, 24, 32).numpy()
    empty = (boxes[:, 1] < boxes[:, 0]) | (boxes[:, 3] < boxes[:, 2])
    assert empty[:3].all()
    inside = (
        (boxes[:, 0] >= ref[:, 0])
        & (boxes[:, 1] <= ref[:, 1])
        & (boxes[:, 2] >= ref[:, 2])
        & (boxes[:, 3] <= ref[:, 3])
    )
    assert (inside | empty).all()
    assert (boxes[~empty, 1] - boxes[~empty, 0]).sum() < 0.9 * (ref[~empty, 1] - ref[~empty, 0]).sum()
    ys, xs = torch.meshgrid(torch.arange(24), torch.arange(32), indexing="ij")
    px, py = xs.reshape(-1), ys.reshape(-1)
    for g in range(500):
        x0, x1, y0, y1 = ref[g]
        in_ref = (px >= x0) & (px <= x1) & (py >= y0) & (py <= y1)
        x0, x1, y0, y1 = boxes[g]
        left_out = in_ref & ~((px >= x0) & (px <= x1) & (py >= y0) & (py <= y1))
        gid = torch.full((int(left_out.sum()),), g)
        _, keep = _pair_alpha(means2d, conics, opacities, gid, px[left_out], py[left_out])
        assert not keep.any(), f"Gaussian {g}: a composited pixel lies outside its tight box"


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_native_depth_order_is_torchs_stable_argsort(dtype):
    """Each tile list (in index order) sorted by the depth keys is torch's stable argsort of its
    depths: ties by index, -0.0 == 0.0, lists of 0, 1, 2 and many entries."""
    from spc3d.reconstruct.splat.native_prep import _depth_key, sort_tiles

    rng = np.random.default_rng(3)
    depths = (rng.standard_normal(3000) * 10.0 ** rng.integers(-3, 4, 3000)).astype(dtype)
    depths[::7], depths[5], depths[6], depths[9] = depths[3], -0.0, 0.0, 1e30  # ties, signed zeros
    bits = depths.view(np.int32 if dtype == np.float32 else np.int64)
    keys = np.array([_depth_key(b, bits.itemsize) for b in bits])
    ids = np.arange(3000, dtype=np.int32)[::4].copy()  # the Gaussians listed, in index order
    offsets = np.array([0, 0, 1, 3, 400, len(ids)])
    sort_tiles(ids, keys, offsets, bits.itemsize)
    for lo, hi in zip(offsets[:-1], offsets[1:]):
        listed = np.arange(3000)[::4][lo:hi]
        expected = listed[torch.argsort(torch.from_numpy(depths[listed]), stable=True).numpy()]
        assert np.array_equal(ids[lo:hi], expected)


def test_reference_matches_dense():
    args = screen_scene(60, 16, 20, seed=3)
    for a, b in zip(rasterize_reference(*args), rasterize_dense(*args)):
        assert (a - b).abs().max() < 1e-5


def test_native_gradients_match_reference():
    args = screen_scene(200, 24, 32, seed=7)
    for name, gn, gr in zip(
        ("means2d", "conics", "opacities", "colors", "background"),
        grads(rasterize_native, args),
        grads(rasterize_reference, args),
    ):
        rel = (gn - gr).norm() / gr.norm()
        assert rel < 1e-4, f"{name}: relative error {rel:.2e}"


@pytest.mark.parametrize("backend", ["native", "reference"])
def test_rasterizer_gradcheck_float64(backend):
    args = screen_scene(4, 8, 8, seed=11, dtype=torch.float64, sigma=(1.0, 2.5))
    fn = RASTERIZERS[backend]

    def f(means2d, conics, opacities, colors, background):
        return fn(means2d, conics, opacities, colors, args[4], args[5], 8, 8, background)

    inputs = [args[i].clone().requires_grad_() for i in (0, 1, 2, 3, 8)]
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


@pytest.mark.parametrize("channels", [1, 4])
def test_native_any_channel_count(channels):
    args = screen_scene(100, 16, 20, seed=12)
    args[3], args[8] = torch.rand(100, channels), torch.rand(channels)
    for a, b in zip(rasterize_native(*args), rasterize_reference(*args)):
        assert (a - b).abs().max() < 1e-5
    for gn, gr in zip(grads(rasterize_native, args), grads(rasterize_reference, args)):
        assert (gn - gr).norm() / gr.norm() < 1e-4


def test_native_float64_in_float64_out():
    args = screen_scene(30, 8, 8, seed=2, dtype=torch.float64)
    image, alpha = rasterize_native(*args)
    assert image.dtype == torch.float64 and alpha.dtype == torch.float64


def test_native_float32_simd_matches_float64_path():
    """float32 RGB runs the SIMD kernels (native_simd), float64 the exact float64 kernels: the
    two agree in values and gradients (opaque stacks included: early termination, clamps)."""
    args = screen_scene(1500, 40, 56, seed=21)
    args[2][:300] = 0.99  # clamped alphas and pixels that terminate early
    args64 = [a.double() if torch.is_tensor(a) and a.is_floating_point() else a for a in args]
    for a, b in zip(rasterize_native(*args), rasterize_native(*args64)):
        assert a.dtype == torch.float32 and b.dtype == torch.float64
        assert (a.double() - b).abs().max() < 1e-5
    for name, g32, g64 in zip(
        ("means2d", "conics", "opacities", "colors", "background"),
        grads(rasterize_native, args),
        grads(rasterize_native, args64),
    ):
        assert (g32.double() - g64).norm() / g64.norm() < 1e-4, name


def test_native_exp2_polynomial_accuracy():
    from spc3d.reconstruct.splat.native_simd import _exp2

    x = np.linspace(-20.0 * np.log2(np.e), 0.0, 20001).astype(np.float32)
    got = np.array([_exp2(v) for v in x], dtype=np.float64)
    assert np.abs(got / np.exp2(x.astype(np.float64)) - 1).max() < 3e-7


@pytest.mark.parametrize("use_openmp", [True, False])
def test_native_worker_threads_run_every_share_once(use_openmp, monkeypatch):
    from spc3d.reconstruct.splat import native_threads

    if not use_openmp:
        monkeypatch.setattr(native_threads, "_GOMP", None)
    seen = []
    native_threads.run_parallel(seen.append, 5)
    assert sorted(seen) == [0, 1, 2, 3, 4]

    def fail(w):
        if w == 3:
            raise KeyError("worker 3")

    with pytest.raises(KeyError, match="worker 3"):
        native_threads.run_parallel(fail, 4)


def test_next_item_deals_every_item_once():
    """The atomic counter of the dynamically scheduled kernels: 4 workers racing for 20k items
    take each exactly once (a lost or doubled increment would show as a 0 or a 2)."""
    from numba import njit

    from spc3d.reconstruct.splat import native_threads

    @njit(nogil=True)
    def drain(counter, taken):
        while True:
            i = native_threads.next_item(counter)
            if i >= len(taken):
                return
            taken[i] += 1

    counter, taken = np.zeros(1, np.int64), np.zeros(20000, np.int64)
    native_threads.run_parallel(lambda w: drain(counter, taken), 4)
    assert (taken == 1).all() and counter[0] >= len(taken)


def test_next_chunk_deals_every_item_once():
    """Chunks of 7 of 20003 items (the last one short), 4 racing workers: every item once."""
    from numba import njit

    from spc3d.reconstruct.splat import native_threads

    @njit(nogil=True)
    def drain(counter, taken):
        while True:
            c0, n = native_threads.next_chunk(counter, len(taken), 7)
            if n <= 0:
                return
            for i in range(c0, c0 + n):
                taken[i] += 1

    counter, taken = np.zeros(1, np.int64), np.zeros(20003, np.int64)
    native_threads.run_parallel(lambda w: drain(counter, taken), 4)
    assert (taken == 1).all()


def test_native_projection_and_tile_lists_do_not_depend_on_threads(monkeypatch):
    """Projection (forward, backward) and set-up passes take chunks dynamically: outputs and
    tile lists are identical for 1, 2 and 3 threads."""
    from spc3d.reconstruct.splat.native_prep import prepare_tiles

    means, scales, quats = gaussians3d(5000, seed=5)
    opacities = torch.rand(5000, generator=torch.Generator().manual_seed(5)).numpy()
    cam = rotated_camera()
    results = []
    for n in (1, 2, 3):
        monkeypatch.setattr(torch, "get_num_threads", lambda n=n: n)
        leaves = [t.clone().float().requires_grad_() for t in (means, scales, quats)]
        p = project_gaussians_native(*leaves, **cam)
        (p.means2d.sum() + p.conics.sum() + p.depths.sum()).backward()
        lists = prepare_tiles(
            p.means2d.detach().numpy(),
            p.conics.detach().numpy(),
            opacities,
            p.depths.detach().numpy(),
            p.radii.numpy(),
            24,
            32,
            np.float32,
        )
        results.append(
            [
                p.means2d,
                p.conics,
                p.depths,
                p.radii,
                *(t.grad for t in leaves),
                *(torch.from_numpy(np.asarray(a)) for a in lists[2:4]),
            ]
        )
    for out in zip(*results):
        assert all(torch.equal(out[0], other) for other in out[1:])


def test_float32_forward_refuses_a_too_small_pair_cache():
    """The G cache is sized by ``cache_rows``; a smaller one is an error naming it, not a write
    past its end."""
    from spc3d.reconstruct.splat.native_prep import prepare_tiles
    from spc3d.reconstruct.splat.native_simd import forward_tiles32

    means2d, conics, opacities, colors, depths, radii, height, width, bg = screen_scene(300, 24, 32, seed=9)
    gs, boxes, offsets, ids, keys, key_bytes, _ = prepare_tiles(
        means2d.numpy(),
        conics.numpy(),
        opacities.numpy(),
        depths.numpy(),
        radii.numpy(),
        height,
        width,
        np.float32,
        sort=False,
    )
    out = [
        np.empty((height, width, 3), np.float32),
        np.empty((height, width), np.float32),
        np.empty((height, width), np.float32),
        np.empty((height, width), np.int32),
    ]
    tiles = np.arange(len(offsets) - 1)
    with pytest.raises(RuntimeError, match="cache_rows"):
        forward_tiles32(
            gs,
            boxes,
            colors.numpy(),
            bg.numpy(),
            offsets,
            ids,
            tiles,
            np.zeros(1, np.int64),
            height,
            width,
            2,
            *out,
            keys,
            key_bytes,
            np.empty(len(ids), np.int64),
            np.empty((8, 16), np.float32),
            np.zeros(1, np.int64),
        )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_two_threads_match_one(monkeypatch, dtype):
    """float32 (SIMD kernels, tiles dealt out dynamically, gradients per tile-list record summed
    in one fixed order): the same bits for any thread count; float64: per-worker sums."""
    args = screen_scene(800, 40, 56, seed=22, dtype=dtype)
    results = []
    for n in (1, 2, 3):
        monkeypatch.setattr(torch, "get_num_threads", lambda n=n: n)
        results.append([*rasterize_native(*args), *grads(rasterize_native, args)])
    for out in zip(*results):
        for other in out[1:]:
            if dtype == torch.float32:
                assert torch.equal(out[0], other)
            else:
                assert torch.allclose(out[0], other, rtol=1e-12, atol=1e-14)


# ---------------------------------------------------------------- rasterizers: extremes


@pytest.mark.parametrize("backend", ["native", "reference"])
def test_zero_opacity_shows_background(backend):
    args = screen_scene(50, 12, 12, seed=4)
    args[2] = torch.zeros(50)
    image, alpha = RASTERIZERS[backend](*args)
    assert torch.allclose(image, args[8].expand(12, 12, 3)) and alpha.abs().max() == 0
    assert all(torch.isfinite(g).all() for g in grads(RASTERIZERS[backend], args))


@pytest.mark.parametrize("backend", ["native", "reference"])
def test_stacked_opaque_gaussians_stay_finite(backend):
    """300 Gaussians at opacity 0.99 on the same spot: transmittance would underflow."""
    args = screen_scene(300, 12, 12, seed=5)
    args[0] = torch.full((300, 2), 6.0) + 0.01 * torch.randn(300, 2)
    args[2] = torch.full((300,), 0.99)
    image, alpha = RASTERIZERS[backend](*args)
    assert torch.isfinite(image).all() and (alpha <= 1).all() and alpha.max() > 0.999
    assert all(torch.isfinite(g).all() for g in grads(RASTERIZERS[backend], args))
    other = rasterize_reference(*args) if backend == "native" else rasterize_native(*args)
    assert (image - other[0]).abs().max() < 1e-5


def test_dispatch_registry():
    args = screen_scene(20, 8, 8)
    assert set(BACKENDS) == {"native", "reference"}
    assert torch.allclose(rasterize(*args, backend="reference")[0], rasterize(*args)[0], atol=1e-5)
    with pytest.raises(ValueError, match="unknown backend"):
        rasterize(*args, backend="cuda")
    with pytest.raises(ValueError, match="no CUDA back-end such as gsplat"):
        rasterize(*args, backend="gsplat")


# ---------------------------------------------------------------- projection


def camera(height=24, width=32):
    return dict(
        w2c=torch.cat([torch.eye(3), torch.zeros(3, 1)], 1).double(),
        fx=30.0,
        fy=30.0,
        cx=width / 2,
        cy=height / 2,
        height=height,
        width=width,
    )


def gaussians3d(n, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    z = 2 + 2 * torch.rand(n, generator=g, dtype=dtype)
    xy = (torch.rand(n, 2, generator=g, dtype=dtype) - 0.5) * z[:, None] * 0.6
    means = torch.cat([xy, z[:, None]], 1)
    scales = 0.05 + 0.1 * torch.rand(n, 3, generator=g, dtype=dtype)
    return means, scales, torch.randn(n, 4, generator=g, dtype=dtype)


def projection_outputs(means, scales, quats, cam, project=project_gaussians):
    p = project(means, scales, quats, **cam)
    return p.means2d, p.conics, p.depths, p.cov2d


def assert_finite_with_grads(means, scales, quats, cam, project=project_gaussians):
    leaves = [t.detach().clone().requires_grad_() for t in (means, scales, quats)]
    outs = projection_outputs(*leaves, cam, project)
    assert all(torch.isfinite(o).all() for o in outs)
    sum(o.sum() for o in outs).backward()
    assert all(torch.isfinite(t.grad).all() for t in leaves)


def rotated_camera():
    cam = camera()
    c, s = math.cos(0.3), math.sin(0.3)  # a rotated and translated camera, off-centre principal point
    cam["w2c"] = torch.tensor([[c, 0, s, 0.1], [0, 1, 0, -0.2], [-s, 0, c, 0.3]], dtype=torch.float64)
    cam["cx"], cam["fy"] = 15.3, 28.0
    return cam


@pytest.mark.parametrize("projector", ["torch", "native"])
def test_projection_gradcheck_float64(projector):
    means, scales, quats = gaussians3d(5)
    cam = rotated_camera()
    inputs = [t.clone().requires_grad_() for t in (means, scales, quats)]
    fn = PROJECTORS[projector]
    assert torch.autograd.gradcheck(lambda m, s_, q: projection_outputs(m, s_, q, cam, fn), inputs)


def test_native_projection_matches_torch():
    """Values and gradients, including Gaussians beyond the Jacobian clamp, culled ones and
    degenerate scales / quaternions."""
    means, scales, quats = gaussians3d(300, seed=4)
    means[:100, :2] *= 3  # many beyond 1.3 tan(fov/2): the clamp of x/z, y/z is active
    means[0, 2], means[1, 2], scales[2], scales[3], quats[4] = -1.0, 0.005, 1e-8, 1e3, 0.0
    cam = rotated_camera()
    results = []
    for fn in (project_gaussians, project_gaussians_native):
        leaves = [t.clone().requires_grad_() for t in (means, scales, quats)]
        p = fn(*leaves, **cam)
        g = torch.Generator().manual_seed(0)
        outs = (p.means2d, p.conics, p.depths, p.cov2d)
        sum((o * torch.randn(o.shape, generator=g, dtype=o.dtype)).sum() for o in outs).backward()
        results.append((p, [t.grad for t in leaves]))
    (p_t, g_t), (p_n, g_n) = results
    assert torch.equal(p_t.radii, p_n.radii)
    for a, b in zip((p_t.means2d, p_t.conics, p_t.depths, p_t.cov2d), (p_n.means2d, p_n.conics, p_n.depths, p_n.cov2d)):
        assert torch.allclose(a, b, rtol=1e-9, atol=1e-9)
    for a, b in zip(g_t, g_n):
        assert (a - b).norm() / a.norm() < 1e-7


def test_centre_projects_to_image_centre():
    p = project_gaussians(
        torch.tensor([[0.0, 0.0, 3.0]]),
        torch.full((1, 3), 0.1),
        torch.tensor([[1.0, 0, 0, 0]]),
        **{**camera(24, 32), "w2c": torch.cat([torch.eye(3), torch.zeros(3, 1)], 1)},
    )
    assert torch.allclose(p.means2d, torch.tensor([[16.0, 12.0]])) and p.radii[0] > 0


def test_view_space_gradient_for_densification():
    """means2d.grad (retain_grad) is the 3DGS densification signal: same for both pipelines."""
    means, scales, quats = gaussians3d(200, seed=6, dtype=torch.float32)
    cam = {**camera(), "w2c": camera()["w2c"].float()}
    g = torch.Generator().manual_seed(2)
    opacities, colors = torch.rand(200, generator=g), torch.rand(200, 3, generator=g)
    grads2d = []
    for project, backend in ((project_gaussians, "reference"), (project_gaussians_native, "native")):
        p = project(means.clone().requires_grad_(), scales, quats, **cam)
        p.means2d.retain_grad()
        image, _ = rasterize(
            p.means2d, p.conics, opacities, colors, p.depths, p.radii, 24, 32, torch.zeros(3), backend=backend
        )
        image.square().sum().backward()
        grads2d.append(p.means2d.grad)
    assert grads2d[0].abs().sum() > 0
    assert (grads2d[0] - grads2d[1]).norm() / grads2d[0].norm() < 1e-4


@pytest.mark.parametrize("projector", ["torch", "native"])
def test_culling_behind_camera_and_off_image(projector):
    means = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 0.005], [500.0, 0.0, 2.0], [0.0, 0.0, 2.0]], dtype=torch.float64)
    scales = torch.full((4, 3), 0.05, dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 4, dtype=torch.float64)
    p = PROJECTORS[projector](means, scales, quats, **camera())
    assert p.radii.tolist()[:3] == [0, 0, 0] and p.radii[3] > 0
    assert_finite_with_grads(means, scales, quats, camera(), PROJECTORS[projector])


@pytest.mark.parametrize("projector", ["torch", "native"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_degenerate_gaussians_finite(dtype, projector):
    """Zero quaternion, tiny and huge scales, a flat disc seen edge-on (a needle in the image)."""
    means = torch.tensor([[0.1, 0.0, 2.0]] * 4, dtype=dtype)
    scales = torch.tensor([[0.1] * 3, [1e-8] * 3, [1e3] * 3, [1.0, 1e-8, 1.0]], dtype=dtype)
    quats = torch.tensor([[0.0, 0, 0, 0], [1, 0, 0, 0], [0.3, 0.1, 0.2, 0.9], [1, 0, 0, 0]], dtype=dtype)
    cam = {**camera(), "w2c": camera()["w2c"].to(dtype)}
    p = PROJECTORS[projector](means, scales, quats, **cam)
    assert (p.radii > 0).all()
    assert_finite_with_grads(means, scales, quats, cam, PROJECTORS[projector])
    a, b, c = p.cov2d.double().unbind(-1)
    assert (a * c - b * b)[[0, 1, 3]].min() > 0.3**2 * 0.99  # low-pass floor: det >= 0.09
    assert torch.isfinite(p.conics).all() and (p.conics[:, 0] > 0).all() and (p.conics[:, 2] > 0).all()


def test_low_pass_keeps_determinants_positive():
    g = torch.Generator().manual_seed(9)
    n = 2000
    means = torch.cat([torch.randn(n, 2, generator=g), 1 + 4 * torch.rand(n, 1, generator=g)], 1)
    scales = 10 ** (-8 + 8 * torch.rand(n, 3, generator=g))  # 1e-8 .. 1
    cam = {**camera(), "w2c": torch.cat([torch.eye(3), torch.zeros(3, 1)], 1)}
    p = project_gaussians(means, scales, torch.randn(n, 4, generator=g), **cam)
    a, b, c = p.cov2d.double().unbind(-1)
    assert (a * c - b * b).min() > 0.3**2 * 0.99
    assert torch.isfinite(p.conics).all()


# ---------------------------------------------------------------- spherical harmonics


def real_sh_numpy(degree, dirs):
    """Independent real SH basis (N, (degree+1)²) from scipy's complex harmonics (with the
    Condon-Shortley phase): sqrt2·Im Y_l^|m| for m < 0, Y_l^0, sqrt2·Re Y_l^m for m > 0."""
    from scipy.special import sph_harm_y

    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    theta, phi = np.arccos(np.clip(d[:, 2], -1, 1)), np.arctan2(d[:, 1], d[:, 0])
    cols = []
    for ell in range(degree + 1):
        for m in range(-ell, ell + 1):
            Y = sph_harm_y(ell, abs(m), theta, phi)
            cols.append(Y.real if m == 0 else np.sqrt(2) * (Y.imag if m < 0 else Y.real))
    return np.stack(cols, 1)


def test_eval_sh_degree0():
    sh = torch.randn(10, 1, 3)
    out = eval_sh(0, sh, torch.randn(10, 3))
    assert torch.allclose(out, (SH_C0 * sh[:, 0] + 0.5).clamp_min(0))


@pytest.mark.parametrize("rest", [15, 8, 0])
def test_eval_sh_native_matches_eval_sh(rest):
    """Colour and gradients (directions, DC, rest) of the numba SH as autograd through eval_sh,
    including a zero direction (clamped norm), clamped colours and coefficients above the
    active degree (zero gradient, as autograd through the concatenation gives them)."""
    g = torch.Generator().manual_seed(1)
    n = 300
    for degree in range(4):
        if (degree + 1) ** 2 > rest + 1:
            continue
        dirs = torch.randn(n, 3, generator=g, dtype=torch.float64) * torch.rand(n, 1, generator=g, dtype=torch.float64)
        dirs[0] = 0.0
        dc, sh_rest = (
            torch.randn(n, 1, 3, generator=g, dtype=torch.float64),
            torch.randn(n, rest, 3, generator=g, dtype=torch.float64),
        )
        weight = torch.randn(n, 3, generator=g, dtype=torch.float64)
        ref = [t.clone().requires_grad_() for t in (dirs, dc, sh_rest)]
        nat = [t.clone().requires_grad_() for t in (dirs, dc, sh_rest)]
        expected = eval_sh(degree, torch.cat([ref[1], ref[2]], 1), ref[0])
        out = eval_sh_native(degree, nat[1], nat[2], nat[0])
        assert (expected == 0).any() and torch.allclose(out, expected, rtol=0, atol=1e-13)
        (expected * weight).sum().backward()
        (out * weight).sum().backward()
        for r, m in zip(ref, nat):
            want = torch.zeros_like(r) if r.grad is None else r.grad  # degree 0: no direction gradient
            assert torch.allclose(m.grad, want, rtol=1e-12, atol=1e-12)


def test_eval_sh_native_gradcheck_and_float32(one_thread):
    g = torch.Generator().manual_seed(2)
    args = (
        torch.randn(12, 3, generator=g, dtype=torch.float64),
        torch.randn(12, 1, 3, generator=g, dtype=torch.float64),
        torch.randn(12, 15, 3, generator=g, dtype=torch.float64),
    )
    args = tuple(a.requires_grad_() for a in args)
    assert torch.autograd.gradcheck(lambda d, dc, r: eval_sh_native(3, dc, r, d), args)
    d32, dc32, r32 = (a.detach().float() for a in args)
    out = eval_sh_native(3, dc32, r32, d32)
    assert out.dtype == torch.float32
    assert torch.allclose(out, eval_sh(3, torch.cat([dc32, r32], 1), d32), atol=1e-6)
    with pytest.raises(ValueError, match="degree"):
        eval_sh_native(3, dc32, r32[:, :8], d32)


def test_eval_sh_degree3_matches_independent_basis():
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(50, 3)) * rng.uniform(0.1, 10, size=(50, 1))  # unnormalised on purpose
    sh = rng.normal(size=(50, 16, 3)) * 0.2
    expected = np.maximum(np.einsum("nk,nkc->nc", real_sh_numpy(3, dirs), sh) + 0.5, 0)
    out = eval_sh(3, torch.tensor(sh), torch.tensor(dirs))
    assert np.abs(out.numpy() - expected).max() < 1e-10
    with pytest.raises(ValueError, match="degree"):
        eval_sh(2, torch.tensor(sh[:, :4]), torch.tensor(dirs))
