"""Figures a person would rather look at than a table.

``qualitative_figure``: the paper's Figure 2 for one evaluation scene: one held-out view as the
binary SPC input, every combination's render (titled with its PSNR on that view) and the ground
truth, in one row per ``per_row`` panels.
"""

from __future__ import annotations

import math
import os
import textwrap
from pathlib import Path

import numpy as np

from spc3d import io, llff
from spc3d.cameras import split_views
from spc3d.evaluation import scores
from spc3d.names import source_label
from spc3d.plotting import pyplot, save_png


def pick_view(scene_dir: str | os.PathLike, view: str | None = None) -> str:
    """``view`` if given (must be a held-out view), else the scene's first held-out view."""
    names = llff.read_scene(scene_dir).names
    _, test = split_views(len(names))
    held_out = [names[i] for i in test]
    if view is None:
        return held_out[0]
    if view not in held_out:
        raise ValueError(f"figure view {view!r} is not a held-out view of {scene_dir}; choose one of {held_out}")
    return view


def qualitative_figure(
    scene_dir: str | os.PathLike,
    spc_dir: str | os.PathLike,
    recon_dirs: dict[str, str],
    out_png: str | os.PathLike,
    labels: dict[str, str] | None = None,
    view: str | None = None,
    per_row: int = 6,
) -> str:
    """Binary input | renders of ``recon_dirs`` (combination -> recon folder) | ground truth."""
    view = pick_view(scene_dir, view)
    gt = io.read_rgb(Path(scene_dir) / "images" / f"{view}.png")
    panels = [("binary SPC input (K=1)", io.read_rgb(Path(spc_dir) / "binary" / f"{view}.png"))]
    for combo, folder in recon_dirs.items():
        if not (Path(folder) / "renders").is_dir():
            continue  # not reconstructed (its train.json says why, e.g. COLMAP posed too few views)
        img = io.read_rgb(Path(folder) / "renders" / f"{view}.png")
        source, model = combo.split("+", 1)
        name = f"{source_label(source, labels or {})} + {model}"
        panels.append((f"{name}\n{scores.psnr(img, gt):.2f} dB", img))
    panels.append(("ground truth", gt))
    _draw(panels, out_png, f"{Path(scene_dir).name}, held-out view {view}", per_row)
    return view


TITLE_CHARS = 34  # characters per title line at 7 pt in a 2.4-inch panel: longer labels wrap
TITLE_LINE_IN = 0.13  # height of one 7-pt title line (inches)


def wrap_title(label: str, width: int = TITLE_CHARS) -> str:
    """``label`` with each of its lines wrapped at ``width`` characters (words kept whole), so long
    row names stay inside their panel instead of running into the next one's title."""
    return "\n".join(textwrap.fill(line, width, break_long_words=False) or line for line in label.split("\n"))


def _draw(panels: list[tuple[str, np.ndarray]], out_png, title: str, per_row: int) -> None:
    save_png(panel_figure(panels, title, per_row), out_png, dpi=120)


def panel_figure(panels: list[tuple[str, np.ndarray]], title: str, per_row: int):
    """A figure of titled image panels, ``per_row`` to a row, each title wrapped to its panel."""
    plt = pyplot()
    cols = min(per_row, len(panels))
    rows = math.ceil(len(panels) / cols)
    h, w = panels[0][1].shape[:2]
    titles = [wrap_title(label) for label, _ in panels]
    lines = max(t.count("\n") + 1 for t in titles)
    height = rows * (2.4 * h / w + lines * TITLE_LINE_IN + 0.2)
    fig, axes = plt.subplots(rows, cols, figsize=(2.4 * cols, height + 0.4), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, label, (_, img) in zip(axes.flat, titles, panels):
        ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
        ax.set_title(label, fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
