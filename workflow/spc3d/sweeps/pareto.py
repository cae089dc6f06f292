"""Pareto fronts and tables of the sweeps: quality against time (no torch, no plotting).

A point's record (:func:`point_record`) comes from the files of its jobs: the scores from its
evaluate ``metrics.json``, the time from the benchmark TSVs of its jobs (summed, see there).

``tradeoff_table``: one row per point (combination, setting number, every knob, wall time, peak
memory, PSNR, SSIM, LPIPS-alex/vgg, CPU time, stage-1 PSNR, whether the point is on its
combination's PSNR-time Pareto front, a label of the knobs that vary), the front computed against
wall or CPU time (``clock_column``). ``photon_table``: one row per (combination, K, detection
level). ``pareto_mask`` / ``front_steps``: the front and its step line (the best quality reachable
within a time budget). Figures and report files: :mod:`spc3d.sweeps.report`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from spc3d import io
from spc3d.evaluation.record import RunRecord
from spc3d.jobs import BENCHMARK_COLUMNS
from spc3d.names import METRICS
from spc3d.sweeps.knobs import KNOBS, label

SCORES = tuple(METRICS)  # every row score (spc3d.names.METRICS)


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


def read_benchmark(path: str | os.PathLike) -> dict:
    """One job's benchmark row (:data:`spc3d.jobs.BENCHMARK_COLUMNS`, written by ``spc3d.jobs.logged``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the benchmark of a sweep point's job is missing (rerun the job to time it)")
    row = pd.read_csv(path, sep="\t").iloc[-1]
    return {k: row[k] for k in BENCHMARK_COLUMNS}


def point_record(point: dict) -> dict:
    """A sweep point's record from its files (``point``: an entry of :func:`spc3d.sweeps.plan.sweep_points`
    with ``benchmarks``, the benchmark TSV of each of its jobs).

    Time: ``wall_s`` is the sum of the wall times of the point's jobs and ``cpu_s`` the sum of their
    user + system CPU times, ``times_s`` the same per rule, ``peak_rss_mb`` the largest peak of any
    of them: the time the point costs alone, run one job after another. A job several points share
    (a setting's scene and SPC folder, shared by every combination swept at that setting; a
    translator shared by two stage-2 models) counts in full in each of them, as each would run it
    alone: the sum over points can exceed the sweep's own time, never the reverse.
    Scores, iterations and capacity: the point's evaluate metrics.json; resolved settings: the
    train.json of its reconstruction (and translator), the spc.json of its SPC folder.
    """
    metrics = RunRecord.read(point["metrics"])
    jobs = [(Path(b).parent.name, read_benchmark(b)) for b in point["benchmarks"]]
    times: dict[str, float] = {}
    for rule, bench in jobs:
        times[rule] = times.get(rule, 0.0) + float(bench["s"])
    recon = io.read_json(Path(point["recon"]) / "train.json")
    model = io.read_json(Path(point["model"]) / "train.json") if point.get("model") else None
    spc = io.read_json(Path(point["spc"]) / "spc.json") if point.get("spc") else None
    return {
        "combination": point["combination"],
        "scene": metrics.scene,
        "seed": metrics.seed,
        "setting": point["setting"],
        "used_knobs": point["used_knobs"],
        "times_s": {rule: round(t, 3) for rule, t in times.items()},
        "wall_s": sum(float(b["s"]) for _, b in jobs),
        "cpu_s": sum(float(b["user_s"]) + float(b["sys_s"]) for _, b in jobs),
        "peak_rss_mb": max(float(b["max_rss_mb"]) for _, b in jobs),
        "jobs": len(jobs),
        "mean": metrics.mean,
        "per_view": metrics.get("per_view"),
        "stage1": io.read_json(point["stage1"])["mean"] if point.get("stage1") else None,
        "iterations": metrics.get("iterations"),
        "capacity": metrics.capacity,
        "frames": metrics.frames,
        "resolved": {
            "stage2": recon["settings"],
            "translator": model and {k: model.get(k) for k in ("parameters", "train_s", "settings", "train", "pairs")},
        },
        "spc_record": spc,
    }


def collect_points(points: list[dict]) -> pd.DataFrame:
    """One row per sweep point (:func:`point_record`): combination, knobs, times, memory, scores."""
    rows = []
    for point in points:
        rec = point_record(point)
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
                "path": str(point["metrics"]),
            }
        )
    if not rows:
        raise ValueError("no sweep points to summarise")
    return pd.DataFrame(rows)


def tradeoff_table(points: list[dict], combos: list[str], clock: str = "wall") -> pd.DataFrame:
    """The trade-off table, combinations in ``combos`` order, each sorted by time.

    ``clock``: the time the Pareto front is computed against: ``wall`` (elapsed) or ``cpu`` (user +
    system CPU seconds, which other load on a shared machine barely changes). ``label`` names the
    knobs that the combination uses and that vary among its points.
    """
    time_key = clock_column(clock)
    df = collect_points(points)
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


def photon_table(points: list[dict], combos: list[str]) -> pd.DataFrame:
    """The photon-level table, by combination (``combos`` order), K and detection level."""
    df = collect_points(points)
    df["order"] = df["combination"].map({c: i for i, c in enumerate(combos)})
    df = df.sort_values(["order", "K", "detection"]).reset_index(drop=True)
    return df[
        ["combination", "K", "detection", "measured_detection", *SCORES, "stage1_psnr", "wall_time_s", "peak_memory_mb"]
    ]
