"""A real SPAD sensor against the simulator and stage 1: ../shared/data/spad/wision_yellowthroat.

    python benchmarks/real_spad.py [--data DIR] [--models results/models] [--out results/real_spad] [--docs]
    python benchmarks/real_spad.py --smoke --models DIR --out DIR     # a 48 x 64 crop, a few draws

The capture: one monochrome 384 x 256 scene as means of K = 1, 4, 16, 64, 256 binary frames
(``average{K}.png``, read with :func:`spc3d.captures.photon_cubes.read_frame_mean`).

1. Physics (:mod:`spc3d.physics.real_frames`): λT per pixel from the 256-frame mean; the real
   means against ``--draws`` simulator draws from it (nested, as the capture's), statistic by
   statistic, real with block-bootstrap intervals, simulated with the range over draws. Written
   to ``OUT/tables/real_spad_physics.md``.
2. Stage 1: every trained model in ``--models`` (the methods of ``spc3d.translate.MODULES``
   that have a folder there) translates the real K = 1 frame and ``--sim-frames`` frames the
   simulator draws from the reference (:func:`spc3d.translate.apply.translate_mean`, mono input
   copied to the three channels, luminance kept). Reference: the mean of the capture's *other*
   255 frames (the 1-frame mean is the first frame of the 256: :mod:`spc3d.physics.real_frames`
   shows it), as λT shown with average metering. Each output is scored by PSNR at its best single
   gain against that reference (an oracle step: the gain is fitted on the reference, as the
   exposure of a real frame is unknown), the same for real and simulated frames; the gap is
   simulated - real. Written to ``OUT/tables/real_spad_stage1.md`` and the figure
   ``OUT/real_spad_stage1.png`` (``--docs``: ``docs/figures/real_spad_stage1.png``).

``--docs`` then copies both tables into the generated blocks ``spad:tables/...`` of the README and
docs/ (:func:`readme_results.refresh_run`), the rest left as they are: one command makes them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

from spc3d import io  # noqa: E402
from spc3d.captures.photon_cubes import read_frame_mean  # noqa: E402
from spc3d.inputs.exposure import PREVIEW_LEVEL, display_srgb, metered_gain  # noqa: E402
from spc3d.physics import real_frames as rf  # noqa: E402

DATA = REPO.parent / "shared" / "data" / "spad" / "wision_yellowthroat"
KS = (1, 4, 16, 64, 256)
SMOKE_CROP = (slice(96, 144), slice(160, 224))  # 48 x 64 pixels around the bird
RUN = "spad"  # the run name of the docs' generated blocks: <!-- generated: spad:tables/... -->
GAIN_STOPS = np.linspace(-3.0, 3.0, 121)  # oracle gain search: +-3 stops around the least-squares gain


def read_capture(data: Path, crop=None) -> dict:
    means = {k: read_frame_mean(data / f"average{k}.png", k) for k in KS}
    return {k: (m.counts if crop is None else m.counts[crop]) for k, m in means.items()}


# --------------------------------------------------------------------------------------------
# 1. physics


def fmt(value: float, digits: int = 3) -> str:
    return f"{value:.{digits}f}"


def interval(v: tuple, digits: int = 3) -> str:
    return f"{fmt(v[0], digits)} [{fmt(v[1], digits)}, {fmt(v[2], digits)}]"


def physics_table(r: dict) -> str:
    real, sim, indep, pred = r["real"], r["sim"], r["independent"], r["predictions"]
    h, w = r["shape"]
    ks = sorted(pred)
    lines = [
        "# Real SPAD frames against the simulator",
        "",
        f"Real: WISION yellowthroat capture, {w} x {h} = {r['pixels']:,} pixels, means of K = "
        f"{', '.join(map(str, [*ks, r['k_ref']]))} binary frames; value [95 % interval: bootstrap over "
        f"{r['block']} x {r['block']} pixel blocks, {r['bootstrap']} draws]. Simulated: the project's "
        f"simulator (bernoulli mode) drawing {r['k_ref']} frames per pixel from λT = -log(1 - S_256/256) "
        f"of the real 256-frame mean, the K-means nested (the first K frames); mean [2.5-97.5 % range] over "
        f"{r['draws']} draws.",
        "",
        "| check | K | real | simulated | model says |",
        "|---|---|---|---|---|",
    ]
    for k in ks:
        p = pred[k]
        lines.append(
            f"| Var(m_K − m_256) / (p̂(1−p̂)/K) | {k} | {interval(real['nested_ratio', k])} | "
            f"{interval(sim['nested_ratio', k])} | nested {fmt(p['nested'])}; independent {fmt(p['independent'])} "
            f"(simulated: {interval(indep['nested_ratio', k])}) |"
        )
    for k in ks:
        lines.append(
            f"| Var(m_K − m_other) / binomial, disjoint frames | {k} | {interval(real['disjoint_ratio', k])} | "
            f"{interval(sim['disjoint_ratio', k])} | 1 |"
        )
    chain = [*ks, r["k_ref"]]
    for a, b in zip(chain[:-1], chain[1:]):
        v = real["violations", (a, b)][0]
        lines.append(
            f"| pixels where the {a}-mean cannot lie inside the {b}-mean | {a} ⊂ {b} | {int(v)} | "
            f"{int(sim['violations', (a, b)][0])} | 0 if nested; independent frames: "
            f"{interval(indep['violations', (a, b)], 0)} |"
        )
    for k in ks:
        lines.append(
            f"| histogram of S_K vs hypergeometric given S_256 (TV distance) | {k} | "
            f"{fmt(real['histogram_tv', k][0], 4)} | {interval(sim['histogram_tv', k], 4)} | sampling noise only |"
        )
    for name in rf.NEIGHBOURS:
        lines.append(
            f"| neighbour correlation of residuals m_1 − m_other ({name}) | 1 | "
            f"{interval(real['neighbour_corr', name], 4)} | {interval(sim['neighbour_corr', name], 4)} | "
            "0 (no crosstalk) |"
        )
    lines.append(
        f"| hot pixels (robust z > 6 over 256 frames) | 256 | {int(real['hot', None][0])} | "
        f"{interval(sim['hot', None], 1)} | 0 (simulated: hot/dead pixels replaced by their neighbours) |"
    )
    lines.append(
        f"| dead (cold) pixels (z < −6) | 256 | {int(real['cold', None][0])} | {interval(sim['cold', None], 1)} | 0 |"
    )
    lines.append(
        f"| detection rate of the binary frame | 1 | {fmt(real['detection_rate', ks[0]][0], 4)} | "
        f"{interval(sim['detection_rate', ks[0]], 4)} | — |"
    )
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# 2. stage 1


def oracle_psnr(out: np.ndarray, ref_lam: np.ndarray, ref_srgb: np.ndarray, ref_gain: float, block: int):
    """(PSNR, its block-bootstrap parts, gain): ``out`` (λT) shown at the best single gain against
    the reference display ``ref_srgb`` (λT ``ref_lam`` at ``ref_gain``), the gain searched over ±3
    stops around the least-squares one in linear light."""
    base = float((out * ref_lam).sum() / max(float((out * out).sum()), 1e-300))
    base = base if base > 0 else 1.0
    best = None
    for stops in GAIN_STOPS:
        a = base * 2.0**stops
        se = (display_srgb(a * out, ref_gain).astype(np.float64) - ref_srgb) ** 2
        mse = float(se.mean())
        if best is None or mse < best[0]:
            best = (mse, se, a)
    mse, se, a = best
    parts = (rf.block_sums(se, block), rf.block_sums(np.ones_like(se), block))
    return 10 * np.log10(1 / mse), parts, a


def _psnr(se, n):
    return 10 * np.log10(n / se)


def stage1(real: dict, models: Path, sim_frames: int, ensemble: int, block: int, bootstrap: int, seed: int):
    """Per method: real PSNR [block bootstrap], simulated PSNRs, outputs for the figure."""
    import torch

    from spc3d.physics import spc
    from spc3d.translate import MODULES
    from spc3d.translate.apply import mono_input_kind, translate_mean
    from spc3d.translate.model_io import load_translator

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    k_ref = KS[-1]
    other = real[k_ref] - real[1]  # the 255 frames besides the binary one (nested: see the physics table)
    ref_lam = rf.lam_t(other, k_ref - 1)
    ref_gain = metered_gain(ref_lam, PREVIEW_LEVEL)
    ref_srgb = display_srgb(ref_lam, ref_gain).astype(np.float64)
    real_frame = real[1].astype(np.float64)
    sims = [
        spc.simulate_plane(ref_lam, rf.UNIT, rng)[0].astype(np.float64) for _ in range(sim_frames)
    ]  # UNIT: one frame, λT per pixel
    rows, shown = [], {}
    candidates = [("binary frame, MLE (no model)", None)] + [
        (m, models / m) for m in MODULES if (models / m / "model.pt").is_file()
    ]
    for name, model_dir in candidates:
        t0 = time.perf_counter()
        if model_dir is None:

            def run(mean):
                return rf.lam_t(mean.astype(np.int64), 1)

            kind, trained = "—", "—"
        else:
            kind = mono_input_kind(model_dir)
            _, model = load_translator(model_dir, torch.device("cpu"))
            record = io.read_json(model_dir / "train.json") if (model_dir / "train.json").is_file() else {}
            trained = trained_text(record)

            def run(mean, model=model):
                return translate_mean(model, mean, ensemble)

        out_real = run(real_frame)
        psnr_real, parts, gain = oracle_psnr(out_real, ref_lam, ref_srgb, ref_gain, block)
        lo, hi = rf.block_bootstrap(parts, _psnr, bootstrap, rng)
        psnr_sim = [oracle_psnr(run(s), ref_lam, ref_srgb, ref_gain, block)[0] for s in sims]
        shown[name] = display_srgb(gain * out_real, ref_gain)
        rows.append(
            {
                "method": name,
                "input": kind,
                "trained": trained,
                "real": float(psnr_real),
                "real_interval": [lo, hi],
                "sim": [float(v) for v in psnr_sim],
                "gap": float(np.mean(psnr_sim) - psnr_real),
                "oracle_gain": float(gain),
                "seconds": time.perf_counter() - t0,
            }
        )
        print(f"  {name}: real {psnr_real:.2f} dB, simulated {np.mean(psnr_sim):.2f} dB", flush=True)
    return rows, shown, ref_srgb


def trained_text(record: dict) -> str:
    """What a model folder's train.json says was trained: the step kept of the budget, where it
    stopped, and the training pairs."""
    budget = (record.get("train") or {}).get("iterations", record.get("iterations"))
    pairs = record.get("pairs")
    on = f"{pairs} pairs" if pairs else "the training scenes"
    if not budget:
        return f"no network; fitted on {on}"
    stopped = record.get("stopped") or {}
    text = f"step {record.get('model_step')} of {budget}"
    if stopped.get("step") is not None and stopped["step"] < budget:
        text += f" (stopped at {stopped['step']}: {stopped.get('reason')})"
    return f"{text}; {on}"


def stage1_table(rows: list[dict], pixels: int, shape, sim_frames: int, ensemble: int, models: Path) -> str:
    h, w = shape
    lines = [
        "# Stage 1 on a real binary frame and on simulated ones",
        "",
        f"PSNR (dB) of each stage-1 method's output at its best single gain (an oracle step: the gain is fitted "
        f"on the reference) against the reference, the mean of the capture's other 255 binary frames (as λT, "
        f"average-metered); {w} x {h} = {pixels:,} pixels. Real: the capture's one binary frame [95 % interval: "
        f"bootstrap over pixel blocks]. Simulated: {sim_frames} binary frames the project's simulator draws from "
        f"the reference's λT, mean [min, max]. Gap = simulated − real. Models: `{shown_path(models)}` "
        f"(trained on the simulated RGB sensor's training scenes; the mono frame copied to their three channels, "
        f"the luminance of their output scored; trained: the step kept of the budget, as train.json records it), "
        f"self-ensemble {ensemble}.",
        "",
        "| method | trained | real K = 1 frame | simulated K = 1 frames | sim-to-real gap |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lo, hi = r["real_interval"]
        lines.append(
            f"| {r['method']} | {r['trained']} | {r['real']:.2f} [{lo:.2f}, {hi:.2f}] | "
            f"{np.mean(r['sim']):.2f} [{min(r['sim']):.2f}, {max(r['sim']):.2f}] | {r['gap']:+.2f} |"
        )
    return "\n".join(lines) + "\n"


def shown_path(path: Path) -> str:
    """``path`` relative to the repository when inside it (a table names no machine's folders)."""
    path = Path(path).resolve()
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


def figure(real_frame: np.ndarray, shown: dict, ref: np.ndarray, path: Path) -> None:
    from spc3d.plotting import pyplot, save_png

    plt = pyplot()
    panels = [("real binary frame (K = 1)", real_frame)] + list(shown.items()) + [("reference: 255 frames", ref)]
    cols = min(5, len(panels))
    rows = -(-len(panels) // cols)
    h, w = ref.shape
    fig, axes = plt.subplots(rows, cols, figsize=(cols * 2.4, rows * 2.4 * h / w + 0.4 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (title, img) in zip(axes.flat, panels):
        ax.imshow(np.clip(img, 0, 1), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(title, fontsize=7)
    fig.tight_layout()
    save_png(fig, path, dpi=150)


# --------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--models", type=Path, default=REPO / "results" / "models")
    ap.add_argument("--out", type=Path, default=REPO / "results" / "real_spad")
    ap.add_argument("--draws", type=int, default=20, help="simulator draws of the physics table")
    ap.add_argument("--bootstrap", type=int, default=2000, help="block-bootstrap resamples")
    ap.add_argument("--block", type=int, default=16, help="bootstrap block side (pixels)")
    ap.add_argument("--sim-frames", type=int, default=4, help="simulated binary frames scored per method")
    ap.add_argument("--ensemble", type=int, default=4, help="self-ensemble of the translators (stage1.ensemble)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--smoke", action="store_true", help="a 48 x 64 crop, 2 draws: seconds (the test)")
    ap.add_argument("--docs", action="store_true", help="refresh the docs' spad: blocks and docs/figures/")
    args = ap.parse_args(argv)
    if args.smoke:
        if args.docs:
            raise SystemExit("--smoke makes a crop's numbers: they do not go into the docs (drop --docs)")
        args.draws, args.bootstrap, args.block, args.sim_frames, args.ensemble = 2, 100, 8, 1, 1
    real = read_capture(args.data, SMOKE_CROP if args.smoke else None)
    t0 = time.perf_counter()
    physics = rf.compare(real, KS[-1], args.draws, args.seed, args.block, args.bootstrap)
    print(physics_table(physics))
    print(f"physics: {time.perf_counter() - t0:.1f} s", flush=True)
    rows, shown, ref = stage1(real, args.models, args.sim_frames, args.ensemble, args.block, args.bootstrap, args.seed)
    table = stage1_table(rows, physics["pixels"], physics["shape"], args.sim_frames, args.ensemble, args.models)
    print(table)
    fig_path = REPO / "docs" / "figures" / "real_spad_stage1.png" if args.docs else args.out / "real_spad_stage1.png"
    record = {
        "data": str(args.data),
        "smoke": args.smoke,
        "physics": {k: v for k, v in physics.items() if k not in ("real", "sim", "independent")},
        "physics_values": {
            part: {str(key): value for key, value in physics[part].items()} for part in ("real", "sim", "independent")
        },
        "stage1": rows,
        "figure": str(fig_path),
    }
    with io.atomic_path(args.out / "tables", is_dir=True) as tmp:
        io.write_text(tmp / "real_spad_physics.md", physics_table(physics))
        io.write_text(tmp / "real_spad_stage1.md", table)
    io.write_text(args.out / "real_spad.json", json.dumps(record, indent=1, default=io.json_default))
    figure(real[1].astype(np.float32), shown, ref, fig_path)
    if args.docs:
        sys.path.insert(0, str(REPO / "workflow" / "tools"))
        from readme_results import refresh_run

        counts = refresh_run(REPO / "README.md", RUN, args.out)
        print(f"docs: {sum(counts.values())} generated block(s) of run {RUN} refreshed from {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
