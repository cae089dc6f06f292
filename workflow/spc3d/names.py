"""The workflow's vocabulary: stage-1 methods, sources and their grammar, combinations and their
photon budgets, labels, and the config turned into SPC / translator settings.

The bottom of the package: torch-free (its one spc3d import, :mod:`spc3d.specs`, is too), so
parsing the Snakefile stays fast and every room may use it. Nothing here knows about Snakemake
objects or files.
"""

from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass

from spc3d import specs


class ConfigError(ValueError):
    """A config value that passed the JSON schema but is still wrong (e.g. an unknown scene)."""


# Stage-1 methods and stage-2 models: the model specs' names (spc3d.specs). The untrained methods
# (a spec's ``trained`` False) are rows of their own that show what learning adds: ``prior``, the
# translators' untrained start (the blurred-MLE physics prior alone), and ``classical``, the best
# non-learned denoiser. PLAIN_SOURCES: the stage-2 sources without stage 1.
STAGE1_METHODS = tuple(specs.TRANSLATORS)
TRAINED_METHODS = tuple(n for n, spec in specs.TRANSLATORS.items() if spec.trained)  # with a published form
PLAIN_SOURCES = ("gt", "none", "mle", "bernoulli")
STAGE2_MODELS = tuple(specs.RECONSTRUCTORS)
# A configured row's model may also be the NeRF family: "x+nerf" is row "x+<stage2.nerf_variant>"
# (nerf-mlp, the paper's MLP NeRF, or nerf-grid), so that one key swaps every NeRF row of a run.
NERF_FAMILY = "nerf"
ROW_MODELS = (*STAGE2_MODELS, NERF_FAMILY)


def row_model(model: str, nerf_variant: str) -> str:
    """The stage-2 model a row's ``model`` names: the NeRF family resolved to ``nerf_variant``."""
    return nerf_variant if model == NERF_FAMILY else model


# Sources whose photon budget is chosen per row: "mle-k16" is the MLE of 16 frames per view; without
# the suffix they use stage2.frames. Translators use stage1.frames; "none" is frame 0; "gt" is the oracle.
BUDGET_SOURCES = ("mle", "bernoulli")
# The single-frame sources that read the capture-resolution frame (spc.capture_factor) at K = 1.
CAPTURE_SOURCES = ("none", "mle")
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
    **{name: spec.label for name, spec in specs.TRANSLATORS.items()},
    "mle": "MLE",
    "none": "binary frame (no stage 1)",
    "gt": "ground truth",
    "bernoulli": "SPAD likelihood on binary",
}
# A source "joint-<method>": one 3D fit of the SPAD likelihood of the frames plus a prior term
# pulling each render towards the stage-1 method's output (spc3d.reconstruct.objectives.JointObjective).
JOINT = "joint-"
JOINT_SOURCES = tuple(JOINT + m for m in STAGE1_METHODS)
# The scores of every row: key -> (the tables' title, higher is better). spc3d.evaluation.evaluate
# computes them (its SCORERS, one per key); the tables, findings and sweeps read these keys.
METRICS = {
    "psnr": ("PSNR↑", True),
    "ssim": ("SSIM↑", True),
    "lpips_alex": ("LPIPS-alex↓", False),
    "lpips_vgg": ("LPIPS-vgg↓", False),
}
# What each source-name suffix means (after an optional "-k<K>", in this order), for labels and errors.
SUFFIXES = {
    "-x1": "the frame at the working resolution (not the capture-resolution frame)",
    "-pub": "the published network (prior_sigma: 0), not a residual over the physics prior",
    "-mse": "3DGS fitted with MSE instead of 0.8 L1 + 0.2 D-SSIM (the mean of the targets, not their median)",
}


@dataclass(frozen=True)
class SourceName:
    """A stage-2 source name taken apart: ``[joint-]base[-k<K>][-x1][-pub][-mse]``.

    ``k``: its own frame budget (mle, bernoulli); ``x1``: a single-frame source (none, mle) at the
    working resolution instead of the capture-resolution frame; ``pub``: a translator's published
    network; ``mse``: an image source fitted with MSE by 3DGS; ``joint``: the SPAD likelihood of
    the frames and the stage-1 method ``base`` as a prior, fitted together (:data:`JOINT`)."""

    base: str
    k: int | None = None
    x1: bool = False
    pub: bool = False
    mse: bool = False
    joint: bool = False

    @property
    def method(self) -> str | None:
        """The stage-1 model folder it reads (``pix2pixhd-pub``), None for a source without stage 1."""
        return self.base + "-pub" * self.pub if self.base in STAGE1_METHODS else None

    @property
    def images(self) -> str:
        """The source's image set without the stage-2 loss (``none-x1`` for ``none-x1-mse``): what
        stage 1 scores."""
        return str(dataclasses.replace(self, mse=False))

    def __str__(self) -> str:
        head = JOINT * self.joint + self.base + (f"-k{self.k}" if self.k else "")
        return head + "-x1" * self.x1 + "-pub" * self.pub + "-mse" * self.mse


# The row grammar, one home for it: ``[joint-]base[-k<K>][-x1][-pub][-mse]+model[@poses]``. The
# workflow's wildcard constraints (``source``, ``poses``) are these strings, and the schema's
# patterns of ``stage2.combinations`` and of the sweeps' combinations are copies of the two row
# patterns (Snakemake's validate reads a schema file; tests/test_source_names.py checks the copies).
PART = "[a-z0-9]+"
SOURCE_PATTERN = f"({JOINT})?{PART}(-k[0-9]+)?" + "".join(f"({suffix})?" for suffix in SUFFIXES)
MODEL_PATTERN = f"{PART}(-{PART})*"
POSES_PATTERN = f"(@{PART}(-k[0-9]+)?)?"  # "" (the scene's cameras) or "@<image source>"
COMBINATION_PATTERN = f"^{SOURCE_PATTERN}\\+{MODEL_PATTERN}{POSES_PATTERN}$"
SWEEP_COMBINATION_PATTERN = f"^({JOINT})?{PART}\\+{MODEL_PATTERN}$"  # sweeps: no suffixes, no estimated poses


@dataclass(frozen=True)
class RowName:
    """A row name taken apart: ``source+model[@poses]``; ``str()`` spells it back."""

    source: SourceName
    model: str
    poses: SourceName | None = None

    def __str__(self) -> str:
        return f"{self.source}+{self.model}" + (f"@{self.poses}" if self.poses is not None else "")


def parse_row(combo: str) -> RowName:
    """``RowName`` of ``combo`` (its parts as :func:`parse_combination` and :func:`parse_source` read them)."""
    source, model, poses = parse_combination(combo)
    return RowName(parse_source(source), model, parse_source(poses) if poses else None)


def parse_source(source: str) -> SourceName:
    """``SourceName`` of ``source`` (suffixes stripped from the end, in the order of :data:`SUFFIXES`);
    unknown parts stay in ``base``, which :func:`check_source` then rejects."""
    joint = source.startswith(JOINT) and len(source) > len(JOINT)
    rest, flags = source[len(JOINT) :] if joint else source, {"joint": joint}
    for suffix in reversed(SUFFIXES):
        if rest.endswith(suffix) and len(rest) > len(suffix):
            rest, flags[suffix[1:]] = rest[: -len(suffix)], True
    base, sep, k = rest.partition("-k")
    if not (sep and k.isdigit() and int(k) >= 1):
        return SourceName(rest, None, **flags)
    return SourceName(base, int(k), **flags)


def split_source(source: str) -> tuple[str, int | None]:
    """("mle", 16) for "mle-k16"; (base, None) without a frame suffix."""
    name = parse_source(source)
    return name.base, name.k


def source_label(source: str, labels: dict[str, str] = LABELS, frames: bool = True) -> str:
    """A source's name for tables and figures: its base's label and what each suffix means (with
    its own frame budget unless ``frames`` is False: a table states K in a column of its own)."""
    name = parse_source(source)
    extras = [f"K = {name.k}" if name.k and frames else None] + [
        text.split(" (")[0] for suffix, text in SUFFIXES.items() if getattr(name, suffix[1:])
    ]
    label = labels.get(name.base, name.base) + "".join(f"; {e}" for e in extras if e)
    return f"Joint: SPAD likelihood + {label} (prior term)" if name.joint else label


def source_frames(source: str, stage1_frames: int, stage2_frames: int) -> int | None:
    """Binary frames per view a source consumes (its photon budget K); None for the oracle ``gt``.
    A joint row reads the first frames of each view for both terms: the larger of the two budgets."""
    name = parse_source(source)
    if name.joint:
        return max(stage1_frames, stage2_frames)
    if name.base == "gt":
        return None
    if name.base == "none":
        return 1
    if name.base in STAGE1_METHODS:
        return stage1_frames
    return name.k or stage2_frames


def reads_capture_frame(source: str, stage2_frames: int) -> bool:
    """Whether a row reads the capture-resolution frame (``spc/{scene}/capture``, spc.capture_factor²
    bits per working pixel): ``none`` and ``mle`` at K = 1 without ``-x1`` (the paper-faithful
    single stage: a loader area-downsampling a binary image taken at the camera's resolution)."""
    name = parse_source(source)
    return name.base in CAPTURE_SOURCES and not name.x1 and source_frames(source, 1, stage2_frames) == 1


def as_read(combination: str, K, S) -> str:
    """The combination under the name of the frame it read: a capture has no capture-resolution
    frame, so its ``none`` / ``mle`` runs at K = 1 record S = 1 and are ``-x1`` rows (a record
    without S keeps its name)."""
    source, sep, model = combination.partition("+")
    name = parse_source(source)
    if K == 1 and S == 1 and name.base in CAPTURE_SOURCES and not name.x1:
        return str(dataclasses.replace(name, x1=True)) + sep + model
    return combination


def source_images(source: str, stage2_frames: int) -> tuple[str, str]:
    """(folder kind, subfolder) of an image source's views (:data:`SOURCE_IMAGES`; the capture frame
    for :func:`reads_capture_frame`)."""
    kind, sub = SOURCE_IMAGES[parse_source(source).base]
    if reads_capture_frame(source, stage2_frames) and kind == "spc":
        return kind, "capture"
    return kind, sub


def display_budget(source: str, stage2_frames: int, stage1_frames: int = 1) -> str:
    """The metered display a physics source reads: ``k{K}`` (its first K frames) or ``capture``
    (a joint row: the display of the frames its likelihood fits, every frame it consumed)."""
    if reads_capture_frame(source, stage2_frames):
        return "capture"
    return f"k{source_frames(source, stage1_frames, stage2_frames)}"


def parse_combination(combo: str) -> tuple[str, str, str | None]:
    """("bernoulli", "3dgs", "mle-k16") for "bernoulli+3dgs@mle-k16"; poses None for the scene's
    (ground-truth) cameras. After "@": the image source COLMAP poses the training views from
    (:mod:`spc3d.poses.estimate`)."""
    head, _, poses = combo.partition("@")
    source, _, model = head.partition("+")
    return source, model, poses or None


def nearest(name: str, valid, what: str) -> str:
    """``unknown {what} 'name'; did you mean 'x'? valid: a, b, ...`` (the closest valid name by
    :mod:`difflib`, tried also with '_' read as '-' and without separators)."""
    valid = list(valid)
    tries = (name, name.replace("_", "-"), name.replace("_", "").replace("-", ""), name.lower())
    close = next((c[0] for t in tries if (c := difflib.get_close_matches(t, valid, n=1, cutoff=0.6))), None)
    hint = f"did you mean {close!r}? " if close else ""
    return f"unknown {what} {name!r}; {hint}valid: {', '.join(valid)}"


def combination_problem(combo: str) -> str | None:
    """What is wrong with a row name, part by part (the source before '+', the model after it, the
    poses after '@'), with the valid parts and the nearest match; None when each part is known
    (the suffixes' rules are then :func:`check_source`'s)."""
    if "+" not in combo:
        base = parse_source(combo).base
        example = f"{combo}+3dgs" if base in PLAIN_SOURCES + STAGE1_METHODS else f"gt+{combo}"
        if example == f"gt+{combo}" and combo not in ROW_MODELS:
            example = "pix2pixhd+3dgs"
        return f"a row is 'source+model' and has no '+' here (e.g. {example!r}; models: {', '.join(ROW_MODELS)})"
    source, model, poses = parse_combination(combo)
    if model not in ROW_MODELS:
        return nearest(model, ROW_MODELS, "model")
    base = parse_source(source).base
    if base not in PLAIN_SOURCES + STAGE1_METHODS:
        return nearest(base, PLAIN_SOURCES + STAGE1_METHODS, "source") + (
            f" (with the suffixes -k<K>, {', '.join(SUFFIXES)}; joint rows: '{JOINT}<method>')"
        )
    if poses is not None and parse_source(poses).base not in SOURCE_IMAGES:
        return nearest(parse_source(poses).base, sorted(SOURCE_IMAGES), "pose source after '@'")
    return None


def check_pose_source(poses: str, combo: str, where: str) -> None:
    name = parse_source(poses)
    if (
        name.base not in SOURCE_IMAGES
        or name.x1
        or name.mse
        or (poses != name.base and (name.k is None or name.base != "mle"))
    ):
        raise ConfigError(
            f"{where}: {combo!r}: poses from {poses!r}? After '@' name the images COLMAP poses the "
            f"training views from: {sorted(SOURCE_IMAGES)} (mle may take '-k<K>'), e.g. 'bernoulli+3dgs@mle-k16'"
        )


def check_source(source: str, combo: str, where: str) -> None:
    """A stage-2 source name: a known base with only the suffixes that apply to it."""
    name = parse_source(source)
    known = nearest(name.base, PLAIN_SOURCES + STAGE1_METHODS, "source")
    problems = {
        f"{known} (joint: '{JOINT}<method>'), with the suffixes {list(SUFFIXES)}": name.base
        not in PLAIN_SOURCES + STAGE1_METHODS,
        f"only {list(BUDGET_SOURCES)} take a frame budget '-k<K>' (translators use stage1.frames, "
        "'none' is one frame, 'gt' none)": name.k is not None and name.base not in BUDGET_SOURCES,
        f"'-x1' ({SUFFIXES['-x1']}) applies to {list(CAPTURE_SOURCES)} at one frame per view only": name.x1
        and (name.base not in CAPTURE_SOURCES or (name.k or 1) > 1),
        f"'-pub' ({SUFFIXES['-pub']}) applies to the trained methods {list(TRAINED_METHODS)}": name.pub
        and name.base not in TRAINED_METHODS,
        f"'-mse' ({SUFFIXES['-mse']}) applies to {list(CAPTURE_SOURCES)}": name.mse
        and name.base not in CAPTURE_SOURCES,
        f"'{JOINT}' (the likelihood with a stage-1 prior) takes a stage-1 method {list(STAGE1_METHODS)}, "
        "without -k<K>, -x1 or -mse": name.joint
        and (name.base not in STAGE1_METHODS or name.k is not None or name.x1 or name.mse),
        f"write its suffixes in the order -k<K>, -x1, -pub, -mse ({str(name)!r})": str(name) != source,
    }
    for problem, bad in problems.items():
        if bad:
            raise ConfigError(f"{where}: {combo!r}: {problem}")


def resolve_combinations(combinations: list[str], nerf_variant: str, where: str = "stage2.combinations") -> list[str]:
    """``source+model[@poses]`` names with the family ``nerf`` resolved to the configured NeRF variant
    (``stage2.nerf_variant``: ``nerf-mlp`` or ``nerf-grid``)."""
    out = []
    for combo in combinations:
        source, model, poses = parse_combination(combo)
        problem = combination_problem(combo) if source else "a row is 'source+model' (e.g. 'pix2pixhd+3dgs')"
        if problem:
            raise ConfigError(f"{where}: {combo!r}: {problem}")
        if poses is not None:
            check_pose_source(poses, combo, where)
        check_source(source, combo, where)
        resolved = f"{source}+{row_model(model, nerf_variant)}"
        out.append(resolved + (f"@{poses}" if poses else ""))
    return list(dict.fromkeys(out))


def joint_settings(joint: dict, model: str | None) -> dict:
    """The settings of ``model``'s joint rows: stage2.joint, with its ``models: {model: {...}}`` entry
    laid over it (each 3D model's prior term is its own image loss, so each has its own weight);
    ``choose`` (the candidates a fold chooses its weight among, spc3d.choices) is not a setting of the fit."""
    common = {k: v for k, v in joint.items() if k not in ("models", "choose")}
    return {**common, **((joint.get("models") or {}).get(model) or {})}


def stage2_row_settings(stage2: dict, model: str, poses: str | None) -> dict:
    """The settings a row's stage-2 job gets: the model's block of ``stage2``, and for a model that
    refines cameras ``pose_refine`` per ``stage2.refine_poses`` unless the block sets it (all rows,
    or by default the rows on estimated poses, ``poses`` not None)."""
    settings, refine = dict(stage2.get(model) or {}), stage2.get("refine_poses", "estimated")
    if specs.RECONSTRUCTORS[model].refines_poses and "pose_refine" not in settings:
        settings["pose_refine"] = refine == "all" or (refine == "estimated" and bool(poses))
    return settings


def uses_display(source: str) -> bool:
    """Whether a source reads a metered display: the MLE images, or the gain of a likelihood."""
    name = parse_source(source)
    return name.base in BUDGET_SOURCES or name.joint


def combination_sources(combinations: list[str]) -> set[str]:
    """Every image or frame source the combinations read: their sources and their pose sources."""
    return {s for c in combinations for s in parse_combination(c)[::2] if s}


def stage1_sources(combinations: list[str]) -> list[str]:
    """The stage-1 model folders the combinations need (registry order, each method's published
    form after it), as sources or pose sources."""
    used = {parse_source(s).method for s in combination_sources(combinations)}
    return [m for base in STAGE1_METHODS for m in (base, f"{base}-pub") if m in used]


def scored_before_3d(combinations: list[str]) -> list[str]:
    """The sources scored before 3D (the rule ``score_images``): the stage-1 model folders in use
    (:func:`stage1_sources`), then the training-free images the rows read (the binary frame always;
    MLE and binary variants as the rows use them, without their stage-2 loss)."""
    sources = [parse_source(parse_combination(c)[0]) for c in combinations]
    plain = {s.images for s in sources if s.base in ("mle", "none")}
    return stage1_sources(combinations) + sorted(plain | {"none"})


def display_budgets(combinations: list[str], stage2_frames: int, stage1_frames: int = 1) -> list[str]:
    """The metered displays (``k{K}`` or ``capture``, :func:`display_budget`) the combinations need:
    mle / bernoulli / joint rows, and MLE images that pose a row."""
    used = [s for s in combination_sources(combinations) if uses_display(s)]
    budgets = {display_budget(s, stage2_frames, stage1_frames) for s in used}
    return sorted(budgets, key=lambda b: (b == "capture", int(b[1:]) if b != "capture" else 0))


# The spc block's keys that are the camera's physics (spc3d.physics.spc.SPCParams); the others set its exposure.
SPC_PHYSICS = ("mode", "q", "tau_d", "exposure_s", "dark_count_rate", "frames")


def spc_settings(spc: dict, seed: int, frames: int | None = None, detection: float | None = None) -> dict:
    """Arguments of :func:`spc3d.inputs.build.simulate_scene` from the config's ``spc`` block: the physics,
    the exposure (a fixed ``flux_scale``, or calibration to ``target_detection``), the capture
    frame's resolution factor and the seed. ``frames`` overrides K stored per view; ``detection``
    sets a calibration target (whatever ``flux_scale`` says), as a sweep's ``K`` and ``detection``
    knobs do."""
    physics = {k: spc[k] for k in SPC_PHYSICS}
    if frames is not None:
        physics["frames"] = frames
    exposure = (None, detection) if detection is not None else (spc["flux_scale"], spc["target_detection"])
    return {
        "physics": physics,
        "flux_scale": exposure[0],
        "target_detection": exposure[1],
        "capture_factor": spc.get("capture_factor", 1),
        "seed": seed,
    }


def translator_settings(stage1: dict, method: str) -> tuple[dict, dict]:
    """(model overrides, training settings) of ``method`` (a model folder name: ``pix2pixhd-pub`` is
    pix2pixhd's block with ``prior_sigma: 0``, the published network): its ``train`` block overrides
    stage1.train (its ``validation`` block is :func:`translator_validation`'s)."""
    name = parse_source(method)
    settings = dict(stage1.get(name.base) or {})
    train = {**stage1.get("train", {}), **settings.pop("train", {})}
    settings.pop("validation", None)
    if name.pub:
        settings["prior_sigma"] = 0.0
    return settings, train


def translator_validation(stage1: dict, method: str) -> dict:
    """stage1.validation, overridden by the method's own ``validation`` block."""
    return {**stage1.get("validation", {}), **(stage1.get(parse_source(method).base) or {}).get("validation", {})}
