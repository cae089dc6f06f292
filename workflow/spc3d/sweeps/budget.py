"""A sweep point's settings of one stage: the config's values with the point's knobs applied.

Called by :class:`spc3d.sweeps.plan.PointSettings` for the job a point's settings object answers
(:class:`spc3d.sweeps.plan.Point`): a scene's spec at the point's width (:func:`scale_spec`), the
translator's width, steps and training crop (:func:`translator_settings`), the stage-2 model's
iterations, Gaussian cap and grid resolution (:func:`stage2_settings`).

Iteration-valued schedules (densification, SH steps, grid growth) scale with ``iters`` so a
shorter run keeps the shape of the default one; the grid schedule's resolutions scale so that
it ends at ``grid``.
"""

from __future__ import annotations

import dataclasses

from spc3d import specs
from spc3d.names import STAGE1_METHODS
from spc3d.specs.build import build_config
from spc3d.specs.reconstructors import reconstructor_config
from spc3d.specs.translators import TrainSettings, model_config

# From the model specs (spc3d.specs): the translator's main width (``width`` knob) per stage-1
# method with a network (not the untrained ``prior`` / ``classical``), and the stage-2 settings counted
# in iterations (``iters``).
WIDTH_KEYS = {name: spec.width_field for name, spec in specs.TRANSLATORS.items() if spec.width_field}
ITERATION_FIELD = {name: spec.iteration_field for name, spec in specs.RECONSTRUCTORS.items()}
SCHEDULE_FIELDS = {name: spec.schedule_fields for name, spec in specs.RECONSTRUCTORS.items()}
CROP_MULTIPLE = 16  # translator training crops: at least a multiple of this (and of the network's own)


def scale_spec(spec: dict, res: int | None) -> dict:
    """A scene spec at width ``res``; a built-in scene's height keeps the spec's aspect ratio."""
    spec = dict(spec)
    if res is None:
        return spec
    if spec["kind"] == "builtin":
        spec["height"] = max(8, round(res * spec["height"] / spec["width"]))
    spec["width"] = res
    return spec


def translator_settings(settings: dict, train: dict, method: str, knobs: dict, scene: dict) -> tuple[dict, dict]:
    """(the method's model overrides with ``width``, its training settings with ``steps`` and a crop
    that fits ``scene``'s images)."""
    if method not in STAGE1_METHODS:
        raise ValueError(f"unknown stage-1 method {method!r}; choose one of {sorted(STAGE1_METHODS)}")
    settings = dict(settings)
    if "width" in knobs and method in WIDTH_KEYS:  # an untrained method has no network to widen
        settings[WIDTH_KEYS[method]] = knobs["width"]
    train = dataclasses.asdict(build_config(TrainSettings, dict(train), "stage1.train"))
    if "steps" in knobs:
        train["iterations"] = knobs["steps"]
    multiple = max(CROP_MULTIPLE, specs.crop_multiple(method, model_config(method, settings)))
    train["crop"] = fit_crop(train["crop"], scene, multiple)
    return settings, train


def fit_crop(crop: int, scene: dict, multiple: int = CROP_MULTIPLE) -> int:
    """The largest multiple of ``multiple`` (the network's crop multiple) at most ``crop`` and the
    image's shorter side; an error naming the resolution when not even one fits."""
    side = min(crop, scene["width"], scene.get("height", scene["width"]))
    fitted = side // multiple * multiple
    if fitted < multiple:
        raise ValueError(
            f"res={scene['width']}: images are too small for the translator's {multiple}-pixel crops "
            f"(its crop sides must be multiples of {multiple}; use a larger res or a network with fewer halvings)"
        )
    return fitted


def stage2_settings(settings: dict, model: str, knobs: dict) -> dict:
    """Every setting of the stage-2 model (a complete override dict) with iters / cap / grid applied."""
    cfg = dataclasses.asdict(reconstructor_config(model, settings))
    if "iters" in knobs:
        factor = knobs["iters"] / cfg[ITERATION_FIELD[model]]
        cfg[ITERATION_FIELD[model]] = knobs["iters"]
        for key in SCHEDULE_FIELDS[model]:
            cfg[key] = max(1, round(cfg[key] * factor))
        if model == "nerf-grid":
            cfg["res_schedule"] = [[round(it * factor), r] for it, r in cfg["res_schedule"]]
    if model == "3dgs" and "cap" in knobs:  # a cap below init_points is refused (spc3d.checks.crosscheck.check_point)
        cfg["max_gaussians"] = knobs["cap"]
    if model == "nerf-grid" and "grid" in knobs:
        final = cfg["res_schedule"][-1][1]
        cfg["res_schedule"] = [[it, max(4, round(r * knobs["grid"] / final))] for it, r in cfg["res_schedule"]]
    return cfg
