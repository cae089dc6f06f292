"""The sweeps' config, checked, turned into what the rules pass on (imports neither torch nor Snakemake).

A sweep point is an ordinary set of DAG jobs: the grid's own rules, from the scene to its metrics,
with a *settings overlay* in their paths, the ``{overlay}`` wildcard right
after ``results/`` (and after ``logs/{rule}/``, ``benchmarks/{rule}/``)::

    results/eval/courtyard/gt+3dgs/metrics.json                                   (the grid: overlay "")
    results/sweeps/tradeoff/iters~300/res~64/eval/courtyard/gt+3dgs/metrics.json  (a trade-off point)
    results/sweeps/photon_level/detection~0.02/K~1/eval/courtyard/mle+3dgs/metrics.json

The overlay names the sweep and one setting (its Paramspace path: ``knob~value`` segments), so a
job's settings object is found from the wildcard alone (:meth:`Settings.at`): the grid's
(:class:`spc3d.settings.Grid`) for the empty overlay, which leaves every path and param of the grid
unchanged, else a :class:`Point`, the grid's answers with the knobs applied (:class:`PointSettings`,
:mod:`.budget`). A setting's jobs are shared by every combination swept at it (one scene, one SPC
folder, one translator of a method at that setting), as the grid shares them between its rows.
:func:`sweep_points` lists each point's files and jobs for the report rules.
"""

from __future__ import annotations

import re

import pandas as pd

from spc3d.names import (
    BUDGET_SOURCES,
    PLAIN_SOURCES,
    SOURCE_IMAGES,
    parse_source,
    source_frames,
    spc_settings,
    uses_display,
)
from spc3d.settings import Grid, Paths
from spc3d.sweeps.knobs import KNOBS, check_setting, distinct_rows, split_combination, used_knobs

SWEEPS = ("tradeoff", "photon_level")
# The overlay wildcard: "" (the grid) or sweeps/<sweep>/<knob>~<value>/... (one setting of a sweep).
OVERLAY_PATTERN = rf"(sweeps/({'|'.join(SWEEPS)})/(({'|'.join(KNOBS)})~[0-9.e+-]+/)+)?"


def overlay(sweep: str, pattern: str) -> str:
    """The overlay of one setting: ``sweeps/{sweep}/{pattern}/`` (``pattern``: a Paramspace path)."""
    if sweep not in SWEEPS:
        raise ValueError(f"unknown sweep {sweep!r}; use one of {list(SWEEPS)}")
    return f"sweeps/{sweep}/{pattern.strip('/')}/"


def parse_overlay(value: str) -> tuple[str, dict]:
    """``"sweeps/tradeoff/iters~300/res~64/"`` -> ``("tradeoff", {"iters": 300, "res": 64})``;
    ``""`` (the grid) -> ``("", {})``."""
    if not value:
        return "", {}
    if not re.fullmatch(OVERLAY_PATTERN, value):
        raise ValueError(f"{value!r} is not a sweep overlay (sweeps/<sweep>/<knob>~<value>/...)")
    _, sweep, *parts = value.strip("/").split("/")
    return sweep, check_setting(dict(p.split("~", 1) for p in parts), f"overlay {value}")


class PointSettings:
    """The settings a rule's job runs with under an overlay: the config's values with the point's knobs
    applied, as :mod:`.budget` resolves them (the same functions for every rule, so the stages agree).

    ``specs``: the sweeps' scene specs (name -> spec); ``scene`` and ``train``: the sweeps'
    evaluation and training scenes;
    ``photon_budget``: the knobs every photon-level point shares (``photon_level.budget``).
    """

    def __init__(self, config: dict, specs: dict[str, dict], scene: str, train: list[str], photon_budget: dict):
        self.config, self.specs, self.photon_budget = config, specs, photon_budget
        self.scene_name, self.train = scene, list(train)

    def setting(self, value: str) -> dict:
        """The knobs of an overlay (a photon-level point's shared budget under its own K and detection)."""
        sweep, knobs = parse_overlay(value)
        return {**self.photon_budget, **knobs} if sweep == "photon_level" else knobs

    def scene(self, value: str, scene: str) -> dict:
        """The scene's spec at the point's width (``res``)."""
        from spc3d.sweeps.budget import scale_spec

        return scale_spec(self.specs[scene], self.setting(value).get("res"))

    def spc(self, value: str) -> dict:
        """simulate_scene's settings: K frames per view and the calibration target ``detection``;
        no finer capture frame (S = 1: the capture frame is frame 0)."""
        knobs = self.setting(value)
        settings = spc_settings(self.config["spc"], self.config["seed"], knobs.get("K"), knobs.get("detection"))
        return settings | {"capture_factor": 1}

    def frames(self, value: str, source: str) -> int | None:
        """Binary frames per view the source uses: K if the point sets it, else the config's value
        (None for the oracle ``gt``, 1 for the binary frame ``none``)."""
        if source in ("gt", "none"):
            return None if source == "gt" else 1
        knobs, config = self.setting(value), self.config
        if "K" in knobs:
            return knobs["K"]
        return source_frames(source, config["stage1"]["frames"], config["stage2"]["frames"])

    def translator(self, value: str, method: str, settings: dict, train: dict) -> tuple[dict, dict]:
        """(model overrides, training settings) of ``method`` with ``width`` and ``steps`` applied
        and a training crop that fits the point's evaluation images."""
        from spc3d.sweeps.budget import translator_settings

        return translator_settings(settings, train, method, self.setting(value), self.scene(value, self.scene_name))

    def stage2(self, value: str, model: str, settings: dict) -> dict:
        """Every setting of the stage-2 model with ``iters``, ``cap`` and ``grid`` applied."""
        from spc3d.sweeps.budget import stage2_settings

        return stage2_settings(settings, model, self.setting(value))


class Point(Grid):
    """What a job of one sweep point (``overlay``) runs with: the grid's answers (:class:`Grid`)
    with the point's knobs applied (``points``: :class:`PointSettings`). A point has its own
    scenes and training scenes (no folds, no captures, no COLMAP init, no chosen joint weight),
    simulates no finer capture frame (S = 1) and trains its translators on fixed pairs, unvalidated."""

    def __init__(self, grid: Grid, points: PointSettings, overlay: str):
        vars(self).update(vars(grid))  # the grid's configuration, code location, ...
        self.specs, self.folds, self.train = points.specs, {"": points.train}, points.train
        self.eval = [points.scene_name]
        self.paths, self.no_reference, self.joint_choose = Paths(overlay), [], {}
        self.points, self.overlay = points, overlay

    def frames(self, w) -> int | None:
        return self.points.frames(self.overlay, w.source)

    def fold(self, w) -> str:
        return ""

    def scene_spec(self, w) -> dict:
        """The scene's spec at the point's width (knob ``res``)."""
        return self.points.scene(self.overlay, w.scene)

    def spc(self, w) -> dict:
        return self.points.spc(self.overlay)

    def capture_factor(self, w) -> int:
        return 1

    def sensor(self, w) -> str:
        return ""

    def display(self, w) -> str:
        """The metered MLE images of the point's K."""
        return self.paths.display(w.scene, f"k{self.frames(w)}")

    def translator(self, w) -> tuple[dict, dict]:
        """The method's settings with the point's ``width`` and ``steps`` and a crop that fits."""
        return self.points.translator(self.overlay, w.method, *super().translator(w))

    def translator_frames(self, w) -> int:
        return self.points.frames(self.overlay, w.method)

    def translator_data(self, w) -> str:
        return "fixed"

    def translator_validation(self, w) -> dict:
        return {"every": 0}

    def source_kind(self, w) -> tuple[str, str]:
        """A point's binary frame is frame 0 (S = 1)."""
        return SOURCE_IMAGES[parse_source(w.source).base]

    def model_settings(self, w) -> dict:
        """The row's stage-2 settings at the point's budget (``iters``, ``cap``, ``grid``)."""
        return self.points.stage2(self.overlay, w.model, super().model_settings(w))

    def init(self, w) -> None:
        """A point starts from random points, as every source alike (None: recorded so)."""
        return None


class Settings:
    """Each job's settings object by its overlay: ``grid`` for "" (the grid's jobs), a
    :class:`Point` of ``points`` for a sweep point's (made once per overlay)."""

    def __init__(self, grid: Grid, points: PointSettings):
        self.grid, self.points = grid, points
        self._made: dict[str, Point] = {}

    def at(self, overlay: str) -> Grid:
        if not overlay:
            return self.grid
        if overlay not in self._made:
            self._made[overlay] = Point(self.grid, self.points, overlay)
        return self._made[overlay]


def sweep_scenes(
    scene: str | None, train: list[str] | None, eval_scenes: list[str], train_scenes: list[str], known: list[str]
) -> tuple[str, list[str]]:
    """(evaluation scene, training scenes) of the sweeps: ``tradeoff.scene`` / ``train_scenes`` or the
    first of ``scenes.eval`` / ``scenes.train``; every name must be ``known`` and the two disjoint.
    A sweep simulates its scene at every budget, so its default is the first evaluation scene that is
    not a capture (or, when all are, the first known scene outside the training ones). Defaulted
    training scenes leave the sweep's scene out (leave-one-scene-out: it may be among scenes.train)."""
    given = train is not None
    train = list(train_scenes if train is None else train)
    simulated = [s for s in eval_scenes if s in known] or [s for s in known if s not in train]
    scene = scene or simulated[0]
    if not given:
        train = [s for s in train if s != scene]
    for key, names in (("tradeoff.scene", [scene]), ("tradeoff.train_scenes", train)):
        for name in names:
            if name not in known:
                raise ValueError(
                    f"{key}: unknown scene {name!r}; use a built-in layout or an llff_scenes name ({', '.join(known)})"
                )
    if scene in train:
        raise ValueError(f"tradeoff.scene {scene!r} is also in tradeoff.train_scenes: evaluate held-out content")
    return scene, train


def photon_budget(budget: dict) -> dict:
    """``photon_level.budget``, checked: the knobs every photon-level point shares (not the swept K, detection)."""
    budget = check_setting(budget, "photon_level.budget")
    for swept, key in (("K", "frames"), ("detection", "detection")):
        if swept in budget:
            raise ValueError(f"photon_level.budget: knob {swept!r} is swept by photon_level.{key}; remove it here")
    return budget


def point_outputs(combo: str, value: str, scene: str, train: list[str], frames: int | None) -> list[str]:
    """What each job a point needs makes, under overlay ``value`` (not the shared LPIPS weights): the
    evaluation scene's and, for a translator or a metered display (``frames``: the source's K), the
    training scenes' folders; the translator; the source's scores before 3D; the fit and its metrics.
    One output per job, in the order they run: the workflow finds each job's rule by its output
    pattern (workflow/rules/common.smk), so the library names no rule."""
    source, model = split_combination(combo)
    stage1, trained = source not in PLAIN_SOURCES, source not in PLAIN_SOURCES or source in BUDGET_SOURCES
    if trained and not train:
        raise ValueError(f"{combo}: source {source!r} needs training scenes (tradeoff.train_scenes is empty)")
    paths, scenes = Paths(value), [scene, *train] if trained else [scene]  # a point: its own training scenes
    outputs = [paths.scene(s) for s in scenes]
    if source != "gt":
        outputs += [paths.spc(s) for s in scenes]
    if uses_display(source):
        outputs += [paths.calibration("", f"k{frames}"), paths.display(scene, f"k{frames}")]  # the MLE of the point's K
    if stage1:
        method = parse_source(source).method  # a joint row's prior term: that method's translation
        outputs += [paths.augment(s) for s in train] + [paths.model(method), paths.translated(scene, method)]
    if source_scored(source):
        outputs.append(paths.stage1(scene, source))
    return outputs + [paths.recon(scene, combo), paths.metrics(scene, combo)]


def source_scored(source: str) -> bool:
    """Whether a point scores its source's images before 3D (translated, MLE, binary; not gt, bernoulli)."""
    return SOURCE_IMAGES.get(source, (None,))[0] in ("translated", "display", "spc")


def sweep_points(
    sweep: str, space_table: pd.DataFrame, patterns: list[str], combos: list[str], points: PointSettings, scene: str
) -> list[dict]:
    """Every point of a sweep (combination x table row, skipping rows that repeat a point of that
    combination): its combination, setting, overlay, the files the report reads (``metrics``,
    ``stage1``, ``recon``, ``model``, ``spc``: paths, or None where the point has none) and its jobs'
    ``outputs`` (:func:`point_outputs`). A point that cannot run (e.g. a translator without training
    scenes) carries its ``error`` instead: the sweep is planned whenever the Snakefile is parsed,
    but the error is raised only when its report is asked for (:func:`point_inputs`)."""
    out = []
    for combo in combos:
        source, model = split_combination(combo)
        for pattern, keep in zip(patterns, distinct_rows(space_table, combo), strict=True):
            if not keep:
                continue
            value = overlay(sweep, pattern)
            paths = Paths(value)
            out.append(
                {
                    "combination": combo,
                    "setting": points.setting(value),
                    "used_knobs": [k for k in used_knobs(combo) if k in points.setting(value)],
                    "overlay": value,
                    "metrics": paths.metrics(scene, combo),
                    "stage1": paths.stage1(scene, source) if source_scored(source) else None,
                    "recon": paths.recon(scene, combo),
                    "model": paths.model(parse_source(source).method) if source not in PLAIN_SOURCES else None,
                    "spc": paths.spc(scene) if source != "gt" else None,
                    **planned_outputs(combo, value, scene, points.train, points.frames(value, source), points),
                }
            )
    return out


def planned_outputs(
    combo: str, value: str, scene: str, train: list[str], frames: int | None, points: PointSettings | None = None
) -> dict:
    """``{"outputs": ...}`` of a point, or ``{"outputs": [], "error": why}`` when it cannot run: its jobs
    cannot be planned, or its settings contradict each other (:func:`spc3d.checks.crosscheck.check_point`,
    the main configuration's cross-checks with the point's knobs applied)."""
    from spc3d.checks.crosscheck import check_point

    try:
        outputs = point_outputs(combo, value, scene, train, frames)
        if points is not None:
            check_point(points, combo, value)
        return {"outputs": outputs}
    except ValueError as e:
        return {"outputs": [], "error": str(e)}


def point_inputs(points: list[dict]) -> list[str]:
    """The files of the points a report reads (its rule's inputs); the first point that cannot run
    stops here, naming why."""
    for p in points:
        if p.get("error"):
            raise ValueError(f"{p['overlay']}: {p['error']}")
    keys = ("metrics", "stage1", "recon", "model", "spc")
    return list(dict.fromkeys(p[k] for p in points for k in keys if p[k]))
