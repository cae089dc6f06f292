"""One sweep point: the whole pipeline of one combination at one budget, in one folder.

``run_point`` calls the stage functions the workflow's rules call (the same arguments), in order:

    prepare      spc3d.inputs.build.prepare_scene         the evaluation scene (+ training scenes)
    simulate     spc3d.inputs.build.simulate_scene        SPC frames (not for gt)
    augment      spc3d.inputs.augment.augment_scene        training pairs       } stage-1
    train        spc3d.translate.train.train_translator                  } sources
    translate    spc3d.translate.apply.translate_scene                   } only
    reconstruct  spc3d.reconstruct.stage2.reconstruct           stage 2, renders of the held-out views
    evaluate     spc3d.evaluation.evaluate.evaluate            PSNR / SSIM / LPIPS (+ the source images before 3D)

Output folder::

    metrics.json   combination, setting, used knobs, seed, wall time of every stage and in total,
                   CPU time, peak memory, mean and per-view scores, stage-1 scores of the source
                   images, capacity, resolved settings of every stage
    recon/         the reconstruction's renders and train.json
    work/          scenes, SPC data, pairs, model, translations: deleted at the end unless keep_work

A killed point resumes its trainings (``checkpoints``: a folder outside the output folder, e.g.
``results/checkpoints/tradeoff/...``; deleted at the end unless keep_work). Every other stage runs
again: its outputs come out identical, but for the timings in their records, which is why the
checkpoints are fingerprinted with the point's resolved plan and input files instead of digests of
``work/`` (:class:`Resume`). ``resumed_from`` in metrics.json says where each training picked up; a
resumed point's stage times count this attempt only (its trainings' ``train_s`` count all).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import resource
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from spc3d import io
from spc3d.checkpoints import CheckpointPolicy, canonical, digest_path
from spc3d.evaluation.evaluate import evaluate
from spc3d.inputs.augment import AugmentSettings, augment_scene
from spc3d.inputs.build import prepare_scene, simulate_scene
from spc3d.names import BUDGET_SOURCES, SOURCE_IMAGES
from spc3d.physics.spc import SPCParams
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct
from spc3d.sweeps.budget import resolve_point
from spc3d.sweeps.plan import scene_inputs
from spc3d.training import peak_rss_mb

log = logging.getLogger(__name__)
STAGES = ("prepare", "simulate", "augment", "train", "translate", "reconstruct", "evaluate")
TRANSLATOR_KEYS = ("parameters", "train_s", "settings", "train", "pairs", "peak_rss_mb")  # kept from train.json


@contextlib.contextmanager
def timed(times: dict, stage: str):
    """Add the wall time of the block to ``times[stage]`` (seconds)."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        times[stage] = times.get(stage, 0.0) + time.perf_counter() - t0


def cpu_seconds() -> float:
    """User + system CPU time of this process so far."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


@dataclass(frozen=True)
class Resume:
    """Where a point's trainings checkpoint (``folder``; None: nowhere) and what identifies their
    inputs (``digests``: the point's plan and input files, see the module docstring)."""

    folder: Path | None
    digests: dict
    policy: CheckpointPolicy = CheckpointPolicy()

    def kwargs(self, name: str) -> dict:
        """Checkpoint arguments of the training ``name`` (translator, reconstruct)."""
        if self.folder is None:
            return {}
        return {"checkpoint": self.folder / f"{name}.pt", "policy": self.policy, "input_digests": self.digests}


def point_digests(plan: dict, base: dict) -> dict:
    """The point's resolved settings of every stage and the content of the LLFF files it reads."""
    files = {f: digest_path(f) for f in scene_inputs(base)}
    text = json.dumps(canonical({"plan": plan, "files": files}), sort_keys=True)
    return {"point": hashlib.sha256(text.encode()).hexdigest()}


def run_point(
    out_dir: str | os.PathLike,
    combo: str,
    setting: dict,
    base: dict,
    lpips_dir: str | os.PathLike,
    threads: int = 1,
    keep_work: bool = False,
    checkpoints: str | os.PathLike | None = None,
    policy: CheckpointPolicy = CheckpointPolicy(),
) -> dict:
    """Run ``combo`` at ``setting`` (see :mod:`.budget` for ``base``); write and return metrics.json.

    ``checkpoints``: the folder of the trainings' checkpoints (see the module docstring)."""
    t0, cpu0 = time.perf_counter(), cpu_seconds()
    torch.set_num_threads(threads)
    plan = resolve_point(base, setting, combo)
    out, times = Path(out_dir), {}
    work = out / "work"
    shutil.rmtree(work, ignore_errors=True)
    resume = Resume(Path(checkpoints) if checkpoints else None, point_digests(plan, base), policy)
    log.info("%s at %s", combo, plan["setting"])
    scene_dir, spc_dir = prepare_and_simulate(plan, work, times)
    model_record, image_dir = (
        run_stage1(plan, work, lpips_dir, threads, times, resume) if plan["translator"] else (None, None)
    )
    display_dir = meter_display(plan, work, times) if plan["source"] in BUDGET_SOURCES else None
    with timed(times, "reconstruct"):
        recon = reconstruct(
            ReconstructJob(
                scene_dir,
                out / "recon",
                plan["source"],
                plan["model"],
                plan["stage2"],
                plan["seed"],
                spc_dir=spc_dir,
                image_dir=image_dir,
                frames=plan["frames"],
                threads=threads,
                display_dir=display_dir,
                **resume.kwargs("reconstruct"),
            )
        )
    with timed(times, "evaluate"):
        scores = evaluate(out / "recon", scene_dir, work / "eval.json", lpips_dir=lpips_dir)
        stage1 = score_source(plan, work, image_dir, lpips_dir)
    record = point_record(plan, scores, stage1, times, time.perf_counter() - t0, cpu_seconds() - cpu0)
    record["translator"] = model_record and {k: model_record[k] for k in TRANSLATOR_KEYS}
    record["resumed_from"] = {
        "train": model_record and model_record["resumed_from"],
        "reconstruct": recon["resumed_from"],
    }
    record["spc_record"] = io.read_json(spc_dir / "spc.json") if spc_dir else None
    io.write_json(out / "metrics.json", record)
    if not keep_work:
        shutil.rmtree(work, ignore_errors=True)
        if resume.folder:
            shutil.rmtree(resume.folder, ignore_errors=True)
    log.info("%s: %.2f dB in %.1f s", combo, record["mean"]["psnr"], record["wall_s"])
    return record


def prepare_and_simulate(plan: dict, work: Path, times: dict) -> tuple[Path, Path | None]:
    """Scene folders (evaluation + training) and their SPC folders; returns (scene_dir, spc_dir)."""
    names = [plan["scene_name"], *plan["train_scenes"]]
    specs = dict(zip(names, [plan["scene"], *plan["train_scenes"].values()]))
    with timed(times, "prepare"):
        for name, spec in specs.items():
            prepare_scene(spec, work / "scenes" / name)
    if plan["source"] == "gt":
        return work / "scenes" / names[0], None
    s = plan["spc"]
    with timed(times, "simulate"):
        for name in names:
            simulate_scene(
                work / "scenes" / name,
                work / "spc" / name,
                SPCParams(**s["physics"]),
                s["flux_scale"],
                s["target_detection"],
                s["seed"],
            )
    return work / "scenes" / names[0], work / "spc" / names[0]


def meter_display(plan: dict, work: Path, times: dict) -> Path:
    """The metered MLE display of the evaluation scene at the point's K (level fitted on its training scenes)."""
    from spc3d.inputs.exposure import calibrate_display, write_display

    with timed(times, "simulate"):
        train = list(plan["train_scenes"])
        calibrate_display(
            [work / "scenes" / n for n in train],
            [work / "spc" / n for n in train],
            plan["frames"],
            work / "display.json",
        )
        write_display(work / "spc" / plan["scene_name"], work / "display.json", plan["frames"], work / "display")
    return work / "display"


def run_stage1(
    plan: dict, work: Path, lpips_dir, threads: int, times: dict, resume: Resume = Resume(None, {})
) -> tuple[dict, Path]:
    """Augment the training scenes, train the translator, translate the evaluation scene."""
    from spc3d.evaluation.lpips_weights import cache_file, load_npz
    from spc3d.translate.apply import translate_scene
    from spc3d.translate.train import TranslatorJob, train_translator, training_data

    aug, tr = plan["augment"], plan["translator"]
    with timed(times, "augment"):
        settings = AugmentSettings(**{k: tuple(v) if k == "zoom" else v for k, v in aug["settings"].items()})
        for name, count in aug["counts"].items():
            augment_scene(
                work / "scenes" / name, work / "spc" / name, work / "augment" / name, count, settings, plan["seed"]
            )
    with timed(times, "train"):
        job = TranslatorJob(
            tr["method"],
            training_data("fixed", [work / "augment" / n for n in aug["counts"]]),
            work / "model",
            tr["settings"],
            tr["train"],
            seed=plan["seed"],
            frames=plan["frames"],
            threads=threads,
            **resume.kwargs("translator"),
        )
        record = train_translator(job, vgg_weights=load_npz(cache_file("vgg", lpips_dir), "vgg"))
    eval_name = plan["scene_name"]
    with timed(times, "translate"):
        translate_scene(
            work / "model",
            work / "spc" / eval_name,
            work / "scenes" / eval_name,
            work / "translate",
            frames=plan["frames"],
            threads=threads,
            ensemble=tr.get("ensemble", 1),
        )
    return record, work / "translate" / "images"


def score_source(plan: dict, work: Path, image_dir: Path | None, lpips_dir) -> dict | None:
    """Scores of the source's held-out images before 3D (translators, MLE, binary frame); None for gt/bernoulli."""
    from spc3d.translate.apply import score_images

    source, name = plan["source"], plan["scene_name"]
    kind, sub = SOURCE_IMAGES.get(source, (None, None))
    if image_dir is None and kind not in ("spc", "display"):  # scored before 3D: translated, MLE and binary
        return None
    folder = image_dir or (work / "display" / sub if kind == "display" else work / kind / name / sub)
    return score_images(folder, work / "scenes" / name, work / "stage1.json", source, lpips_dir=lpips_dir)["mean"]


def point_record(plan: dict, scores: dict, stage1: dict | None, times: dict, wall_s: float, cpu_s: float) -> dict:
    """metrics.json of a point (see the module docstring)."""
    return {
        "combination": plan["combination"],
        "source": plan["source"],
        "model": plan["model"],
        "scene": scores["scene"],
        "seed": plan["seed"],
        "setting": plan["setting"],
        "used_knobs": [k for k in plan["used_knobs"] if k in plan["setting"]],
        "times_s": {stage: round(times.get(stage, 0.0), 3) for stage in STAGES},
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "peak_rss_mb": peak_rss_mb(),
        "mean": scores["mean"],
        "per_view": scores["per_view"],
        "stage1": stage1,
        "iterations": scores["iterations"],
        "capacity": scores["capacity"],
        "frames": plan["frames"],
        "resolved": {k: plan[k] for k in ("scene", "train_scenes", "spc", "augment", "translator", "stage2")},
        "conventions": scores["conventions"],
    }
