"""Speed of one training step of every stage-1 translator at the default (CPU-sized) settings.

    python benchmarks/translators.py [--batch 4 --crop 64 --threads 1,2 --steps 6 --rounds 3]
                                     [--methods pix2pixhd,pix2pix,...] [--allocator keep|default] [--no-prior]

Each method is built with its ``Config()`` defaults (what config.yaml's empty blocks select; the
VGG loss of pix2pixHD gets random weights of the right shapes, which cost the same) and trained
on one fixed batch: ``--batch`` binary crops (Bernoulli bits of a smooth image) and their RGB
targets, ``--crop`` pixels square. For every torch thread count the methods take turns in
``--rounds`` rounds of ``--steps`` consecutive steps (one untimed step first in each round), so
all see the same load from other jobs. Printed per method and thread count, medians over the
rounds: steps/s, CPU seconds per step (user + system of the whole process, all threads; steadier
than wall time on a shared machine, but with 2 threads on a busy machine it counts OpenMP
workers spinning while they wait for a descheduled partner) and the share of it spent in the
kernel. ``--allocator keep`` (the default) sets up the process as a workflow job is set up
(:func:`spc3d.runtime.keep_freed_memory`); ``default`` leaves glibc's malloc as it is.
The last line, ``steps_per_s_1thread: method=value ...``, is machine-readable.
``--smoke``: batch 1, one thread, one round of one step (seconds; its rates mean nothing).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import time

import numpy as np
import torch

from spc3d.evaluation import lpips_specs
from spc3d.specs import TRANSLATORS as SPECS
from spc3d.translate import MODULES


def make_batch(batch: int, crop: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """(binary, rgb): (B, 3, crop, crop) Bernoulli bits of a smooth random image, and that image."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(batch, 3, 4, 4, generator=g)
    rgb = torch.nn.functional.interpolate(coarse, size=(crop, crop), mode="bilinear", align_corners=False)
    binary = torch.bernoulli(0.2 + 0.6 * rgb, generator=g)
    return binary, rgb


def build(method: str, seed: int = 0, prior: bool = True):
    """The method's Translator with Config() defaults on the CPU (seeded); ``prior=False``: the
    published network alone (``prior_sigma: 0``)."""
    torch.manual_seed(seed)
    module = MODULES[method]
    rng = np.random.default_rng(seed)
    vgg = {k: (0.01 * rng.standard_normal(s)).astype(np.float32) for k, s in lpips_specs.expected_shapes("vgg").items()}
    cfg = module.Config() if prior else module.Config(prior_sigma=0.0)
    return module.Translator(cfg, torch.device("cpu"), vgg)


FORMATS = ("contiguous", "channels_last")


def to_channels_last(model) -> None:
    """Every network of ``model`` (its modules and any other nn.Module attribute, e.g. the frozen VGG)
    in channels-last (NHWC) memory: 4-D weights and buffers are restrided, so the activations follow."""
    for value in vars(model).values():
        if isinstance(value, torch.nn.Module):
            value.to(memory_format=torch.channels_last)


def cpu_seconds() -> tuple[float, float]:
    """(user, system) CPU seconds of this process so far, all threads."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime, r.ru_stime


def measure(models: dict, batch: tuple, steps: int, rounds: int) -> dict[str, dict]:
    """Per method, medians over the rounds: steps/s, CPU seconds per step, kernel share of those."""
    rounds_of = {m: [] for m in models}  # (steps/s, user s, system s) per round
    for _ in range(rounds):
        for method, model in models.items():
            model.train_step(*batch)  # untimed: caches and allocator after the previous method
            u0, s0 = cpu_seconds()
            t0 = time.perf_counter()
            for _ in range(steps):
                model.train_step(*batch)
            wall = time.perf_counter() - t0
            u1, s1 = cpu_seconds()
            rounds_of[method].append((steps / wall, (u1 - u0) / steps, (s1 - s0) / steps))
    out = {}
    for m, rows in rounds_of.items():
        rate, user, system = (statistics.median(col) for col in zip(*rows))
        out[m] = {"steps_per_s": rate, "cpu_s": user + system, "sys_share": system / max(user + system, 1e-12)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--crop", type=int, default=64)
    ap.add_argument("--threads", default="1,2", help="comma-separated torch thread counts")
    ap.add_argument("--steps", type=int, default=6, help="timed steps per round")
    ap.add_argument("--rounds", type=int, default=3)
    trained = [m for m in MODULES if SPECS[m].trained]  # the prior and classical: no step
    ap.add_argument("--methods", default=",".join(trained), help="comma-separated methods")
    ap.add_argument(
        "--allocator",
        choices=("keep", "default"),
        default="keep",
        help="keep: as a workflow job (freed memory reused); default: glibc's own behaviour",
    )
    ap.add_argument("--no-prior", action="store_true", help="the published networks (prior_sigma: 0)")
    ap.add_argument(
        "--formats",
        default="contiguous",
        help="comma-separated memory formats of the networks, timed in turns: contiguous, channels_last",
    )
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        vars(args).update(batch=1, threads="1", steps=1, rounds=1)
    if args.allocator == "keep":
        from spc3d.runtime import keep_freed_memory

        keep_freed_memory()
    methods = args.methods.split(",")
    formats = args.formats.split(",")
    unknown = [f for f in formats if f not in FORMATS]
    if unknown:
        raise SystemExit(f"--formats: unknown memory format(s) {unknown}; use {', '.join(FORMATS)}")
    batch = make_batch(args.batch, args.crop)
    results = {}
    for threads in (int(t) for t in args.threads.split(",")):
        torch.set_num_threads(threads)
        models = {}  # fresh models: every thread count starts alike
        for m in methods:
            for fmt in formats:
                models[m if fmt == "contiguous" else f"{m}[{fmt}]"] = model = build(m, prior=not args.no_prior)
                if fmt == "channels_last":
                    to_channels_last(model)
        results[threads] = measure(models, batch, args.steps, args.rounds)
    print(
        f"batch {args.batch}, crop {args.crop}, allocator {args.allocator}, physics prior {not args.no_prior}, "
        f"torch {torch.__version__}, "
        f"OMP_WAIT_POLICY {os.environ.get('OMP_WAIT_POLICY', 'unset')}, load average {os.getloadavg()[0]:.1f}"
    )
    print(f"{'method':<24} {'threads':>7} {'steps/s':>8} {'CPU s/step':>11} {'kernel':>7}")
    for threads, rows in results.items():
        for m, r in rows.items():
            print(f"{m:<24} {threads:>7} {r['steps_per_s']:>8.2f} {r['cpu_s']:>11.3f} {100 * r['sys_share']:>6.1f}%")
    one = results.get(1, {})
    print("steps_per_s_1thread: " + " ".join(f"{m}={r['steps_per_s']:.2f}" for m, r in one.items()))


if __name__ == "__main__":
    main()
