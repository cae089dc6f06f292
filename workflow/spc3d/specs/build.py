"""Settings dataclasses from configuration blocks: :func:`build_config` checks every key, type,
shape (from the annotations) and range (one rule per setting name, :data:`BOUNDED` and friends)
before the class's own ``__post_init__`` checks, and names the block, key and value on failure.

Torch-free, like the settings classes of :mod:`spc3d.specs`: the workflow builds every job's
settings here at parse time, before any job runs.
"""

from __future__ import annotations

import dataclasses
import difflib
import fnmatch
import typing


def build_config(cls, settings: dict, where: str, base=None):
    """``cls`` with ``settings`` overriding ``base`` (or the defaults).

    Unknown keys, values of the wrong type (judged by the field's default) and the class's own
    checks (``__post_init__``) raise a ValueError that names ``where``, the key and the value.
    """
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(settings) - set(fields))
    if unknown:
        close = difflib.get_close_matches(unknown[0], fields, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise ValueError(f"{where}: unknown setting(s) {unknown}; {hint}valid keys: {sorted(fields)}")
    values = {k: _tuples(v) for k, v in settings.items()}
    hints = typing.get_type_hints(cls)
    for key, value in values.items():
        _check_type(where, key, value, _default(fields[key]))
        check_shape(f"{where}.{key}", value, hints.get(key), value)
        check_range(where, key, value)
    try:
        return dataclasses.replace(base, **values) if base is not None else cls(**values)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {e}") from None


def require_positive(cfg, *names: str) -> None:
    """For a config's ``__post_init__``: every named count must be >= 1."""
    bad = [f"{n} = {getattr(cfg, n)!r}" for n in names if getattr(cfg, n) < 1]
    if bad:
        raise ValueError(f"{', '.join(bad)}: must be >= 1")


def _default(field):
    if field.default is not dataclasses.MISSING:
        return field.default
    return field.default_factory() if field.default_factory is not dataclasses.MISSING else None


def _check_type(where: str, key: str, value, default) -> None:
    """``value`` must have the kind of ``default`` (an int is a fine float; None defaults take anything)."""
    if default is None or value is None:
        return
    kinds = {bool: (bool,), int: (int,), float: (int, float), str: (str,), tuple: (tuple,)}
    want = kinds.get(type(default))
    if want and (not isinstance(value, want) or (isinstance(value, bool) and bool not in want)):
        raise ValueError(f"{where}.{key} = {value!r}: expected {type(default).__name__} (like the default {default!r})")


def check_shape(where: str, value, hint, whole=None) -> None:
    """A tuple setting has the shape its annotation says: ``tuple[int, int]`` two items,
    ``tuple[int, ...]`` any number, nested as annotated (``tuple[tuple[int, int], ...]``: a list of
    pairs). Only tuples are judged; other types are :func:`_check_type`'s."""
    if typing.get_origin(hint) is not tuple:
        return
    if not isinstance(value, tuple):
        raise ValueError(f"{where} = {_as_lists(whole)!r}: expected a list ({_shape_text(hint)})")
    args = typing.get_args(hint)
    if len(args) == 2 and args[1] is Ellipsis:
        items = [args[0]] * len(value)
    elif len(args) != len(value):
        raise ValueError(f"{where} = {_as_lists(whole)!r}: expected {_shape_text(hint)}, got {len(value)} item(s)")
    else:
        items = list(args)
    for i, (item, item_hint) in enumerate(zip(value, items)):
        check_shape(f"{where}[{i}]", item, item_hint, whole)


def _as_lists(v):
    """A setting as the YAML list the user wrote (tuples shown as lists)."""
    return [_as_lists(x) for x in v] if isinstance(v, tuple) else v


def _shape_text(hint) -> str:
    args = typing.get_args(hint)
    if len(args) == 2 and args[1] is Ellipsis:
        inner = _shape_text(args[0]) if typing.get_origin(args[0]) is tuple else getattr(args[0], "__name__", "item")
        return f"a list of {inner}s" if not inner.startswith("a list") else f"a list of [{inner}]"
    names = [_shape_text(a) if typing.get_origin(a) is tuple else getattr(a, "__name__", "item") for a in args]
    return f"[{', '.join(names)}]"


# The ranges of every numeric model and training setting, by name: none is signed (counts, loss
# weights, rates, thresholds, blur widths are all >= 0, and 0 means "off" wherever it is allowed);
# learning rates and scales must be > 0; momenta and decays lie in [0, 1); and the settings below
# have both ends: (low, high, high included, what the number is). A setting whose name is not
# listed has no upper end (a count, an iteration, a loss weight such as lambda_L1 = 100).
POSITIVE = ("lr", "lr_*", "*_lr", "*_lr_*", "residual_scale", "xy_extent", "ffn_expansion_factor")
UNIT_INTERVAL = ("beta1", "beta2", "ema_decay", "adam_betas", "betas")
BOUNDED = {
    "ssim_weight": (0.0, 1.0, True, "a mix weight: the loss is (1 - w) L1 + w D-SSIM, so w > 1 makes L1's negative"),
    "percent_dense": (0.0, 1.0, False, "a fraction of the scene extent: 0.01 is 1 %"),
    "background": (0.0, 1.0, True, "a colour in render space [0, 1]: white is [1, 1, 1], not 255"),
    "alpha_init": (0.0, 1.0, False, "an opacity α of one sample"),
    "occupancy_thres": (0.0, 1.0, False, "an opacity α below which a cell is empty; 1 or more empties every cell"),
    "weight_thres": (0.0, 1.0, False, "a compositing weight"),
    "min_trans": (0.0, 1.0, False, "a transmittance"),
    "prune_opacity": (0.0, 1.0, False, "an opacity; 1 or more prunes every Gaussian"),
    "plateau_gain": (0.0, 1.0, False, "a relative drop of the objective (0.01 = 1 %)"),
    "decay_from": (0.0, 1.0, True, "a fraction of the run"),
    "decay_until": (0.0, 1.0, True, "a fraction of the run"),
    "lr_decay": (0.0, 1.0, True, "the final learning rate as a fraction of the initial one (a decay, not a rise)"),
    "eta": (0.0, 1.0, True, "DDIM's stochasticity: 0 deterministic, 1 DDPM"),
}


def check_range(where: str, key: str, value, whole=None) -> None:
    """``value`` (a number, or a tuple of them: ``whole`` is the setting shown) within the range of
    setting ``key``: see :data:`POSITIVE`, :data:`UNIT_INTERVAL` and :data:`BOUNDED`; every other number >= 0."""
    if isinstance(value, tuple):
        for item in value:
            check_range(where, key, item, value if whole is None else whole)
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if key in BOUNDED:
        low, high, closed, what = BOUNDED[key]
        if not (low <= value <= high if closed else low <= value < high):
            shown = value if whole is None else _as_lists(whole)
            raise ValueError(
                f"{where}.{key} = {shown!r}: must be in [{low:g}, {high:g}{']' if closed else ')'} ({what})"
            )
    elif any(fnmatch.fnmatchcase(key, p) for p in POSITIVE):
        if not value > 0:
            raise ValueError(f"{where}.{key} = {value!r}: must be > 0 (a learning rate or scale)")
    elif key in UNIT_INTERVAL:
        if not 0 <= value < 1:
            raise ValueError(f"{where}.{key} = {value!r}: must be in [0, 1) (a momentum or decay, e.g. 0.9)")
    elif value < 0:
        raise ValueError(
            f"{where}.{key} = {value!r}: must be >= 0 (no setting is signed: counts, loss weights, "
            "thresholds and widths; 0 turns a term off where it may be off)"
        )


def _tuples(v):
    """YAML lists -> tuples, so frozen configs stay hashable."""
    return tuple(_tuples(x) for x in v) if isinstance(v, list) else v
