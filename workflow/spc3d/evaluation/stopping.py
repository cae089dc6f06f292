"""Where each stage-2 row stopped, and what stopping there cost: the ``stopping`` (trade) table.

One row per combination, over its runs (scenes x seeds, each fit one unit): how many stopped on
their plateau (:class:`spc3d.training.Plateau`) rather than at the budget, the steps used of the
maximum, the training seconds and the final capacity. Runs trained in observe mode (to the budget,
rendered at the stop too: ``stage2.observe_plateau``, ``benchmarks/stopping_trade.py``) add the
trade itself, paired within each fit: the share of training time the stop saves and the held-out
PSNR change from the budget's renders to the stop's (mean, 95 % sign-flip interval: the same test as
the findings; unbounded below 6 runs), and the SSIM change.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pandas as pd

from spc3d.evaluation.findings import interval
from spc3d.evaluation.record import RunRecord, read_runs
from spc3d.evaluation.tables import write_plain_table, write_text_table

CAPTION = "Adaptive stage-2 budgets: where each row stopped, and the trade against its full budget"
PROTOCOL = (
    "A row stops once its training objective gains less than the rule's min_gain over patience windows, "
    "judged on its training views or on training views held out of its fit (never the scored views). "
    "Observed runs train on to the budget; time saved and ΔPSNR / ΔSSIM "
    "(stop − budget, held-out views) are paired within each fit; interval: 95 % sign-flip (unbounded with < 6 runs)."
)


def stopped_runs(metrics_files: list[str | os.PathLike]) -> list[RunRecord]:
    """The scored runs that carry a stopping record (rows of trainers with a plateau rule)."""
    return [r for r in read_runs(metrics_files) if r.mean and r.stopped]


def early(stopped: dict) -> bool:
    """The plateau rule ended the fit before its budget (a rule that fires on the last step saved nothing)."""
    return stopped["reason"] == "plateau" and stopped["step"] < stopped["of"]


def row(combination: str, runs: list[RunRecord]) -> dict:
    """One line of the table from the runs of one combination."""
    steps = [r.stopped["step"] / r.stopped["of"] for r in runs]
    out = {
        "combination": combination,
        "n": len(runs),
        "stopped early": f"{sum(early(r.stopped) for r in runs)}/{len(runs)}",
        "steps used": float(np.mean(steps)),
        "max steps": runs[0].stopped["of"],
        "judged on": judged_on(runs[0].stopped.get("rule", {})),
        "train s": float(np.mean([r.train_s for r in runs])),
        "capacity": capacity_text(runs),
    }
    observed = [r for r in runs if r.at_stop]
    if len(observed) == len(runs):
        d = np.array([r.at_stop["psnr"] - r.mean["psnr"] for r in runs])
        lo, hi = interval(d) if np.isfinite(d).all() else (math.nan, math.nan)
        out |= {
            "time saved": float(np.mean([1.0 - r.at_stop["train_s"] / r.train_s for r in runs])),
            "ΔPSNR": float(d.mean()),
            "ΔPSNR lo": lo,
            "ΔPSNR hi": hi,
            "ΔSSIM": float(np.mean([r.at_stop["ssim"] - r.mean["ssim"] for r in runs])),
        }
    return out


def judged_on(rule: dict) -> str:
    """What the rule read: the training loss, or the objective on N training views held out of the fit."""
    views = rule.get("views") or []
    return f"{len(views)} held-out training views" if views else "training loss"


def capacity_text(runs: list[RunRecord]) -> str:
    """Mean Gaussians (3DGS) or occupied grid cells (grid NeRF) at the end, as the record gives them."""
    for key in ("gaussians", "occupied_cells"):
        capacities = [r.capacity for r in runs]
        values = [c[key] for c in capacities if isinstance(c, dict) and key in c]
        if values:
            return f"{np.mean(values):,.0f} {key.replace('_', ' ')}"
    return ""


def stopping_table(metrics_files: list[str | os.PathLike], stem: str | os.PathLike) -> pd.DataFrame:
    """Write ``stem``.csv / .md / .tex / .html; returns the table (empty when no row has a rule)."""
    groups: dict[str, list[RunRecord]] = {}
    for r in stopped_runs(metrics_files):
        groups.setdefault(r.combination, []).append(r)
    df = pd.DataFrame([row(c, rs) for c, rs in groups.items()])
    if df.empty:
        write_text_table(stem, f"{CAPTION}: no scored row has a stopping rule")
    else:
        write_plain_table(display(df), df, stem, CAPTION, PROTOCOL)
    return df


def display(df: pd.DataFrame) -> pd.DataFrame:
    """The table's display strings."""
    out = pd.DataFrame(
        {
            "combination": df["combination"],
            "n": df["n"],
            "stopped early": df["stopped early"],
            "steps used": [f"{s:.0%} of {m}" for s, m in zip(df["steps used"], df["max steps"])],
            "judged on": df["judged on"],
            "train s": [f"{s:.1f}" for s in df["train s"]],
            "capacity": df["capacity"],
        }
    )
    if "ΔPSNR" in df:
        out["time saved"] = [dash(v, "{:.0%}") for v in df["time saved"]]
        out["ΔPSNR (dB)"] = [psnr_text(m, lo, hi) for m, lo, hi in zip(df["ΔPSNR"], df["ΔPSNR lo"], df["ΔPSNR hi"])]
        out["ΔSSIM"] = [dash(v, "{:+.4f}") for v in df["ΔSSIM"]]
    return out


def dash(value, fmt: str) -> str:
    return "–" if value is None or not np.isfinite(value) else fmt.format(value)


def psnr_text(mean, lo, hi) -> str:
    """``+0.03 [−0.10, +0.12]``; the interval reads "n < 6" when no test could bound it."""
    if mean is None or not np.isfinite(mean):
        return "–"
    bounds = f"[{lo:+.2f}, {hi:+.2f}]" if np.isfinite(lo) and np.isfinite(hi) else "[n < 6: unbounded]"
    return f"{mean:+.2f} {bounds}"
