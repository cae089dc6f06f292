"""What the `paper` preset would cost on this machine, from measured per-iteration costs.

    python benchmarks/paper_budget.py [--threads 2 --steps 3] [--preset workflow/presets/paper.yaml]
    python benchmarks/paper_budget.py --smoke          # the plan at full size, the steps timed tiny

Plans from the preset's own configuration (config.yaml with the preset merged over it, as
``snakemake --configfile`` reads it: :func:`spc3d.config.workflow_config`): every translator training
its combinations need (stage-1 model folders x training folds x seeds, each at its own iterations;
the untrained prior and classical denoiser cost no training) and every stage-2 fit (combinations x
evaluation scenes x seeds, each at its model's iterations). Times a few optimisation steps of each
on the CPU at the preset's sizes (translators at the preset's settings, batch 1, its crop; the NeRF
variants through their own trainer at the preset's settings; 3DGS forward+backward at 504x378 with
100k Gaussians, a typical LLFF count, since a fit's cost follows its Gaussians, not its settings)
and multiplies. Prints a table (seconds per step, steps, hours) and the total; the last line,
``paper_preset_hours_on_this_cpu: <hours>``, is machine-readable.
Only compute is extrapolated: data preparation, evaluation and Snakemake overhead are left out.
``--smoke`` keeps the plan and times one step of tiny stand-ins (translators at config.yaml's CPU
sizes and width 4 on their smallest crop, 3DGS 2,000 Gaussians at 64x48, the NeRFs on 64 rays), so
its hours mean nothing: it checks that the script runs (tests/test_benchmarks_smoke.py).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from rasterizer import make_scene, train_step  # noqa: E402

from spc3d import specs  # noqa: E402
from spc3d.config import workflow_config  # noqa: E402
from spc3d.evaluation import lpips_specs  # noqa: E402
from spc3d.inputs.scenes import render_scene  # noqa: E402
from spc3d.jobs import scene_fold, training_scene_names  # noqa: E402
from spc3d.names import parse_combination, parse_source, resolve_combinations, stage1_sources, translator_settings  # noqa: E402
from spc3d.reconstruct import RECONSTRUCTORS  # noqa: E402
from spc3d.reconstruct.views import Views  # noqa: E402
from spc3d.translate import MODULES  # noqa: E402
from spc3d.translate.model_io import model_config  # noqa: E402

PRESET = Path(__file__).resolve().parents[1] / "workflow" / "presets" / "paper.yaml"


@dataclass(frozen=True)
class Item:
    """One kind of training in the plan: ``runs`` of ``steps`` iterations each."""

    kind: str  # "stage1" or "stage2"
    name: str  # a translator's model folder name or a stage-2 model
    settings: dict  # what the step is built from (the preset's, resolved)
    runs: int
    steps: int

    @property
    def total_steps(self) -> int:
        return self.runs * self.steps


def plan(config: dict) -> list[Item]:
    """Every training a configuration plans, grouped by what one step costs."""
    combos = resolve_combinations(config["stage2"]["combinations"], config["stage2"]["nerf_variant"])
    scenes, seeds = config["scenes"], config["seeds"]
    train, evaluate = training_scene_names(config), scenes["eval"]
    folds = {scene_fold(scene, train, scenes["leave_one_out"]) for scene in evaluate}
    items = []
    for method in stage1_sources(combos):
        if not specs.TRANSLATORS[parse_source(method).base].trained:
            continue  # nothing to train (the prior, the classical denoiser)
        settings, training = translator_settings(config["stage1"], method)
        runs, steps = len(folds) * seeds, training["iterations"]
        items.append(Item("stage1", method, settings | {"crop": training["crop"]}, runs, steps))
    fits = Counter(parse_combination(c)[1] for c in combos)
    for model, n in fits.items():
        spec = specs.RECONSTRUCTORS[model]
        settings = config["stage2"].get(model) or {}
        steps = getattr(specs.load(spec.config)(settings), spec.iteration_field)
        items.append(Item("stage2", model, settings, n * len(evaluate) * seeds, steps))
    return items


def seconds_per_step(step, steps: int) -> float:
    """Median wall time of ``steps`` calls after one warm-up call (0: the one call's time)."""
    if steps == 0:
        t0 = time.perf_counter()
        step()
        return time.perf_counter() - t0
    step()
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def translator_step(method: str, settings: dict, crop: int | None):
    """(crop, one training step) of a translator at ``settings`` on a batch of one ``crop``-pixel
    square (None: the smallest crop the network takes, its ``multiple``)."""
    vgg = {
        k: np.random.default_rng(0).standard_normal(s).astype(np.float32) * 0.01
        for k, s in lpips_specs.expected_shapes("vgg").items()
    }
    settings = {k: v for k, v in settings.items() if k != "crop"}
    base = parse_source(method).base
    model = MODULES[base].Translator(model_config(base, settings), torch.device("cpu"), vgg)
    crop = crop or max(32, model.multiple)
    x, y = torch.rand(1, 3, crop, crop).round(), torch.rand(1, 3, crop, crop)
    return crop, lambda: model.train_step(x, y)


def ray_step(model: str, settings: dict):
    """One training step of a ray-batch model (NeRF, grid NeRF) at ``settings``: its cost is the
    batch of rays, not the scene's size."""
    scene = render_scene("courtyard", height=24, width=32, views=9, supersample=1)
    views = Views(torch.as_tensor(scene.images, dtype=torch.float32), scene.cameras, scene.names)
    trainer, _, _ = RECONSTRUCTORS[model](views, None, settings, 0)
    counter = iter(range(1, 10**9))
    return lambda: trainer.step(next(counter))


def step_of(item: Item, smoke: bool):
    """(label, the step to time) of one plan item."""
    if item.kind == "stage1":
        settings, crop = (smoke_sizes(item.name), None) if smoke else (item.settings, item.settings["crop"])
        crop, step = translator_step(item.name, settings, crop)
        return f"{item.name} (crop {crop})", step
    if item.name == "3dgs":
        n, h, w = (2_000, 48, 64) if smoke else (100_000, 378, 504)
        gs = make_scene(n, h, w)
        return f"3dgs fwd+bwd {n // 1000}k Gaussians {w}x{h}", lambda: train_step(gs, "native")
    settings = {**item.settings, "batch_rays": 64, "chunk": 1024} if smoke else item.settings
    rays = specs.load(specs.RECONSTRUCTORS[item.name].config)(settings).batch_rays  # a preset's included
    return f"{item.name} ({rays} rays)", ray_step(item.name, settings)


def smoke_sizes(method: str) -> dict:
    """A translator's settings in config.yaml (the CPU sizes) at the sweeps' smallest width: the
    smoke mode's stand-in."""
    settings = translator_settings(workflow_config()["stage1"], method)[0]
    width = specs.TRANSLATORS[parse_source(method).base].width_field
    return settings | ({width: 4} if width else {})


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=0, help="torch threads; 0: torch's default")
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--preset", type=Path, default=PRESET)
    ap.add_argument("--smoke", action="store_true", help="the plan at full size, one step of tiny stand-ins")
    args = ap.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    items = plan(workflow_config(args.preset))
    fits = sum(i.runs for i in items if i.kind == "stage2")
    trainings = sum(i.runs for i in items if i.kind == "stage1")
    print(f"threads {torch.get_num_threads()}; {args.preset.name}: {trainings} translator trainings, {fits} fits")
    print(f"{'component':<48} {'runs':>5} {'s/step':>8} {'steps':>12} {'hours':>10}")
    total = 0.0
    for item in items:
        label, step = step_of(item, args.smoke)
        s = seconds_per_step(step, 0 if args.smoke else args.steps)
        total += s * item.total_steps
        hours = s * item.total_steps / 3600
        print(f"{label:<48} {item.runs:>5} {s:>8.3f} {item.total_steps:>12} {hours:>10.1f}", flush=True)
    print(f"paper_preset_hours_on_this_cpu: {total / 3600:.0f}  (= {total / 86400 / 365:.1f} years)")


if __name__ == "__main__":
    main()
