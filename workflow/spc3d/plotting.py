"""Matplotlib without a display: the one set-up of every figure the library draws."""

from __future__ import annotations

import os

from spc3d import io


def pyplot():
    """``matplotlib.pyplot`` on the Agg back-end (imported on first use: tables and tests need no GUI)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path: str | os.PathLike, dpi: int) -> None:
    """Write ``fig`` as a PNG atomically (a failed write keeps any earlier figure) and close it."""
    with io.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
