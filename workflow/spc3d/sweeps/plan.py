"""The sweeps' config, checked, turned into what the sweep rules pass on (imports neither torch nor Snakemake).

``workflow/rules/tradeoff.smk`` calls these once while parsing; ``ByCombination`` maps a point's
``{combo}`` wildcard to its values, so a rule can use it directly as an input or params function.
"""

from __future__ import annotations

import pandas as pd

from spc3d.names import BUDGET_SOURCES
from spc3d.sweeps.knobs import check_setting, distinct_rows, split_combination


class ByCombination(dict):
    """combination -> value; called with a rule's wildcards it returns the value of ``wildcards.combo``."""

    def __call__(self, wildcards):
        return self[wildcards.combo]


def sweep_scenes(
    scene: str | None, train: list[str] | None, eval_scenes: list[str], train_scenes: list[str], known: list[str]
) -> tuple[str, list[str]]:
    """(evaluation scene, training scenes) of the sweeps: ``tradeoff.scene`` / ``train_scenes`` or the
    first of ``scenes.eval`` / ``scenes.train``; every name must be ``known`` and the two disjoint.
    A sweep simulates its scene at every budget, so its default is the first evaluation scene that is
    not a capture (or, when all are, the first known scene outside the training ones)."""
    train = list(train_scenes if train is None else train)
    simulated = [s for s in eval_scenes if s in known] or [s for s in known if s not in train]
    scene = scene or simulated[0]
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


def point_base(
    combo: str,
    config: dict,
    scene: str,
    train: list[str],
    specs: dict[str, dict],
    translators: dict[str, tuple[dict, dict]],
) -> dict:
    """The config's values a point of ``combo`` starts from (the ``base`` of :mod:`.budget`).

    ``specs``: scene name -> spec; ``translators``: stage-1 method -> (model overrides, training
    settings), as ``spc3d.names.translator_settings`` resolves them.
    """
    source, model = split_combination(combo)
    translator = None
    if source in translators:
        settings, train_settings = translators[source]
        translator = {
            "settings": settings,
            "train": train_settings,
            "frames": config["stage1"]["frames"],
            "ensemble": config["stage1"]["ensemble"],
        }
    return {
        "seed": config["seed"],
        "scene_name": scene,
        "scene": specs[scene],
        "train_scenes": {name: specs[name] for name in train} if translator or source in BUDGET_SOURCES else {},
        "spc": dict(config["spc"]),
        "augment": dict(config["augment"]),
        "translator": translator,
        "stage2": {"settings": dict(config["stage2"][model]), "frames": config["stage2"]["frames"]},
    }


def scene_inputs(base: dict) -> list[str]:
    """The files of the real LLFF scenes a point reads (poses and images: editing one reruns it)."""
    from spc3d.jobs import llff_input_files

    specs = [base["scene"], *base["train_scenes"].values()]
    return [f for s in specs if s["kind"] == "llff" for f in llff_input_files(s["path"], s["factor"])]


def point_paths(folder: str, table: pd.DataFrame, patterns: list[str], combos: list[str]) -> list[str]:
    """``{folder}/{combo}/{pattern}/metrics.json`` of every combination and table row (``patterns``:
    the rows' Paramspace paths), skipping rows that repeat a point of that combination."""
    paths = []
    for combo in combos:
        keep = distinct_rows(table, combo)
        paths += [f"{folder}/{combo}/{p}/metrics.json" for p, k in zip(patterns, keep, strict=True) if k]
    return paths
