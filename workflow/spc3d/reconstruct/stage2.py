"""Stage 2: fit a reconstructor to one scene's source images and render its held-out views.

``reconstruct`` is the entry point of the workflow's ``reconstruct`` rule. Output folder
(``results/recon/{scene}/{source}+{model}/``), written atomically at the end:

    renders/{view}.png   the held-out (every 8th) views rendered in sRGB
    train.json           model, source, objective, seed, resolved settings, iterations, training and
                         rendering wall time, capacity (Gaussians / voxels / parameters, peak memory;
                         3DGS: every density-control pass), where and why training stopped (the
                         plateau rule of the training objective, or the budget)

The checkpoint lives outside that folder (``checkpoint``, e.g. ``results/checkpoints/...``) so
that Snakemake's clean-up of an interrupted job's outputs keeps it: a rerun resumes from it, but
only when its fingerprint (resolved settings, seed, source, input digests, code) is the job's own
(:mod:`spc3d.checkpoints`); a checkpoint of other settings is discarded, with the reason logged.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from tqdm import tqdm

from spc3d import io, llff
from spc3d.cameras import Cameras, split_views
from spc3d.checkpoints import Checkpoint, CheckpointPolicy, digest_path, fingerprint
from spc3d.poses.colmap import sparse_points
from spc3d.poses.estimate import NoPoses, poses_summary
from spc3d.reconstruct import RECONSTRUCTORS
from spc3d.reconstruct.objectives import JointObjective
from spc3d.reconstruct.sources import load_source, with_estimated_poses
from spc3d.training import Plateau, peak_rss_mb, run, seed_everything

log = logging.getLogger(__name__)


@runtime_checkable
class RefinesCameras(Protocol):
    """The optional hook of a trainer that learns corrections of its training cameras (3DGS under
    ``pose_refine``): held-out views are rendered in its own world, after re-aligning its corrected
    training cameras with the reference ones (``train``: the reference cameras of its views)."""

    def heldout_cameras(self, train: Cameras, test: Cameras) -> Cameras: ...


@runtime_checkable
class StopsOnPlateau(Protocol):
    """A trainer that ends its training when its objective stops improving; ``plateau`` says where
    and why it stopped (:class:`spc3d.training.Plateau`)."""

    plateau: Plateau


@dataclass(frozen=True)
class ReconstructJob:
    """One stage-2 job: what to fit, from which inputs, where. Built once from the config layer
    (the ``reconstruct`` rule's adapter script, a test, a benchmark); its settings are recorded.

    ``frames``: binary frames per view the source consumes (its photon budget K, recorded; the
    bernoulli source fits that many; None for the oracle ``gt``). ``display_dir``: the metered MLE
    folder of that budget (mle and bernoulli sources, :mod:`spc3d.inputs.exposure`).
    ``poses_dir``: an ``estimate_poses`` folder (:mod:`spc3d.poses.estimate`): train on the training
    views COLMAP posed, at their estimated cameras; the row's budget K is then the larger of its
    source's and its pose source's. ``points_dir``: a ``colmap_poses`` folder whose sparse points
    initialise a model that accepts them (random initialisation when None, or when that run has no
    aligned reconstruction). ``init_setting``: the config's ``stage2.init``, recorded beside what
    was done. ``observe_plateau``: train past the plateau stop to the budget, rendering the held-out
    views at the stop too (``renders_at_stop/``: the trade table's paired measurement).
    ``checkpoint``: outside ``out_dir`` (Snakemake's clean-up of a failed job keeps it);
    ``policy``: when it is written. ``joint``: stage2.joint, the prior term's schedule of a joint source.
    """

    scene_dir: str | os.PathLike
    out_dir: str | os.PathLike
    source: str
    model: str
    settings: dict
    seed: int = 0
    frames: int | None = 1
    spc_dir: str | os.PathLike | None = None
    image_dir: str | os.PathLike | None = None
    display_dir: str | os.PathLike | None = None
    points_dir: str | os.PathLike | None = None
    poses_dir: str | os.PathLike | None = None
    init_setting: str | None = None
    observe_plateau: bool = False
    checkpoint: str | os.PathLike | None = None
    policy: CheckpointPolicy = CheckpointPolicy()
    threads: int | None = None
    joint: dict | None = None

    def inputs(self) -> dict:
        """What the job fitted, as given (input folders, settings, K, init), for the record: another
        fit of the same row (a new seed, observe mode) is ``ReconstructJob(**inputs, out_dir=...)``."""
        kept = ("scene_dir", "source", "model", "settings", "frames", "spc_dir", "image_dir", "display_dir")
        kept += ("points_dir", "poses_dir", "init_setting", "joint")
        values = {k: getattr(self, k) for k in kept}
        return {k: str(v) if isinstance(v, os.PathLike) else v for k, v in values.items()}

    def digests(self) -> dict:
        """What identifies the inputs in the checkpoint's fingerprint: digests of the input folders."""
        folders = {"scene": self.scene_dir, "spc": self.spc_dir, "images": self.image_dir}
        folders |= {"points": self.points_dir, "display": self.display_dir, "poses": self.poses_dir}
        return {k: digest_path(v) for k, v in folders.items()}


def reconstruct(job: ReconstructJob) -> dict:
    """Train ``job.model`` on ``job.source`` images of a scene, render the held-out views into
    ``job.out_dir``; return the record (``train.json``). Too few views posed by COLMAP
    (``poses_dir``): the record says so and nothing is rendered (evaluate scores no row)."""
    if job.model not in RECONSTRUCTORS:
        raise ValueError(f"unknown stage-2 model {job.model!r}; choose one of {sorted(RECONSTRUCTORS)}")
    if job.threads:
        torch.set_num_threads(job.threads)
    seed_everything(job.seed)
    src = load_source(
        job.source, job.scene_dir, job.spc_dir, job.image_dir, job.frames or 1, job.display_dir, job.joint
    )
    frames, poses = job.frames, "ground truth (the scene's cameras)"
    if job.poses_dir is not None:
        poses = poses_summary(job.poses_dir)
        spent = [k for k in (frames, poses["frames"]) if k is not None]  # the frames that posed the views count
        frames = max(spent) if spent else None
        try:
            src = with_estimated_poses(src, job.poses_dir)
        except NoPoses as e:
            log.warning("%s", e)
            unposed = {"model": job.model, "source": job.source, "seed": job.seed, "frames": frames}
            return write_unposed(job.scene_dir, job.out_dir, unposed | {"poses": poses, "status": str(e)})
    points, init = initial_points(job.points_dir)
    trainer, iterations, cfg = RECONSTRUCTORS[job.model](src.views, src.objective, job.settings, job.seed, points)
    fitted = trainer.views.names
    held = len(src.views.names) - len(fitted)
    log.info("%s+%s on %s: %d training views", job.source, job.model, Path(job.scene_dir).name, len(fitted))
    if held:
        log.info("%d more held out of the fit to judge when it stops: %s", held, ", ".join(trainer.plateau.views))
    meta = {
        "model": job.model,
        "source": job.source,
        "objective": getattr(src.objective, "name", "rgb"),
        "loss": "mse" if getattr(src.objective, "kind", None) == "mse" else "the model's own",
        "seed": job.seed,
        "settings": dataclasses.asdict(cfg),
        "frames": frames,
        "capture_factor": src.capture_factor,
        "poses": poses,
        "train_views": len(fitted),  # fitted; the stopping rule's held-out views: stopped.rule.views
        "init": {"setting": job.init_setting or ("colmap" if job.points_dir else "random"), "used": init},
        "display": display_record(job.display_dir),
    }
    if isinstance(src.objective, JointObjective):  # the prior term's schedule and penalty
        meta["joint"] = dataclasses.asdict(src.objective.cfg)
    record = train(trainer, iterations, job, meta)
    at_stop = None
    if job.observe_plateau and isinstance(trainer, StopsOnPlateau):
        at_stop = render_heldout(trainer, job.scene_dir)
        record |= {"at_stop": {"step": record["steps"], "train_s": record["train_s"]}}
        record |= continue_to_budget(trainer, iterations, record, job)
    record["job"] = job.inputs()
    render_s = write_renders(trainer, job.scene_dir, job.out_dir, record | meta, at_stop)
    return record | meta | {"render_s": render_s}


def train(trainer, iterations: int, job: ReconstructJob, meta: dict) -> dict:
    """Run the training loop (resuming the job's checkpoint when its fingerprint is this job's);
    the training part of the record."""
    ckpt = Checkpoint(job.checkpoint, fingerprint("reconstruct", meta, job.digests())) if job.checkpoint else None
    result = run(
        trainer,
        iterations,
        ckpt,
        job.policy,
        desc=f"{job.source}+{job.model}",
        postfix=lambda stats: {k: v for k, v in trainer.capacity().items() if isinstance(v, int)},
    )
    record = {
        **{k: v for k, v in result.items() if k != "final"},
        "final_loss": result["final"].get("loss"),
        "final_train_psnr": result["final"].get("psnr"),
        "capacity": {**trainer.capacity(), "peak_rss_mb": peak_rss_mb()},
    }
    if isinstance(trainer, StopsOnPlateau):
        record["stopped"] = trainer.plateau.record(iterations, result["steps"])
    if getattr(trainer, "poses", None) is not None:
        record["pose_corrections"] = trainer.poses.magnitude()
    return record


def continue_to_budget(trainer: StopsOnPlateau, iterations: int, record: dict, job: ReconstructJob) -> dict:
    """Observe mode: after the plateau stop, train on to the budget (no checkpoints: a killed
    continuation restarts from the stop's); the record's steps, time and capacity at the budget."""
    trainer.plateau.patience = 0  # the rule has spoken; from here it only keeps its curve
    t0 = time.perf_counter()
    stats = {}
    for it in tqdm(range(record["steps"] + 1, iterations + 1), desc=f"{job.source}+{job.model} (observe)"):
        stats = trainer.step(it)
    return {
        "steps": iterations,
        "stopped_early": False,
        "train_s": record["train_s"] + time.perf_counter() - t0,
        "final_loss": stats.get("loss", record["final_loss"]),
        "final_train_psnr": stats.get("psnr", record["final_train_psnr"]),
        "capacity": {**trainer.capacity(), "peak_rss_mb": peak_rss_mb()},
    }


def write_unposed(scene_dir, out_dir, record: dict) -> dict:
    """The folder of a row whose views COLMAP could not pose: ``train.json`` with the reason, no renders."""
    scene = llff.read_scene(scene_dir, with_images=False)
    test = [scene.names[i] for i in split_views(len(scene.names))[1]]
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        io.write_json(tmp / "train.json", record | {"test_views": test})
    return record


def display_record(display_dir) -> dict | None:
    """The metered display gain a row used (mle / bernoulli), for its record."""
    if display_dir is None:
        return None
    rec = io.read_json(Path(display_dir) / "display.json")
    return {k: rec[k] for k in ("K", "gain", "level", "gain_likelihood", "level_likelihood", "rule")}


def initial_points(points_dir) -> tuple[tuple[np.ndarray, np.ndarray] | None, str]:
    """(sparse points or None, how the model was initialised) for the record."""
    if points_dir is None:
        return None, "random"
    try:
        xyz, rgb = sparse_points(points_dir)
    except ValueError as e:
        log.warning("random initialisation: %s", e)
        return None, f"random ({e})"
    return (xyz, rgb), f"colmap sparse points ({len(xyz)}) from {points_dir}"


def render_heldout(trainer, scene_dir) -> dict[str, np.ndarray]:
    """The held-out views rendered in sRGB, view name -> (H, W, 3) in [0, 1]."""
    scene = llff.read_scene(scene_dir, with_images=False)
    _, test = split_views(len(scene.names))
    cams = scene.cameras.subset(test)
    if isinstance(trainer, RefinesCameras):
        index = {n: i for i, n in enumerate(scene.names)}
        cams = trainer.heldout_cameras(scene.cameras.subset([index[n] for n in trainer.views.names]), cams)
    images = (trainer.render(cams, j).detach().cpu().numpy() for j in range(len(test)))
    return {scene.names[i]: np.clip(image, 0.0, 1.0) for i, image in zip(test, images)}


def write_renders(trainer, scene_dir, out_dir, record: dict, at_stop: dict | None = None) -> float:
    """Render every held-out view into ``out_dir/renders`` (and the observed stop's into
    ``renders_at_stop``) and write ``train.json``, atomically."""
    t0 = time.perf_counter()
    renders = render_heldout(trainer, scene_dir)
    render_s = time.perf_counter() - t0
    with io.atomic_path(out_dir, is_dir=True) as tmp:
        for folder, images in (("renders", renders), ("renders_at_stop", at_stop or {})):
            for name, image in images.items():
                io.write_image(tmp / folder / f"{name}.png", image)
        io.write_json(tmp / "train.json", record | {"render_s": render_s, "test_views": list(renders)})
    return render_s
