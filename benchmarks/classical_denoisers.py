"""The classical denoisers compared on the training scenes: what the ``classical`` method chooses from.

    python benchmarks/classical_denoisers.py --results RESULTS_DIR [--scenes tabletop orchard gallery]
                                             [--frames 1] [--every 1] [--families gaussian nlm wavelet tv bm3d]

Reads a finished run's training data (``RESULTS_DIR/augment/{scene}``, ``scenes/``, ``spc/`` of the
training scenes; e.g. ``results`` after the default ``snakemake --cores 2``). For every candidate of
:data:`spc3d.specs.translators.classical.GRID` whose family can run here (wavelets need PyWavelets, BM3D the
non-commercial ``bm3d`` package; the others are reported as not run) it fits the gain on the
augmented pairs (every ``--every``-th; 1 = all, as the chosen model's gain is fitted), then prints
its PSNR and SSIM on the training scenes' held-out views (the validation slice of stage 1, displayed
as validation displays it; no evaluation scene is read) and its time per image. The ``classical``
method's search ranks the same candidates by the same PSNR (its gains on every 4th pair).
``gaussian(sigma=2.0)`` is the ``prior`` method.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import pandas as pd
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from spc3d.evaluation.metrics import psnr, ssim  # noqa: E402
from spc3d.translate import classical  # noqa: E402
from spc3d.translate.camera import from_camera  # noqa: E402
from spc3d.translate.data import load_pairs  # noqa: E402
from spc3d.translate.validate import load_views  # noqa: E402


def candidate_row(index: int, pairs: list, views: list, frames: int) -> dict:
    """One candidate: its gain on ``pairs``, PSNR / SSIM on ``views`` and milliseconds per image."""
    name, params = classical.GRID[index]
    model = classical.Translator(classical.Config(choice=name, params=params, frames=frames), torch.device("cpu"))
    gain = model.net.fit(pairs).tolist()
    psnrs, ssims, seconds = [], [], 0.0
    for view in views:
        start = time.perf_counter()
        camera = model.translate(view.binary[None])[0]
        seconds += time.perf_counter() - start
        shown = from_camera(camera, view.exposure)
        psnrs.append(psnr(shown, view.rgb))
        ssims.append(ssim(shown.permute(1, 2, 0).numpy(), view.rgb.permute(1, 2, 0).numpy()))
    return {
        "candidate": classical.label(index),
        "PSNR (dB)": sum(psnrs) / len(psnrs),
        "SSIM": sum(ssims) / len(ssims),
        "ms / image": 1000 * seconds / len(views),
        "gain R": gain[0],
        "gain G": gain[1],
        "gain B": gain[2],
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, default=Path("results"), help="a finished run's results folder")
    ap.add_argument("--scenes", nargs="+", default=["tabletop", "orchard", "gallery"], help="training scenes")
    ap.add_argument("--frames", type=int, default=1, help="K binary frames averaged into the input")
    ap.add_argument("--every", type=int, default=1, help="fit each gain on every n-th pair (1: all)")
    ap.add_argument("--families", nargs="+", default=list(classical.DENOISERS), choices=list(classical.DENOISERS))
    args = ap.parse_args(argv)
    r, scenes = args.results, args.scenes
    missing = [p for s in scenes for p in (r / "augment" / s, r / "scenes" / s, r / "spc" / s) if not p.is_dir()]
    if missing:
        sys.exit(f"{missing[0]} is missing: run the workflow first (snakemake --cores 2) or pass its results folder")
    torch.set_num_threads(1)
    binary, rgb = load_pairs([r / "augment" / s for s in scenes], args.frames)
    pairs = list(zip(binary, rgb))[:: args.every]
    views = load_views([r / "scenes" / s for s in scenes], [r / "spc" / s for s in scenes], args.frames)
    indices = [i for i, (n, _) in enumerate(classical.GRID) if n in args.families]
    skipped = {n: classical.unavailable(n) for n in dict.fromkeys(classical.GRID[i][0] for i in indices)}
    rows = [candidate_row(i, pairs, views, args.frames) for i in indices if not skipped[classical.GRID[i][0]]]
    print(
        f"classical denoisers on {len(views)} held-out views of {', '.join(scenes)} (gain fitted on "
        f"{len(pairs)} of {len(binary)} augmented pairs, K = {args.frames}; one thread)"
    )
    df = pd.DataFrame(rows)
    print(df.to_markdown(index=False, floatfmt=".3f"))
    for name, why in skipped.items():
        if why:
            print(f"not run: {name}: {why}")
    if rows:
        best = df.loc[df["PSNR (dB)"].idxmax()]
        print(f"best: {best['candidate']} ({best['PSNR (dB)']:.2f} dB)")


if __name__ == "__main__":
    main()
