"""Tests of spc3d.inputs.scenes: the built-in procedural LLFF captures."""

from __future__ import annotations

import numpy as np
import pytest

from spc3d import llff
from spc3d.cameras import project
from spc3d.inputs.scenes import LAYOUTS, render_scene, write_builtin_scene
from spc3d.inputs.scenes.primitives import Box, Sphere, ground, nearest, quad
from spc3d.inputs.scenes.textures import solid, texture

H, W, N, SS = 36, 48, 4, 2


@pytest.fixture(scope="module")
def small_scenes():
    return {name: render_scene(name, H, W, views=N, supersample=SS, seed=0) for name in LAYOUTS}


def test_at_least_four_layouts_registered():
    assert len(LAYOUTS) >= 4
    assert all(callable(builder) for builder in LAYOUTS.values())


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_layout_renders_like_a_photo(small_scenes, name):
    s = small_scenes[name]
    assert s.images.shape == (N, H, W, 3) and s.images.dtype == np.float32
    assert s.depths.shape == (N, H, W) and s.depths.dtype == np.float32
    assert np.isfinite(s.images).all() and s.images.min() >= 0.0 and s.images.max() <= 1.0
    assert s.names == [f"image{i:03d}" for i in range(N)]
    assert s.meta["layout"] == name and s.meta["seed"] == 0
    for img in s.images:
        assert img.std() > 0.08  # textured, lit content, not a flat colour
        assert np.ptp(img.mean(axis=(0, 1))) > 0.01 or img.std(axis=(0, 1)).min() > 0.05  # colour
    d = s.depths
    assert np.isfinite(d).all() and d.min() > 0
    lo, hi = np.percentile(d, [1, 99])
    assert hi / lo > 2.5  # depths spread like an LLFF scene (near:far about 1:4)
    jumps = np.abs(np.diff(d, axis=2)) / d[:, :, 1:]
    assert (jumps > 0.1).mean() > 0.01  # occlusion edges: several objects at different depths


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_cameras_look_like_a_forward_facing_capture(small_scenes, name):
    cams = small_scenes[name].cameras
    fx, fy, cx, cy = cams.intrinsics.T
    np.testing.assert_allclose(fx, fy)
    np.testing.assert_allclose(cx, W / 2)
    np.testing.assert_allclose(cy, H / 2)
    hfov = np.degrees(2 * np.arctan(W / 2 / fx))
    assert np.all((hfov > 55) & (hfov < 65))
    fwd = cams.w2c[:, 2, :3]  # camera z axes in world coordinates
    assert np.all(fwd @ fwd.mean(0) / np.linalg.norm(fwd.mean(0)) > np.cos(np.radians(10)))
    down = cams.w2c[:, 1, :3]
    assert np.all(down[:, 1] < -0.95)  # upright images: world up (+y) is image up
    near, far = cams.bounds.T
    assert np.all(np.isfinite(cams.bounds)) and np.all(near > 0) and np.all(far > 2 * near)
    spread = np.ptp(cams.centers, axis=0)
    assert spread[:2].max() > 0.05 * np.median(far)


def test_same_seed_is_bit_identical_and_seed_moves_cameras():
    a = render_scene("orchard", 24, 32, views=3, supersample=2, seed=7)
    b = render_scene("orchard", 24, 32, views=3, supersample=2, seed=7)
    c = render_scene("orchard", 24, 32, views=3, supersample=2, seed=8)
    assert np.array_equal(a.images, b.images) and np.array_equal(a.depths, b.depths)
    assert np.array_equal(a.cameras.w2c, b.cameras.w2c)
    assert not np.allclose(a.cameras.w2c, c.cameras.w2c)
    assert not np.array_equal(a.images, c.images)


def _reprojection_errors(scene, a: int, b: int):
    """Colour error of view a's pixels warped into view b with depth + cameras, and a baseline."""
    cams, h, w = scene.cameras, scene.cameras.height, scene.cameras.width
    ys, xs = np.mgrid[0:h, 0:w]
    z = scene.depths[a].astype(np.float64)
    fx, fy, cx, cy = cams.intrinsics[a]
    X = np.stack([(xs + 0.5 - cx) / fx * z, (ys + 0.5 - cy) / fy * z, z], -1).reshape(-1, 3)
    R, t = cams.w2c[a, :, :3], cams.w2c[a, :, 3]
    world = (X - t) @ R  # R^T (x - t)
    uv, zb = project(cams.subset([b]), world)
    px, py = uv[0, :, 0] - 0.5, uv[0, :, 1] - 0.5  # continuous pixel index
    inside = (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
    xi, yi = np.clip(np.round(px).astype(int), 0, w - 1), np.clip(np.round(py).astype(int), 0, h - 1)
    visible = inside & (np.abs(scene.depths[b][yi, xi] - zb[0]) < 0.02 * zb[0])
    smooth = np.ones((h, w), bool)  # away from depth edges, where pixels mix two surfaces
    for d in (scene.depths[a], scene.depths[b]):
        edge = np.zeros((h, w), bool)
        edge[:, 1:] |= np.abs(np.diff(d, axis=1)) > 0.03 * d[:, 1:]
        edge[1:, :] |= np.abs(np.diff(d, axis=0)) > 0.03 * d[1:, :]
        edge = edge | np.roll(edge, 1, 0) | np.roll(edge, -1, 0) | np.roll(edge, 1, 1) | np.roll(edge, -1, 1)
        smooth &= ~edge
    keep = visible & smooth.ravel() & smooth[yi, xi]
    x0, y0 = np.clip(np.floor(px).astype(int), 0, w - 2), np.clip(np.floor(py).astype(int), 0, h - 2)
    fx_, fy_ = (px - x0)[:, None], (py - y0)[:, None]
    img = scene.images[b]
    warped = (img[y0, x0] * (1 - fx_) + img[y0, x0 + 1] * fx_) * (1 - fy_) + (
        img[y0 + 1, x0] * (1 - fx_) + img[y0 + 1, x0 + 1] * fx_
    ) * fy_
    src = scene.images[a].reshape(-1, 3)
    err = np.abs(warped - src)[keep].mean()
    baseline = np.abs(img.reshape(-1, 3) - src)[keep].mean()  # same pixels, no warp
    return err, baseline, keep.mean()


@pytest.mark.parametrize("name", ["tabletop", "courtyard"])
def test_depth_cameras_and_images_are_mutually_consistent(name):
    scene = render_scene(name, 72, 96, views=4, supersample=3, seed=1)
    err, baseline, frac = _reprojection_errors(scene, 0, 3)
    assert frac > 0.3  # most of the view is seen by both cameras
    assert err < 0.03
    assert err < 0.4 * baseline


def test_written_folder_round_trips(tmp_path):
    out = tmp_path / "scene"
    scene = write_builtin_scene("gallery", out, 32, 40, views=3, supersample=2, seed=3)
    assert np.load(out / "poses_bounds.npy").shape == (3, 17)
    back = llff.read_scene(out, with_depth=True)
    assert back.names == scene.names
    assert np.abs(back.images - scene.images).max() <= 0.5 / 255 + 1e-6
    np.testing.assert_allclose(back.cameras.w2c, scene.cameras.w2c, atol=1e-5)
    np.testing.assert_allclose(back.cameras.intrinsics, scene.cameras.intrinsics, atol=1e-5)
    np.testing.assert_allclose(back.cameras.bounds, scene.cameras.bounds, atol=1e-5)
    np.testing.assert_array_equal(back.depths, scene.depths)
    rec = back.meta
    assert rec["source"] == "builtin" and rec["layout"] == "gallery" and rec["seed"] == 3
    assert rec["settings"]["supersample"] == 2 and rec["wall_s"] >= 0


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(layout="nowhere"), "tabletop"),
        (dict(views=1), "views"),
        (dict(views=201), "views"),
        (dict(height=7), "height"),
        (dict(width=4), "width"),
        (dict(supersample=0), "supersample"),
        (dict(views=2.5), "views"),
    ],
)
def test_bad_arguments_raise_value_error_naming_them(kwargs, word):
    args = dict(layout="tabletop", height=16, width=16, views=2, supersample=1) | kwargs
    with pytest.raises(ValueError, match=word):
        render_scene(**args)


def test_write_builtin_scene_rejects_bad_arguments_before_writing(tmp_path):
    with pytest.raises(ValueError, match="layout"):
        write_builtin_scene("nowhere", tmp_path / "s", 16, 16, 2, 1, 0)
    assert not (tmp_path / "s").exists()


def test_primitives_intersect_and_occlude():
    tex = solid((0.5, 0.5, 0.5))
    origin = np.zeros((3, 1))
    dirs = np.array([[0.0, 0.0, -1.0], [0.3, 0.0, -1.0], [0.0, -0.5, -1.0]]).T  # (3, M): 3 rays
    sphere = Sphere(np.array([0.0, 0.0, -5.0]), 1.0, tex)
    np.testing.assert_allclose(sphere.intersect(origin, dirs), [4.0, np.inf, np.inf])
    box = Box(np.array([0.0, 0.0, -3.0]), np.array([0.5, 0.5, 0.5]), tex, 1.0, yaw=45)
    np.testing.assert_allclose(box.intersect(origin, dirs), [3 - 0.5 * np.sqrt(2), np.inf, np.inf])
    card = quad((0.0, 0.0, -2.0), 0.2, 0.2, tex)
    np.testing.assert_allclose(card.intersect(origin, dirs), [2.0, np.inf, np.inf])  # finite extent
    floor = ground(-1.0, tex, 1.0)
    np.testing.assert_allclose(floor.intersect(origin, dirs), [np.inf, np.inf, 2.0])
    t, idx = nearest((sphere, box, card, floor), origin, dirs)
    assert list(idx) == [2, -1, 3]  # the card hides box and sphere; ray 1 misses everything
    np.testing.assert_allclose(t, [2.0, np.inf, 2.0])
    turned = Box(np.array([0.0, 0.0, -3.0]), np.array([0.5, 0.2, 0.1]), tex, 1.0, yaw=90)
    np.testing.assert_allclose(turned.normal(np.array([[0.0], [0.0], [-3.5]]))[:, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(turned.normal(np.array([[0.05], [0.2], [-3.2]]))[:, 0], [0, 1, 0], atol=1e-12)


def test_textures_are_cached_linear_and_filtered():
    a, b = texture("brick", (0.8, 0.4, 0.2)), texture("brick", (0.8, 0.4, 0.2))
    assert a is b and a.size <= 512
    lvl0 = a.levels[0]
    assert lvl0.shape[0] == 3 and lvl0.max() <= 0.8 + 1e-6
    u = np.array([0.3, 0.3])
    v = np.array([0.6, 0.6])
    coarse = a.sample(u, v, np.array([1.0, 1e6]))[:, 1]
    np.testing.assert_allclose(coarse, a.levels[-1][:, 0, 0], rtol=1e-5)  # far away: the mean colour


# --- held-out content -------------------------------------------------------------------------


def test_content_pools_are_disjoint_and_every_layout_keeps_to_its_pool():
    from spc3d.inputs.scenes import LAYOUT_ROLES, content
    from spc3d.inputs.scenes.procedural import PATTERNS
    from spc3d.inputs.scenes.textures import EVAL_SOURCES, SAMPLE_IMAGES, TRAIN_SOURCES

    assert not TRAIN_SOURCES & EVAL_SOURCES
    assert TRAIN_SOURCES | EVAL_SOURCES == set(SAMPLE_IMAGES) | {f"proc:{p}" for p in PATTERNS}
    assert set(LAYOUT_ROLES) == set(LAYOUTS)
    for name, role in LAYOUT_ROLES.items():
        pool = TRAIN_SOURCES if role == "train" else EVAL_SOURCES
        assert content(name) and content(name) <= pool, (name, sorted(content(name) - pool))


def test_the_sample_images_shapes_are_the_stored_images_own():
    """The table the planner reads instead of the images (scikit-image stays out of the parse)."""
    from spc3d.inputs.scenes.textures import SAMPLE_IMAGES, _raw_image, source_shape

    assert {name: _raw_image(name).shape[:2] for name in SAMPLE_IMAGES} == SAMPLE_IMAGES
    with pytest.raises(ValueError, match="unknown texture 'bricks'; available: astronaut, brick"):
        source_shape("bricks")


def test_six_evaluation_layouts_hold_out_all_training_content():
    """The findings take the scene as the unit and need six evaluation scenes for any verdict; none
    shows a source of a training layout."""
    from spc3d.inputs.scenes import LAYOUT_ROLES, shared_content

    train = sorted(n for n, role in LAYOUT_ROLES.items() if role == "train")
    evaluate = sorted(n for n, role in LAYOUT_ROLES.items() if role == "eval")
    assert {"courtyard", "observatory", "harbour", "greenhouse", "workshop", "library"} <= set(evaluate)
    assert shared_content(train, evaluate) == {}


def test_the_scenes_page_lists_every_layout_with_its_role():
    """docs/scenes.md's table of layouts names each built-in layout once, with its LAYOUT_ROLES role."""
    import re

    from spc3d.inputs.scenes import LAYOUT_ROLES

    from conftest import REPO

    rows = re.findall(r"^\| `(\w+)` \| (train|eval) \|", (REPO / "docs" / "scenes.md").read_text(), re.M)
    assert sorted(rows) == sorted(LAYOUT_ROLES.items())


def test_harbour_renders_at_a_tiny_size():
    s = render_scene("harbour", 12, 16, views=2, supersample=1, seed=0)
    assert s.images.shape == (2, 12, 16, 3) and s.meta["layout"] == "harbour"
    assert np.isfinite(s.images).all() and s.images.min() >= 0.0 and s.images.max() <= 1.0
    assert np.isfinite(s.depths).all() and s.depths.min() > 0


def test_the_default_split_shares_no_texture_source():
    """The default config (and the smoke preset) train and evaluate on layouts that share nothing."""
    import yaml

    from spc3d.inputs.scenes import content, shared_content

    from conftest import REPO

    for path in (REPO / "config.yaml", REPO / "workflow" / "presets" / "smoke.yaml"):
        scenes = yaml.safe_load(path.read_text())["scenes"]
        assert shared_content(scenes["train"], scenes["eval"]) == {}, path
        seen = set().union(*(content(n) for n in scenes["train"]))
        assert not seen & set().union(*(content(n) for n in scenes["eval"]))


def test_a_split_that_shares_content_is_refused_naming_the_source():
    import yaml

    from spc3d.jobs import scene_specs
    from spc3d.names import ConfigError

    from conftest import REPO

    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg["scenes"] = {"train": ["tabletop", "orchard"], "eval": ["gallery"]}
    with pytest.raises(ConfigError, match=r"share content \('astronaut' in tabletop/orchard and gallery"):
        scene_specs(cfg, sorted(LAYOUTS))


def test_procedural_patterns_are_deterministic_and_in_range():
    from spc3d.inputs.scenes import procedural

    for name, spec in procedural.PATTERNS.items():
        img = procedural.pattern(name)
        again = np.clip(spec.make(*spec.shape), 0.0, 1.0)
        assert img.shape == (*spec.shape, 3) and np.array_equal(img, again), name
        assert 0.0 <= img.min() and img.max() <= 1.0 and img.std() > 0.02, name  # a pattern, not a flat colour
    tex = texture("proc:tiles")
    assert tex.name == "proc:tiles" and tex.shape == (256, 256) and tex.levels[0].shape == (3, 256, 256)
    with pytest.raises(ValueError, match="proc:lava"):
        texture("proc:lava")
