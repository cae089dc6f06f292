"""Score a reconstruction's held-out renders against the ground truth: ``metrics.json``.

Per held-out view and averaged: PSNR (dB; identical images give inf), SSIM (Gaussian window 11,
sigma 1.5, Wang et al.: see :mod:`spc3d.evaluation.metrics`), LPIPS with the AlexNet and the VGG backbone
(named in every key). On a scene captured by a colourless sensor (mono) both images are first
reduced to their luminance (``scored_on`` says which). The record also carries what the
reconstruction wrote in ``train.json``: model, source, seed, resolved settings, iterations, training
and rendering time, capacity, where and why training stopped; a reconstruction trained in observe mode
also gets the PSNR and SSIM of its renders at the plateau stop (``at_stop``: the trade table's pair).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from spc3d import io, llff
from spc3d.evaluation import scores
from spc3d.evaluation.record import write_run
from spc3d.names import METRICS
from spc3d.physics import sensors, spc

CONVENTIONS = {
    "psnr": "data range 1, mean of per-view dB",
    "ssim": "Wang et al.: Gaussian window 11, sigma 1.5, K1 0.01, K2 0.03, valid filtering",
    "lpips": "v0.1 net-lin, AlexNet (lpips_alex) and VGG16 (lpips_vgg), inputs x*2-1",
}


LUMINANCE_NOTE = "luminance (Rec. 709 Y of linear light, as gray sRGB): a colourless sensor records no colour"


def scored_on(colour: bool) -> str:
    return "RGB" if colour else LUMINANCE_NOTE


def scene_has_colour(scene_dir: str | os.PathLike) -> bool:
    """False for a capture by a colourless sensor (scene.json ``"colour": false``: mono, all-W): its
    rows are scored on the luminance of render and reference, since no row can know colour there."""
    meta = Path(scene_dir) / "scene.json"
    return not meta.exists() or io.read_json(meta).get("colour", True) is not False


def score_view(
    pred: np.ndarray, gt: np.ndarray, lpips_dir: str | os.PathLike | None = None, colour: bool = True, keys=METRICS
) -> dict[str, float]:
    """The metrics ``keys`` (default: all) of one (H, W, 3) sRGB render against its ground truth;
    ``colour`` False (a scene of a colourless sensor): of their luminance
    (:func:`spc3d.physics.sensors.luminance_srgb`)."""
    if not colour:
        pred, gt = sensors.luminance_srgb(pred), sensors.luminance_srgb(gt)
    return {key: SCORERS[key](pred, gt, lpips_dir) for key in keys}


# One scorer per key of spc3d.names.METRICS: (render, ground truth, LPIPS weights folder) -> value.
SCORERS = {
    "psnr": lambda pred, gt, lpips_dir: scores.psnr(pred, gt),
    "ssim": lambda pred, gt, lpips_dir: scores.ssim(pred, gt),
    "lpips_alex": lambda pred, gt, lpips_dir: scores.lpips(pred, gt, net="alex", cache_dir=lpips_dir),
    "lpips_vgg": lambda pred, gt, lpips_dir: scores.lpips(pred, gt, net="vgg", cache_dir=lpips_dir),
}


def mean_scores(per_view: list[dict]) -> dict[str, float]:
    """Means over views; PSNR is averaged as the papers do (mean of per-view dB; inf stays inf)."""
    return {k: float(np.mean([v[k] for v in per_view])) for k in METRICS}


def combination_name(train: dict) -> str:
    """``source+model``, with ``@poses`` when the row trained on estimated poses."""
    poses = train.get("poses")
    at = f"@{poses['source']}" if isinstance(poses, dict) else ""
    return f"{train['source']}+{train['model']}{at}"


def evaluate(
    recon_dir: str | os.PathLike,
    scene_dir: str | os.PathLike,
    out_json: str | os.PathLike,
    lpips_dir: str | os.PathLike | None = None,
    spc_dir: str | os.PathLike | None = None,
) -> dict:
    """Write ``out_json`` for the renders in ``recon_dir/renders`` of the scene in ``scene_dir``
    (``spc_dir``: its frames, for the no-reference score of a scene without reference views)."""
    recon_dir = Path(recon_dir)
    train = io.read_json(recon_dir / "train.json")
    if train.get("status"):  # not reconstructed (e.g. COLMAP posed too few views): no scores, the reason
        record = {"scene": Path(scene_dir).name, "combination": combination_name(train), **train, "mean": None}
        write_run(out_json, record)
        return record
    if not llff.has_reference(scene_dir):
        return write_unscored(recon_dir, scene_dir, out_json, train, spc_dir)
    scene = llff.read_scene(scene_dir)
    index = {n: i for i, n in enumerate(scene.names)}
    colour = scene_has_colour(scene_dir)
    per_view = []
    for name in train["test_views"]:
        pred = io.read_rgb(recon_dir / "renders" / f"{name}.png")
        per_view.append({"view": name, **score_view(pred, scene.images[index[name]], lpips_dir, colour)})
    if (recon_dir / "renders_at_stop").is_dir():  # observe mode: the same fit where its plateau rule stopped
        images = {n: scene.images[index[n]] for n in train["test_views"]}
        train = train | {"at_stop": train["at_stop"] | at_stop_scores(recon_dir / "renders_at_stop", images, colour)}
    record = {
        **row_record(scene_dir, train),
        "mean": mean_scores(per_view),
        "per_view": per_view,
        "scored_on": scored_on(colour),
        "conventions": CONVENTIONS,
    }
    write_run(out_json, record)
    return record


def at_stop_scores(folder: Path, references: dict[str, np.ndarray], colour: bool) -> dict[str, float]:
    """Mean PSNR and SSIM of the renders in ``folder`` (view name -> reference image)."""
    keys = ("psnr", "ssim")
    views = [score_view(io.read_rgb(folder / f"{n}.png"), gt, None, colour, keys) for n, gt in references.items()]
    return {k: float(np.mean([v[k] for v in views])) for k in keys}


ROW_KEYS = (
    "source",
    "model",
    "objective",
    "loss",
    "seed",
    "iterations",
    "train_s",
    "render_s",
    "capacity",
    "settings",
    "frames",
    "capture_factor",
    "poses",
    "init",
    "display",
    "stopped",
    "at_stop",
)


def row_record(scene_dir: str | os.PathLike, train: dict) -> dict:
    """What a row consumed and how it was trained (train.json), for its metrics.json. On a capture
    whose poses COLMAP estimated from all its frames (it had none), every row says so; K stays the
    row's own budget, since every row of that scene shares those poses (as LLFF scenes share theirs)."""
    row = {k: train.get(k) for k in ROW_KEYS}
    meta_path = Path(scene_dir) / "scene.json"
    scene_poses = io.read_json(meta_path).get("poses") if meta_path.exists() else None
    if not isinstance(row["poses"], dict) and isinstance(scene_poses, dict) and scene_poses.get("frames"):
        k = scene_poses["frames"]
        row["poses"] = (
            f"COLMAP on every view's {k}-frame MLE (the capture has no poses): "
            f"{scene_poses['registered']}/{scene_poses['total']} views"
        )
    return {"scene": Path(scene_dir).name, "combination": combination_name(train), **row}


def write_unscored(
    recon_dir: Path, scene_dir: str | os.PathLike, out_json: str | os.PathLike, train: dict, spc_dir=None
) -> dict:
    """metrics.json of a row on a scene without reference views (a capture without images/): no
    image scores (mean null), the renders listed and, with the scene's SPC folder, how well they
    explain the held-out views' photons (:mod:`spc3d.evaluation.heldout`, a no-reference score)."""
    views = train["test_views"]
    record = {
        **row_record(scene_dir, train),
        "reference": False,
        "mean": None,
        "status": "no reference views: renders only, not scored against images",
        "renders": [str(recon_dir / "renders" / f"{n}.png") for n in views],
        "no_reference": None if spc_dir is None else heldout_score(recon_dir, spc_dir, views),
        "conventions": CONVENTIONS,
    }
    write_run(out_json, record)
    return record


def heldout_score(recon_dir: Path, spc_dir: str | os.PathLike, views: list[str]) -> dict:
    """:func:`spc3d.evaluation.heldout.heldout_photon_score` of a row's renders against all frames of
    the held-out views."""
    from spc3d.evaluation.heldout import heldout_photon_score
    from spc3d.physics.record import params_from_record, read_spc_record, spc_sensor

    params = params_from_record(read_spc_record(spc_dir))
    sensor = spc_sensor(spc_dir)
    fractions = [
        spc.unpack_frames(*io.load_frames(Path(spc_dir) / "frames" / f"{n}.npz")).mean(0, dtype=np.float64)
        for n in views
    ]
    renders = [io.read_rgb(recon_dir / "renders" / f"{n}.png") for n in views]
    pattern, valid = (None, None) if sensor is None else sensor
    return heldout_photon_score(renders, fractions, params.frames, params, pattern, valid)
