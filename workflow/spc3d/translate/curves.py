"""The training-curve figure of a stage-1 model folder (``curve.png``, beside ``curve.csv``).

``plot_curve`` draws every loss and validation value of the curve (the frame that
:func:`spc3d.translate.model_io.write_model_folder` also writes as ``curve.csv``) against the
iteration, one panel each.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from spc3d.plotting import pyplot, save_png


def plot_curve(frame: pd.DataFrame, path: Path, title: str, best_step: int | None = None) -> None:
    """Every loss and validation value against the iteration, one panel each (log scale where all
    positive; validation values as points joined, the kept model's step dashed)."""
    plt = pyplot()

    keys = [c for c in frame.columns if c != "iteration"]
    fig, axes = plt.subplots(1, max(len(keys), 1), figsize=(3.2 * max(len(keys), 1), 2.6), squeeze=False)
    for ax, key in zip(axes[0], keys):
        points = frame[["iteration", key]].dropna()
        validation = key.startswith("val_")
        ax.plot(
            points["iteration"],
            points[key],
            lw=1.2,
            marker="o" if validation else None,
            ms=2.5,
            color="C1" if validation else "C0",
        )
        if (points[key] > 0).all() and not validation:
            ax.set_yscale("log")
        if validation and best_step is not None:
            ax.axvline(best_step, color="0.4", ls="--", lw=0.8)
        ax.set_title(VALIDATION_TITLES.get(key, key), fontsize=9)
        ax.set_xlabel("iteration", fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{title}: training losses" + (" and validation" if "val_psnr" in keys else ""), fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=110)


VALIDATION_TITLES = {"val_psnr": "validation PSNR (dB)", "val_l1": "validation L1"}
