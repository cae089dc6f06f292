"""Which image sources can pose a scene: COLMAP on each source's training views (spc3d.poses.estimate).

    python benchmarks/poses_sources.py RESULTS_DIR [--scene courtyard]

Reads a finished run's folders (the scene, its binary frames, the metered MLE images of every K
there, every translator's outputs) and runs :func:`spc3d.poses.estimate.estimate_poses` on each into a
temporary folder, then prints how many training views COLMAP posed and the median rotation and
centre errors after the similarity alignment, with the time taken.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from spc3d.names import STAGE1_METHODS  # noqa: E402
from spc3d.poses.estimate import estimate_poses  # noqa: E402


def image_sets(results: Path, scene: str) -> dict[str, tuple[Path, int | None]]:
    """Source name -> (image folder, frames per view) of everything the run wrote for ``scene``."""
    sets = {"gt": (results / "scenes" / scene / "images", None), "none": (results / "spc" / scene / "binary", 1)}
    for folder in sorted((results / "mle" / scene).glob("k*")):
        k = int(folder.name[1:])
        sets[f"mle-k{k}"] = (folder / "images", k)
    for method in STAGE1_METHODS:
        folder = results / "translate" / scene / method / "images"
        if folder.is_dir():
            sets[method] = (folder, 1)
    return sets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("--scene", default="courtyard")
    args = parser.parse_args()
    if not (args.results / "scenes" / args.scene).is_dir():
        raise SystemExit(f"{args.results / 'scenes' / args.scene} does not exist: run the workflow first")
    print(f"| source ({args.scene}) | K | posed | rotation (median) | centre (median, % spread) | time |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, (folder, k) in image_sets(args.results, args.scene).items():
            t0 = time.perf_counter()
            rec = estimate_poses(folder, args.results / "scenes" / args.scene, Path(tmp) / name, name, k)
            ok = rec["status"] == "ok"
            rot = f"{rec['rotation_deg']['median']:.2f}°" if ok else "–"
            cen = f"{100 * rec['center_rel']['median']:.1f} %" if ok else "–"
            k_text = "–" if k is None else str(k)
            posed = f"{rec['registered']}/{rec['total']}"
            print(f"| {name} | {k_text} | {posed} | {rot} | {cen} | {time.perf_counter() - t0:.1f} s |", flush=True)


if __name__ == "__main__":
    main()
