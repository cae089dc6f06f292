"""Tuned choices made inside a fold, from its training scenes only, by a job of the workflow.

**The joint rows' prior weight** (``stage2.joint.choose``). A joint row fits the SPAD likelihood plus
w times its model's image loss towards a stage-1 method's output; the best w follows the method's
quality on the content and the model's loss scale, so it is chosen, per fold, method and model,
among listed candidates, on the fold's *held-out training scenes*: the last
``stage1.validation.hold_out`` training scenes of the fold, which its translators validate on and
never train on. There the translation is out of sample, as on the left-out scene, so the choice
does not favour a method's in-sample output. Every candidate is fitted exactly as the row would be
(the same :class:`~spc3d.reconstruct.stage2.ReconstructJob`: settings, budget, seed, K, display
level of the fold) and scored by the row's own evaluation on each held-out training scene's
held-out views; the weight with the best mean PSNR over those scenes is the fold's (ties: the first
listed). The record keeps every candidate's scores, so the choice can be read back and audited.

Nothing of the left-out scene is an input: the rule lists the fold's model folder, display level
and held-out training scenes only (``tests/test_choices.py`` walks the job graph to check it).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from spc3d import io
from spc3d.evaluation.evaluate import evaluate
from spc3d.inputs.exposure import write_display
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct
from spc3d.specs.reconstructors import check_candidates
from spc3d.translate.apply import translate_scene


def constant(weight: float) -> dict:
    """The joint schedule of one constant prior weight (stage2.joint's keys)."""
    return {"weight": float(weight), "weight_final": float(weight)}


def choose_joint_weight(
    model_dir: str | os.PathLike,
    scenes: list[tuple[str, str]],
    calibration: str | os.PathLike,
    out_json: str | os.PathLike,
    *,
    method: str,
    model: str,
    settings: dict,
    joint: dict,
    candidates: list[float],
    seed: int,
    frames: int,
    display: tuple[int, bool],
    lpips_dir: str | os.PathLike | None = None,
) -> dict:
    """Choose the fold's prior weight of ``joint-{method}+{model}`` (module doc); write ``out_json``.

    ``scenes``: (scene folder, SPC folder) of each held-out training scene; ``calibration``: the
    fold's display level; ``display``: (K, capture) of the display the row reads; ``joint``: the
    row's stage2.joint settings, whose weight each candidate replaces."""
    candidates = check_candidates(candidates, f"stage2.joint.choose.{model}")
    if not scenes:
        raise ValueError(
            f"choosing the weight of joint-{method}+{model} needs held-out training scenes "
            "(stage1.validation.hold_out >= 1), got none"
        )
    t0, c0 = time.perf_counter(), time.process_time()
    scores: dict[str, dict[str, float]] = {str(w): {} for w in candidates}
    out_json = Path(out_json)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_json.parent, prefix=f".{out_json.stem}-") as tmp:
        for scene_dir, spc_dir in scenes:
            name, work = Path(scene_dir).name, Path(tmp) / Path(scene_dir).name
            write_display(spc_dir, calibration, display[0], work / "display", capture=display[1])
            translate_scene(model_dir, spc_dir, scene_dir, work / "translated", frames=1, threads=1)
            for w in candidates:
                recon = work / f"w{w:g}"
                job = ReconstructJob(
                    scene_dir,
                    recon,
                    f"joint-{method}",
                    model,
                    dict(settings),
                    seed,
                    frames=frames,
                    spc_dir=spc_dir,
                    image_dir=str(work / "translated" / "images"),
                    display_dir=str(work / "display"),
                    threads=1,
                    joint=joint | constant(w),
                )
                reconstruct(job)
                metrics = evaluate(recon, scene_dir, work / f"w{w:g}.json", lpips_dir=lpips_dir)
                scores[str(w)][name] = float(metrics["mean"]["psnr"])
    means = {w: sum(by_scene.values()) / len(by_scene) for w, by_scene in scores.items()}
    chosen = max(candidates, key=lambda w: means[str(w)])  # the first listed of equal means
    record = {
        "row": f"joint-{method}+{model}",
        "chosen": constant(chosen),
        "candidates": candidates,
        "psnr": scores,
        "mean_psnr": means,
        "scenes": [Path(s).name for s, _ in scenes],
        "model_dir": str(model_dir),
        "calibration": str(calibration),
        "how": "each candidate fitted as the row (same settings, budget, seed, K) on the fold's held-out "
        "training scenes, scored on their held-out views; the best mean PSNR wins (ties: the first listed)",
        "seed": seed,
        "settings": settings,
        "joint": joint,
        "wall_s": round(time.perf_counter() - t0, 2),
        "cpu_s": round(time.process_time() - c0, 2),
    }
    io.write_json(out_json, record)
    return record


def chosen_joint(joint: dict, choice_json: str | os.PathLike | None) -> dict:
    """The row's stage2.joint settings with the fold's chosen weight (``choice_json``; None: as configured)."""
    if not choice_json:
        return joint
    return joint | io.read_json(choice_json)["chosen"]
