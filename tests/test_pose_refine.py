"""Camera refinement in 3DGS (spc3d.reconstruct.pose_refine): the scene motion renders exactly what
the corrected camera sees, its gradient matches finite differences, test views are re-aligned."""

import copy
import dataclasses

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from spc3d.cameras import split_views, transform_cameras
from spc3d.inputs.scenes import render_scene
from spc3d.reconstruct.gaussians import GaussianConfig, GaussianModel, random_points
from spc3d.reconstruct.objectives import RGBObjective
from spc3d.reconstruct.pose_refine import (
    PoseCorrections,
    RowAdam,
    axis_angle_matrix,
    axis_angle_quat,
    heldout_cameras,
    quat_mul,
)
from spc3d.reconstruct.splatting import SplatTrainer, pose_lr
from spc3d.reconstruct.views import Views

BLACK = torch.zeros(3)


@pytest.fixture(scope="module")
def scene():
    return render_scene("courtyard", 24, 32, views=9, supersample=1)


@pytest.fixture(scope="module")
def model(scene):
    torch.manual_seed(0)
    pts = random_points(scene.cameras, 300, seed=0)
    m = GaussianModel(pts, torch.rand(300, 3), sh_degree=1)
    m.active_degree = 1
    with torch.no_grad():
        m.opacity_logits.fill_(0.0)
        m.log_scales.add_(0.7)  # overlapping splats: a smooth image
        m.sh_rest.normal_(0, 0.3)  # view-dependent colour, so the SH direction matters
        m.quats.copy_(torch.randn(300, 4))
    return m


@pytest.mark.parametrize("w", [[0.0, 0.0, 0.0], [1e-6, -2e-6, 3e-7], [0.02, -0.01, 0.03], [0.9, 0.4, -1.3]])
def test_axis_angle_matches_scipy(w):
    ref = Rotation.from_rotvec(w)
    t = torch.tensor(w, dtype=torch.float64)
    np.testing.assert_allclose(axis_angle_matrix(t).numpy(), ref.as_matrix(), atol=1e-12)
    x, y, z, s = ref.as_quat()
    np.testing.assert_allclose(axis_angle_quat(t).numpy(), [s, x, y, z], atol=1e-12)


def test_axis_angle_gradient_at_zero_is_finite_and_right():
    w = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: axis_angle_matrix(v), (w,))
    assert torch.autograd.gradcheck(lambda v: axis_angle_quat(v), (w,))
    v = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda u: axis_angle_matrix(u), (v,))


def test_quaternion_product_composes_rotations():
    a, b = Rotation.random(random_state=1), Rotation.random(random_state=2)
    wxyz = [torch.tensor(np.roll(r.as_quat(), 1)) for r in (a, b)]
    x, y, z, s = (a * b).as_quat()
    got = quat_mul(wxyz[0], wxyz[1][None])[0].numpy()
    np.testing.assert_allclose(got * np.sign(got[0]) * np.sign(s), [s, x, y, z], atol=1e-12)


def test_scene_motion_renders_what_the_corrected_camera_sees(scene, model):
    """Rendering the scene moved by T_i with camera i == rendering the scene with camera D_i w2c_i."""
    cams = scene.cameras
    poses = PoseCorrections(cams, scale=2.0)
    with torch.no_grad():
        poses.delta.copy_(torch.randn(len(cams), 6) * 0.02)
    refined = poses.refined(cams)
    for i in (0, 4):
        with torch.no_grad():
            moved = model.render(cams, i, BLACK, motion=poses.motion(i))["image"]
            direct = model.render(refined, i, BLACK)["image"]
        assert moved.abs().max() > 0.05  # the view shows something
        torch.testing.assert_close(moved, direct, atol=2e-4, rtol=0)


def test_correction_gradient_matches_finite_differences(scene, model):
    cams = scene.cameras
    poses = PoseCorrections(cams, scale=1.0)
    target = torch.rand(cams.height, cams.width, 3, generator=torch.Generator().manual_seed(0))

    def loss():
        return ((model.render(cams, 2, BLACK, motion=poses.motion(2))["image"] - target) ** 2).mean()

    value = loss()
    value.backward()
    grad = poses.delta.grad[2].clone()
    assert torch.count_nonzero(poses.delta.grad[[0, 1, 3]]) == 0  # only view 2's correction moves
    eps, fd = 1e-3, torch.zeros(6)
    for k in range(6):
        with torch.no_grad():
            poses.delta[2, k] += eps
            up = loss().item()
            poses.delta[2, k] -= 2 * eps
            down = loss().item()
            poses.delta[2, k] += eps
        fd[k] = (up - down) / (2 * eps)
    # Float32 renders with a 3-sigma footprint cut-off: close, not exact, component by component.
    assert torch.nn.functional.cosine_similarity(fd, grad, dim=0) > 0.995, (fd, grad)
    torch.testing.assert_close(grad, fd, rtol=0.1, atol=5e-4)


def test_heldout_cameras_follow_the_refined_world(scene):
    """A model whose refined training cameras are the reference moved by a similarity renders the
    held-out views at the reference test cameras moved by that similarity."""
    train, test = split_views(len(scene.names))
    ref_train, ref_test = scene.cameras.subset(train), scene.cameras.subset(test)
    R = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    s, t = 1.7, np.array([0.3, -0.1, 2.0])
    moved_train = transform_cameras(ref_train, s, R, t)
    got = heldout_cameras(moved_train, ref_train, ref_test)
    want = transform_cameras(ref_test, s, R, t)
    np.testing.assert_allclose(got.w2c, want.w2c, atol=1e-9)
    np.testing.assert_allclose(got.centers, want.centers, atol=1e-9)


def test_trainer_refines_resumes_and_records(scene):
    train, test = split_views(len(scene.names))
    views = Views(torch.tensor(scene.images[train]), scene.cameras.subset(train), [scene.names[i] for i in train])
    cfg = GaussianConfig(iterations=6, init_points=200, densify_from=100, pose_refine=True, pose_from=3, pose_lr=1e-2)
    a = SplatTrainer(views, RGBObjective(), cfg, seed=0)
    for it in range(1, 4):
        a.step(it)
    state = copy.deepcopy(a.state())  # as a checkpoint file holds it (no tensor shared with a)
    b = SplatTrainer(views, RGBObjective(), cfg, seed=0)
    b.load(state)
    for trainer in (a, b):
        for it in range(4, 7):
            trainer.step(it)
    assert torch.count_nonzero(a.poses.delta) > 0  # corrections moved after pose_from
    torch.testing.assert_close(a.poses.delta, b.poses.delta)  # a resumed run continues the same way
    mag = a.poses.magnitude()
    assert mag["rotation_deg_max"] >= mag["rotation_deg_median"] > 0
    cams = a.heldout_cameras(scene.cameras.subset(train), scene.cameras.subset(test))
    assert len(cams) == len(test) and np.isfinite(cams.w2c).all()
    plain = SplatTrainer(views, RGBObjective(), dataclasses.replace(cfg, pose_refine=False), seed=0)
    assert plain.poses is None and plain.heldout_cameras(views.cameras, scene.cameras.subset(test)) is not None


def test_pose_lr_decays_from_pose_from_to_the_last_iteration():
    cfg = GaussianConfig(iterations=1000, pose_from=200, pose_lr=1e-3, pose_lr_final=1e-5)
    lrs = [pose_lr(it, cfg) for it in range(cfg.pose_from, cfg.iterations + 1)]
    assert (
        lrs[0] == pytest.approx(1e-3) and lrs[-1] == pytest.approx(1e-5) and pose_lr(5000, cfg) == pytest.approx(1e-5)
    )
    assert pose_lr(600, cfg) == pytest.approx(1e-4)  # half way, in log space
    assert all(a > b for a, b in zip(lrs, lrs[1:]))
    constant = GaussianConfig(pose_lr=5e-4, pose_lr_final=5e-4)
    assert {pose_lr(it, constant) for it in (0, 300, 10_000, constant.iterations)} == {5e-4}  # exactly


def test_row_adam_is_adam_on_the_visited_row_and_leaves_the_others():
    """Visiting one row is torch's Adam on that row; the rows not visited keep their values and moments."""
    torch.manual_seed(0)
    grads = torch.randn(12, 6)
    ours = torch.nn.Parameter(torch.zeros(3, 6))
    theirs = torch.nn.Parameter(torch.zeros(6))
    row_adam, adam = RowAdam(ours), torch.optim.Adam([theirs], lr=1e-3)
    for step, g in enumerate(grads):
        lr = 1e-3 * 0.9**step  # a changing lr, as the decay sets it
        for group in adam.param_groups:
            group["lr"] = lr
        ours.grad = torch.zeros(3, 6)
        ours.grad[1] = g
        theirs.grad = g.clone()
        row_adam.step(1, lr)
        adam.step()
    torch.testing.assert_close(ours.detach()[1], theirs.detach(), rtol=1e-5, atol=1e-8)
    assert not ours.detach()[[0, 2]].any() and row_adam.t.tolist() == [0, len(grads), 0]
    resumed = RowAdam(torch.nn.Parameter(ours.detach().clone()))
    resumed.load_state_dict(row_adam.state_dict())
    assert all(torch.equal(a, b) for a, b in zip(resumed.state_dict().values(), row_adam.state_dict().values()))
    with pytest.raises(ValueError, match="before per-view Adam"):
        resumed.load_state_dict({"state": {}, "param_groups": []})  # torch's Adam state, an old checkpoint


def test_views_held_out_to_judge_the_stop_follow_the_refined_world(scene):
    """Move the whole model and its refined training cameras by one similarity: the fit is the
    same, so the objective on the views held out of it (plateau_views) must not change."""
    train, _ = split_views(len(scene.names))
    views = Views(torch.tensor(scene.images[train]), scene.cameras.subset(train), [scene.names[i] for i in train])
    cfg = GaussianConfig(iterations=6, init_points=200, sh_degree=0, pose_refine=True, plateau_views=1)
    trainer = SplatTrainer(views, RGBObjective(), cfg, seed=0)
    before = trainer.check_loss()
    s, t = 1.5, torch.tensor([0.2, -0.1, 0.3])
    with torch.no_grad():
        trainer.model.means.mul_(s).add_(t)
        trainer.model.log_scales.add_(float(np.log(s)))
    trainer.poses.refined = lambda cams: transform_cameras(cams, s, np.eye(3), t.numpy())
    assert trainer.check_loss() == pytest.approx(before, rel=1e-4)
    unmapped = SplatTrainer(views, RGBObjective(), dataclasses.replace(cfg, pose_refine=False), seed=0)
    unmapped.model = trainer.model  # the moved model seen from the check cameras as given: another value
    assert unmapped.check_loss() != pytest.approx(before, rel=1e-2)
