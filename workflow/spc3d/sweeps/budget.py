"""A sweep point's settings of every stage: the config's values with the point's knobs applied.

``base`` holds the config's values for one combination, as the workflow passes them::

    {"seed": 0,
     "scene_name": "courtyard",        # the evaluation scene ...
     "scene": {...},                   # ... and its spec (spc3d.inputs.build.prepare_scene)
     "train_scenes": {name: {...}},    # specs of the stage-1 training scenes (disjoint from it)
     "spc": {...},                     # the config's spc block
     "augment": {...},                 # the config's augment block (count = total pairs)
     "translator": {"settings": {...}, "train": {...}, "frames": 1} | None,   # stage-1 method's block
     "stage2": {"settings": {...}, "frames": 1}}                              # the model's block

Iteration-valued schedules (densification, SH steps, grid growth) scale with ``iters`` so a
shorter run keeps the shape of the default one; the grid schedule's resolutions scale so that
it ends at ``grid``.
"""

from __future__ import annotations

import dataclasses

from spc3d import models
from spc3d.inputs.augment import split_count
from spc3d.names import BUDGET_SOURCES, PLAIN_SOURCES, STAGE1_METHODS, spc_settings
from spc3d.sweeps.knobs import check_setting, split_combination, used_knobs
from spc3d.training import build_config

# From the model specs (spc3d.models): the translator's main width (``width`` knob) per stage-1
# method with a network (not ``prior``), and the stage-2 settings counted in iterations (``iters``).
WIDTH_KEYS = {name: spec.width_field for name, spec in models.TRANSLATORS.items() if spec.width_field}
ITERATION_FIELD = {name: spec.iteration_field for name, spec in models.RECONSTRUCTORS.items()}
SCHEDULE_FIELDS = {name: spec.schedule_fields for name, spec in models.RECONSTRUCTORS.items()}
CROP_MULTIPLE = 16  # translator training crops: a multiple of every default network's stride


def resolve_point(base: dict, setting: dict, combo: str) -> dict:
    """Every stage's settings of ``combo`` at ``setting`` (see the module docstring for ``base``)."""
    source, model = split_combination(combo)
    knobs = check_setting(setting, f"{combo} setting")
    scene = scale_spec(base["scene"], knobs.get("res"))
    stage1 = source not in PLAIN_SOURCES
    if stage1 and not base.get("translator"):
        raise ValueError(f"{combo}: source {source!r} is a stage-1 method but no translator settings were given")
    trained = stage1 or source in BUDGET_SOURCES  # translators learn from them; metered rows fit their display level
    train_scenes = {n: scale_spec(s, knobs.get("res")) for n, s in base["train_scenes"].items()} if trained else {}
    if trained and not train_scenes:
        raise ValueError(f"{combo}: source {source!r} needs training scenes (tradeoff.train_scenes is empty)")
    if base["scene_name"] in train_scenes:
        raise ValueError(f"{combo}: scene {base['scene_name']!r} is both evaluated and trained on; keep them apart")
    spc = spc_settings(base["spc"], base["seed"], frames=knobs.get("K"), detection=knobs.get("detection"))
    return {
        "combination": combo,
        "source": source,
        "model": model,
        "seed": base["seed"],
        "setting": knobs,
        "used_knobs": used_knobs(combo),
        "scene_name": base["scene_name"],
        "scene": scene,
        "train_scenes": train_scenes,
        "spc": spc,
        "frames": source_frames(base, source, knobs, spc),
        "augment": augment_settings(base["augment"], list(train_scenes) if stage1 else []),
        "translator": translator_settings(base["translator"], source, knobs, scene) if stage1 else None,
        "stage2": stage2_settings(base["stage2"]["settings"], model, knobs),
    }


def scale_spec(spec: dict, res: int | None) -> dict:
    """A scene spec at width ``res``; a built-in scene's height keeps the spec's aspect ratio."""
    spec = dict(spec)
    if res is None:
        return spec
    if spec["kind"] == "builtin":
        spec["height"] = max(8, round(res * spec["height"] / spec["width"]))
    spec["width"] = res
    return spec


def source_frames(base: dict, source: str, knobs: dict, spc: dict) -> int | None:
    """Binary frames the source uses: K if given, else the config's value for that source."""
    if source == "gt":
        return None  # the oracle: no photons
    if source == "none":
        return 1  # frame 0
    if "K" in knobs:
        return knobs["K"]
    return base["stage2"]["frames"] if source in BUDGET_SOURCES else base["translator"]["frames"]


def augment_settings(augment: dict, train_names: list[str]) -> dict:
    """Augmentation ranges and the pairs of each training scene (the total split as the workflow does)."""
    ranges = {k: v for k, v in augment.items() if k != "count"}
    counts = {n: split_count(augment["count"], len(train_names), i) for i, n in enumerate(train_names)}
    return {"settings": ranges, "counts": counts}


def translator_settings(translator: dict, method: str, knobs: dict, scene: dict) -> dict:
    """The method's model overrides with ``width``, training settings with ``steps`` and a crop that fits."""
    from spc3d.translate.train import TrainSettings

    if method not in STAGE1_METHODS:
        raise ValueError(f"unknown stage-1 method {method!r}; choose one of {sorted(STAGE1_METHODS)}")
    settings = dict(translator["settings"])
    if "width" in knobs and method in WIDTH_KEYS:  # the prior alone has no network to widen
        settings[WIDTH_KEYS[method]] = knobs["width"]
    train = dataclasses.asdict(build_config(TrainSettings, dict(translator["train"]), "stage1.train"))
    if "steps" in knobs:
        train["iterations"] = knobs["steps"]
    train["crop"] = fit_crop(train["crop"], scene)
    return {"method": method, "settings": settings, "train": train}


def fit_crop(crop: int, scene: dict) -> int:
    """The largest multiple of 16 at most ``crop`` and the image's shorter side (at least 16)."""
    side = min(crop, scene["width"], scene.get("height", scene["width"]))
    fitted = side // CROP_MULTIPLE * CROP_MULTIPLE
    if fitted < CROP_MULTIPLE:
        raise ValueError(f"res={scene['width']}: images are too small for {CROP_MULTIPLE}-pixel translator crops")
    return fitted


def stage2_config(model: str, settings: dict):
    """The model's resolved config dataclass (as spc3d.reconstruct.RECONSTRUCTORS builds it)."""
    if model == "3dgs":
        from spc3d.reconstruct.gaussians import GaussianConfig

        return build_config(GaussianConfig, settings, "stage2.3dgs")
    if model == "nerf-grid":
        from spc3d.reconstruct.nerf_grid import GridConfig

        return build_config(GridConfig, settings, "stage2.nerf-grid")
    from spc3d.reconstruct.nerf import NerfConfig, nerf_preset

    settings = dict(settings)
    return build_config(NerfConfig, settings, "stage2.nerf", nerf_preset(settings.pop("preset", "paper")))


def stage2_settings(settings: dict, model: str, knobs: dict) -> dict:
    """Every setting of the stage-2 model (a complete override dict) with iters / cap / grid applied."""
    cfg = dataclasses.asdict(stage2_config(model, settings))
    if "iters" in knobs:
        factor = knobs["iters"] / cfg[ITERATION_FIELD[model]]
        cfg[ITERATION_FIELD[model]] = knobs["iters"]
        for key in SCHEDULE_FIELDS[model]:
            cfg[key] = max(1, round(cfg[key] * factor))
        if model == "nerf-grid":
            cfg["res_schedule"] = [[round(it * factor), r] for it, r in cfg["res_schedule"]]
    if model == "3dgs" and "cap" in knobs:
        cfg["max_gaussians"] = knobs["cap"]
        cfg["init_points"] = min(cfg["init_points"], knobs["cap"])
    if model == "nerf-grid" and "grid" in knobs:
        final = cfg["res_schedule"][-1][1]
        cfg["res_schedule"] = [[it, max(4, round(r * knobs["grid"] / final))] for it, r in cfg["res_schedule"]]
    return cfg
