"""COLMAP-format scenes (spc3d.inputs.colmap_scene): a COLMAP twin of an LLFF scene reads to the same
cameras (.txt and .bin models), general intrinsics survive the canonical folder (intrinsics.npy),
distorted cameras are refused or undistorted, and scene folders are told apart (inputs.scene_layout).

The twin's model is written here from the COLMAP text-format documentation (cameras.txt,
images.txt with w-first quaternions of cam_from_world, points3D.txt with tracks), not by the code
under test; pycolmap converts it to the binary variant. Its 3-D points are designed so that LLFF's
bound rule (0.1 / 99.9 percentile of each view's observed depths) returns the LLFF folder's bounds
exactly: per view two observed points at depth near, two at depth far, and shared points that a
view observes only where their depth lies strictly inside its bounds.
Tolerances: w2c 1e-9 absolute (text holds 17 digits; rotations pass through quaternions),
intrinsics 1e-12 relative, bounds 1e-9 relative.
"""

import logging
import shutil

import numpy as np
import pycolmap
import pytest

from spc3d import llff
from spc3d.cameras import Cameras, cameras_to_llff, llff_to_cameras, project
from spc3d.inputs import build as inputs
from spc3d.inputs import colmap_scene
from spc3d.inputs.scenes import write_builtin_scene

W2C_ATOL, INTR_RTOL, BOUNDS_RTOL = 1e-9, 1e-12, 1e-9


def quaternion_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of rotation R: eigenvector of Bar-Itzhack's symmetric 4x4 matrix."""
    K = (
        np.array(
            [
                [R[0, 0] - R[1, 1] - R[2, 2], R[1, 0] + R[0, 1], R[2, 0] + R[0, 2], R[2, 1] - R[1, 2]],
                [R[1, 0] + R[0, 1], R[1, 1] - R[0, 0] - R[2, 2], R[2, 1] + R[1, 2], R[0, 2] - R[2, 0]],
                [R[2, 0] + R[0, 2], R[2, 1] + R[1, 2], R[2, 2] - R[0, 0] - R[1, 1], R[1, 0] - R[0, 1]],
                [R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], R[0, 0] + R[1, 1] + R[2, 2]],
            ]
        )
        / 3.0
    )
    x, y, z, w = np.linalg.eigh(K)[1][:, -1]
    return np.array([w, x, y, z]) * (1.0 if w >= 0 else -1.0)


def rotation_of(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def twin_points(cams: Cameras, n_shared: int = 300, seed: int = 0) -> tuple[np.ndarray, list[np.ndarray]]:
    """World points (M, 3) and, per view, the indices of the points it observes, such that each
    view's 0.1 / 99.9 percentile of observed depths is exactly its (near, far) bound."""
    rng = np.random.default_rng(seed)
    n, (H, W) = len(cams), (cams.height, cams.width)

    def unproject(view, u, v, z):  # pixels (u, v) at camera depth z of views ``view`` -> world
        fx, fy, cx, cy = cams.intrinsics[view].T
        p_cam = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=-1)
        return np.einsum("...ji,...j->...i", cams.w2c[view, :, :3], p_cam - cams.w2c[view, :, 3])  # R^T (p - t)

    own, seen = [], [[] for _ in range(n)]
    for i, (near, far) in enumerate(cams.bounds):
        for z in (near, near, far, far):
            seen[i].append(len(own))
            own.append(unproject(i, rng.uniform(0, W), rng.uniform(0, H), z))
    view = rng.integers(n, size=n_shared)
    z = rng.uniform(cams.bounds[view, 0], cams.bounds[view, 1])
    shared = unproject(view, rng.uniform(0, W, n_shared), rng.uniform(0, H, n_shared), z)
    uv, depth = project(cams, shared)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    inside &= (depth > cams.bounds[:, :1]) & (depth < cams.bounds[:, 1:])
    for i in range(n):
        seen[i] += (len(own) + np.flatnonzero(inside[i])).tolist()
    return np.concatenate([np.array(own), shared]), [np.array(s) for s in seen]


def camera_line(cams: Cameras, i: int, model: str = "PINHOLE", extra=()) -> str:
    fx, fy, cx, cy = cams.intrinsics[i]
    params = [fx, cx, cy] if model.startswith("SIMPLE") else [fx, fy, cx, cy]
    return " ".join([model, str(cams.width), str(cams.height), *(repr(float(v)) for v in [*params, *extra])])


def write_model(folder, cams: Cameras, names: list[str], points=None, seen=None, camera_lines=None, fmt="txt"):
    """A COLMAP model of ``cams`` (one camera per view, ``camera_lines[i]`` = "MODEL W H PARAMS")
    with image ids in shuffled order; ``fmt="bin"`` converts the text model with pycolmap."""
    if points is None:
        points, seen = twin_points(cams)
    folder.mkdir(parents=True, exist_ok=True)
    lines = camera_lines or [camera_line(cams, i) for i in range(len(cams))]
    (folder / "cameras.txt").write_text("".join(f"{i + 1} {line}\n" for i, line in enumerate(lines)))
    ids = 10 + np.random.default_rng(1).permutation(len(cams))
    tracks = [[] for _ in points]
    images = []
    for i in np.argsort(ids):
        uv, _ = project(cams.subset([i]), points[seen[i]])
        q, t = quaternion_wxyz(cams.w2c[i, :, :3]), cams.w2c[i, :, 3]
        images.append(" ".join(map(repr, [int(ids[i]), *map(float, q), *map(float, t), int(i) + 1])) + f" {names[i]}\n")
        images.append(" ".join(f"{float(u)!r} {float(v)!r} {p + 1}" for (u, v), p in zip(uv[0], seen[i])) + "\n")
        for k, p in enumerate(seen[i]):
            tracks[p] += [int(ids[i]), k]
    (folder / "images.txt").write_text("".join(images))
    (folder / "points3D.txt").write_text(
        "".join(
            " ".join(map(str, [p + 1, *map(repr, map(float, xyz)), 128, 128, 128, 0.5, *tracks[p]])) + "\n"
            for p, xyz in enumerate(points)
            if tracks[p]
        )
    )
    if fmt == "bin":
        rec = pycolmap.Reconstruction()
        rec.read_text(str(folder))
        for name in ("cameras", "images", "points3D"):
            (folder / f"{name}.txt").unlink()
        rec.write_binary(str(folder))
        for extra in ("rigs.bin", "frames.bin"):  # COLMAP >= 3.12 only; 3DGS-era models lack them
            (folder / extra).unlink(missing_ok=True)
    return folder


def colmap_twin(llff_dir, out, fmt="txt", camera_lines=None):
    """A COLMAP-format copy of a canonical scene folder: its images/ and a model of its cameras."""
    scene = llff.read_scene(llff_dir, with_images=False)
    shutil.copytree(llff_dir / "images", out / "images")
    write_model(
        out / "sparse" / "0", scene.cameras, [f"{n}.png" for n in scene.names], fmt=fmt, camera_lines=camera_lines
    )
    return out


@pytest.fixture(scope="module")
def builtin(tmp_path_factory):
    """A small built-in scene written canonically (the LLFF twin)."""
    out = tmp_path_factory.mktemp("builtin") / "courtyard"
    write_builtin_scene("courtyard", out, height=24, width=32, views=6, supersample=1, seed=0)
    return out


def assert_same_cameras(a: Cameras, b: Cameras):
    assert (a.height, a.width) == (b.height, b.width)
    np.testing.assert_allclose(a.w2c, b.w2c, rtol=0, atol=W2C_ATOL)
    np.testing.assert_allclose(a.intrinsics, b.intrinsics, rtol=INTR_RTOL)
    np.testing.assert_allclose(a.bounds, b.bounds, rtol=BOUNDS_RTOL)


def test_quaternion_helper_matches_its_rotation():
    rng = np.random.default_rng(4)
    for _ in range(20):
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        R *= np.linalg.det(R)  # a proper rotation
        np.testing.assert_allclose(rotation_of(quaternion_wxyz(R)), R, atol=1e-12)


@pytest.mark.parametrize("fmt", ["txt", "bin"])
def test_colmap_twin_reads_to_the_llff_cameras(builtin, tmp_path, fmt):
    twin = colmap_twin(builtin, tmp_path / "twin", fmt)
    assert colmap_scene.model_format(twin / "sparse" / "0") == fmt
    got, ref = colmap_scene.load_colmap(twin), llff.read_scene(builtin)
    assert got.names == ref.names  # image ids were shuffled: views come back sorted by name
    assert_same_cameras(got.cameras, ref.cameras)
    np.testing.assert_array_equal(got.images, ref.images)
    assert got.meta["colmap"]["format"] == fmt and got.meta["colmap"]["images_not_read"] == []
    assert not (builtin / llff.INTRINSICS_FILE).exists()  # centred fx = fy cameras: LLFF alone holds them


def test_fern_twin_at_factor_8_reads_as_fern(fern, tmp_path):
    """The real fern: full-size COLMAP cameras (hwf) read with images_8, as load_llff reads fern."""
    pb = np.load(fern / "poses_bounds.npy")
    full = llff_to_cameras(pb)  # 4032 x 3024, the size COLMAP ran at
    twin = tmp_path / "fern"
    (twin / "images").mkdir(parents=True)
    (twin / "images_8").symlink_to(fern / "images_8")
    names = [f.name for f in sorted((fern / "images_8").iterdir())]
    write_model(twin / "sparse" / "0", full, names, fmt="bin")
    for width in (None, 252):
        got, ref = colmap_scene.load_colmap(twin, 8, width), llff.load_llff(fern, 8, width)
        assert got.names == ref.names
        assert_same_cameras(got.cameras, ref.cameras)
        np.testing.assert_allclose(got.images, ref.images, atol=1e-6)


def test_bounds_are_llffs_percentiles_of_observed_depths(tmp_path):
    cams = Cameras(
        np.array([[[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]]),
        np.array([[30.0, 30, 16, 12]]),
        24,
        32,
        np.array([[1.0, 2.0]]),
    )
    rng = np.random.default_rng(2)
    n = 2500  # > 1000 observations: the percentiles interpolate between distinct depths
    z = rng.lognormal(1.0, 0.5, n)
    u, v = rng.uniform(0, 32, n), rng.uniform(0, 24, n)
    pts = np.stack([(u - 16) / 30 * z, (v - 12) / 30 * z, z], 1)
    hidden = pts[:50] * [1, 1, 40]  # points the view does not observe must not count
    write_model(tmp_path / "s" / "sparse" / "0", cams, ["a.png"], np.concatenate([pts, hidden]), [np.arange(n)])
    rec = colmap_scene.read_model(tmp_path / "s" / "sparse" / "0")
    got = colmap_scene.model_cameras(rec, ["a"], 24, 32, tmp_path)
    np.testing.assert_allclose(got.bounds[0], np.percentile(z, [0.1, 99.9]), rtol=1e-12)


def off_centre_cameras(cams: Cameras) -> tuple[list[str], np.ndarray]:
    """Per-view pinhole cameras that LLFF cannot hold (fx != fy, principal points off the centre):
    their cameras.txt lines and their (N, 4) fx, fy, cx, cy."""
    lines, intr = [], []
    for i in range(len(cams)):
        f, _, cx, cy = cams.intrinsics[i]
        if i % 3 == 0:
            k = [f + i, f * 1.1, cx + 1.5 + i, cy - 2.25]
            lines.append("PINHOLE " + " ".join(repr(float(v)) for v in k))
        elif i % 3 == 1:
            k = [f - i, f - i, cx - 3.0, cy + 0.5 * i]
            lines.append("SIMPLE_PINHOLE " + " ".join(repr(float(v)) for v in (k[0], k[2], k[3])))
        else:  # a radial model without distortion is a pinhole
            k = [f + 0.5, f + 0.5, cx + 2.0, cy + 1.0]
            lines.append("SIMPLE_RADIAL " + " ".join(repr(float(v)) for v in (k[0], k[2], k[3], 0.0)))
        lines[-1] = lines[-1].replace(" ", f" {cams.width} {cams.height} ", 1)
        intr.append(k)
    return lines, np.array(intr, dtype=float)


def test_off_centre_pinhole_survives_import_and_resize(builtin, tmp_path):
    lines, intr = off_centre_cameras(llff.read_scene(builtin, with_images=False).cameras)
    twin = colmap_twin(builtin, tmp_path / "twin", camera_lines=lines)
    got = colmap_scene.load_colmap(twin)
    np.testing.assert_allclose(got.cameras.intrinsics, intr, rtol=INTR_RTOL)  # per view, exactly as written
    inputs.import_colmap(twin, tmp_path / "canonical", width=16)  # 32 x 24 -> 16 x 12
    assert (tmp_path / "canonical" / llff.INTRINSICS_FILE).is_file()
    back = llff.read_scene(tmp_path / "canonical")
    np.testing.assert_allclose(back.cameras.intrinsics, intr / 2, rtol=INTR_RTOL)  # principal point scaled too
    np.testing.assert_allclose(back.cameras.w2c, got.cameras.w2c, atol=W2C_ATOL)
    np.testing.assert_allclose(back.cameras.bounds, got.cameras.bounds, rtol=BOUNDS_RTOL)
    cams_only = llff.read_scene(tmp_path / "canonical", with_images=False).cameras
    np.testing.assert_allclose(cams_only.intrinsics, intr / 2, rtol=INTR_RTOL)
    assert back.meta["source"] == "colmap" and back.meta["colmap"]["format"] == "txt"


def test_canonical_folder_round_trips_general_intrinsics(tmp_path):
    rng = np.random.default_rng(0)
    w2c = np.tile(np.eye(4)[:3], (2, 1, 1))
    intr = np.array([[40.0, 42.5, 13.0, 14.5], [41.0, 39.0, 17.25, 10.0]])
    cams = Cameras(w2c, intr, 24, 32, np.tile([1.0, 9.0], (2, 1)))
    scene = llff.SceneData(rng.random((2, 24, 32, 3)).astype(np.float32), cams, ["a", "b"])
    llff.write_scene(tmp_path / "s", scene, {})
    np.testing.assert_allclose(llff.read_scene(tmp_path / "s").cameras.intrinsics, intr, rtol=INTR_RTOL)
    half = llff.resize_scene(llff.read_scene(tmp_path / "s"), 16)
    np.testing.assert_allclose(half.cameras.intrinsics, intr / 2, rtol=INTR_RTOL)
    np.save(tmp_path / "s" / llff.INTRINSICS_FILE, intr[:1])
    with pytest.raises(ValueError, match=r"intrinsics\.npy: array of shape \(1, 4\).*expected 2 x 4"):
        llff.read_scene(tmp_path / "s")


def test_intrinsics_file_refers_to_the_hwf_size(builtin, tmp_path):
    """Like LLFF's focal, intrinsics.npy is for the size written in hwf and rescaled to the images."""
    folder = shutil.copytree(builtin, tmp_path / "s")
    cams = llff.read_scene(folder, with_images=False).cameras.rescaled(48, 64)  # hwf says 64 x 48
    np.save(folder / "poses_bounds.npy", cameras_to_llff(cams))
    intr = cams.intrinsics + [0.0, 3.0, 5.0, -4.0]
    np.save(folder / llff.INTRINSICS_FILE, intr)
    np.testing.assert_allclose(llff.read_scene(folder).cameras.intrinsics, intr / 2, rtol=INTR_RTOL)  # 32 x 24


@pytest.mark.parametrize(
    "line, words",
    [
        ("OPENCV 32 24 30 30 16 12 0.05 0 0 0", ["camera 1: OPENCV", "k1=0.05", "image_undistorter"]),
        ("SIMPLE_RADIAL 32 24 30 16 12 -0.1", ["SIMPLE_RADIAL", "k=-0.1", "undistort=True"]),
        ("OPENCV_FISHEYE 32 24 30 30 16 12 0 0 0 0", ["OPENCV_FISHEYE", "k1=0"]),
    ],
)
def test_distorted_cameras_are_refused_by_name(builtin, tmp_path, line, words):
    cams = llff.read_scene(builtin, with_images=False).cameras
    twin = colmap_twin(
        builtin, tmp_path / "twin", camera_lines=[line] + [camera_line(cams, i) for i in range(1, len(cams))]
    )
    with pytest.raises(ValueError, match="cameras.txt") as err:
        colmap_scene.load_colmap(twin)
    for word in words:
        assert word in str(err.value)


def test_undistort_resamples_to_pinhole_and_keeps_poses(builtin, tmp_path):
    cams = llff.read_scene(builtin, with_images=False).cameras
    lines = [camera_line(cams, i, "OPENCV", (-0.02, 0.0, 0.0, 0.0)) for i in range(len(cams))]
    got = colmap_scene.load_colmap(colmap_twin(builtin, tmp_path / "twin", "bin", lines), undistort=True)
    np.testing.assert_allclose(got.cameras.w2c, cams.w2c, atol=W2C_ATOL)
    colmap_record = got.meta["colmap"]
    assert colmap_record["undistorted_from"]["camera_models"] == {"OPENCV": len(cams)}
    assert colmap_record["camera_models"] == {"PINHOLE": len(cams)} and colmap_record["format"] == "bin"
    assert np.isfinite(got.images).all() and got.images.shape[0] == len(cams)
    with pytest.raises(ValueError, match="factor 1"):
        colmap_scene.load_colmap(tmp_path / "twin", factor=2, undistort=True)


def test_model_and_image_errors_name_the_file(builtin, tmp_path):
    twin = colmap_twin(builtin, tmp_path / "twin")
    (twin / "images" / "image003.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"image003\.png"):
        colmap_scene.load_colmap(twin)
    shutil.copy(twin / "images" / "image002.png", twin / "images" / "image003.png")
    (twin / "images" / "extra.png").write_bytes((twin / "images" / "image002.png").read_bytes())
    assert colmap_scene.load_colmap(twin).meta["colmap"]["images_not_read"] == ["extra.png"]
    model = twin / "sparse" / "0"
    (model / "points3D.txt").write_text("")
    with pytest.raises(ValueError, match=r"image00\d\.png' observes 3-D point\(s\) \[\d+.*points3D lacks"):
        colmap_scene.load_colmap(twin)
    lines = (model / "images.txt").read_text().splitlines()
    (model / "images.txt").write_text("".join(line + "\n" if k % 2 == 0 else "\n" for k, line in enumerate(lines)))
    with pytest.raises(ValueError, match=r"view 'image000' \(and 5 more\) gets bounds near=nan"):
        colmap_scene.load_colmap(twin)  # a model without points (e.g. poses known, nothing triangulated)
    (twin / "sparse" / "0" / "points3D.txt").unlink()
    with pytest.raises(FileNotFoundError, match=r"sparse/0 holds: cameras\.txt, images\.txt"):
        colmap_scene.load_colmap(twin)


def test_image_size_must_match_the_cameras(builtin, tmp_path):
    twin = colmap_twin(builtin, tmp_path / "twin")
    shutil.copytree(twin / "images", twin / "images_2")
    with pytest.raises(ValueError, match=r"image000\.png is 32x24 pixels .* must be 16x12"):
        colmap_scene.load_colmap(twin, factor=2)
    cams = llff.read_scene(builtin, with_images=False).cameras
    lines = ["PINHOLE 64 48 55 55 32 24"] + [camera_line(cams, i) for i in range(1, len(cams))]
    other = colmap_twin(builtin, tmp_path / "other", camera_lines=lines)
    with pytest.raises(ValueError, match=r"cameras differ in image size \(camera 1: PINHOLE 64x48"):
        colmap_scene.load_colmap(other)


def test_scene_layout(builtin, tmp_path, caplog):
    twin = colmap_twin(builtin, tmp_path / "twin")
    assert inputs.scene_layout(builtin) == "llff" and inputs.scene_layout(twin) == "colmap"
    shutil.copy(builtin / "poses_bounds.npy", twin / "poses_bounds.npy")
    with caplog.at_level(logging.INFO, logger="spc3d.inputs.build"):
        assert inputs.scene_layout(twin) == "llff"
    assert "read as LLFF" in caplog.text and "sparse/0" in caplog.text
    empty = tmp_path / "empty"
    (empty / "sparse" / "0").mkdir(parents=True)
    (empty / "sparse" / "0" / "cameras.bin").write_bytes(b"")
    (empty / "notes.txt").write_text("")
    with pytest.raises(
        FileNotFoundError,
        match=r"neither an LLFF .* holds: notes\.txt, sparse/; sparse/0/ holds: "
        r"cameras\.bin",
    ):
        inputs.scene_layout(empty)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        inputs.scene_layout(tmp_path / "nowhere")


def test_prepare_scene_colmap_kind(builtin, tmp_path):
    twin = colmap_twin(builtin, tmp_path / "twin", "bin")
    inputs.prepare_scene({"kind": "colmap", "path": str(twin), "width": 32}, tmp_path / "out")
    back, ref = llff.read_scene(tmp_path / "out"), llff.read_scene(builtin)
    assert_same_cameras(back.cameras, ref.cameras)
    assert back.meta["source"] == "colmap" and back.meta["settings"] == {"factor": 1, "width": 32, "undistort": False}
    with pytest.raises(ValueError, match="'builtin', 'llff' or 'colmap'"):
        inputs.prepare_scene({"kind": "nerfstudio"}, tmp_path / "x")


def test_named_spec_for_tools_and_benchmarks(tmp_path):
    """A built-in layout by name, else an LLFF folder under the root, else None."""
    from spc3d.inputs.build import named_spec

    spec = named_spec("courtyard", 128, tmp_path)
    assert spec == {
        "kind": "builtin",
        "layout": "courtyard",
        "height": 96,
        "width": 128,
        "views": 24,
        "supersample": 3,
        "seed": 0,
    }
    (tmp_path / "fern").mkdir()
    assert named_spec("fern", 168, tmp_path) == {
        "kind": "llff",
        "path": str(tmp_path / "fern"),
        "factor": 8,
        "width": 168,
    }
    assert named_spec("nowhere", 64, tmp_path) is None
