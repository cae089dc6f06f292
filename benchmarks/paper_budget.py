"""What the `paper` preset would cost on this machine, from measured per-iteration costs.

    python benchmarks/paper_budget.py [--threads 2 --steps 3]

Times a few optimisation steps of every model at the paper preset's sizes on the CPU (stage-1
translators at PAPER sizes, batch 1, 256 px crops; the MLP NeRF with the `llff` preset, 1024
rays; 3DGS forward+backward at 504x378 with 100k Gaussians, a typical LLFF count) and multiplies
by the preset's budgets (workflow/presets/paper.yaml): 3M translator steps (100 + 100 epochs over
15k pairs at batch 1), NeRF 50k and 3DGS 30k iterations per combination, 3 seeds, 14 combinations
on one evaluation scene. Prints a table (seconds per step, steps, hours) and the total.
Only compute is extrapolated: data preparation, evaluation and Snakemake overhead are left out.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from rasterizer import make_scene, train_step  # noqa: E402

from spc3d.evaluation import lpips_specs  # noqa: E402
from spc3d.inputs.scenes import render_scene  # noqa: E402
from spc3d.reconstruct import make_nerf  # noqa: E402
from spc3d.reconstruct.views import Views  # noqa: E402
from spc3d.translate import TRANSLATORS  # noqa: E402
from spc3d.translate.model_io import model_config  # noqa: E402

PRESET = Path(__file__).resolve().parents[1] / "workflow" / "presets" / "paper.yaml"


def seconds_per_step(step, steps: int) -> float:
    """Median wall time of ``steps`` calls after one warm-up call."""
    step()
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def translator_step(method: str, crop: int):
    vgg = {
        k: np.random.default_rng(0).standard_normal(s).astype(np.float32) * 0.01
        for k, s in lpips_specs.expected_shapes("vgg").items()
    }
    model = TRANSLATORS[method].Translator(model_config(method, {"preset": "paper"}), torch.device("cpu"), vgg)
    x, y = torch.rand(1, 3, crop, crop).round(), torch.rand(1, 3, crop, crop)
    return lambda: model.train_step(x, y)


def nerf_step():
    scene = render_scene("courtyard", height=24, width=32, views=9, supersample=1)
    views = Views(torch.as_tensor(scene.images, dtype=torch.float32), scene.cameras, scene.names)
    trainer, _, _ = make_nerf(views, None, {"preset": "llff"}, seed=0)
    counter = iter(range(1, 10**9))
    return lambda: trainer.step(next(counter))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=0, help="torch threads; 0: torch's default")
    ap.add_argument("--steps", type=int, default=3)
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    p = yaml.safe_load(PRESET.read_text())
    runs = 14 * p["stage2"]["seeds"] * len(p["scenes"]["eval"])
    tr = p["stage1"]["train"]
    rows = [
        (f"{m} (paper size, crop {tr['crop']})", translator_step(m, tr["crop"]), tr["iterations"]) for m in TRANSLATORS
    ]
    rows.append(
        (
            "NeRF MLP (llff preset, 1024 rays) x 7 nerf rows x seeds",
            nerf_step(),
            p["stage2"]["nerf"]["n_iters"] * 7 * p["stage2"]["seeds"],
        )
    )
    gs = make_scene(100_000, 378, 504)
    rows.append(
        (
            "3DGS fwd+bwd 100k Gaussians 504x378 x 7 3dgs rows x seeds",
            lambda: train_step(gs, "native"),
            p["stage2"]["3dgs"]["iterations"] * 7 * p["stage2"]["seeds"],
        )
    )
    total = 0.0
    print(f"threads {torch.get_num_threads()}; {runs} stage-2 runs")
    print(f"{'component':<62} {'s/step':>8} {'steps':>10} {'hours':>10}")
    for name, step, n in rows:
        s = seconds_per_step(step, args.steps)
        total += s * n
        print(f"{name:<62} {s:>8.3f} {n:>10} {s * n / 3600:>10.1f}", flush=True)
    print(f"paper_preset_hours_on_this_cpu: {total / 3600:.0f}  (= {total / 86400 / 365:.1f} years)")


if __name__ == "__main__":
    main()
