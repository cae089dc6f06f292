"""A row's ``metrics.json`` on one scene and seed: the one record type it is written and read as.

:func:`spc3d.evaluation.evaluate.evaluate` writes it (:func:`write_run`); the tables, the findings,
the stopping table and the sweeps' reports read it (:meth:`RunRecord.read`). The defaults of keys
that older records lack live here and nowhere else: no ``capture_factor`` is S = 1, no
``reference`` is a scene with reference views, ``init`` as a dict (``{"used": ...}``) is the value used.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

from spc3d import io
from spc3d.names import as_read

# What every record names: the row (scene, combination) and whether it has scores ("mean": None when
# not reconstructed or not scored against images). A record without one of these is not a run's.
REQUIRED = ("scene", "combination", "mean")


@dataclass(frozen=True)
class RunRecord:
    """One run of one row: what it consumed, how it trained and its scores (``fields``: the whole
    record as written, e.g. ``per_view``, ``settings``, ``iterations``)."""

    scene: str
    combination: str  # as written: source+model[@poses]
    seed: int | None
    frames: int | None  # K, binary frames per view consumed (None: the oracle)
    capture_factor: int  # S: S x S sensor pixels per image pixel
    reference: bool  # False: a capture without reference views (scored on its held-out photons)
    mean: dict | None  # the scores averaged over the held-out views; None: no image scores
    fields: dict = field(repr=False)

    @classmethod
    def from_dict(cls, rec: dict, where: str = "metrics record") -> RunRecord:
        missing = [k for k in REQUIRED if k not in rec]
        if missing:
            raise ValueError(f"{where}: not a run's metrics record, it lacks {missing} (written by rule evaluate)")
        return cls(
            scene=rec["scene"],
            combination=rec["combination"],
            seed=rec.get("seed"),
            frames=rec.get("frames"),
            capture_factor=rec.get("capture_factor") or 1,
            reference=rec.get("reference") is not False,
            mean=rec["mean"] or None,
            fields=rec,
        )

    @classmethod
    def read(cls, path: str | os.PathLike) -> RunRecord:
        return cls.from_dict(io.read_json(path), str(path))

    def get(self, key: str, default=None):
        """Any key of the record as written (``stopped``, ``at_stop``, ``capacity``, ``poses``, ...)."""
        return self.fields.get(key, default)

    @property
    def row(self) -> str:
        """The row's name as read (a capture's K = 1 frame is its ``-x1`` row: :func:`spc3d.names.as_read`)."""
        return as_read(self.combination, self.frames, self.fields.get("capture_factor"))

    @property
    def budget(self) -> tuple[int | None, int]:
        """(K, S): what the row consumed; rows compare only at one budget."""
        return self.frames, self.capture_factor

    @property
    def init(self):
        """Where a 3DGS fit's points started ("colmap", "random"; None: not recorded)."""
        init = self.fields.get("init")
        return init.get("used") if isinstance(init, dict) else init

    @property
    def scored_on(self) -> str:
        """ "RGB", or luminance where the scene was captured by a colourless sensor."""
        return self.fields.get("scored_on", "RGB")

    @property
    def stopped(self) -> dict | None:
        """Where and why the fit stopped (step, of, reason, the rule); None for a fit without a rule."""
        return self.fields.get("stopped")

    @property
    def at_stop(self) -> dict | None:
        """Observe mode: the scores and training seconds where the rule would have stopped the fit."""
        return self.fields.get("at_stop")

    @property
    def train_s(self) -> float | None:
        return self.fields.get("train_s")

    @property
    def capacity(self) -> dict | None:
        """The model's size at the end (Gaussians, occupied grid cells, ...)."""
        return self.fields.get("capacity")

    def score(self, metric: str) -> float:
        """The mean of ``metric`` over the held-out views; NaN where the run has no such score."""
        value = (self.mean or {}).get(metric)
        return math.nan if value is None else float(value)


def read_runs(paths: list[str | os.PathLike]) -> list[RunRecord]:
    """The records of ``paths``, in order."""
    return [RunRecord.read(p) for p in paths]


def write_run(path: str | os.PathLike, record: dict) -> dict:
    """Write a run's record atomically, after checking it is one (:data:`REQUIRED`)."""
    RunRecord.from_dict(record, str(path))
    io.write_json(path, record)
    return record
