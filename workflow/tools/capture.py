"""Captured SPAD scenes from the command line: export a simulated scene as a capture, inspect a capture.

    python workflow/tools/capture.py export results/spc/courtyard captures/courtyard-rggb \\
        --cfa RGGB --format npy.gz --scene results/scenes/courtyard [--no-poses]
    python workflow/tools/capture.py inspect captures/courtyard-rggb inspect/courtyard-rggb

``export`` writes the folder layout of :mod:`spc3d.captures.folders` (sensor.json, frames/, and with
``--scene`` the reference images/ and poses_bounds.npy). ``inspect`` reads any capture folder (a
real one or an export), detects hot pixels and writes MLE previews, the hot-pixel map and
capture.json (:func:`spc3d.captures.folders.inspect_capture`). Errors name the file and what is wrong.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # a source checkout works without `pip install -e .`

from spc3d.captures import folders as captures  # noqa: E402  (after the path line above)
from spc3d.captures import photon_cubes


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    ex = sub.add_parser("export", help="write a simulated SPC folder (results/spc/{scene}) as a capture")
    ex.add_argument("spc_dir", type=Path)
    ex.add_argument("out_dir", type=Path)
    ex.add_argument("--cfa", default="RGGB", help="mono | RGGB | BGGR | GRBG | GBRG | RGBW (default RGGB)")
    ex.add_argument("--format", default="npy.gz", choices=photon_cubes.FORMATS)
    ex.add_argument("--bitorder", default="big", choices=photon_cubes.BITORDERS)
    ex.add_argument("--scene", type=Path, help="the scene folder: reference views and poses are copied")
    ex.add_argument("--seed", type=int, default=0, help="seed of the fresh draws of W / mono pixels")
    ex.add_argument("--no-poses", action="store_true", help="leave poses_bounds.npy out (COLMAP poses the views)")
    ins = sub.add_parser("inspect", help="hot pixels, detection rates and MLE previews of a capture")
    ins.add_argument("folder", type=Path)
    ins.add_argument("out_dir", type=Path)
    ins.add_argument("--frames", type=int, help="use the first N frames of every view (default: sensor.json)")
    ins.add_argument(
        "--level",
        type=float,
        default=captures.PREVIEW_LEVEL,
        help="linear grey level the mean flux is shown at (average metering)",
    )
    ins.add_argument("--threshold", type=float, default=6.0, help="hot-pixel robust z-score threshold")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        if args.command == "export":
            rec = captures.export_simulated(
                args.spc_dir,
                args.out_dir,
                args.cfa,
                args.format,
                args.bitorder,
                args.scene,
                seed=args.seed,
                poses=not args.no_poses,
            )
            print(
                f"{args.out_dir}: {rec['frames']} frames of {rec['width']}x{rec['height']}, "
                f"cfa {rec['cfa']}, format {rec['format']}"
            )
        else:
            rec = captures.inspect_capture(args.folder, args.out_dir, args.frames, args.level, args.threshold)
            rates = ", ".join(f"{c} {r:.3f}" for c, r in rec["detection_rate"].items())
            hot = rec["hot_pixels"]
            print(
                f"{args.folder}: {len(rec['views'])} views, {rec['frames']} frames of "
                f"{rec['width']}x{rec['height']}, cfa {rec['cfa']}"
            )
            print(f"  detection rate per colour: {rates}")
            print(f"  hot pixels: {hot['count']} ({100 * hot['count'] / hot['pixels']:.3f} %)")
            print(f"  previews, hot_pixels.png, capture.json in {args.out_dir}")
    except (OSError, ValueError) as e:
        print(f"capture {args.command}: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
