"""Job glue for the thin rule scripts: logging and per-job benchmarks (:func:`logged`), and the
config's scenes turned into scene specs, checked against what is on disk (:func:`scene_specs`).

Top of the package: it may import any room (scene inputs, captures) and nothing imports it but
the config layer, the rules and the scripts.
"""

from __future__ import annotations

import contextlib
import logging
import os
import resource
import sys
import time
from pathlib import Path

from spc3d import io
from spc3d.names import ConfigError


@contextlib.contextmanager
def logged(log_path: str):
    """Send stdout, stderr and ``logging`` of a rule script to its log file; log the wall time and
    write the job's benchmark (:func:`write_benchmark`, beside the log under ``benchmarks/``).

    Every rule script enters here, so this is also where the job's process is set up: freed
    memory is kept for reuse (:func:`spc3d.runtime.keep_freed_memory`: without it the large
    tensors of every training step are faulted in, and zero-filled by the kernel, afresh).
    """
    from spc3d.runtime import keep_freed_memory

    keep_freed_memory()
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "w", buffering=1) as f, contextlib.redirect_stdout(f), contextlib.redirect_stderr(f):
        logging.basicConfig(
            stream=f, level=logging.INFO, force=True, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
        )
        t0, status = time.perf_counter(), "failed"
        try:
            yield
            status = "ok"
        except Exception:
            logging.exception("failed after %.1f s", time.perf_counter() - t0)
            raise
        finally:
            write_benchmark(benchmark_path(log_path), time.perf_counter() - t0, status)
        logging.info("done in %.1f s", time.perf_counter() - t0)


BENCHMARK_COLUMNS = ("s", "user_s", "sys_s", "max_rss_mb", "status")


def benchmark_path(log_path: str | os.PathLike) -> Path | None:
    """``logs/{rule}/x.log`` -> ``benchmarks/{rule}/x.tsv`` (None for a log outside ``logs/``)."""
    parts = Path(log_path).parts
    if len(parts) < 2 or parts[0] != "logs":
        return None
    return Path("benchmarks", *parts[1:]).with_suffix(".tsv")


def write_benchmark(path: Path | None, wall_s: float, status: str) -> None:
    """One TSV row of what the job's process (and any child it waited for) used: wall, user and
    system CPU seconds, peak resident memory (MB), whether it succeeded.

    The job measures itself, exactly and for free (``getrusage``). Snakemake's ``benchmark:``
    directive instead samples the job from outside through ``/proc/{pid}/smaps`` (twice a second
    for the first 15 s, then every 30 s): each sample of a process with torch loaded costs kernel
    time (a large share of the default run's system time), and it can miss a short peak.
    """
    if path is None:
        return
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    peak_kb = max(own.ru_maxrss, children.ru_maxrss)  # kilobytes on Linux
    row = (
        f"{wall_s:.2f}",
        f"{own.ru_utime + children.ru_utime:.2f}",
        f"{own.ru_stime + children.ru_stime:.2f}",
        f"{peak_kb / 1024:.1f}",
        status,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("\t".join(BENCHMARK_COLUMNS) + "\n" + "\t".join(row) + "\n")
    os.replace(tmp, path)


def translator_checkpoint(model_dir: str | os.PathLike) -> Path:
    """Where the training of ``results/{overlay}models{sensor}{fold}/{method}{rep}`` checkpoints:
    ``results/{overlay}checkpoints/models{sensor}{fold}/{method}{rep}/checkpoint.pt``. Derived from
    the output, not a param: where a training checkpoints never changes its weights, so it stays out
    of the between-workflow cache's key."""
    model_dir = Path(model_dir)
    return model_dir.parent.parent / "checkpoints" / model_dir.parent.name / model_dir.name / "checkpoint.pt"


def training_scene_names(config: dict) -> list[str]:
    """``scenes.train``, and with ``scenes.train_llff`` (the default) every ``llff_scenes`` entry not
    in ``scenes.eval`` after it: configured real photographs are training content. An evaluation
    scene never joins (with ``leave_one_out`` it trains the other folds only if listed)."""
    scenes = config["scenes"]
    train = list(scenes["train"])
    if scenes.get("train_llff", True):
        train += [n for n in config.get("llff_scenes", {}) if n not in train and n not in scenes["eval"]]
    return train


def check_scene_names(builtin_layouts, llff_scenes: dict, captures: dict) -> None:
    """One name, one scene: a name given twice across the built-in layouts, ``llff_scenes`` and
    ``captures`` is refused, naming both (else one would silently replace the other)."""
    sources = (
        ("a built-in scene", set(builtin_layouts)),
        ("in llff_scenes", set(llff_scenes)),
        ("in captures", set(captures)),
    )
    for i, (first, a) in enumerate(sources):
        for second, b in sources[i + 1 :]:
            clash = sorted(a & b)
            if clash:
                key = second.removeprefix("in ")
                raise ConfigError(
                    f"{key}: {', '.join(map(repr, clash))} is also {first}; a scene name must be unique across "
                    f"the built-in scenes, llff_scenes and captures (rename it, e.g. {clash[0]}_{key[:4]})"
                )


def scene_specs(config: dict, builtin_layouts: list[str], base_dir: str | Path = ".") -> dict[str, dict]:
    """Scene name -> spec for :func:`spc3d.inputs.build.prepare_scene`, checking every name in the config."""
    res, llff_scenes, captures = config["resolution"], config["llff_scenes"], config.get("captures", {})
    check_scene_names(builtin_layouts, llff_scenes, captures)
    specs = {}
    for role in ("train", "eval"):
        for name in config["scenes"][role]:
            if name in captures:
                specs[name] = capture_spec(name, captures[name], role, config, base_dir)
            elif name in llff_scenes:
                specs[name] = real_scene_spec(name, Path(base_dir) / llff_scenes[name], res)
            elif name in builtin_layouts:
                specs[name] = {
                    "kind": "builtin",
                    "layout": name,
                    "height": res["height"],
                    "width": res["width"],
                    "views": config["builtin"]["views"],
                    "supersample": config["builtin"]["supersample"],
                    "seed": config["seed"],
                }
            else:
                raise ConfigError(
                    f"scenes.{role}: unknown scene {name!r}; use a built-in layout "
                    f"({', '.join(builtin_layouts)}), add it to llff_scenes as name: folder, "
                    "or to captures as name: capture folder"
                )
    train, evaluate = config["scenes"]["train"], config["scenes"]["eval"]
    overlap = set(train) & set(evaluate)
    if overlap and not config["scenes"].get("leave_one_out"):
        raise ConfigError(
            f"scenes.train and scenes.eval share {sorted(overlap)}: evaluation scenes must be held out "
            "(or set scenes.leave_one_out: true to evaluate each on translators trained without it)"
        )
    leave_one_out = bool(config["scenes"].get("leave_one_out"))
    folds = training_folds(train, evaluate, leave_one_out)
    for scene in evaluate:
        check_disjoint_content(folds[scene_fold(scene, train, leave_one_out)], [scene])
    return specs


FOLD_PREFIX = "-without-"


def scene_fold(scene: str, train: list[str], leave_one_out: bool) -> str:
    """The tag of the training scenes an evaluation scene is evaluated with: "" for all of
    ``train``, ``-without-{scene}`` for ``train`` less the scene itself (leave-one-scene-out)."""
    return f"{FOLD_PREFIX}{scene}" if leave_one_out and scene in train else ""


def training_folds(train: list[str], evaluate: list[str], leave_one_out: bool) -> dict[str, list[str]]:
    """Fold tag -> its training scenes, for the folds the evaluation scenes use (:func:`scene_fold`);
    "" (all of ``train``) is always there, for the sweeps and the data summary. A fold left with no
    training scene is refused (a translator needs data).

    A leave-one-out fold lists the scenes after its left-out one in ``train``'s order, then those
    before it, so that its last scene — the one ``stage1.validation.hold_out: 1`` keeps out of the
    training, to stop the translators and choose the joint weights on (spc3d.choices) — is the scene
    just before the left-out one, cyclically: each scene is held out by exactly one fold, instead of
    the last scene of ``train`` by all but one."""
    folds = {"": list(train)}
    for scene in evaluate:
        fold = scene_fold(scene, train, leave_one_out)
        if not fold:
            continue
        at = train.index(scene)
        folds[fold] = [s for s in train[at + 1 :] + train[:at] if s != scene]
        if not folds[fold]:
            raise ConfigError(
                f"scenes.leave_one_out: evaluating {scene!r} leaves no training scene (scenes.train = {train}); "
                "list at least two scenes in scenes.train"
            )
    return folds


def real_scene_spec(name: str, path: Path, res: dict) -> dict:
    """The spec of a real RGB scene: an LLFF folder (checked now, not in a job) or a COLMAP-format one."""
    from spc3d.inputs.build import scene_layout

    if not Path(path).is_dir():
        raise ConfigError(
            f"llff_scenes.{name}: the folder {path} does not exist (a relative path is taken from the "
            "repository root). Point it at an LLFF folder (images_<factor>/ and poses_bounds.npy) or a "
            "COLMAP-format one; the real-scene presets read the six real scenes of ../shared/data/llff "
            "beside the repository, and workflow/presets/findings.yaml needs no data"
        )
    try:
        layout = scene_layout(path)
    except FileNotFoundError as e:
        raise ConfigError(f"llff_scenes.{name}: {path} is not an LLFF folder nor a COLMAP-format one: {e}") from None
    if layout == "colmap":
        return {"kind": "colmap", "path": str(path), "factor": 1, "width": res["width"], "undistort": True}
    files = llff_input_files(path, res["llff_factor"], f"llff_scenes.{name}")
    image_width = io.image_shape(files[1])[1]
    if res["width"] > image_width:  # possible (tiny test scenes), but no longer the photographs' detail
        print(
            f"spc3d warning: resolution.width = {res['width']} is wider than the images of llff_scenes.{name} at "
            f"llff_factor {res['llff_factor']} ({image_width} px): they are upsampled; use a width <= "
            f"{image_width} or a smaller resolution.llff_factor",
            file=sys.stderr,
        )
    from spc3d.llff import rig_warnings

    # From the poses alone (cheap); the images' motion is judged once, by the prepare_scene job.
    for warning in rig_warnings(io.load_npy(files[0])):  # possible, unlikely right
        print(f"spc3d warning: llff_scenes.{name}: {warning}", file=sys.stderr)
    return {"kind": "llff", "path": str(path), "factor": res["llff_factor"], "width": res["width"]}


def capture_spec(name: str, entry: str | dict, role: str, config: dict, base_dir: str | Path = ".") -> dict:
    """The spec of a captured SPAD scene (:mod:`spc3d.captures.folders`), its sensor.json checked now.
    ``entry``: the folder, or {"path": folder, and sensor settings that replace sensor.json's}."""
    from spc3d.captures.importing import capture_sensor

    where = f"captures.{name}"
    entry = {"path": entry} if isinstance(entry, str) else dict(entry)
    path, overrides = Path(base_dir) / entry.pop("path"), entry
    if role != "eval":
        raise ConfigError(
            f"scenes.train lists capture {name!r}: translators train on simulated scenes (RGB truth and "
            "photons drawn from it); list captures in scenes.eval"
        )
    if not (path / "sensor.json").is_file():
        raise ConfigError(f"{where}: {path} is not a capture folder (no sensor.json; see spc3d.captures.folders)")
    try:
        tag, sensor = capture_sensor(path, overrides)
        frames, warnings = capture_plausibility(path, overrides)
    except (ValueError, FileNotFoundError) as e:
        raise ConfigError(f"{where}: {e}") from None
    for warning in warnings:  # possible, unlikely right; the import job records them for the captions
        print(f"spc3d warning: {where}: {warning}", file=sys.stderr)
    return {
        "frames": frames,
        "kind": "capture",
        "path": str(path),
        "overrides": overrides,
        "sensor_tag": tag,
        "sensor": sensor,
        "reference": (path / "images").is_dir(),
        "max_features": config["colmap"]["max_features"],
        "seed": config["seed"],
    }


def capture_plausibility(path: Path, overrides: dict) -> tuple[int, list[str]]:
    """(frames per view, warnings) of a capture folder whose sensor.json and listings passed
    :func:`spc3d.captures.importing.capture_sensor`: what reads fine but cannot be right is refused
    (:func:`spc3d.captures.plausibility.check_capture`)."""
    from spc3d.captures.folders import capture_views, read_sensor
    from spc3d.captures.plausibility import check_capture

    sensor = read_sensor(path, overrides)
    return sensor.params.frames, check_capture(path, sensor, capture_views(path, sensor.format))


def folder_files(path: str | Path) -> list[str]:
    """Every file of a capture or COLMAP-format scene folder (sensor.json, frames, reference views,
    poses, sparse model): rule inputs, so an edit reruns the scene and what follows."""
    path = Path(path)
    files = [p for p in sorted(path.rglob("*")) if p.is_file() and not any(s.startswith(".") for s in p.parts)]
    return [str(p) for p in files]


def check_disjoint_content(train: list[str], evaluate: list[str]) -> None:
    """No texture, object or background of a built-in evaluation scene may appear in a training one."""
    from spc3d.inputs.scenes import LAYOUT_ROLES, shared_content

    shared = shared_content(train, evaluate)
    if shared:
        seen = "; ".join(f"{src!r} in {'/'.join(a)} and {'/'.join(b)}" for src, (a, b) in list(shared.items())[:4])
        pools = {role: [n for n, r in LAYOUT_ROLES.items() if r == role] for role in ("train", "eval")}
        raise ConfigError(
            f"scenes.train and scenes.eval share content ({seen}{' ...' if len(shared) > 4 else ''}): "
            f"evaluation scenes must be unseen in training; train on {pools['train']} and evaluate "
            f"on {pools['eval']}"
        )


def llff_input_files(path: str | Path, factor: int, where: str = "llff_scenes") -> list[str]:
    """The files a real LLFF scene is read from (poses_bounds.npy and every image of the folder at
    ``factor``), after checking the folder (:func:`spc3d.llff.llff_contents`): declared as rule
    inputs, so editing one image reruns that scene and what follows."""
    from spc3d.llff import check_views, llff_contents

    try:
        images, poses_bounds = llff_contents(path, factor)
        check_views(poses_bounds, images, Path(path) / "poses_bounds.npy")
    except FileNotFoundError as e:
        raise ConfigError(f"{where}: {e} (resolution.llff_factor={factor})") from None
    except ValueError as e:
        raise ConfigError(f"{where}: {e}") from None
    return [str(Path(path) / "poses_bounds.npy"), *map(str, images)]
