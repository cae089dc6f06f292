"""The budget knobs of a sweep point, sweep tables and combinations (imports neither torch nor Snakemake).

A setting maps knob names to values; a knob a setting leaves out keeps the config's value. Knobs
a combination does not use (the translator width for ``gt+3dgs``) are recorded but change nothing,
so :func:`distinct_rows` skips table rows that would repeat a point of that combination.
"""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from spc3d.names import PLAIN_SOURCES, ROW_MODELS, combination_problem, nearest, row_model

# Knob -> (type, what it sets). Order = the order of path components in a default table.
KNOBS: dict[str, tuple[type, str]] = {
    "iters": (int, "stage-2 iterations (3DGS iterations, NeRF n_iters); iteration schedules scale with it"),
    "res": (int, "image width in pixels; built-in scenes keep the config's aspect (4:3), LLFF scenes theirs"),
    "K": (int, "binary frames: spc.frames, and the frames the source uses (stage-1 input, bernoulli, MLE)"),
    "width": (
        int,
        "the translator's main width: ngf (pix2pixhd, pix2pix, cyclegan), dim (restormer), base_channels (diffusion)",
    ),
    "steps": (int, "the translator's training iterations"),
    "cap": (int, "3DGS capacity cap: max_gaussians"),
    "grid": (int, "nerf-grid final grid resolution (the res_schedule is scaled to end there)"),
    "detection": (float, "exposure: mean detection probability spc.target_detection (calibrated flux)"),
}


def split_combination(combo: str) -> tuple[str, str]:
    """``"pix2pixhd+3dgs"`` -> ``("pix2pixhd", "3dgs")``."""
    source, sep, model = combo.partition("+")
    if not sep or not source or model not in ROW_MODELS:
        raise ValueError(f"combination {combo!r}: {combination_problem(combo) or 'must be source+model'}")
    return source, model


def parse_combinations(
    combos: list[str], nerf_variant: str, sources: tuple[str, ...] | list[str], key: str
) -> list[str]:
    """Checked combinations with the family ``nerf`` resolved to ``nerf_variant``; errors name ``key``."""
    out = []
    for combo in combos:
        try:
            source, model = split_combination(combo)
        except ValueError as e:
            raise ValueError(f"{key}: {e}") from None
        if source not in sources:
            raise ValueError(f"{key}: {combo!r}: {nearest(source, sources, 'source')}")
        out.append(f"{source}+{row_model(model, nerf_variant)}")
    if not out:
        raise ValueError(f"{key}: give at least one combination")
    return list(dict.fromkeys(out))


def used_knobs(combo: str) -> list[str]:
    """The knobs that change the result of ``combo`` (in :data:`KNOBS` order)."""
    source, model = split_combination(combo)
    stage1 = source not in PLAIN_SOURCES
    used = {
        "iters": True,
        "res": True,
        "K": stage1 or source in ("mle", "bernoulli"),
        "width": stage1,
        "steps": stage1,
        "cap": model == "3dgs",
        "grid": model == "nerf-grid",
        "detection": source != "gt",
    }
    return [k for k in KNOBS if used[k]]


def check_setting(setting: dict, where: str) -> dict:
    """``setting`` with plain Python values, checked: known knobs, positive integers, detection in (0, 1)."""
    out = {}
    for name, value in setting.items():
        if name not in KNOBS:
            raise ValueError(f"{where}: unknown knob {name!r}; valid knobs: {', '.join(KNOBS)}")
        kind = KNOBS[name][0]
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: knob {name}={value!r} is not a number") from None
        if kind is int and (not number.is_integer() or number < 1):
            raise ValueError(f"{where}: knob {name}={value!r} must be a positive integer")
        if kind is float and not 0.0 < number < 1.0:
            raise ValueError(f"{where}: knob {name}={value!r} must lie strictly between 0 and 1")
        out[name] = int(number) if kind is int else number
    return out


def read_table(path: str | os.PathLike) -> pd.DataFrame:
    """A sweep table (``.tsv`` or ``.csv``, ``#`` comments): one row per setting, one column per knob."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"sweep table {path} does not exist")
    sep = "\t" if path.suffix == ".tsv" else ","
    try:
        table = pd.read_csv(path, sep=sep, comment="#", skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise ValueError(
            f"{path}: not a {'tab' if sep == chr(9) else 'comma'}-separated table "
            f"({str(e).strip().splitlines()[-1]}); every row needs one value per column"
        ) from None
    table.columns = [str(c).strip() for c in table.columns]
    if table.empty:
        raise ValueError(f"{path}: the sweep table has no rows")
    for column in table.columns:
        if column not in KNOBS:
            raise ValueError(f"{path}: unknown knob column {column!r}; valid knobs: {', '.join(KNOBS)}")
        if table[column].isna().any():
            raise ValueError(f"{path}: column {column!r} has an empty cell (every row sets every column)")
    for i, row in enumerate(table.to_dict("records")):
        check_setting(row, f"{path} row {i + 1}")
    if table.duplicated().any():
        raise ValueError(f"{path}: rows {list(table.index[table.duplicated()] + 1)} repeat an earlier row")
    return table


def distinct_rows(table: pd.DataFrame, combo: str) -> list[bool]:
    """Per row: True unless an earlier row has the same values of every knob ``combo`` uses."""
    keys = [k for k in used_knobs(combo) if k in table.columns]
    seen, keep = set(), []
    for row in table[keys].itertuples(index=False):
        keep.append(tuple(row) not in seen)
        seen.add(tuple(row))
    return keep


def photon_table(levels: list[float], frames: list[int], key: str = "photon_level") -> pd.DataFrame:
    """Every (detection level, K) pair as a sweep table with columns ``detection`` and ``K``."""
    rows = [check_setting({"detection": d, "K": k}, key) for d in levels for k in frames]
    if not rows:
        raise ValueError(f"{key}: give at least one detection level and one K")
    return pd.DataFrame(rows, columns=["detection", "K"]).drop_duplicates(ignore_index=True)


def label(setting: dict, knobs: list[str]) -> str:
    """Short human label of a setting from the given knobs, e.g. ``"1200it 128px cap40k"``."""
    fmt = {
        "iters": "{}it",
        "res": "{}px",
        "K": "K{}",
        "width": "w{}",
        "steps": "{}st",
        "cap": "cap{}",
        "grid": "grid{}",
        "detection": "p{}",
    }
    parts = []
    for k in knobs:
        v = setting.get(k)
        if v is not None and v == v:  # skip missing and NaN
            v = int(v) if KNOBS[k][0] is int else float(v)
            v = f"{v // 1000}k" if k == "cap" and v >= 1000 and v % 1000 == 0 else v
            parts.append(fmt[k].format(v))
    return " ".join(parts)
