"""Poses from the photons: COLMAP on a source's images of the training views, for stage 2.

A real SPAD user has no ground-truth poses. ``estimate_poses`` (rule ``estimate_poses``) runs
COLMAP (:mod:`spc3d.poses.colmap`: SIFT, exhaustive matching, incremental mapping with the lens's
known intrinsics) on the images of one source of a scene: a stage-1 translator's outputs, the
metered MLE of K frames (``mle-kK``), the binary frame (``none``), or the ground-truth RGB (``gt``,
an oracle). Only the **training views** go in; the held-out views are never shown to COLMAP.

Stage 2 then trains on the registered training views at their estimated cameras (unregistered
views are left out of training) and renders the held-out views. Evaluation needs the renders in
the reference frame, so the estimated world is mapped onto the reference world by the similarity
that best aligns the estimated training cameras with their reference cameras (rotation from the
orientations, scale and translation from the centres: :func:`spc3d.poses.alignment.fit_similarity`),
the standard protocol of pose-free novel-view-synthesis evaluations. That similarity is a choice of
gauge (world frame and scale), which training does not depend on; the relative geometry the model
sees is COLMAP's alone. The pose error of the training cameras after the alignment is recorded.

Output folder (``results/poses/{scene}/{source}``), written atomically:

    cameras.json     status, the source and its frame budget K, the registered training views
                     with their estimated cameras mapped into the reference world (w2c, intrinsics,
                     near/far bounds from COLMAP's points), registered / total, the pose error
    pose_error.json, sparse/0/, colmap.log   COLMAP's record and model (:func:`spc3d.poses.colmap.colmap_poses`)

A run that registers fewer than ``MIN_VIEWS`` training views is a finding, not an error: status
says so and stage 2 records the row as not reconstructed (:func:`estimated_views` raises
:class:`NoPoses`, which :func:`spc3d.reconstruct.stage2.reconstruct` turns into a record without renders).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pycolmap

from spc3d import io, llff
from spc3d.cameras import Cameras, split_views, transform_cameras
from spc3d.poses.alignment import similarity_of
from spc3d.poses.colmap import colmap_poses, reconstruction_cameras

MIN_VIEWS = 3  # a similarity (and any reconstruction worth the name) needs three posed views
POSES_FILE = "cameras.json"


class NoPoses(RuntimeError):
    """COLMAP did not pose enough training views of a source to train stage 2 on."""


def estimate_poses(
    image_dir: str | os.PathLike,
    scene_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    source: str,
    frames: int | None,
    max_features: int = 4096,
    seed: int = 0,
    num_threads: int = 1,
) -> dict:
    """COLMAP on ``image_dir``'s images of the training views of ``scene_dir``; write ``out_dir``.

    ``source`` names the images (for the record), ``frames`` their photon budget K (None for the
    ground truth). Returns the ``cameras.json`` record.
    """
    scene = llff.read_scene(scene_dir, with_images=False)
    train, _ = split_views(len(scene.names))
    names = [scene.names[i] for i in train]
    ref = scene.cameras.subset(train)
    files = {p.stem: p for p in io.list_images(image_dir)}
    missing = [n for n in names if n not in files]
    if missing:
        raise FileNotFoundError(f"{image_dir}: source {source!r} has no image for training views {missing[:5]}")
    with tempfile.TemporaryDirectory(prefix="spc3d-poses-") as tmp:
        images = Path(tmp) / "images"
        images.mkdir()
        for n in names:  # the training views only: COLMAP never sees a held-out view
            shutil.copyfile(files[n], images / files[n].name)
        with io.atomic_path(out_dir, is_dir=True) as out:
            colmap = colmap_poses(images, ref, out / "colmap", max_features, seed, num_threads, names=names)
            for item in ("sparse", "pose_error.json", "colmap.log"):
                if (out / "colmap" / item).exists():
                    shutil.move(out / "colmap" / item, out / item)
            shutil.rmtree(out / "colmap")
            record = poses_record(colmap, out, ref, names, source, frames)
            io.write_json(out / POSES_FILE, record)
    return record


def poses_record(colmap: dict, out: Path, ref: Cameras, names: list[str], source: str, frames: int | None) -> dict:
    """The ``cameras.json`` record: status, counts, pose error and the aligned estimated cameras."""
    pose = colmap["pose"]
    record = {
        "source": source,
        "frames": frames,
        "registered": colmap["registered"],
        "total": colmap["total"],
        "views_given": "training views only (the held-out views never reach COLMAP)",
        "rotation_deg": pose.get("rotation_deg"),
        "center_rel": pose.get("center_rel"),
        "alignment": "similarity onto the reference training cameras (orientations, then centres)",
        "colmap_status": colmap["status"],
        "cameras": None,
    }
    if colmap["registered"] < MIN_VIEWS or not pose.get("aligned"):
        why = pose.get("reason") or colmap["status"]
        return {**record, "status": f"failed: {colmap['registered']} of {colmap['total']} training views posed ({why})"}
    rec = pycolmap.Reconstruction(str(out / "sparse" / "0"))
    est, idx = reconstruction_cameras(rec, names, ref)
    aligned = transform_cameras(est, *similarity_of(pose))
    aligned = Cameras(aligned.w2c, aligned.intrinsics, aligned.height, aligned.width, filled_bounds(aligned.bounds))
    cameras = {
        "names": [names[i] for i in idx],
        "w2c": aligned.w2c.tolist(),
        "intrinsics": aligned.intrinsics.tolist(),
        "bounds": aligned.bounds.tolist(),
        "height": aligned.height,
        "width": aligned.width,
    }
    return {**record, "status": "ok", "cameras": cameras}


def filled_bounds(bounds: np.ndarray) -> np.ndarray:
    """Near / far per view, a view without COLMAP points taking the others' median (all NaN: 1, 100)."""
    bounds = np.array(bounds, dtype=np.float64)
    ok = np.isfinite(bounds).all(1)
    fill = np.median(bounds[ok], axis=0) if ok.any() else np.array([1.0, 100.0])
    bounds[~ok] = fill
    return bounds


def read_poses(poses_dir: str | os.PathLike) -> dict:
    """The ``cameras.json`` record of an ``estimate_poses`` folder."""
    return io.read_json(Path(poses_dir) / POSES_FILE)


def estimated_views(names: list[str], poses_dir: str | os.PathLike) -> tuple[list[int], Cameras]:
    """Indices into ``names`` (training views) of the posed views, and their estimated cameras.

    Raises :class:`NoPoses` (naming the folder and what COLMAP managed) when too few were posed.
    """
    record = read_poses(poses_dir)
    if record["status"] != "ok":
        raise NoPoses(f"{poses_dir}: no poses from {record['source']!r}: {record['status']}")
    cams = record["cameras"]
    unknown = sorted(set(cams["names"]) - set(names))
    if unknown:
        raise ValueError(f"{poses_dir}: posed views {unknown[:5]} are not training views of this scene")
    row = {n: i for i, n in enumerate(cams["names"])}  # view -> its row in cameras.json
    keep = [i for i, n in enumerate(names) if n in row]
    order = [row[names[i]] for i in keep]
    cameras = Cameras(
        np.asarray(cams["w2c"], float)[order],
        np.asarray(cams["intrinsics"], float)[order],
        int(cams["height"]),
        int(cams["width"]),
        np.asarray(cams["bounds"], float)[order],
    )
    return keep, cameras


def poses_summary(poses_dir: str | os.PathLike) -> dict:
    """What a stage-2 record says about its estimated poses (for train.json and the tables)."""
    r = read_poses(poses_dir)
    keys = ("source", "frames", "status", "registered", "total", "rotation_deg", "center_rel")
    return {"kind": "estimated (COLMAP)", **{k: r.get(k) for k in keys}}
