"""Figures and report files of the sweeps (no torch); the tables and Pareto fronts come from :mod:`.pareto`.

Both reports take the sweep's points (:func:`spc3d.sweeps.plan.sweep_points`, each with the
benchmark TSVs of its jobs). A point's wall (CPU) time is the sum of the wall (user + system CPU)
times of every job it needs, its peak memory the largest of theirs; a job shared by several points
(the scene and SPC data of a setting, shared by the combinations swept at it) counts in each
point that needs it, so each point's time is what it would cost run alone
(:func:`spc3d.sweeps.pareto.point_record`).

``tradeoff_report``: ``tradeoff.csv`` (the table of :func:`spc3d.sweeps.pareto.tradeoff_table`: one
row per point with its knobs, times, memory, scores and whether it is on its combination's
PSNR-time Pareto front) and the figure: PSNR and LPIPS-alex against wall (or CPU) time, one colour
per combination, points numbered by setting (the settings are listed under the panels), each front
as a step line (the best quality reachable within a time budget).

``photon_level_report``: ``photon_level.csv`` and the figure: PSNR and LPIPS-alex against the mean
detection probability (logit axis), one line per (combination, K), and in grey the PSNR of the MLE
image itself before 3D.
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd

from spc3d import io
from spc3d.plotting import pyplot, save_png
from spc3d.sweeps.knobs import KNOBS, label
from spc3d.sweeps.pareto import clock_column, front_steps, photon_table, tradeoff_table

K_STYLES = ("-", "--", "-.", (0, (5, 1)), (0, (3, 1, 1, 1, 1, 1)))
K_MARKERS = ("o", "s", "^", "D", "v", "P")


def tradeoff_figure(
    table: pd.DataFrame, out_png: str | os.PathLike, labels: dict[str, str] | None = None, clock: str = "wall"
) -> None:
    """PSNR and LPIPS-alex against time (log), fronts as step lines, points labelled by setting."""
    plt = pyplot()
    time_key = clock_column(clock)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.6))
    colours = plt.get_cmap("tab10").colors
    panels = (("psnr", "PSNR (dB) ↑", 1.0), ("lpips_alex", "LPIPS-alex ↓", -1.0))
    for ax, (key, ylabel, sign) in zip(axes, panels):
        for i, (combo, group) in enumerate(table.groupby("combination", sort=False)):
            c = colours[i % len(colours)]
            ax.scatter(group[time_key], group[key], color=c, s=30, zorder=3, label=_combo_label(combo, labels))
            t, q = front_steps(group[time_key], sign * group[key])
            ax.step(np.append(t, t[-1] * 1.15), sign * np.append(q, q[-1]), where="post", color=c, lw=1.3, alpha=0.8)
            for _, row in group.iterrows():
                ax.annotate(
                    str(row["setting"]),
                    (row[time_key], row[key]),
                    fontsize=8,
                    color=c,
                    textcoords="offset points",
                    xytext=(4, 4),
                    fontweight="bold",
                )
        _log_seconds(ax)
        ax.set_xlabel(f"{'wall' if clock == 'wall' else 'CPU'} time of the whole point (s, log scale; 1 thread)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8, title="combination (line: Pareto front)", title_fontsize=8)
    fig.suptitle("Speed–accuracy trade-off: held-out view quality against the time of the whole pipeline", fontsize=11)
    fig.text(0.01, 0.01, setting_legend(table), fontsize=7.5, family="monospace", va="bottom")
    fig.tight_layout(rect=(0, 0.03 + 0.028 * table["setting"].nunique(), 1, 1))
    save_png(fig, out_png, dpi=130)


def setting_legend(table: pd.DataFrame) -> str:
    """One line per numbered setting with every knob that varies in the table."""
    knobs = [k for k in KNOBS if k in table.columns and table[k].nunique() > 1]
    first = table.drop_duplicates("setting").sort_values("setting")
    lines = [f"{row['setting']:>2}: {label(row.to_dict(), knobs)}" for _, row in first.iterrows()]
    return "settings (a combination ignores the knobs it does not use):\n" + "\n".join(lines)


def _log_seconds(ax) -> None:
    """Log x axis with plain-number tick labels (no overlapping minor labels)."""
    from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

    ax.set_xscale("log")
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.margins(x=0.12)


def photon_figure(table: pd.DataFrame, out_png: str | os.PathLike, labels: dict[str, str] | None = None) -> None:
    """PSNR and LPIPS-alex against mean detection probability (logit axis), a line per (combination, K)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.0))
    colours = plt.get_cmap("tab10").colors
    ks = sorted(table["K"].unique())
    for ax, (key, ylabel) in zip(axes, (("psnr", "PSNR (dB) ↑"), ("lpips_alex", "LPIPS-alex ↓"))):
        for i, (combo, group) in enumerate(table.groupby("combination", sort=False)):
            for k, line in group.groupby("K"):
                style = dict(
                    color=colours[i % len(colours)],
                    ls=K_STYLES[ks.index(k) % len(K_STYLES)],
                    marker=K_MARKERS[ks.index(k) % len(K_MARKERS)],
                    ms=4,
                    lw=1.4,
                )
                ax.plot(line["detection"], line[key], label=f"{_combo_label(combo, labels)}, K={k}", **style)
                if key == "psnr" and combo.startswith("mle+") and line["stage1_psnr"].notna().any():
                    ax.plot(
                        line["detection"],
                        line["stage1_psnr"],
                        color="0.35",
                        ls=style["ls"],
                        lw=1.0,
                        marker=style["marker"],
                        ms=3,
                        mfc="none",
                        label=f"MLE image alone (no 3D), K={k}",
                    )
        _logit_levels(ax, sorted(table["detection"].unique()))
        ax.set_ylabel(ylabel)
    handles, names = axes[0].get_legend_handles_labels()
    rows = -(-len(names) // 3)
    fig.legend(handles, names, loc="lower center", ncol=3, fontsize=7.5, frameon=False)
    fig.suptitle("Quality against photon level (exposure) and number of binary frames K", fontsize=11)
    fig.tight_layout(rect=(0, 0.035 * rows + 0.01, 1, 1))
    save_png(fig, out_png, dpi=130)


def _logit_levels(ax, levels: list[float]) -> None:
    """Logit x axis ticked at the swept detection levels, labelled as plain numbers."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    ax.set_xscale("logit")
    ax.xaxis.set_major_locator(FixedLocator(levels))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xlabel("mean detection probability per binary frame (logit scale)")
    ax.grid(alpha=0.3)


def _combo_label(combo: str, labels: dict[str, str] | None) -> str:
    source, _, model = combo.partition("+")
    return f"{(labels or {}).get(source, source)} + {model}"


def tradeoff_report(
    points: list[dict],
    combos: list[str],
    out_csv: str | os.PathLike,
    out_png: str | os.PathLike,
    labels: dict[str, str] | None = None,
    clock: str = "wall",
) -> pd.DataFrame:
    """Write the trade-off table and figure (Pareto front against ``clock``); return the table."""
    table = tradeoff_table(points, combos, clock)
    io.write_text(out_csv, table.to_csv(index=False, float_format="%.4g"))
    tradeoff_figure(table, out_png, labels, clock)
    return table


def photon_level_report(
    points: list[dict],
    combos: list[str],
    out_csv: str | os.PathLike,
    out_png: str | os.PathLike,
    labels: dict[str, str] | None = None,
) -> pd.DataFrame:
    """Write the photon-level table and figure; return the table."""
    table = photon_table(points, combos)
    io.write_text(out_csv, table.to_csv(index=False, float_format="%.4g"))
    photon_figure(table, out_png, labels)
    return table
