"""Translate one capture frame with a trained stage-1 model.

    python -m spc3d.translate MODEL_DIR FRAME.png OUT.png [--frames K] [--ensemble 1|2|4] [--level 0.18]

FRAME.png is one binary frame (0 / full scale) or the mean of K binary frames of a monochrome SPAD
sensor, an 8- or 16-bit single-channel PNG; K is ``--frames`` or the sidecar FRAME.json
(``{"frames": K}``), and a file with only 0 and full scale is one frame. MODEL_DIR is a trained
model folder (``results/models/{method}``, rule train_translator). OUT.png is the model's output
as grey (the luminance of its colour output) shown with average metering (the mean at linear
``--level``): the exposure of a real frame is not known. See :func:`spc3d.translate.apply.translate_frame`.
"""

from __future__ import annotations

import argparse
import logging
import sys

from spc3d.translate.apply import ENSEMBLE_FLIPS, translate_frame


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m spc3d.translate", description=__doc__.split("\n\n")[0])
    ap.add_argument("model_dir", help="a trained model folder (results/models/{method})")
    ap.add_argument("frame", help="a binary frame or K-frame mean, monochrome PNG")
    ap.add_argument("out", help="the output image (.png)")
    ap.add_argument("--frames", type=int, default=None, help="K, the frames the PNG averages (default: its sidecar)")
    ap.add_argument("--ensemble", type=int, default=1, choices=sorted(ENSEMBLE_FLIPS), help="flipped passes averaged")
    ap.add_argument("--level", type=float, default=0.18, help="linear grey the mean is shown at (average metering)")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    try:
        record = translate_frame(
            args.model_dir, args.frame, args.out, args.frames, args.ensemble, args.level, args.threads
        )
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(
        f"{record['method']}: {args.frame} (K = {record['frames']}, {record['size'][1]}x{record['size'][0]}, "
        f"input {record['input']}) -> {args.out}, shown at gain {record['display']['gain']:.4g} "
        f"detections per frame for white ({record['seconds']:.2f} s)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
