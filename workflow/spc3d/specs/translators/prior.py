"""The physics prior's settings (method ``prior``, :mod:`spc3d.translate.blurred_mle`).
Torch-free, so the workflow checks them when it plans a run (:mod:`spc3d.specs.translators`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Config:
    prior_sigma: float = 2.0  # blur of the prior in pixels (the translators' default; must be > 0)


PAPER: dict = {}  # the paper has no such method: its preset is the default
