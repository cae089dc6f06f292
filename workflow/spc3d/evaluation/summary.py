"""The data summary: one table row and one figure row per scene.

Table (``data_summary.csv`` / ``.md``): origin, size, the SPC exposure (flux scale, mean detection
rate, saturated fraction), the K-frame MLE's PSNR against the ground truth at the simulator's exact
gain (a diagnostic of the simulation; the table rows meter their gain), and for each COLMAP
input (rgb / binary / average) the registered views and median pose errors.
Figure (``data_summary.png``): RGB | one binary frame | K-frame average | MLE flux estimate, for
the first test view of each scene.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from spc3d import io
from spc3d.inputs.exposure import PREVIEW_LEVEL, display_srgb, metered_gain
from spc3d.physics.record import camera_exposure, read_spc_record
from spc3d.plotting import pyplot, save_png


def scene_row(scene_dir: Path, spc_dir: Path, colmap_dirs: dict[str, Path], role: str) -> dict:
    """One table row from the records the scene, SPC and COLMAP steps wrote."""
    meta, rec = io.read_json(scene_dir / "scene.json"), read_spc_record(spc_dir)
    row = {
        "scene": scene_dir.name,
        "role": role,
        "source": meta.get("source"),
        "layout/path": meta.get("layout") or meta.get("path"),
        "views": meta["views"],
        "size": f"{meta['width']}x{meta['height']}",
        "K": rec["params"]["frames"],
        "flux_scale": rec["flux_scale"],
        "exposure_photons": camera_exposure(rec, f"{spc_dir / 'spc.json'}"),  # per frame at linear 1, as reported
        "sensor": (rec.get("sensor") or {}).get("name", "RGB (simulated)"),
        "detection_rate": rec["mean_detection_rate"],
        "saturated": rec.get("mean_saturated_fraction"),
        "mle_psnr_exact_gain_db": rec.get("mean_mle_psnr_exact_gain_db"),  # simulated scenes: the flux scale is known
    }
    for name, d in colmap_dirs.items():
        row |= colmap_columns(name, io.read_json(d / "pose_error.json"))
    return row


def colmap_columns(name: str, rec: dict) -> dict:
    """Registered views and median pose / reprojection errors of one COLMAP run (None if failed)."""
    pose, reproj = rec.get("pose") or {}, rec.get("reprojection") or {}
    return {
        f"{name}_registered": f"{rec['registered']}/{rec['total']}",
        f"{name}_rot_deg": (pose.get("rotation_deg") or {}).get("median"),
        f"{name}_center_rel": (pose.get("center_rel") or {}).get("median"),
        f"{name}_reproj_px": reproj.get("median_px"),
    }


def summary_table(rows: list[dict]) -> pd.DataFrame:
    return pd.DataFrame(rows).set_index("scene")


def write_tables(df: pd.DataFrame, csv_path: str | os.PathLike, md_path: str | os.PathLike) -> None:
    io.write_text(csv_path, df.to_csv(float_format="%.4g"))
    io.write_text(md_path, "# Data summary\n\n" + df.to_markdown(floatfmt=".4g", missingval="–") + "\n")


def figure_panels(scene_dir: Path, spc_dir: Path) -> tuple[str, list[np.ndarray | None], bool]:
    """(view name, [rgb, binary, average, MLE], exact gain) of the scene's first view (a test view).
    rgb is None for a capture without reference views; a capture's MLE is shown at a metered gain."""
    view = sorted(p.stem for p in (spc_dir / "binary").glob("*.png"))[0]
    flux = io.read_image(spc_dir / "mle" / f"{view}.exr")
    scale = read_spc_record(spc_dir)["flux_scale"]  # None for a capture: average metering instead
    mle = display_srgb(flux, scale if scale is not None else metered_gain(flux, PREVIEW_LEVEL))
    reference = scene_dir / "images" / f"{view}.png"
    rgb = io.read_rgb(reference) if reference.is_file() else None
    panels = [rgb] + [io.read_rgb(spc_dir / k / f"{view}.png") for k in ("binary", "average")] + [mle]
    return view, panels, scale is not None


def write_figure(scenes: list[tuple[Path, Path]], path: str | os.PathLike, K: int) -> None:
    """Grid figure: a row per scene, columns RGB | binary | K-frame average | MLE."""
    plt = pyplot()

    titles = ["RGB (ground truth)", "one binary frame", f"{K}-frame average", f"MLE flux ({K} frames)"]
    fig, axes = plt.subplots(len(scenes), 4, figsize=(12, 2.4 * len(scenes) + 0.4), squeeze=False)
    for r, (scene_dir, spc_dir) in enumerate(scenes):
        view, panels, exact = figure_panels(scene_dir, spc_dir)
        for c, img in enumerate(panels):
            ax = axes[r, c]
            ax.set_xticks([]), ax.set_yticks([])
            if r == 0:
                ax.set_title(titles[c], fontsize=10)
            if img is None:  # a capture without reference views: say so rather than show a black frame
                ax.imshow(np.full_like(panels[1], 0.9))
                ax.text(0.5, 0.5, "no reference views\n(a capture)", ha="center", va="center", transform=ax.transAxes)
                continue
            ax.imshow(img, interpolation="nearest")
        gain = "exact gain (simulator)" if exact else "metered gain (capture)"
        axes[r, 3].text(0.02, 0.03, gain, color="w", fontsize=7, transform=axes[r, 3].transAxes)
        axes[r, 0].set_ylabel(f"{scene_dir.name}\n{view}", fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=110)


def write_summary(
    scene_dirs: list[str],
    spc_dirs: list[str],
    colmap_dirs: list[str],
    roles: list[str],
    out_csv: str,
    out_md: str,
    out_png: str,
) -> pd.DataFrame:
    """Entry point of the ``data_summary`` rule. ``colmap_dirs`` are ``results/colmap/{scene}/{input}``."""
    by_scene: dict[str, dict[str, Path]] = {}
    for d in map(Path, colmap_dirs):
        by_scene.setdefault(d.parent.name, {})[d.name] = d
    pairs = [(Path(s), Path(p)) for s, p in zip(scene_dirs, spc_dirs)]
    rows = [scene_row(s, p, by_scene.get(s.name, {}), role) for (s, p), role in zip(pairs, roles)]
    df = summary_table(rows)
    write_tables(df, out_csv, out_md)
    write_figure(pairs, out_png, int(df["K"].iloc[0]))
    return df
