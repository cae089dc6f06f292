"""The model specs: one torch-free description per model family, every translator (stage 1) and
every reconstructor (stage 2) of the project, and what the rest of the code derives from them.

From these specs come the registries (:data:`spc3d.translate.MODULES`,
:data:`spc3d.reconstruct.RECONSTRUCTORS`), the workflow's method and model names and labels
(:mod:`spc3d.names`), the config's accepted model blocks (:mod:`spc3d.config`), the rules'
branches (COLMAP points, pose refinement, GPU requests: :mod:`spc3d.settings`, ``common.smk``) and the
sweeps' knobs (:mod:`spc3d.sweeps.budget`). The built-in models' settings dataclasses live beside
them (:mod:`.translators`, :mod:`.reconstructors`; built by :mod:`.build`), so
that the workflow checks every job's settings at parse time without importing torch. Adding a
model is: its file, its spec and settings here, its settings block in ``config.yaml``
(``workflow/rules/README.md``).

Models defined outside the package register through :func:`register` from a plugin file named in
the environment variable ``SPC3D_PLUGINS`` (``os.pathsep``-separated ``.py`` paths). Each plugin
defines ``spc3d_register(register)``; the plugins are loaded once, when this module is first
imported, so the Snakefile and every job process see the same registry.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType


@dataclass(frozen=True)
class TranslatorSpec:
    """A stage-1 model. ``module`` (dotted name, or a ``.py`` path) holds the ``Translator`` (the
    contract of :mod:`spc3d.translate.base`). ``config`` and ``paper`` name its settings dataclass
    and published sizes as ``"module:attribute"``; left empty, they are ``module``'s ``Config`` and
    ``PAPER`` (a plugin's usual form; the built-ins name torch-free ones, :mod:`.translators`)."""

    name: str  # config key and source name: [a-z0-9]+ (suffixes such as -pub follow a '-')
    label: str  # the tables' name
    module: str
    width_field: str | None = None  # the Config field the sweeps' width knob sets (None: no network)
    trained: bool = True  # False: nothing to train (prior, classical), so no published (-pub) form either
    # Config fields whose sum n makes the Translator's ``multiple`` 2**n: its training crops' sides
    # must be multiples of it (checked at parse time, spc3d.config.check_crops); () for a network
    # that pads its input (Restormer, the diffusion restorer) or has none (the prior).
    crop_halvings: tuple[str, ...] = ()
    config: str = ""
    paper: str = ""


@dataclass(frozen=True)
class ReconstructorSpec:
    """A stage-2 model. ``factory`` and ``config`` are ``"module:function"`` (module dotted or a
    ``.py`` path): ``factory(views, objective, settings, seed, points)`` returns
    ``(trainer, iterations, config)``, ``config(settings)`` the settings dataclass (checked at parse
    time). A trainer has ``step / render / capacity / state / load`` (:func:`spc3d.training.run`)
    and may have the optional hooks of :class:`spc3d.reconstruct.stage2.TrainerHooks`."""

    name: str  # config key and model name: [a-z0-9-]+
    label: str
    factory: str
    config: str
    iteration_field: str  # the Config field counting iterations (the sweeps' iters knob)
    schedule_fields: tuple[str, ...] = ()  # fields counted in iterations, scaled with them
    accepts_points: bool = False  # starts from COLMAP's sparse points under stage2.init: colmap
    refines_poses: bool = False  # learns camera corrections (stage2.refine_poses)
    gpu: bool = False  # uses CUDA when present (the scheduler is asked for a GPU)


TRANSLATOR_NAME = re.compile(r"[a-z0-9]+")
RECONSTRUCTOR_NAME = re.compile(r"[a-z0-9]+(-[a-z0-9]+)*")

TRANSLATORS: dict[str, TranslatorSpec] = {}
RECONSTRUCTORS: dict[str, ReconstructorSpec] = {}


def register(spec: TranslatorSpec | ReconstructorSpec) -> None:
    """Add a model family; its name must be new and fit the source grammar (:mod:`spc3d.names`)."""
    registry, pattern = (
        (TRANSLATORS, TRANSLATOR_NAME) if isinstance(spec, TranslatorSpec) else (RECONSTRUCTORS, RECONSTRUCTOR_NAME)
    )
    if not pattern.fullmatch(spec.name):
        raise ValueError(f"model name {spec.name!r} must match {pattern.pattern} ({type(spec).__name__})")
    if spec.name in TRANSLATORS or spec.name in RECONSTRUCTORS:
        raise ValueError(f"model name {spec.name!r} is already registered")
    registry[spec.name] = spec


def _builtin(name: str, label: str, module: str, width_field: str | None, **kw) -> TranslatorSpec:
    """A built-in translator: its Translator in ``spc3d.translate.<module>``, its settings dataclass
    ``Config`` and published sizes ``PAPER`` in ``spc3d.specs.translators.<name>``."""
    here = f"spc3d.specs.translators.{name}"
    return TranslatorSpec(
        name, label, f"spc3d.translate.{module}", width_field, config=f"{here}:Config", paper=f"{here}:PAPER", **kw
    )


for _spec in (
    _builtin("pix2pixhd", "Pix2PixHD", "pix2pixhd", "ngf", crop_halvings=("n_downsample_global", "n_local_enhancers")),
    _builtin("pix2pix", "Pix2Pix", "pix2pix", "ngf", crop_halvings=("num_downs",)),
    _builtin("cyclegan", "CycleGAN", "cyclegan", "ngf", crop_halvings=("n_downsampling",)),
    _builtin("restormer", "Restormer", "restormer", "dim"),
    _builtin("diffusion", "Diffusion (DiffBIR stand-in)", "diffusion", "base_channels"),
    _builtin("prior", "Physics prior (blurred MLE, no training)", "blurred_mle", None, trained=False),
    _builtin(
        "classical",
        "Classical denoiser (best of NLM / wavelet / TV / Gaussian after a VST, then MLE)",
        "classical",
        None,
        trained=False,
    ),
    ReconstructorSpec(
        "3dgs",
        "3DGS",
        "spc3d.reconstruct.splatting:make_3dgs",
        "spc3d.specs.reconstructors:config_3dgs",
        "iterations",
        ("densify_from", "densify_until", "densify_every", "opacity_reset_every", "sh_interval"),
        accepts_points=True,
        refines_poses=True,
    ),
    ReconstructorSpec(
        "nerf-mlp",
        "NeRF (MLP) [nerf-mlp]",
        "spc3d.reconstruct.nerf_trainer:make_nerf",
        "spc3d.specs.reconstructors:config_nerf",
        "n_iters",
        gpu=True,
    ),
    ReconstructorSpec(
        "nerf-grid",
        "NeRF [nerf-grid]",
        "spc3d.reconstruct.nerf_trainer:make_nerf_grid",
        "spc3d.specs.reconstructors:config_nerf_grid",
        "n_iters",
        ("occupancy_every", "occupancy_warmup"),
        gpu=True,
    ),
):
    register(_spec)


def crop_multiple(method: str, cfg) -> int:
    """The side a training crop of translator ``method`` (its Config ``cfg``) must be a multiple
    of: 2 ** the sum of its spec's ``crop_halvings`` fields (1: any side)."""
    return 2 ** sum(getattr(cfg, name) for name in TRANSLATORS[method].crop_halvings)


def settings_classes(method: str) -> tuple[type, dict]:
    """Translator ``method``'s settings dataclass and published sizes (its spec's ``config`` and
    ``paper``, else its module's ``Config`` and ``PAPER``)."""
    spec = TRANSLATORS[method]
    return load(spec.config or f"{spec.module}:Config"), load(spec.paper or f"{spec.module}:PAPER")


def import_module(module: str) -> ModuleType:
    """A dotted module name, or a ``.py`` file (imported once, under its stem)."""
    if not module.endswith(".py"):
        return importlib.import_module(module)
    path = Path(module).resolve()
    name = f"spc3d_plugin_{path.stem}"
    if name in sys.modules:
        return sys.modules[name]
    if not path.is_file():
        raise FileNotFoundError(f"model module {module}: no such file")
    spec = importlib.util.spec_from_file_location(name, path)
    found = importlib.util.module_from_spec(spec)
    sys.modules[name] = found
    spec.loader.exec_module(found)
    return found


def load(target: str):
    """The object named by ``"module:attribute"`` (module dotted or a ``.py`` path)."""
    module, _, attribute = target.rpartition(":")
    if not module:
        raise ValueError(f"{target!r}: expected 'module:attribute'")
    return getattr(import_module(module), attribute)


PLUGINS_ENV = "SPC3D_PLUGINS"


def load_plugins(paths: str) -> None:
    """Import each plugin file of ``paths`` (``os.pathsep``-separated) and call its
    ``spc3d_register(register)``."""
    for path in filter(None, paths.split(os.pathsep)):
        plugin = import_module(path)
        hook = getattr(plugin, "spc3d_register", None)
        if hook is None:
            raise ValueError(f"{PLUGINS_ENV} names {path}, which defines no spc3d_register(register)")
        if not getattr(plugin, "_spc3d_registered", False):
            hook(register)
            plugin._spc3d_registered = True


load_plugins(os.environ.get(PLUGINS_ENV, ""))
