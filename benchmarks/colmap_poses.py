"""COLMAP pose accuracy and time on the built-in scenes and the real LLFF scenes.

For each scene: prepare the canonical folder (render or import at ``--width``), simulate K SPC
frames (calibrated to a mean detection of 0.5), then run ``spc3d.poses.colmap.colmap_poses`` on the RGB
views, on one binary frame per view and on the K-frame averages. Prints one row per (scene, input):
registered views, median rotation error (deg), median centre error (% of camera spread), median
reprojection error of the sparse points through the reference poses (px) and wall time.

    python benchmarks/colmap_poses.py                          # courtyard + fern + flower, 128 px wide
    python benchmarks/colmap_poses.py --width 504 --scenes fern flower
Real scenes are read from ../shared/data/llff (skipped when absent).
``--smoke``: courtyard at 64 px wide, K = 2 (seconds).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from spc3d.inputs.build import named_spec, prepare_scene, simulate_scene
from spc3d.physics.spc import SPCParams
from spc3d.poses.colmap import colmap_poses

LLFF_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "llff"
INPUTS = {"rgb": ("scene", "images"), "binary": ("spc", "binary"), "average": ("spc", "average")}


def fmt(value, scale=1.0, digits=2) -> str:
    return "-" if value is None else f"{value * scale:.{digits}f}"


def run_scene(name: str, spec: dict, frames: int, work: Path) -> list[str]:
    dirs = {"scene": work / "scenes" / name, "spc": work / "spc" / name}  # stems name the RNG streams
    prepare_scene(spec, dirs["scene"])
    simulate_scene(dirs["scene"], dirs["spc"], SPCParams(frames=frames), seed=0)
    rows = []
    for kind, (base, sub) in INPUTS.items():
        t0 = time.perf_counter()
        rec = colmap_poses(dirs[base] / sub, dirs["scene"], work / "colmap" / name / kind)
        pose, rep = rec["pose"], rec["reprojection"] or {}
        rows.append(
            f"{name:<10} {kind:<8} {rec['registered']:>3}/{rec['total']:<3} "
            f"{fmt((pose['rotation_deg'] or {}).get('median')):>8} "
            f"{fmt((pose['center_rel'] or {}).get('median'), 100, 1):>9} "
            f"{fmt(rep.get('median_px')):>9} {time.perf_counter() - t0:>7.1f}"
        )
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["courtyard", "fern", "flower"])
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--frames", type=int, default=16, help="K for the average input")
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    args = ap.parse_args()
    if args.smoke:
        vars(args).update(scenes=["courtyard"], width=64, frames=2)
    print(f"width {args.width}, K = {args.frames}")
    print(f"{'scene':<10} {'input':<8} {'reg':>7} {'rot_deg':>8} {'centre_%':>9} {'reproj_px':>9} {'wall_s':>7}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes:
            spec = named_spec(name, args.width, LLFF_ROOT)
            if spec is None:
                print(f"{name:<10} skipped: not a built-in layout and not in {LLFF_ROOT}")
                continue
            run_scene(name, spec, args.frames, Path(tmp))


if __name__ == "__main__":
    main()
