"""The one layer between the workflow config and the library: the vocabulary of sources and
models, the config turned into each stage's arguments (scene specs, SPC settings, translator and
validation settings, combinations and their photon budgets), config checks, and logging for the
thin rule scripts.

Both the rules' ``get_*`` helpers (``workflow/rules/common.smk``) and the sweeps
(:mod:`spc3d.sweeps`) build their arguments here. Torch-free, so parsing the Snakefile stays fast;
nothing here knows about Snakemake objects.
"""

from __future__ import annotations

import contextlib
import logging
import os
import resource
import time
from pathlib import Path


class ConfigError(ValueError):
    """A config value that passed the JSON schema but is still wrong (e.g. an unknown scene)."""


@contextlib.contextmanager
def logged(log_path: str):
    """Send stdout, stderr and ``logging`` of a rule script to its log file; log the wall time and
    write the job's benchmark (:func:`write_benchmark`, beside the log under ``benchmarks/``).

    Every rule script enters here, so this is also where the job's process is set up: freed
    memory is kept for reuse (:func:`spc3d.runtime.keep_freed_memory`: without it the large
    tensors of every training step are faulted in, and zero-filled by the kernel, afresh).
    """
    from .runtime import keep_freed_memory

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
    for the first 15 s, then every 30 s): about 10 ms of kernel time a sample for a process with
    torch loaded, a third of the system time of the default run, and it can miss a short peak.
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


def scene_specs(config: dict, builtin_layouts: list[str], base_dir: str | Path = ".") -> dict[str, dict]:
    """Scene name -> spec for :func:`spc3d.inputs.prepare_scene`, checking every name in the config."""
    res, llff_scenes, captures = config["resolution"], config["llff_scenes"], config.get("captures", {})
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
    overlap = set(config["scenes"]["train"]) & set(config["scenes"]["eval"])
    if overlap:
        raise ConfigError(f"scenes.train and scenes.eval share {sorted(overlap)}: evaluation scenes must be held out")
    check_disjoint_content(config["scenes"]["train"], config["scenes"]["eval"])
    return specs


def real_scene_spec(name: str, path: Path, res: dict) -> dict:
    """The spec of a real RGB scene: an LLFF folder (checked now, not in a job) or a COLMAP-format one."""
    from .inputs import scene_layout

    try:
        layout = scene_layout(path)
    except FileNotFoundError as e:
        raise ConfigError(f"llff_scenes.{name}: {path} is not an LLFF folder nor a COLMAP-format one: {e}") from None
    if layout == "colmap":
        return {"kind": "colmap", "path": str(path), "factor": 1, "width": res["width"], "undistort": True}
    llff_input_files(path, res["llff_factor"], f"llff_scenes.{name}")
    return {"kind": "llff", "path": str(path), "factor": res["llff_factor"], "width": res["width"]}


def capture_spec(name: str, entry: str | dict, role: str, config: dict, base_dir: str | Path = ".") -> dict:
    """The spec of a captured SPAD scene (:mod:`spc3d.captures`), its sensor.json checked now.
    ``entry``: the folder, or {"path": folder, and sensor settings that replace sensor.json's}."""
    from .capture_import import capture_sensor

    where = f"captures.{name}"
    entry = {"path": entry} if isinstance(entry, str) else dict(entry)
    path, overrides = Path(base_dir) / entry.pop("path"), entry
    if role != "eval":
        raise ConfigError(
            f"scenes.train lists capture {name!r}: translators train on simulated scenes (RGB truth and "
            "photons drawn from it); list captures in scenes.eval"
        )
    if not (path / "sensor.json").is_file():
        raise ConfigError(f"{where}: {path} is not a capture folder (no sensor.json; see spc3d.captures)")
    try:
        tag, sensor = capture_sensor(path, overrides)
    except (ValueError, FileNotFoundError) as e:
        raise ConfigError(f"{where}: {e}") from None
    return {
        "kind": "capture",
        "path": str(path),
        "overrides": overrides,
        "sensor_tag": tag,
        "sensor": sensor,
        "reference": (path / "images").is_dir(),
        "max_features": config["colmap"]["max_features"],
        "seed": config["seed"],
    }


def folder_files(path: str | Path) -> list[str]:
    """Every file of a capture or COLMAP-format scene folder (sensor.json, frames, reference views,
    poses, sparse model): rule inputs, so an edit reruns the scene and what follows."""
    path = Path(path)
    files = [p for p in sorted(path.rglob("*")) if p.is_file() and not any(s.startswith(".") for s in p.parts)]
    return [str(p) for p in files]


def check_disjoint_content(train: list[str], evaluate: list[str]) -> None:
    """No texture, object or background of a built-in evaluation scene may appear in a training one."""
    from .scenes import LAYOUT_ROLES, shared_content

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
    from .llff import llff_contents

    try:
        images, _ = llff_contents(path, factor)
    except FileNotFoundError as e:
        raise ConfigError(f"{where}: {e} (resolution.llff_factor={factor})") from None
    except ValueError as e:
        raise ConfigError(f"{where}: {e}") from None
    return [str(Path(path) / "poses_bounds.npy"), *map(str, images)]


# Stage-1 methods (keys of spc3d.translate.TRANSLATORS, repeated here so parsing the Snakefile does
# not import torch; a test keeps the two equal) and the stage-2 sources that need no stage 1.
STAGE1_METHODS = ("pix2pixhd", "pix2pix", "cyclegan", "restormer", "diffusion")
PLAIN_SOURCES = ("gt", "none", "mle", "bernoulli")
# Stage-2 models (keys of spc3d.reconstruct.RECONSTRUCTORS, repeated for the same reason; a test keeps them equal).
STAGE2_MODELS = ("3dgs", "nerf", "nerf-grid")
# Sources whose photon budget is chosen per row: "mle-k16" is the MLE of 16 frames per view; without
# the suffix they use stage2.frames. Translators use stage1.frames; "none" is frame 0; "gt" is the oracle.
BUDGET_SOURCES = ("mle", "bernoulli")
# Where each image source's views are: (input folder kind, subfolder). "scene" is results/scenes/{scene},
# "spc" results/spc/{scene}, "display" the metered MLE folder of the row's budget, "translated" a
# stage-1 method's outputs. ``bernoulli`` trains on the frames themselves (no images).
SOURCE_IMAGES = {
    "gt": ("scene", "images"),
    "none": ("spc", "binary"),
    "mle": ("display", "images"),
    **{m: ("translated", "images") for m in STAGE1_METHODS},
}
# How tables and figures name each source (the diffusion model is not DiffBIR; say so everywhere).
LABELS = {
    "pix2pixhd": "Pix2PixHD",
    "pix2pix": "Pix2Pix",
    "cyclegan": "CycleGAN",
    "restormer": "Restormer",
    "diffusion": "Diffusion (DiffBIR stand-in)",
    "mle": "MLE",
    "none": "binary frame (no stage 1)",
    "gt": "ground truth",
    "bernoulli": "SPAD likelihood on binary",
    "prior": "physics prior: blurred MLE, the translators' start (no training)",
}


def split_source(source: str) -> tuple[str, int | None]:
    """("mle", 16) for "mle-k16"; (source, None) without a frame suffix."""
    base, sep, k = source.partition("-k")
    if sep and k.isdigit() and int(k) >= 1:
        return base, int(k)
    return source, None


def source_frames(source: str, stage1_frames: int, stage2_frames: int) -> int | None:
    """Binary frames per view a source consumes (its photon budget K); None for the oracle ``gt``."""
    base, k = split_source(source)
    if base == "gt":
        return None
    if base == "none":
        return 1
    if base in STAGE1_METHODS:
        return stage1_frames
    return k or stage2_frames


def parse_combination(combo: str) -> tuple[str, str, str | None]:
    """("bernoulli", "3dgs", "mle-k16") for "bernoulli+3dgs@mle-k16"; poses None for the scene's
    (ground-truth) cameras. After "@": the image source COLMAP poses the training views from
    (:mod:`spc3d.poses`)."""
    head, _, poses = combo.partition("@")
    source, _, model = head.partition("+")
    return source, model, poses or None


def combination_frames(combo: str, stage1_frames: int, stage2_frames: int) -> int | None:
    """Binary frames per view a row consumes: its source's, or its pose source's when more (the
    frames that posed the views were spent too); None for the oracle with ground-truth poses."""
    source, _, poses = parse_combination(combo)
    ks = [source_frames(s, stage1_frames, stage2_frames) for s in (source, poses) if s]
    ks = [k for k in ks if k is not None]
    return max(ks) if ks else None


def check_pose_source(poses: str, combo: str, where: str) -> None:
    base, k = split_source(poses)
    if base not in SOURCE_IMAGES or (poses != base and (k is None or base != "mle")):
        raise ConfigError(
            f"{where}: {combo!r}: poses from {poses!r}? After '@' name the images COLMAP poses the "
            f"training views from: {sorted(SOURCE_IMAGES)} (mle may take '-k<K>'), e.g. 'bernoulli+3dgs@mle-k16'"
        )


def resolve_combinations(combinations: list[str], nerf_variant: str, where: str = "stage2.combinations") -> list[str]:
    """``source+model[@poses]`` names with the family ``nerf`` resolved to the configured NeRF variant."""
    out = []
    for combo in combinations:
        source, model, poses = parse_combination(combo)
        if "+" not in combo or not source or model not in STAGE2_MODELS:
            raise ConfigError(
                f"{where}: {combo!r} must be 'source+model' (or 'source+model@poses') "
                "with model 3dgs, nerf or nerf-grid"
            )
        if poses is not None:
            check_pose_source(poses, combo, where)
        base, k = split_source(source)
        if base not in PLAIN_SOURCES + STAGE1_METHODS or (source != base and k is None):
            raise ConfigError(
                f"{where}: {combo!r} has unknown source {source!r}; use one of "
                f"{list(PLAIN_SOURCES)} or a stage-1 method {list(STAGE1_METHODS)}"
            )
        if k is not None and base not in BUDGET_SOURCES:
            raise ConfigError(
                f"{where}: {combo!r}: only {list(BUDGET_SOURCES)} take a frame budget '-k<K>' "
                f"(translators use stage1.frames, 'none' is one frame, 'gt' none)"
            )
        resolved = f"{source}+{nerf_variant if model == 'nerf' else model}"
        out.append(resolved + (f"@{poses}" if poses else ""))
    return list(dict.fromkeys(out))


def combination_sources(combinations: list[str]) -> set[str]:
    """Every image or frame source the combinations read: their sources and their pose sources."""
    return {s for c in combinations for s in parse_combination(c)[::2] if s}


def stage1_sources(combinations: list[str]) -> list[str]:
    """The stage-1 methods the combinations need (in registry order), as sources or pose sources."""
    used = combination_sources(combinations)
    return [m for m in STAGE1_METHODS if m in used]


def display_budgets(combinations: list[str], stage2_frames: int) -> list[int]:
    """The frame budgets K whose metered display gain the combinations need (mle / bernoulli rows,
    and MLE images that pose a row)."""
    used = combination_sources(combinations)
    return sorted({source_frames(s, 1, stage2_frames) for s in used if split_source(s)[0] in BUDGET_SOURCES})


# The spc block's keys that are the camera's physics (spc3d.spc.SPCParams); the others set its exposure.
SPC_PHYSICS = ("mode", "q", "tau_d", "exposure_s", "dark_count_rate", "frames")


def spc_settings(spc: dict, seed: int, frames: int | None = None, detection: float | None = None) -> dict:
    """Arguments of :func:`spc3d.inputs.simulate_scene` from the config's ``spc`` block: the physics,
    the exposure (a fixed ``flux_scale``, or calibration to ``target_detection``) and the seed.
    ``frames`` overrides K stored per view; ``detection`` sets a calibration target (whatever
    ``flux_scale`` says), as a sweep's ``K`` and ``detection`` knobs do."""
    physics = {k: spc[k] for k in SPC_PHYSICS}
    if frames is not None:
        physics["frames"] = frames
    if detection is not None:
        return {"physics": physics, "flux_scale": None, "target_detection": detection, "seed": seed}
    return {
        "physics": physics,
        "flux_scale": spc["flux_scale"],
        "target_detection": spc["target_detection"],
        "seed": seed,
    }


def translator_settings(stage1: dict, method: str) -> tuple[dict, dict]:
    """(model overrides, training settings) of ``method``: its ``train`` block overrides stage1.train
    (its ``validation`` block is :func:`translator_validation`'s)."""
    settings = dict(stage1.get(method) or {})
    train = {**stage1.get("train", {}), **settings.pop("train", {})}
    settings.pop("validation", None)
    return settings, train


def translator_validation(stage1: dict, method: str) -> dict:
    """stage1.validation, overridden by the method's own ``validation`` block."""
    return {**stage1.get("validation", {}), **(stage1.get(method) or {}).get("validation", {})}
