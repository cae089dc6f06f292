"""The classical denoiser's settings and its candidate grid (:mod:`spc3d.translate.classical`).
Torch-free, so the workflow checks them when it plans a run (:mod:`spc3d.specs.translators`)."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

# The candidates: (family, params); NLM's h, TV's weight are in units of the VST's noise σ.
GRID: tuple[tuple[str, dict], ...] = (
    *(("gaussian", {"sigma": s}) for s in (1.0, 1.5, 2.0, 2.5, 3.0)),
    ("nlm", {"patch_size": 3, "patch_distance": 3, "h": 1.0, "subtract": True}),
    ("nlm", {"patch_size": 5, "patch_distance": 4, "h": 1.0, "subtract": True}),
    ("nlm", {"patch_size": 3, "patch_distance": 3, "h": 1.0, "subtract": False}),
    ("nlm", {"patch_size": 5, "patch_distance": 4, "h": 0.8, "subtract": False}),
    ("nlm", {"patch_size": 5, "patch_distance": 4, "h": 1.2, "subtract": False}),
    ("nlm", {"patch_size": 5, "patch_distance": 6, "h": 1.0, "subtract": False}),
    ("wavelet", {"wavelet": "db2", "method": "BayesShrink", "levels": 4}),
    ("wavelet", {"wavelet": "sym4", "method": "BayesShrink", "levels": 4}),
    ("wavelet", {"wavelet": "db1", "method": "BayesShrink", "levels": 4}),
    ("wavelet", {"wavelet": "db2", "method": "VisuShrink", "levels": 4}),
    *(("tv", {"weight": w}) for w in (0.5, 0.75, 1.0, 1.5)),
    ("bm3d", {"stage": "all"}),
    ("bm3d", {"stage": "hard"}),
)
GRID_DIGEST = zlib.crc32(repr(GRID).encode())  # saved with a model: its choice indexes this grid


def label(index: int) -> str:
    """``GRID[index]`` as text, e.g. ``tv(weight=0.75)``."""
    name, params = GRID[index]
    return f"{name}({', '.join(f'{k}={v}' for k, v in params.items())})"


FAMILIES = tuple(dict.fromkeys(name for name, _ in GRID))  # in the grid's order


def pinned_index(choice: str, params: dict | None) -> int:
    """The GRID index of family ``choice`` at ``params`` (None: the family's only candidate)."""
    found = [i for i, (n, p) in enumerate(GRID) if n == choice and (params is None or p == dict(params))]
    if len(found) != 1:
        options = [label(i) for i, (n, _) in enumerate(GRID) if n == choice]
        raise ValueError(f"choice = {choice!r}, params = {params}: not one candidate of the grid; pin one of {options}")
    return found[0]


@dataclass(frozen=True)
class Config:
    denoisers: tuple[str, ...] = ("gaussian", "nlm", "wavelet", "tv", "bm3d")  # families searched (if installed)
    choice: str | None = None  # pin one family (skips the search), at `params`; None: search
    params: dict | None = None  # the pinned candidate's GRID params, e.g. {sigma: 2.0} (None: its only one)
    calibration_every: int = 4  # the search fits each candidate's gain on every n-th training pair
    frames: int = 1  # K frames per input: set by the training job from stage1.frames, not here

    def __post_init__(self):
        unknown = [n for n in (*self.denoisers, self.choice) if n is not None and n not in FAMILIES]
        if unknown or not self.denoisers:
            raise ValueError(
                f"denoisers = {list(self.denoisers)}, choice = {self.choice!r}: unknown denoiser {unknown} "
                f"(or none listed); choose from {list(FAMILIES)}"
            )
        if self.frames < 1 or self.calibration_every < 1:
            raise ValueError(f"frames = {self.frames}, calibration_every = {self.calibration_every}: must be >= 1")
        if self.choice is not None:
            pinned_index(self.choice, self.params)


PAPER: dict = {}  # the paper has no such method: its preset is the default
