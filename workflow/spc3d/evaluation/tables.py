"""Paper-layout tables generated from ``metrics.json`` files (mean ± std over runs, with n).

A table spec is a list of rows ``(label, source, stage-2 family, paper (PSNR, SSIM, LPIPS) or None,
role)``; the family ``nerf`` resolves to the configured NeRF variant (``nerf`` or ``nerf-grid``),
whose name appears in the row. Physics rows (``mle``, ``bernoulli``) of other frame budgets that
were run are appended. Every row states its photon budget K (binary frames per view, read from
the records; "–" for the ground-truth oracle) and its poses, and the rows sit in three blocks:
the main block (the smallest K, the paper's setting), multi-frame references (larger K), and the
oracle rows. Best and second-best values per column are marked bold and italic from the numbers,
**only among rows with the same K** (never the oracle). n counts the runs (scenes × seeds) behind
a row; with n = 1 no spread is shown. The paper's values sit in adjacent columns (it does not name
its LPIPS backbone, so both of ours are shown).

Outputs: ``{stem}.csv`` (numbers), ``{stem}.md``, ``{stem}.tex`` and ``{stem}.html`` (formatted).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import pandas as pd

from spc3d import io
from spc3d.evaluation.record import read_runs
from spc3d.names import LABELS, METRICS, NERF_FAMILY, TRAINED_METHODS, as_read, parse_source, row_model, source_label

# What every caption says about the protocol (the rule for the physics rows' display gain included).
PROTOCOL = (
    "K = binary frames per view a row consumed, and S x S sensor pixels behind each image pixel where a row read "
    "the frame taken at S x the resolution (the paper-faithful single stage); ranks (bold best, italic second) "
    "only among rows of equal budget (K, S); oracle rows read the ground truth and are not ranked. No other row "
    "reads the evaluation scene's ground truth or its scored views' frames: every photon-fed row but the raw "
    "binary frame is displayed at the exposure the camera reports (translators: their camera image at that "
    "exposure; MLE: k × the exposure, k fitted on the training scenes; SPAD likelihood: the exposure itself), "
    "so a dark scene displays dark. Poses: ground truth for every row. Mean ± std over n runs (scenes × seeds)."
)

# Paper Table 2 (single-stage), then the variants of its baseline and the rows this project adds.
# "none" is the paper-faithful single stage (the frame at spc.capture_factor x the resolution, area-
# averaged); "-x1" is frame 0 at the working resolution, "-mse" fits it with MSE (spc3d.names.SUFFIXES).
SINGLE_STAGE = [
    (
        "NeRF on binary (single stage; frame at S× resolution, area-averaged)",
        "none",
        "nerf",
        (19.42, 0.6252, 0.50013),
        "paper",
    ),
    (
        "3DGS on binary (single stage; frame at S× resolution, area-averaged)",
        "none",
        "3dgs",
        (18.643, 0.5103, 0.4855),
        "paper",
    ),
    ("NeRF on binary, frame at working resolution", "none-x1", "nerf", None, "variant"),
    ("3DGS on binary, frame at working resolution, L1 + D-SSIM", "none-x1", "3dgs", None, "variant"),
    ("3DGS on binary, frame at working resolution, MSE", "none-x1-mse", "3dgs", None, "variant"),
    ("Pix2PixHD + NeRF", "pix2pixhd", "nerf", (22.70, 0.6843, 0.4949), "paper"),
    ("Pix2PixHD + 3DGS", "pix2pixhd", "3dgs", (22.21, 0.6772, 0.4251), "paper"),
    ("3DGS, SPAD likelihood on binary (single stage)", "bernoulli", "3dgs", None, "ours"),
    ("MLE + 3DGS (frame at S× resolution; physics, no training)", "mle", "3dgs", None, "ours"),
    ("MLE + 3DGS, frame at working resolution, L1 + D-SSIM", "mle-x1", "3dgs", None, "variant"),
    ("MLE + 3DGS, frame at working resolution, MSE", "mle-x1-mse", "3dgs", None, "variant"),
    ("Oracle: ground-truth RGB + NeRF", "gt", "nerf", None, "oracle"),
    ("Oracle: ground-truth RGB + 3DGS", "gt", "3dgs", None, "oracle"),
]


# Paper Table 1 (two-stage); "DiffBIR" rows are our diffusion stand-in (DiffBIR's weights are not
# reachable offline), labelled so, with the paper's DiffBIR numbers alongside for reference. The
# translators' untrained start (the physics prior alone) follows; published-network rows ("-pub")
# that ran are appended as their own block (:func:`published_rows`).
TWO_STAGE = [
    ("Pix2PixHD + NeRF", "pix2pixhd", "nerf", (22.70, 0.6843, 0.4949), "paper"),
    ("Pix2PixHD + 3DGS", "pix2pixhd", "3dgs", (22.21, 0.6772, 0.4251), "paper"),
    ("Pix2Pix + NeRF", "pix2pix", "nerf", (18.35, 0.5578, 0.6473), "paper"),
    ("CycleGAN + NeRF", "cyclegan", "nerf", (16.49, 0.5377, 0.6502), "paper"),
    ("Restormer + NeRF", "restormer", "nerf", (20.416, 0.6562, 0.4886), "paper"),
    ("Restormer + 3DGS", "restormer", "3dgs", (19.2733, 0.4325, 0.6063), "paper"),
    ("Diffusion (DiffBIR stand-in) + NeRF", "diffusion", "nerf", (19.353, 0.6103, 0.5009), "paper"),
    ("Diffusion (DiffBIR stand-in) + 3DGS", "diffusion", "3dgs", (17.195, 0.41825, 0.47815), "paper"),
    ("Physics prior (blurred MLE, the translators' untrained start) + NeRF", "prior", "nerf", None, "ours"),
    ("Physics prior (blurred MLE, the translators' untrained start) + 3DGS", "prior", "3dgs", None, "ours"),
    (
        "Classical denoiser (the best non-learned one, chosen on the training scenes) + NeRF",
        "classical",
        "nerf",
        None,
        "ours",
    ),
    (
        "Classical denoiser (the best non-learned one, chosen on the training scenes) + 3DGS",
        "classical",
        "3dgs",
        None,
        "ours",
    ),
    ("MLE + 3DGS (frame at S× resolution; physics, no training)", "mle", "3dgs", None, "ours"),
    ("Oracle: ground-truth RGB + NeRF", "gt", "nerf", None, "oracle"),
    ("Oracle: ground-truth RGB + 3DGS", "gt", "3dgs", None, "oracle"),
]
PHYSICS = ("mle", "bernoulli")  # sources whose other frame budgets are appended to both tables


# A standalone page per table (the HTML report shows it in its main panel).
HTML_PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{caption}</title><style>
body {{ font-family: sans-serif; font-size: 13px; margin: 12px; }}
table {{ border-collapse: collapse; }} th, td {{ border: 1px solid #ccc; padding: 3px 6px; text-align: right; }}
td:first-child, th:first-child {{ text-align: left; }} th {{ background: #f0f0f0; }}
</style></head><body><h3>{caption}</h3>
{table}
<p>{protocol}</p>
</body></html>
"""


def collect(metrics_files: list[str | os.PathLike]) -> pd.DataFrame:
    """One row per metrics.json: scene, combination, seed, K, 3DGS initialisation and the mean metrics."""
    rows = []
    for rec in read_runs(metrics_files):
        if not rec.reference:  # a capture without reference views: no_reference_table
            continue
        rows.append(
            {
                "scene": rec.scene,
                "combination": rec.row,
                "seed": rec.seed,
                "K": rec.frames,
                "S": rec.capture_factor,
                "init": rec.init,
                "poses": poses_text(rec.get("poses")),
                **{k: rec.score(k) for k in METRICS},  # NaN: not reconstructed
            }
        )
    return pd.DataFrame(rows, columns=["scene", "combination", "seed", "K", "S", "init", "poses", *METRICS])


def poses_text(poses) -> str:
    """How a row was posed: "ground truth", the scene's own estimate (a capture without poses: a
    string), or COLMAP's source, views posed and errors."""
    if isinstance(poses, str) and not poses.startswith("ground truth"):  # a capture posed by COLMAP
        return poses
    if not isinstance(poses, dict):
        return "ground truth"
    text = f"COLMAP on {poses['source']}: {poses['registered']}/{poses['total']} training views"
    if poses["status"] != "ok":
        return text + " (too few: not reconstructed)"
    rot, cen = poses["rotation_deg"]["median"], poses["center_rel"]["median"]
    return text + f", rotation {rot:.2f}°, centre {100 * cen:.1f} % of the spread (medians)"


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    """Mean, std (ddof 0) and n per combination over scenes and seeds, with its budget (K, S) and
    initialisation."""
    g = df.groupby("combination")
    out = g[list(METRICS)].mean().add_suffix("_mean").join(g[list(METRICS)].std(ddof=0).add_suffix("_std"))
    out = out.join(g.size().rename("runs"))
    out["K"] = g["K"].agg(lambda k: _one(k, "K"))
    out["S"] = g["S"].agg(lambda v: _one(v, "S")) if "S" in df else 1
    out["init"] = g["init"].agg(
        lambda v: "; ".join(sorted({str(x).split(" (")[0] for x in v if x is not None})) or None
    )
    if "poses" in df:
        out["poses"] = g["poses"].agg(lambda v: "; ".join(dict.fromkeys(v)))
    return out


def _one(values: pd.Series, what: str):
    distinct = {None if pd.isna(v) else int(v) for v in values}
    if len(distinct) > 1:
        raise ValueError(f"one combination with different {what} across its runs: {sorted(distinct, key=str)}")
    return distinct.pop()


def extra_rows(summary: pd.DataFrame, spec: list, nerf_variant: str, unlisted: bool = False) -> list:
    """Spec rows for combinations that ran but are not in ``spec``: physics rows of other forms and
    frame budgets, the joint rows (likelihood + stage-1 prior, both tables), and the published
    networks ("-pub") of the spec's translator rows (their own block);
    ``unlisted``: also every other translator and oracle row (models the paper has not, plugins')."""
    listed = {f"{src}+{row_model(fam, nerf_variant)}" for _, src, fam, *_ in spec}
    rows = []
    for label, src, family, paper, _ in spec:
        model = row_model(family, nerf_variant)
        pub = f"{src}-pub+{model}"
        if src in TRAINED_METHODS and pub in summary.index and pub not in listed:  # once, if spec lacks it
            rows.append((f"{label} — published network (prior_sigma 0)", f"{src}-pub", family, paper, "published"))
    listed |= {f"{src}+{row_model(fam, nerf_variant)}" for _, src, fam, *_ in rows}
    for combo in summary.index:
        source, _, model = combo.partition("+")
        name = parse_source(source)
        other = unlisted and (name.base == "gt" or name.method is not None)
        if combo not in listed and "@" not in combo and (name.base in PHYSICS or name.joint or other):
            label = f"{source_label(source)} + {model.upper() if model == '3dgs' else model}"
            role = "oracle" if name.base == "gt" else "published" if name.pub else "ours"
            rows.append((label if role != "oracle" else f"Oracle: {label}", source, model, None, role))
    return rows


def table(
    summary: pd.DataFrame, spec: list, nerf_variant: str, in_blocks: bool = True, unlisted: bool = False
) -> pd.DataFrame:
    """Numeric table: the spec's rows (and the rows :func:`extra_rows` adds) in blocks main | published
    networks | references | oracle; ``in_blocks=False``: the spec's rows alone, in the spec's order."""
    rows = []
    extra = extra_rows(summary, spec, nerf_variant, unlisted) if in_blocks else []
    for label, source, family, paper, role in spec + extra:
        model = row_model(family, nerf_variant)
        combo = f"{source}+{model}"
        have = combo in summary.index
        row = {
            "approach": label + (f" [{model}]" if family == NERF_FAMILY else ""),
            "combination": combo,
            "role": role,
            "K": summary.loc[combo, "K"] if have else None,
            "S": int(summary.loc[combo, "S"]) if have and "S" in summary else 1,
            "poses": summary.loc[combo, "poses"] if have and "poses" in summary else "ground truth",
            "init": summary.loc[combo, "init"] if have else None,
            "runs": int(summary.loc[combo, "runs"]) if have else 0,
        }
        for k in METRICS:
            row[f"{k}_mean"] = summary.loc[combo, f"{k}_mean"] if have else np.nan
            row[f"{k}_std"] = summary.loc[combo, f"{k}_std"] if have else np.nan
        row.update(dict(zip(("paper_psnr", "paper_ssim", "paper_lpips"), paper or (np.nan,) * 3)))
        rows.append(row)
    df = pd.DataFrame(rows)
    if df.empty:
        return df
    df["block"] = [block(r, k, s, df) for r, k, s in zip(df["role"], df["K"], df["S"])]
    return df.sort_values("block", kind="stable").reset_index(drop=True) if in_blocks else df


def bits(K, S) -> float | None:
    """Binary samples per working pixel and view behind a row (K frames of S x S sensor pixels)."""
    return None if K is None or pd.isna(K) else float(K) * float(S) ** 2


def block(role: str, K, S, df: pd.DataFrame) -> int:
    """0: the main block (the fewest bits per pixel present), 1: published networks, 2: references
    of more bits per pixel (more frames, or the S x S capture frame), 3: oracle rows."""
    if role == "oracle":
        return 3
    present = [b for b in map(bits, df["K"], df["S"]) if b is not None]
    mine = bits(K, S)
    if present and mine is not None and mine > min(present):
        return 2
    return 1 if role == "published" else 0


def ranks(df: pd.DataFrame, key: str, higher_better: bool) -> pd.Series:
    """1 = best, 2 = second among non-oracle rows of the same budget (K, S, and ground-truth or
    estimated poses) that have a value; 0 otherwise."""
    out = pd.Series(0, index=df.index)
    ranked = df[(df["role"] != "oracle") & df[key].notna()]
    S = ranked["S"] if "S" in ranked else pd.Series(1, index=ranked.index)
    budget = (
        ranked["K"].astype("Int64").astype(str)
        + "x"
        + S.astype(str)
        + ranked["poses"].eq("ground truth").map({True: "", False: "@"})
    )
    for _, group in ranked.groupby(budget):
        order = group[key].rank(ascending=not higher_better, method="min")
        out[group.index] = order.where(order <= 2, 0).astype(int)
    return out


def formatted(df: pd.DataFrame, bold, italic) -> pd.DataFrame:
    """Display strings: mean ± std (best / second within equal K marked; no ± when n = 1), K, n."""
    S = df["S"] if "S" in df else [1] * len(df)
    label = [
        a if n == 0 else f"{a} (oracle, no photons)" if role == "oracle" else f"{a} (K = {k_text(k, s)})"
        for a, k, s, n, role in zip(df["approach"], df["K"], S, df["runs"], df["role"])
    ]
    out = pd.DataFrame(
        {
            "Approach": label,
            "combination": df["combination"],
            "K": [k_text(k, s) for k, s in zip(df["K"], S)],
            "poses": df["poses"],
            "n": df["runs"],
        }
    )
    is_3dgs = df["combination"].str.contains(r"\+3dgs(?:@|$)")
    if is_3dgs.any():  # where each 3DGS started (stage2.init, as done)
        out["3DGS init"] = [i if g and isinstance(i, str) else "–" for g, i in zip(is_3dgs, df["init"])]
    for k, (title, higher) in METRICS.items():
        r = ranks(df, f"{k}_mean", higher)
        digits = 2 if k == "psnr" else 4
        cells = []
        for mean, std, n, rank in zip(df[f"{k}_mean"], df[f"{k}_std"], df["runs"], r):
            text = "–" if np.isnan(mean) else f"{mean:.{digits}f}" + (f" ± {std:.{digits}f}" if n > 1 else "")
            cells.append(bold(text) if rank == 1 else italic(text) if rank == 2 else text)
        out[title] = cells
    for k, title in (("paper_psnr", "paper PSNR"), ("paper_ssim", "paper SSIM"), ("paper_lpips", "paper LPIPS")):
        if df[k].isna().all():
            continue  # a table without paper values (stage 1) gets no empty paper columns
        out[title] = [("–" if np.isnan(v) else f"{v:g}") for v in df[k]]
    return out


def k_text(K, S=1) -> str:
    """ "16", or "1 at 4×4 px" for a frame of S x S sensor pixels per image pixel; "–" for the oracle."""
    if K is None or pd.isna(K):
        return "–"
    return str(int(K)) + (f" at {int(S)}×{int(S)} px" if S and int(S) > 1 else "")


def write_table(df: pd.DataFrame, stem: str | os.PathLike, caption: str, protocol: str = PROTOCOL) -> None:
    """``stem``.csv (numbers), .md, .tex and .html (formatted) atomically."""
    md = formatted(df, lambda s: f"**{s}**", lambda s: f"*{s}*")
    tex = formatted(df, lambda s: f"\\textbf{{{s}}}", lambda s: f"\\textit{{{s}}}")
    tex = tex.map(
        lambda s: (
            s.replace("±", "$\\pm$").replace("↑", "$\\uparrow$").replace("↓", "$\\downarrow$").replace("–", "--")
            if isinstance(s, str)
            else s
        )
    )
    html = formatted(df, lambda s: f"<b>{s}</b>", lambda s: f"<i>{s}</i>").to_html(index=False, escape=False)
    write_formats(stem, df, md, tex, html, caption, protocol)


def write_formats(stem, numbers: pd.DataFrame, md: pd.DataFrame, tex: pd.DataFrame, html: str, caption, protocol):
    """The four files of a table, atomically: ``numbers`` as .csv, the display frames as .md and
    .tex (caption and protocol around them) and the HTML table in the report's page."""
    stem = Path(stem)
    io.write_text(stem.with_suffix(".csv"), numbers.to_csv(index=False, float_format="%.6g"))
    io.write_text(stem.with_suffix(".md"), f"# {caption}\n\n" + md.to_markdown(index=False) + f"\n\n{protocol}\n")
    io.write_text(stem.with_suffix(".tex"), tex.to_latex(index=False, caption=f"{caption}. {protocol}", escape=False))
    io.write_text(stem.with_suffix(".html"), HTML_PAGE.format(caption=caption, table=html, protocol=protocol))


def scoring_note(files: list[str | os.PathLike]) -> str:
    """The caption's sentence naming the scenes scored on luminance (captured by a colourless sensor:
    ``scored_on`` in their records, run or stage-1 ones alike,
    :func:`spc3d.evaluation.evaluate.scene_has_colour`); "" when there are none."""
    scenes = sorted({r["scene"] for r in map(io.read_json, files) if r.get("scored_on", "RGB") != "RGB"})
    if not scenes:
        return ""
    return (
        f" Scene{'s' if len(scenes) > 1 else ''} {', '.join(scenes)}: captured by a colourless sensor, so every "
        "row there is scored on luminance (render and reference reduced to Rec. 709 Y)."
    )


def photon_note(spc_dirs: list[str | os.PathLike]) -> str:
    """The caption's sentence naming the evaluation scenes whose frames carry (almost) no image
    (``warnings`` of their spc.json, :func:`spc3d.physics.record.frame_warnings`) or whose data look
    implausible (an LLFF folder's poses, :func:`spc3d.llff.rig_warnings`; a capture's sensor,
    :func:`spc3d.captures.plausibility.capture_warnings`): their rows may measure the exposure or the
    data, not the method. "" when there are none."""
    said = []
    for folder in spc_dirs:
        path = Path(folder) / "spc.json"
        warnings = io.read_json(path).get("warnings") if path.is_file() else None
        if warnings:
            said.append(f"{Path(folder).name}: {'; '.join(warnings)}")
    if not said:
        return ""
    return (
        f" Warning, frames without an image or implausible data ({', '.join(said)}): the rows there may measure "
        "the exposure or the data, not the method."
    )


def reconstructor_note(summary: pd.DataFrame, nerf_variant: str) -> str:
    """The caption's sentence on what bounds each model's rows: its oracle (ground-truth RGB) score,
    so a NeRF row far below 3DGS's ceiling is read as the NeRF's budget, not its source's."""
    oracle = {m: f"gt+{m}" for m in (nerf_variant, "3dgs") if f"gt+{m}" in summary.index}
    if len(oracle) < 2:
        return ""
    psnr = {m: summary.loc[c, "psnr_mean"] for m, c in oracle.items()}
    gap = psnr["3dgs"] - psnr[nerf_variant]
    bound = f" NeRF rows are bounded by the reconstructor: {gap:.1f} dB below 3DGS's." if gap > 1.0 else ""
    return (
        f" Ceilings on ground-truth RGB: {nerf_variant} {psnr[nerf_variant]:.2f} dB, 3DGS {psnr['3dgs']:.2f} dB "
        f"PSNR.{bound}"
    )


def paper_table(
    metrics_files: list[str],
    stem: str,
    nerf_variant: str,
    spec: list,
    caption: str,
    unlisted: bool = False,
    note: str = "",
) -> pd.DataFrame:
    """A paper-layout table of ``spec`` (+ the rows :func:`extra_rows` adds) from the metrics files;
    ``note`` ends its caption (:func:`photon_note`)."""
    summary = summarise(collect(metrics_files))
    df = table(summary, spec, nerf_variant, unlisted=unlisted)
    note = reconstructor_note(summary, nerf_variant) + scoring_note(metrics_files) + note
    write_table(df, stem, caption, PROTOCOL + note)
    return df


def single_stage_table(metrics_files: list[str], stem: str, nerf_variant: str, note: str = "") -> pd.DataFrame:
    """Paper Table 2 layout (+ the single-stage variants and this project's rows)."""
    caption = "Single-stage vs two-stage (paper Table 2 layout)"
    return paper_table(metrics_files, stem, nerf_variant, SINGLE_STAGE, caption, note=note)


def two_stage_table(metrics_files: list[str], stem: str, nerf_variant: str, note: str = "") -> pd.DataFrame:
    """Paper Table 1 layout (+ the untrained prior, published networks and this project's rows)."""
    caption = "Two-stage: stage-1 translator + stage-2 reconstructor (paper Table 1 layout)"
    return paper_table(metrics_files, stem, nerf_variant, TWO_STAGE, caption, unlisted=True, note=note)


def row_label(source: str, labels: dict[str, str]) -> str:
    """A source's name in a table whose K has a column of its own (``labels`` may name it whole)."""
    return labels.get(source, source_label(source, labels, frames=False))


def stage1_row(rec: dict, combination: str, mean: dict) -> dict:
    """One stage-1 record's scores as a table row named ``combination``."""
    return {
        "scene": rec["scene"],
        "combination": as_read(combination, rec.get("frames"), rec.get("capture_factor")),
        "K": rec.get("frames"),
        "S": rec.get("capture_factor") or 1,
        "init": None,
        **{k: mean[k] for k in METRICS},
    }


def stage1_role(source: str) -> str:
    """A stage-1 row's block: the oracle, the published networks (their own block, as in Table 1), ours."""
    return "oracle" if source == "gt" else "published" if parse_source(source).pub else "ours"


def stage1_table(stage1_files: list[str], stem: str, labels: dict[str, str], note: str = "") -> pd.DataFrame:
    """Stage-1 image quality of the held-out views before 3D, one row per source (best first)."""
    rows, prior_rows, names = [], {}, {}
    records = [io.read_json(path) for path in stage1_files]
    own_prior = any(rec["source"] == "prior" for rec in records)  # the prior scored as a source of its own
    for rec in records:
        rows.append(stage1_row(rec, rec["source"], rec["mean"]))
        if rec.get("prior") and not own_prior:  # the translators' physics prior alone: one row per blur
            sigma = rec["prior"].get("sigma")
            name = names.setdefault(sigma, "prior" if not names else f"prior-{sigma:g}px")
            prior_rows.setdefault((name, rec["scene"], rec.get("seed")), stage1_row(rec, name, rec["prior"]["mean"]))
    rows += prior_rows.values()
    summary = summarise(pd.DataFrame(rows, columns=["scene", "combination", "K", "S", "init", *METRICS]))
    spec = [
        (row_label(src, labels), src, "image", None, stage1_role(src))
        for src in summary.sort_values("psnr_mean", ascending=False).index
    ]
    df = table(summary.rename(index=lambda c: f"{c}+image"), spec, "image")
    df["combination"] = [c.removesuffix("+image") for c in df["combination"]]
    caption = "Stage 1 alone: translated held-out views vs ground truth, before 3D"
    write_table(df, stem, caption, PROTOCOL + scoring_note(stage1_files) + note)
    return df


POSES_PROTOCOL = (
    "Each row with poses from COLMAP trained on the cameras COLMAP estimated from the named source's images of "
    "the training views (held-out views never reach COLMAP; views it did not pose are left out of training); "
    "its twin on the ground-truth poses sits above it. Renders are scored in the reference frame: the estimated "
    "world is mapped onto it by the similarity aligning the posed training cameras with theirs (the pose-free "
    "novel-view-synthesis protocol); pose errors are after that alignment. K counts the binary frames per view "
    "behind the images and the poses; ranks (bold, italic) only among rows of equal K and pose kind."
)


def estimated_poses_table(metrics_files: list[str], stem: str, labels: dict[str, str]) -> pd.DataFrame:
    """Rows trained on estimated poses (``source+model@poses``), each below its ground-truth-pose twin."""
    summary = summarise(collect(metrics_files))
    spec = []
    for combo in (c for c in summary.index if "@" in c):
        twin, _, poses = combo.partition("@")
        for c in ([twin] if twin in summary.index and twin not in {s[1] + "+" + s[2] for s in spec} else []) + [combo]:
            source, _, model = c.partition("+")
            name = f"{row_label(source, labels)} + {model.partition('@')[0].upper()}"
            spec.append((name, source, model, None, "oracle" if source == "gt" else "ours"))
    df = table(summary, spec, "", in_blocks=False)
    if df.empty:
        write_text_table(stem, "No row with estimated poses: add e.g. 'bernoulli+3dgs@mle-k16' to stage2.combinations")
        return df
    caption = "Poses from the photons: rows on COLMAP poses beside ground-truth poses"
    write_table(df, stem, caption, POSES_PROTOCOL + scoring_note(metrics_files))
    return df


NO_REFERENCE_PROTOCOL = (
    "Scenes without reference views (captures without images/) cannot be scored against images. Each row is "
    "scored instead by how well its renders explain the held-out views' binary frames, which no row trained on: "
    "the Bernoulli NLL of those frames at the single gain that fits them best, minus the frames' own entropy "
    "(nats per bit; 0 = as well as any image can; spc3d.evaluation.heldout). Lower is better; ranks (bold best, italic "
    "second) only among rows of one scene and equal K."
)


def no_reference_table(metrics_files: list[str], stem: str) -> pd.DataFrame:
    """Rows on scenes without reference views, scored by the held-out views' photons (``no_reference``)."""
    rows = []
    for rec in read_runs(metrics_files):
        score = rec.get("no_reference") if not rec.reference else None
        if score:
            rows.append(
                {
                    "scene": rec.scene,
                    "combination": rec.combination,
                    "K": rec.frames,
                    "poses": poses_text(rec.get("poses")),
                    "seed": rec.seed,
                    "excess NLL↓": score["excess_nll"],
                    "NLL": score["nll"],
                    "floor": score["floor_nll"],
                    "held-out frames": score["frames"],
                    "views": score["views"],
                }
            )
    if not rows:
        write_text_table(stem, "No row on a scene without reference views (a capture without images/)")
        return pd.DataFrame(rows)
    df = pd.DataFrame(rows).sort_values(["scene", "K", "excess NLL↓"], kind="stable").reset_index(drop=True)
    shown = df.astype(object)
    for _, group in df.groupby(["scene", "K"], dropna=False):
        order = group["excess NLL↓"].rank(method="min")
        for i, r in order.items():
            text = f"{df.at[i, 'excess NLL↓']:.4f}"
            shown.at[i, "excess NLL↓"] = f"**{text}**" if r == 1 else f"*{text}*" if r == 2 else text
    for col in ("NLL", "floor"):
        shown[col] = [f"{v:.4f}" for v in df[col]]
    stem, protocol = Path(stem), NO_REFERENCE_PROTOCOL
    caption = "Scenes without reference views: rows scored by the held-out views' photons"
    plain = shown.map(lambda v: v.strip("*") if isinstance(v, str) else v)
    io.write_text(stem.with_suffix(".csv"), df.to_csv(index=False, float_format="%.6g"))
    io.write_text(stem.with_suffix(".md"), f"# {caption}\n\n{shown.to_markdown(index=False)}\n\n{protocol}\n")
    io.write_text(stem.with_suffix(".tex"), plain.to_latex(index=False, caption=f"{caption}. {protocol}"))
    html = HTML_PAGE.format(caption=caption, table=plain.to_html(index=False), protocol=protocol)
    io.write_text(stem.with_suffix(".html"), html)
    return df


LATEX = {"%": "\\%", "Δ": "$\\Delta$", "–": "--", "−": "$-$"}


def to_latex(text: str) -> str:
    """A display string with the characters LaTeX needs spelled out."""
    return functools.reduce(lambda t, kv: t.replace(*kv), LATEX.items(), text)


def write_plain_table(text: pd.DataFrame, numbers: pd.DataFrame, stem, caption: str, protocol: str) -> None:
    """``stem``.csv (``numbers``) and .md / .tex / .html (``text``: display strings), atomically."""
    tex = text.map(lambda s: to_latex(s) if isinstance(s, str) else s)
    tex.columns = [to_latex(c) for c in tex.columns]
    write_formats(stem, numbers, text, tex, text.to_html(index=False, escape=True), caption, protocol)


def write_text_table(stem: str | os.PathLike, text: str) -> None:
    """A table's four files holding one sentence (a table with no rows)."""
    stem = Path(stem)
    io.write_text(stem.with_suffix(".csv"), "")
    io.write_text(stem.with_suffix(".md"), text + "\n")
    io.write_text(stem.with_suffix(".tex"), f"% {text}\n")
    io.write_text(stem.with_suffix(".html"), HTML_PAGE.format(caption=text, table="", protocol=""))


def write_all_tables(
    metrics_files: list[str],
    stage1_files: list[str],
    folder: str | os.PathLike,
    nerf_variant: str,
    labels: dict[str, str] = LABELS,
    smallest_effect: float | None = None,
    spc_dirs: list[str] = (),
    rivals: dict[str, list[str]] | None = None,
) -> None:
    """single_stage.*, two_stage.*, estimated_poses.*, stage1.*, no_reference.* and the findings
    (findings.md / .json / .html) in ``folder``; the findings decide against the smallest effect of
    interest ``smallest_effect`` (dB PSNR; None: the findings' SMALLEST_EFFECT). ``spc_dirs``: the
    evaluation scenes' SPC folders, whose frame warnings the captions name (:func:`photon_note`);
    ``rivals``: the claims' listed rivals (``findings.rivals``, :func:`spc3d.evaluation.findings.claims`)."""
    from spc3d.evaluation.findings import SMALLEST_EFFECT, write_findings

    folder, note = Path(folder), photon_note(spc_dirs)
    single_stage_table(metrics_files, folder / "single_stage", nerf_variant, note)
    two_stage_table(metrics_files, folder / "two_stage", nerf_variant, note)
    estimated_poses_table(metrics_files, folder / "estimated_poses", labels)
    if stage1_files:
        stage1_table(stage1_files, folder / "stage1", labels, note)
    else:  # every evaluation scene is a capture without reference views: nothing to score before 3D
        write_text_table(folder / "stage1", "Stage 1 alone: no evaluation scene has reference views, nothing scored")
    no_reference_table(metrics_files, folder / "no_reference")
    delta = SMALLEST_EFFECT if smallest_effect is None else smallest_effect
    write_findings(metrics_files, folder / "findings", nerf_variant, stage1_files, smallest_effect=delta, rivals=rivals)
