"""The translators' physics prior alone, by blur: how ``prior_sigma`` was chosen.

    python benchmarks/stage1_prior.py RESULTS_DIR [--sigmas 1 1.5 2 2.5 3 4] [--frames 1]
                                      [--train tabletop orchard gallery]

Reads a finished run's training data (``RESULTS_DIR/augment/{scene}``, ``scenes/``, ``spc/`` of the
training scenes; e.g. ``results`` after the default ``snakemake --cores 2``). For each blur sigma it
fits the prior's gain on the augmented pairs, as training does, and prints the gain and the PSNR
of the prior alone on the training scenes' held-out views (the validation slice of stage 1; no
evaluation scene is read). The default ``prior_sigma`` is this table's best.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from spc3d.translate.data import load_pairs  # noqa: E402
from spc3d.translate.prior import PhysicsPrior  # noqa: E402
from spc3d.translate.validate import load_views, score  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path)
    ap.add_argument("--sigmas", type=float, nargs="+", default=[1.0, 1.5, 2.0, 2.5, 3.0, 4.0])
    ap.add_argument("--frames", type=int, default=1, help="K binary frames averaged into the input")
    ap.add_argument("--train", nargs="+", default=["tabletop", "orchard", "gallery"], help="training scenes")
    args = ap.parse_args()
    r = args.results
    missing = [p for s in args.train for p in (r / "augment" / s, r / "scenes" / s, r / "spc" / s) if not p.is_dir()]
    if missing:
        sys.exit(f"{missing[0]} is missing: run the workflow first (snakemake --cores 2) or pass its results folder")
    binary, rgb = load_pairs([r / "augment" / s for s in args.train], args.frames)
    views = load_views([r / "scenes" / s for s in args.train], [r / "spc" / s for s in args.train], args.frames)
    rows = []
    for sigma in args.sigmas:
        prior = PhysicsPrior(sigma)
        gain = prior.fit(zip(binary, rgb)).tolist()
        scores = score(lambda b, p=prior: p(b).clamp(0.0, 1.0), views)
        rows.append(
            {
                "sigma (px)": sigma,
                "gain R": gain[0],
                "gain G": gain[1],
                "gain B": gain[2],
                "val PSNR (dB)": scores["val_psnr"],
                "val L1": scores["val_l1"],
            }
        )
    df = pd.DataFrame(rows)
    print(
        f"physics prior alone on {len(views)} held-out views of {', '.join(args.train)} "
        f"(gain fitted on {len(binary)} augmented pairs, K = {args.frames})"
    )
    print(df.to_markdown(index=False, floatfmt=".3f"))
    best = df.loc[df["val PSNR (dB)"].idxmax(), "sigma (px)"]
    print(f"best sigma: {best:g} px")


if __name__ == "__main__":
    main()
