"""Paper-layout tables generated from ``metrics.json`` files (mean ± std over scenes and seeds).

A table spec is a list of rows ``(label, source, stage-2 family, paper (PSNR, SSIM, LPIPS) or None,
role)``; the family ``nerf`` resolves to the configured NeRF variant (``nerf`` or ``nerf-grid``),
whose name appears in the row. Best and second-best values per column (among the non-oracle rows
that have results) are marked bold and italic from the numbers themselves. The paper's values sit
in adjacent columns; the paper does not name its LPIPS backbone, so both of ours are shown.

Outputs: ``{stem}.csv`` (numbers), ``{stem}.md`` and ``{stem}.tex`` (formatted).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from . import io

METRICS = {"psnr": ("PSNR↑", True), "ssim": ("SSIM↑", True), "lpips_alex": ("LPIPS-alex↓", False),
           "lpips_vgg": ("LPIPS-vgg↓", False)}

# Paper Table 2 (single-stage), then the rows this project adds.
SINGLE_STAGE = [
    ("NeRF on binary (single stage)", "none", "nerf", (19.42, 0.6252, 0.50013), "paper"),
    ("3DGS on binary (single stage)", "none", "3dgs", (18.643, 0.5103, 0.4855), "paper"),
    ("Pix2PixHD + NeRF", "pix2pixhd", "nerf", (22.70, 0.6843, 0.4949), "paper"),
    ("Pix2PixHD + 3DGS", "pix2pixhd", "3dgs", (22.21, 0.6772, 0.4251), "paper"),
    ("3DGS, SPAD likelihood on binary (single stage)", "bernoulli", "3dgs", None, "ours"),
    ("MLE of K frames + 3DGS", "mle", "3dgs", None, "ours"),
    ("Oracle: ground-truth RGB + NeRF", "gt", "nerf", None, "oracle"),
    ("Oracle: ground-truth RGB + 3DGS", "gt", "3dgs", None, "oracle"),
]


# Paper Table 1 (two-stage); "DiffBIR" rows are our diffusion stand-in (DiffBIR's weights are not
# reachable offline), labelled so, with the paper's DiffBIR numbers alongside for reference.
TWO_STAGE = [
    ("Pix2PixHD + NeRF", "pix2pixhd", "nerf", (22.70, 0.6843, 0.4949), "paper"),
    ("Pix2PixHD + 3DGS", "pix2pixhd", "3dgs", (22.21, 0.6772, 0.4251), "paper"),
    ("Pix2Pix + NeRF", "pix2pix", "nerf", (18.35, 0.5578, 0.6473), "paper"),
    ("CycleGAN + NeRF", "cyclegan", "nerf", (16.49, 0.5377, 0.6502), "paper"),
    ("Restormer + NeRF", "restormer", "nerf", (20.416, 0.6562, 0.4886), "paper"),
    ("Restormer + 3DGS", "restormer", "3dgs", (19.2733, 0.4325, 0.6063), "paper"),
    ("Diffusion (DiffBIR stand-in) + NeRF", "diffusion", "nerf", (19.353, 0.6103, 0.5009), "paper"),
    ("Diffusion (DiffBIR stand-in) + 3DGS", "diffusion", "3dgs", (17.195, 0.41825, 0.47815), "paper"),
    ("MLE of K frames + 3DGS (physics, no training)", "mle", "3dgs", None, "ours"),
    ("Oracle: ground-truth RGB + NeRF", "gt", "nerf", None, "oracle"),
    ("Oracle: ground-truth RGB + 3DGS", "gt", "3dgs", None, "oracle"),
]


# A standalone page per table (the HTML report shows it in its main panel).
HTML_PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{caption}</title><style>
body {{ font-family: sans-serif; font-size: 13px; margin: 12px; }}
table {{ border-collapse: collapse; }} th, td {{ border: 1px solid #ccc; padding: 3px 6px; text-align: right; }}
td:first-child, th:first-child {{ text-align: left; }} th {{ background: #f0f0f0; }}
</style></head><body><h3>{caption}</h3>
{table}
<p>Best in bold, second in italics (from the numbers; oracle rows are not ranked). Mean ± std over scenes and seeds.</p>
</body></html>
"""


def collect(metrics_files: list[str | os.PathLike]) -> pd.DataFrame:
    """One row per metrics.json: scene, combination, seed and the mean metrics."""
    rows = []
    for path in metrics_files:
        rec = io.read_json(path)
        rows.append({"scene": rec["scene"], "combination": rec["combination"], "seed": rec.get("seed"),
                     **{k: rec["mean"][k] for k in METRICS}})
    return pd.DataFrame(rows, columns=["scene", "combination", "seed", *METRICS])


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    """Mean, std and count per combination over scenes and seeds."""
    g = df.groupby("combination")[list(METRICS)]
    out = g.mean().add_suffix("_mean").join(g.std(ddof=0).add_suffix("_std")).join(g.size().rename("runs"))
    return out


def table(summary: pd.DataFrame, spec: list, nerf_variant: str) -> pd.DataFrame:
    """Numeric table in the spec's row order (NaN where a combination has no results yet)."""
    rows = []
    for label, source, family, paper, role in spec:
        model = nerf_variant if family == "nerf" else family
        combo = f"{source}+{model}"
        have = combo in summary.index
        row = {"approach": label + (f" [{model}]" if family == "nerf" else ""), "combination": combo, "role": role,
               "runs": int(summary.loc[combo, "runs"]) if have else 0}
        for k in METRICS:
            row[f"{k}_mean"] = summary.loc[combo, f"{k}_mean"] if have else np.nan
            row[f"{k}_std"] = summary.loc[combo, f"{k}_std"] if have else np.nan
        row.update(dict(zip(("paper_psnr", "paper_ssim", "paper_lpips"), paper or (np.nan,) * 3)))
        rows.append(row)
    return pd.DataFrame(rows)


def ranks(df: pd.DataFrame, key: str, higher_better: bool) -> pd.Series:
    """1 = best, 2 = second among non-oracle rows with a value; 0 otherwise."""
    vals = df[key].where(df["role"] != "oracle")
    order = vals.rank(ascending=not higher_better, method="min")
    return order.where(order <= 2, 0).fillna(0).astype(int)


def formatted(df: pd.DataFrame, bold, italic) -> pd.DataFrame:
    """Display strings: mean ± std (best / second marked), paper values alongside."""
    out = pd.DataFrame({"Approach": df["approach"], "combination": df["combination"], "runs": df["runs"]})
    for k, (title, higher) in METRICS.items():
        r = ranks(df, f"{k}_mean", higher)
        digits = 2 if k == "psnr" else 4
        cells = []
        for mean, std, rank in zip(df[f"{k}_mean"], df[f"{k}_std"], r):
            text = "–" if np.isnan(mean) else f"{mean:.{digits}f} ± {std:.{digits}f}"
            cells.append(bold(text) if rank == 1 else italic(text) if rank == 2 else text)
        out[title] = cells
    for k, title in (("paper_psnr", "paper PSNR"), ("paper_ssim", "paper SSIM"), ("paper_lpips", "paper LPIPS")):
        if df[k].isna().all():
            continue  # a table without paper values (stage 1) gets no empty paper columns
        out[title] = [("–" if np.isnan(v) else f"{v:g}") for v in df[k]]
    return out


def write_table(df: pd.DataFrame, stem: str | os.PathLike, caption: str) -> None:
    """``stem``.csv (numbers), .md, .tex and .html (formatted) atomically."""
    stem = Path(stem)
    io.write_text(stem.with_suffix(".csv"), df.to_csv(index=False, float_format="%.6g"))
    md = formatted(df, lambda s: f"**{s}**", lambda s: f"*{s}*")
    io.write_text(stem.with_suffix(".md"), f"# {caption}\n\n" + md.to_markdown(index=False) + "\n")
    tex = formatted(df, lambda s: f"\\textbf{{{s}}}", lambda s: f"\\textit{{{s}}}")
    tex = tex.map(lambda s: s.replace("±", "$\\pm$").replace("↑", "$\\uparrow$").replace("↓", "$\\downarrow$")
                  .replace("–", "--") if isinstance(s, str) else s)
    io.write_text(stem.with_suffix(".tex"), tex.to_latex(index=False, caption=caption, escape=False))
    html = formatted(df, lambda s: f"<b>{s}</b>", lambda s: f"<i>{s}</i>").to_html(index=False, escape=False)
    io.write_text(stem.with_suffix(".html"), HTML_PAGE.format(caption=caption, table=html))


def single_stage_table(metrics_files: list[str], stem: str, nerf_variant: str) -> pd.DataFrame:
    """Paper Table 2 layout (+ this project's rows) from the given metrics files."""
    df = table(summarise(collect(metrics_files)), SINGLE_STAGE, nerf_variant)
    write_table(df, stem, "Single-stage vs two-stage (paper Table 2 layout); mean ± std over scenes and seeds")
    return df


def two_stage_table(metrics_files: list[str], stem: str, nerf_variant: str) -> pd.DataFrame:
    """Paper Table 1 layout (+ this project's rows) from the given metrics files."""
    df = table(summarise(collect(metrics_files)), TWO_STAGE, nerf_variant)
    write_table(df, stem, "Two-stage: stage-1 translator + stage-2 reconstructor (paper Table 1 layout); "
                          "mean ± std over scenes and seeds")
    return df


def stage1_table(stage1_files: list[str], stem: str, labels: dict[str, str]) -> pd.DataFrame:
    """Stage-1 image quality of the held-out views before 3D, one row per source (best first)."""
    rows = []
    for path in stage1_files:
        rec = io.read_json(path)
        rows.append({"scene": rec["scene"], "combination": rec["source"], **{k: rec["mean"][k] for k in METRICS}})
    summary = summarise(pd.DataFrame(rows, columns=["scene", "combination", *METRICS]))
    spec = [(labels.get(src, src), src, "image", None, "oracle" if src == "gt" else "ours")
            for src in summary.sort_values("psnr_mean", ascending=False).index]
    df = table(summary.rename(index=lambda c: f"{c}+image"), spec, "image")
    df["combination"] = [src for _, src, *_ in spec]
    write_table(df, stem, "Stage 1 alone: translated held-out views vs ground truth, before 3D")
    return df


def write_all_tables(metrics_files: list[str], stage1_files: list[str], folder: str | os.PathLike,
                     nerf_variant: str, labels: dict[str, str]) -> None:
    """single_stage.*, two_stage.* and stage1.* in ``folder``."""
    folder = Path(folder)
    single_stage_table(metrics_files, folder / "single_stage", nerf_variant)
    two_stage_table(metrics_files, folder / "two_stage", nerf_variant)
    if stage1_files:
        stage1_table(stage1_files, folder / "stage1", labels)
