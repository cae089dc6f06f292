"""COLMAP poses with fixed intrinsics, and their error against the reference (LLFF) cameras.

Procedure (pycolmap 4.x, CPU):

1. one SQLite database per run; SIFT features of every image, all images sharing **one PINHOLE
   camera** whose ``fx, fy, cx, cy`` are the reference intrinsics (``CameraMode.SINGLE``, the
   parameters entered as a prior focal length);
2. exhaustive matching with geometric verification;
3. incremental mapping with focal length, principal point and extra parameters **held fixed** in
   every bundle adjustment and absolute-pose step; the largest model is kept.

Why the intrinsics are fixed: forward-facing captures move the camera sideways only, and then the
focal length is nearly unobservable from the images (on a synthetic sideways rig COLMAP estimated
469 px for a true 220 px). The LLFF ``hwf`` focal length is known, so it is entered, not estimated.

Evaluation against reference cameras (internal convention, see :mod:`spc3d.cameras`): the
registered views and the sparse points are read from the reconstruction here and scored with the
similarity alignment of :mod:`spc3d.poses.alignment`: **pose error** (rotation error in degrees and
centre error relative to the camera spread, after mapping the estimated world onto the reference
world) and **reprojection error** (the sparse points projected with the reference cameras against
the keypoints COLMAP observed them at).

A run that registers nothing (e.g. on binary SPC frames) is a finding, not an error: ``run_colmap``
returns None and ``colmap_poses`` records ``"status": "failed: <reason>"``. Measured on fern at
252 px: single 1-bit frames register 0 of 20 views; 16-frame averages register 20 of 20 (median
rotation error 0.5°, centre error 6 % of the spread).

COLMAP's glog output goes to ``colmap.log`` in the work / output folder instead of the terminal.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pycolmap

from spc3d import io, llff
from spc3d.cameras import Cameras
from spc3d.poses.alignment import Similarity, pose_error, reprojection_stats, similarity_of


@contextlib.contextmanager
def native_log_to(path: str | os.PathLike):
    """Send COLMAP's glog output (C++ stderr) to ``path`` for the duration of the block.

    ``logtostderr`` also stops glog from leaving ``*.INFO`` files in /tmp.
    """
    glog = pycolmap.logging
    old = glog.logtostderr
    glog.logtostderr = True
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "ab") as f:
        os.dup2(f.fileno(), 2)
    try:
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)
        glog.logtostderr = old


# COLMAP's defaults assume photographs of a megapixel or more: SIFT keeps extrema above a contrast of
# 0.0067, a view registers from 30 inliers, a pair is matched from 15. Images no larger than SMALL_IMAGE
# px (the built-in scenes are 128 x 96) give fewer and weaker features, so they keep extrema down to
# 0.002, register a view from 15 inliers and match a pair from 10; the first pair keeps COLMAP's 100
# inliers at 16° (it relaxes them itself when none qualifies: lowering them let a bad first pair build
# a wrong model of orchard's RGB views). Chosen on the training scenes at 128 x 96 (all 24 views): with
# COLMAP's defaults their 16-frame MLE images pose 2, 0 and 24 views of tabletop, orchard and gallery;
# with these, 24, 24 and 24 (median rotation error 0.7°, 1.3°, 1.1°), RGB views 24 of 24 either way.
# When that poses fewer than half the views, the mapping is retried from a first pair of 30 inliers at
# 4° and the model that poses more views is kept (courtyard's 16-frame MLE: 2 of 21 training views,
# then 21). A user can run this without reference poses: the choice counts posed views only.
SMALL_IMAGE = 400
SMALL_IMAGE_SETTINGS = {"peak_threshold": 0.002, "abs_pose_min_num_inliers": 15, "min_num_matches": 10}
RELAXED_INIT = {"init_min_num_inliers": 30, "init_min_tri_angle": 4.0}


def mapping_options(
    seed: int, num_threads: int, small: bool = False, relaxed: bool = False, refine_focal: bool = False
) -> pycolmap.IncrementalPipelineOptions:
    """Incremental-mapping options: intrinsics fixed, seeded, ``num_threads`` threads (``small``:
    the thresholds of :data:`SMALL_IMAGE_SETTINGS`; ``relaxed``: the first pair of :data:`RELAXED_INIT`;
    ``refine_focal``: the focal length is only a first guess, refined by bundle adjustment)."""
    opts = pycolmap.IncrementalPipelineOptions()
    if small:
        s = SMALL_IMAGE_SETTINGS
        opts.min_num_matches = s["min_num_matches"]
        opts.mapper.abs_pose_min_num_inliers = s["abs_pose_min_num_inliers"]
    if relaxed:
        opts.mapper.init_min_num_inliers = RELAXED_INIT["init_min_num_inliers"]
        opts.mapper.init_min_tri_angle = RELAXED_INIT["init_min_tri_angle"]
    opts.ba_refine_focal_length = refine_focal
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.mapper.abs_pose_refine_focal_length = refine_focal
    opts.mapper.abs_pose_refine_extra_params = False
    opts.num_threads = opts.mapper.num_threads = num_threads
    opts.random_seed = opts.mapper.random_seed = opts.triangulation.random_seed = seed
    return opts


def run_colmap(
    image_dir: str | os.PathLike,
    work_dir: str | os.PathLike,
    cameras: Cameras,
    max_features: int = 4096,
    seed: int = 0,
    num_threads: int = 1,
    refine_focal: bool = False,
) -> pycolmap.Reconstruction | None:
    """SIFT + exhaustive matching + incremental mapping with the intrinsics of ``cameras[0]``
    (fixed, or with ``refine_focal`` a first guess of the focal length that bundle adjustment refines).

    ``work_dir`` receives ``database.db``, ``models/`` and ``colmap.log``. Returns the
    reconstruction with the most registered images, or None when none could be built. Small
    images (:data:`SMALL_IMAGE`) whose mapping poses fewer than half the views are mapped again
    from a relaxed first pair (:data:`RELAXED_INIT`); the model with more posed views is kept and
    ``work_dir/mapping.txt`` says which.
    """
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    database = work_dir / "database.db"
    database.unlink(missing_ok=True)  # COLMAP appends to an existing database
    files = io.list_images(image_dir)
    check_image_size(files[0], cameras)
    fx, fy, cx, cy = (float(v) for v in cameras.intrinsics[0])
    reader = pycolmap.ImageReaderOptions(camera_model="PINHOLE", camera_params=f"{fx!r},{fy!r},{cx!r},{cy!r}")
    small = max(cameras.height, cameras.width) <= SMALL_IMAGE
    extraction = pycolmap.FeatureExtractionOptions(num_threads=num_threads)
    extraction.sift.max_num_features = max_features
    if small:
        extraction.sift.peak_threshold = SMALL_IMAGE_SETTINGS["peak_threshold"]
    matching = pycolmap.FeatureMatchingOptions(num_threads=num_threads)
    (work_dir / "models").mkdir(exist_ok=True)
    pycolmap.set_random_seed(seed)
    with native_log_to(work_dir / "colmap.log"):
        pycolmap.extract_features(
            database,
            image_dir,
            image_names=[f.name for f in files],
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
        options = mapping_options(seed, num_threads, small, refine_focal=refine_focal)
        best, how = largest(pycolmap.incremental_mapping(database, image_dir, work_dir / "models", options)), "default"
        posed = best.num_reg_images() if best else 0
        if small and posed < len(files) / 2:
            (work_dir / "models_relaxed").mkdir(exist_ok=True)
            options = mapping_options(seed, num_threads, small, relaxed=True, refine_focal=refine_focal)
            retry = largest(pycolmap.incremental_mapping(database, image_dir, work_dir / "models_relaxed", options))
            if retry is not None and retry.num_reg_images() > posed:
                best, how = retry, f"relaxed first pair {RELAXED_INIT} (the default posed {posed} of {len(files)})"
    (work_dir / "mapping.txt").write_text(how + "\n")
    return best


def largest(models: dict) -> pycolmap.Reconstruction | None:
    """The reconstruction with the most registered images (None when none registered any)."""
    models = [m for m in models.values() if m.num_reg_images() > 0]
    return max(models, key=lambda m: m.num_reg_images()) if models else None


def check_image_size(path: Path, cameras: Cameras) -> None:
    """The shared camera is only right for images of the cameras' size."""
    h, w = io.read_image(path).shape[:2]
    if (h, w) != (cameras.height, cameras.width):
        raise ValueError(
            f"{path} is {w}x{h} but the cameras are {cameras.width}x{cameras.height}; "
            "rescale the cameras (Cameras.rescaled) to the images first"
        )


def reconstruction_cameras(rec: pycolmap.Reconstruction, names: list[str], like: Cameras) -> tuple[Cameras, np.ndarray]:
    """Registered views of ``rec`` as internal cameras, sorted by view, and their indices into ``names``.

    Views are matched by file stem. Image size comes from ``like``; bounds are the 0.1 / 99.9
    percentiles of the depths of each view's observed points (as LLFF's imgs2poses), in COLMAP
    units (NaN for a view without points).
    """
    index = {name: i for i, name in enumerate(names)}
    xyz = {pid: p.xyz for pid, p in rec.points3D.items()}
    rows = []
    for image in rec.images.values():
        if not image.has_pose:
            continue
        stem = Path(image.name).stem
        if stem not in index:
            raise ValueError(f"reconstructed image {image.name!r} matches no view name (e.g. {names[:3]})")
        w2c = np.asarray(image.cam_from_world().matrix(), dtype=np.float64)
        cam = image.camera
        intr = [cam.focal_length_x, cam.focal_length_y, cam.principal_point_x, cam.principal_point_y]
        rows.append((index[stem], w2c, intr, view_bounds(image, w2c, xyz)))
    rows.sort(key=lambda r: r[0])
    if not rows:
        empty = Cameras(np.zeros((0, 3, 4)), np.zeros((0, 4)), like.height, like.width, np.zeros((0, 2)))
        return empty, np.zeros(0, dtype=int)
    idx, w2c, intr, bounds = zip(*rows)
    cams = Cameras(np.stack(w2c), np.asarray(intr, float), like.height, like.width, np.asarray(bounds, float))
    return cams, np.asarray(idx, dtype=int)


def view_bounds(image: pycolmap.Image, w2c: np.ndarray, xyz: dict) -> list[float]:
    """Near / far depth of the points a view observes (0.1 / 99.9 percentiles)."""
    pts = [xyz[p.point3D_id] for p in image.get_observation_points2D()]
    if not pts:
        return [float("nan"), float("nan")]
    z = np.asarray(pts) @ w2c[2, :3] + w2c[2, 3]
    return [float(np.percentile(z, 0.1)), float(np.percentile(z, 99.9))]


def finite_or_none(value: float) -> float | None:
    """A float for JSON, or None for NaN / inf (JSON has no NaN)."""
    return float(value) if np.isfinite(value) else None


def observations(rec: pycolmap.Reconstruction, names: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All 2-D observations of 3-D points: view indices (K,), keypoints (K, 2), point xyz (K, 3)."""
    index = {name: i for i, name in enumerate(names)}
    view, uv, xyz = [], [], []
    for image in rec.images.values():
        if not image.has_pose:
            continue
        for p in image.get_observation_points2D():
            view.append(index[Path(image.name).stem])
            uv.append(p.xy)
            xyz.append(rec.points3D[p.point3D_id].xyz)
    return np.asarray(view, int), np.asarray(uv, float).reshape(-1, 2), np.asarray(xyz, float).reshape(-1, 3)


def reprojection_error(rec: pycolmap.Reconstruction, ref: Cameras, names: list[str], sim: Similarity) -> dict:
    """Pixel error of COLMAP's points, mapped by ``sim`` into the reference world and projected
    with the reference cameras, against the keypoints COLMAP observed them at
    (:func:`spc3d.poses.alignment.reprojection_stats` of :func:`observations`).
    """
    return reprojection_stats(*observations(rec, names), ref, sim)


def reference_cameras(
    scene_dir_or_cameras: str | os.PathLike | Cameras, names: list[str] | None, image_files: list[Path]
) -> tuple[Cameras, list[str]]:
    """Reference cameras and names of the views that have an image, rescaled to the image size."""
    if isinstance(scene_dir_or_cameras, Cameras):
        ref = scene_dir_or_cameras
        names = names if names is not None else [f.stem for f in image_files]
    else:
        scene = llff.read_scene(scene_dir_or_cameras, with_images=False)
        ref, names = scene.cameras, names if names is not None else scene.names
    if len(names) != len(ref):
        raise ValueError(f"{len(names)} view names for {len(ref)} reference cameras")
    unknown = sorted({f.stem for f in image_files} - set(names))
    if unknown:
        raise ValueError(f"images {unknown[:5]} match no reference view (views: {names[:3]} ...)")
    present = {f.stem for f in image_files}
    keep = [i for i, name in enumerate(names) if name in present]
    ref, names = ref.subset(keep), [names[i] for i in keep]
    h, w = io.read_image(image_files[0]).shape[:2]
    return (ref if (h, w) == (ref.height, ref.width) else ref.rescaled(h, w)), names


def colmap_poses(
    image_dir: str | os.PathLike,
    scene_dir_or_cameras: str | os.PathLike | Cameras,
    out_dir: str | os.PathLike,
    max_features: int = 4096,
    seed: int = 0,
    num_threads: int = 1,
    names: list[str] | None = None,
    align: str = "rotations",
) -> dict:
    """Run COLMAP on ``image_dir`` and score it against the reference cameras; write ``out_dir``.

    ``image_dir`` holds one image per view (RGB, binary frames as 0/255 or K-frame averages)
    named by view stem; views without an image are left out (``total`` counts the images). The
    reference is a canonical scene folder (``llff.read_scene``) or ``Cameras`` (then ``names``
    defaults to the sorted image stems); ``align`` is the similarity fit of
    :func:`spc3d.poses.alignment.fit_similarity`. Writes atomically:

        out_dir/sparse/0/        the largest reconstruction (only when one was built)
        out_dir/pose_error.json  status, settings, registered/total, pose and reprojection errors
        out_dir/colmap.log       COLMAP's log

    Returns the JSON record.
    """
    start = time.perf_counter()
    files = io.list_images(image_dir)
    ref, names = reference_cameras(scene_dir_or_cameras, names, files)
    settings = {
        "max_features": max_features,
        "seed": seed,
        "num_threads": num_threads,
        "camera_model": "PINHOLE",
        "intrinsics_fixed": [float(v) for v in ref.intrinsics[0]],
        "matching": "exhaustive",
        "mapper": "incremental",
        "small_image_settings": SMALL_IMAGE_SETTINGS if max(ref.height, ref.width) <= SMALL_IMAGE else None,
        "alignment": align,
        "pycolmap": pycolmap.__version__,
    }
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        tmp.mkdir(parents=True, exist_ok=True)
        work = tmp / "work"
        rec = run_colmap(image_dir, work, ref, max_features, seed, num_threads)
        record = pose_errors(rec, ref, names, align)
        if rec is not None:
            (tmp / "sparse" / "0").mkdir(parents=True)
            rec.write(tmp / "sparse" / "0")
        shutil.move(work / "colmap.log", tmp / "colmap.log")
        reference = "cameras given" if isinstance(scene_dir_or_cameras, Cameras) else str(scene_dir_or_cameras)
        record = {
            **record,
            "mapping": (work / "mapping.txt").read_text().strip() if (work / "mapping.txt").exists() else None,
            "image_dir": str(image_dir),
            "reference": reference,
            "settings": settings,
            "seed": seed,
            "wall_time_s": time.perf_counter() - start,
        }
        shutil.rmtree(work)
        io.write_json(tmp / "pose_error.json", record)
    return record


def pose_errors(rec: pycolmap.Reconstruction | None, ref: Cameras, names: list[str], align: str = "rotations") -> dict:
    """Status, counts, pose error and reprojection error of a reconstruction (None: nothing registered)."""
    if rec is None:
        pose = pose_error(ref, ref.subset(np.zeros(0, int)), [], align)
        return {
            "status": "failed: no image registered",
            "registered": 0,
            "total": len(names),
            "num_points3D": 0,
            "registered_names": [],
            "pose": pose,
            "reprojection": None,
        }
    est, idx = reconstruction_cameras(rec, names, ref)
    pose = pose_error(ref, est, idx, align)
    record = {
        "status": "ok" if pose["aligned"] else f"failed: {pose['reason']}",
        "registered": int(len(idx)),
        "total": len(names),
        "num_points3D": int(rec.num_points3D()),
        "colmap_mean_reprojection_error_px": finite_or_none(rec.compute_mean_reprojection_error()),
        "registered_names": [names[i] for i in idx],
        "pose": pose,
        "reprojection": None,
    }
    if pose["aligned"]:
        record["reprojection"] = reprojection_error(rec, ref, names, similarity_of(pose))
    return record


def sparse_points(colmap_dir: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's sparse points of a ``colmap_poses`` folder, in the reference (scene) world.

    Returns xyz (M, 3) mapped by the run's similarity (x_ref = s R x + t) and rgb (M, 3) in [0, 1].
    Raises ValueError when the run has no aligned reconstruction (e.g. nothing registered).
    """
    colmap_dir = Path(colmap_dir)
    record = io.read_json(colmap_dir / "pose_error.json")
    if not (record.get("pose") or {}).get("aligned") or not (colmap_dir / "sparse" / "0").is_dir():
        raise ValueError(f"{colmap_dir}: no aligned COLMAP reconstruction to take points from ({record.get('status')})")
    rec = pycolmap.Reconstruction(str(colmap_dir / "sparse" / "0"))
    points = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in points], dtype=np.float64).reshape(-1, 3) / 255.0
    s, R, t = similarity_of(record["pose"])
    return s * xyz @ R.T + t, rgb
