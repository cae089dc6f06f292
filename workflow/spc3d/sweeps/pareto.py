"""Pareto fronts and tables of the sweeps: quality against time (no torch, no plotting).

``tradeoff_table``: one row per point (combination, setting number, every knob, wall time, peak
memory, PSNR, SSIM, LPIPS-alex/vgg, CPU time, stage-1 PSNR, whether the point is on its
combination's PSNR-time Pareto front, a label of the knobs that vary), the front computed against
wall or CPU time (``clock_column``). ``photon_table``: one row per (combination, K, detection
level). ``pareto_mask`` / ``front_steps``: the front and its step line (the best quality reachable
within a time budget). Figures and report files: :mod:`spc3d.sweeps.report`.
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd

from spc3d import io
from spc3d.sweeps.knobs import KNOBS, label

SCORES = ("psnr", "ssim", "lpips_alex", "lpips_vgg")


def pareto_mask(time, quality) -> np.ndarray:
    """Per point: True when no other point is at least as fast and at least as good, and better in one.

    ``time`` and ``quality`` are (N,) (higher quality is better: pass -LPIPS for LPIPS). Exact
    ties are all kept; points with NaN time or quality are never on the front.
    """
    t, q = np.asarray(time, float), np.asarray(quality, float)
    ok = ~np.isnan(t) & ~np.isnan(q)
    no_worse = (t[None, :] <= t[:, None]) & (q[None, :] >= q[:, None])  # [i, j]: j is no worse than i
    better = (t[None, :] < t[:, None]) | (q[None, :] > q[:, None])
    dominated = (no_worse & better & ok[None, :]).any(axis=1)
    return ok & ~dominated


def front_steps(time, quality) -> tuple[np.ndarray, np.ndarray]:
    """The front's points sorted by time: the step line of the best quality within a time budget."""
    t, q = np.asarray(time, float), np.asarray(quality, float)
    on = pareto_mask(t, q)
    order = np.lexsort((q[on], t[on]))
    return t[on][order], q[on][order]


def collect_points(paths: list[str | os.PathLike]) -> pd.DataFrame:
    """One row per metrics.json of a point: combination, knobs, times, memory, scores."""
    rows = []
    for path in paths:
        rec = io.read_json(path)
        spc = rec.get("spc_record") or {}
        rows.append(
            {
                "combination": rec["combination"],
                **rec["setting"],
                "wall_time_s": rec["wall_s"],
                "peak_memory_mb": rec["peak_rss_mb"],
                **{k: rec["mean"][k] for k in SCORES},
                "cpu_time_s": rec["cpu_s"],
                "stage1_psnr": (rec.get("stage1") or {}).get("psnr", np.nan),
                "measured_detection": spc.get("mean_detection_rate", np.nan),
                "used": tuple(rec["used_knobs"]),
                "path": str(path),
            }
        )
    if not rows:
        raise ValueError("no sweep points to summarise")
    return pd.DataFrame(rows)


def tradeoff_table(paths: list[str | os.PathLike], combos: list[str], clock: str = "wall") -> pd.DataFrame:
    """The trade-off table, combinations in ``combos`` order, each sorted by time.

    ``clock``: the time the Pareto front is computed against: ``wall`` (elapsed) or ``cpu`` (user +
    system CPU seconds, which other load on a shared machine barely changes). ``label`` names the
    knobs that the combination uses and that vary among its points.
    """
    time_key = clock_column(clock)
    df = collect_points(paths)
    knobs = [k for k in KNOBS if k in df.columns]
    keys = [tuple(r) for r in df[knobs].astype(str).itertuples(index=False)]  # settings numbered in input order
    df["setting"] = [list(dict.fromkeys(keys)).index(k) + 1 for k in keys]
    df["pareto"], df["label"] = False, ""
    for _, group in df.groupby("combination"):
        df.loc[group.index, "pareto"] = pareto_mask(group[time_key], group["psnr"])
        varying = [k for k in group["used"].iloc[0] if k in group and group[k].nunique() > 1]
        for i, row in group.iterrows():
            df.loc[i, "label"] = label(row.to_dict(), varying or list(row["used"]))
    df["order"] = df["combination"].map({c: i for i, c in enumerate(combos)})
    df = df.sort_values(["order", time_key]).reset_index(drop=True)
    return df[
        [
            "combination",
            "setting",
            *knobs,
            "wall_time_s",
            "peak_memory_mb",
            *SCORES,
            "cpu_time_s",
            "stage1_psnr",
            "pareto",
            "label",
        ]
    ]


def clock_column(clock: str) -> str:
    """The table column of a clock name (``wall`` or ``cpu``)."""
    if clock not in ("wall", "cpu"):
        raise ValueError(f"tradeoff.clock={clock!r}: use 'wall' (elapsed seconds) or 'cpu' (CPU seconds)")
    return f"{clock}_time_s"


def photon_table(paths: list[str | os.PathLike], combos: list[str]) -> pd.DataFrame:
    """The photon-level table, by combination (``combos`` order), K and detection level."""
    df = collect_points(paths)
    df["order"] = df["combination"].map({c: i for i, c in enumerate(combos)})
    df = df.sort_values(["order", "K", "detection"]).reset_index(drop=True)
    return df[
        ["combination", "K", "detection", "measured_detection", *SCORES, "stage1_psnr", "wall_time_s", "peak_memory_mb"]
    ]
