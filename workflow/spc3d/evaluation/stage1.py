"""Scoring stage-1 images before 3D (rule ``score_images``).

``score_images`` compares the held-out views of any image source (a translator's folder, the MLE
image, the raw binary frame) with the ground truth, so stage-1 and stage-2 errors can be told
apart: ``results/stage1/{scene}/{source}.json``. It reads PNGs and scores them with the numpy
metrics (:mod:`.scores`): the job never imports torch.
"""

from __future__ import annotations

import os
from pathlib import Path

from spc3d import io, llff
from spc3d.cameras import split_views
from spc3d.evaluation.evaluate import mean_scores, scene_has_colour, score_view, scored_on


def score_images(
    image_dir: str | os.PathLike,
    scene_dir: str | os.PathLike,
    out_json: str | os.PathLike,
    source: str,
    lpips_dir: str | os.PathLike | None = None,
    frames: int | None = None,
    seed: int | None = None,
    capture_factor: int = 1,
) -> dict:
    """PSNR / SSIM / LPIPS of a source's held-out views (before any 3D) against the ground truth.

    ``frames``: binary frames per view the source consumed (its photon budget K; None for ground
    truth), ``capture_factor``: S of an image made from the capture-resolution frame (S x S sensor
    pixels per working pixel; else 1), ``seed``: the run's seed; all go into the record, for the tables. A translator's
    physics prior alone (``image_dir``'s sibling ``prior/``, when there) is scored too, under
    ``prior`` with its settings from ``translate.json``.
    """
    scene_dir = Path(scene_dir)
    scene = llff.read_scene(scene_dir, with_images=False)
    test = [scene.names[i] for i in split_views(len(scene.names))[1]]
    colour = scene_has_colour(scene_dir)
    per_view = score_folder(Path(image_dir), scene_dir, test, source, lpips_dir, colour)
    record = {
        "scored_on": scored_on(colour),
        "scene": scene_dir.name,
        "source": source,
        "stage": 1,
        "frames": frames,
        "capture_factor": capture_factor,
        "seed": seed,
        "views": per_view,
        "mean": mean_scores(list(per_view.values())),
    }
    prior_dir = Path(image_dir).parent / "prior"
    if Path(image_dir).name == "images" and prior_dir.is_dir():
        prior_views = score_folder(prior_dir, scene_dir, test, f"{source} (prior)", lpips_dir, colour)
        settings = io.read_json(prior_dir.parent / "translate.json").get("prior") or {}
        record["prior"] = {**settings, "views": prior_views, "mean": mean_scores(list(prior_views.values()))}
    io.write_json(out_json, record)
    return record


def score_folder(
    image_dir: Path,
    scene_dir: Path,
    names: list[str],
    source: str,
    lpips_dir: str | os.PathLike | None,
    colour: bool = True,
) -> dict[str, dict]:
    """Scores of ``image_dir/{name}.png`` against the scene's ground truth, per view name (``colour``
    False: of their luminance, :func:`spc3d.evaluation.evaluate.score_view`)."""
    per_view = {}
    for name in names:
        pred_path = image_dir / f"{name}.png"
        if not pred_path.is_file():
            raise FileNotFoundError(f"{pred_path} is missing: source {source!r} has no image for view {name}")
        per_view[name] = score_view(
            io.read_rgb(pred_path), io.read_rgb(scene_dir / "images" / f"{name}.png"), lpips_dir, colour
        )
    return per_view
