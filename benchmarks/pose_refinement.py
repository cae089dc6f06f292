"""Does 3DGS camera refinement recover from pose noise? Training scenes only (never the evaluation one).

    python benchmarks/pose_refinement.py [--scenes tabletop orchard gallery] [--noise 0 0.5 1]
        [--lr 5e-4] [--lr-final 5e-6] [--start 300] [--iterations 1200] [--seeds 0] [--refined-only]
        [--jobs 2] [--out runs.json]

Each built-in scene is rendered at 128 x 96 (``--width``; 24 views); its training cameras are perturbed by a
random rotation of ``noise`` degrees RMS and a shift of 2 % of the camera spread per degree (a
seeded draw per view), and 3DGS is fitted to the ground-truth images on those cameras, with and
without :mod:`spc3d.reconstruct.pose_refine`. Printed per scene and noise: held-out PSNR (rendered
after the re-alignment the workflow uses), the median rotation error of the training cameras
before and after refinement, and the wall time. This is how ``pose_lr``, ``pose_lr_final`` and ``pose_from`` were
chosen (stage2.3dgs); at zero noise it shows what refinement costs on exact poses, which is why
stage2.refine_poses refines only the rows on estimated poses by default.
``--smoke``: tabletop 32 px wide at 0.5 degrees of noise, 4 iterations, refinement from step 2 (seconds).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from spc3d import io  # noqa: E402
from spc3d.cameras import Cameras, split_views  # noqa: E402
from spc3d.poses.alignment import pose_error  # noqa: E402
from spc3d.reconstruct.gaussians import GaussianConfig  # noqa: E402

DEFAULTS = GaussianConfig()  # the refinement settings the workflow uses unless stage2.3dgs overrides them

# The default config's stage2.3dgs block (config.yaml), but the iterations.
SETTINGS = {
    "densify_from": 100,
    "densify_until": 900,
    "opacity_reset_every": 3000,
    "sh_interval": 300,
    "init_points": 4000,
}


def perturbed(cams: Cameras, noise_deg: float, seed: int = 0) -> Cameras:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    spread = np.linalg.norm(cams.centers - cams.centers.mean(0), axis=1).mean()
    w2c = cams.w2c.copy()
    for i in range(len(w2c)):
        dR = Rotation.from_rotvec(rng.normal(size=3) * np.deg2rad(noise_deg) / np.sqrt(3)).as_matrix()
        dt = rng.normal(size=3) * 0.02 * spread * noise_deg
        w2c[i] = np.concatenate([dR @ w2c[i, :, :3], (dR @ w2c[i, :, 3] + dt)[:, None]], 1)
    return Cameras(w2c, cams.intrinsics, cams.height, cams.width, cams.bounds)


def point(args: tuple) -> dict:
    scene_name, noise, refine, lr, lr_final, start, iterations, seed, width = args
    import torch

    from spc3d import llff
    from spc3d.evaluation.metrics import psnr
    from spc3d.inputs.build import named_spec, prepare_scene
    from spc3d.reconstruct import RECONSTRUCTORS
    from spc3d.reconstruct.views import Views

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        prepare_scene(named_spec(scene_name, width, tmp), Path(tmp) / scene_name)
        scene = llff.read_scene(Path(tmp) / scene_name)
    train, test = split_views(len(scene.names))
    ref = scene.cameras.subset(train)
    noisy = perturbed(ref, noise, seed)
    views = Views(torch.as_tensor(scene.images[train]), noisy, [scene.names[i] for i in train])
    settings = {**SETTINGS, "iterations": iterations, "pose_refine": refine, "pose_lr": lr, "pose_lr_final": lr_final}
    settings["pose_from"] = start
    trainer, n, _ = RECONSTRUCTORS["3dgs"](views, None, settings, seed, None)
    t0 = time.perf_counter()
    for it in range(1, n + 1):
        trainer.step(it)
    cams = trainer.heldout_cameras(ref, scene.cameras.subset(test))
    scores = [psnr(trainer.render(cams, j).clamp(0, 1), torch.as_tensor(scene.images[i])) for j, i in enumerate(test)]
    after = trainer.poses.refined(noisy) if trainer.poses is not None else noisy
    err = [pose_error(ref, c, np.arange(len(ref)))["rotation_deg"]["median"] for c in (noisy, after)]
    return {
        "scene": scene_name,
        "noise": noise,
        "refine": refine,
        "seed": seed,
        "psnr": float(np.mean(scores)),
        "rot_before": err[0],
        "rot_after": err[1],
        "wall_s": time.perf_counter() - t0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["tabletop", "orchard", "gallery"])
    ap.add_argument("--noise", nargs="+", type=float, default=[0.0, 0.5, 1.0])
    ap.add_argument("--lr", type=float, default=DEFAULTS.pose_lr)
    ap.add_argument("--lr-final", type=float, default=DEFAULTS.pose_lr_final, help="lr at the last iteration")
    ap.add_argument("--start", type=int, default=DEFAULTS.pose_from)
    ap.add_argument("--refined-only", action="store_true", help="skip the runs without refinement")
    ap.add_argument("--iterations", type=int, default=1200)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--width", type=int, default=128, help="scene width in pixels (height: 3/4 of it)")
    ap.add_argument("--out", type=Path, help="also write every run (one JSON record each) to this file")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="noise draw and training seed; means over them")
    ap.add_argument("--smoke", action="store_true", help="a tiny run in seconds (tests/test_benchmarks_smoke.py)")
    a = ap.parse_args()
    if a.smoke:
        vars(a).update(scenes=["tabletop"], noise=[0.5], iterations=4, start=2, seeds=[0], jobs=1, width=32)
    modes = (True,) if a.refined_only else (False, True)
    jobs = [
        (s, n, r, a.lr, a.lr_final, a.start, a.iterations, seed, a.width)
        for s in a.scenes
        for n in a.noise
        for r in modes
        for seed in a.seeds
    ]
    with ProcessPoolExecutor(a.jobs) as pool:
        rows = list(pool.map(point, jobs))
    if a.out:  # every run, for paired comparisons between settings (same scene, noise and seed)
        io.write_json(a.out, {"settings": vars(a), "runs": rows})
    print(
        f"pose_lr {a.lr} -> {a.lr_final}, pose_from {a.start}, {a.iterations} iterations, {a.width} px wide, "
        f"ground-truth images; mean over seeds {a.seeds} (± std over seeds when several)"
    )
    print("| scene | noise (deg) | PSNR fixed | PSNR refined | rotation error before -> after (deg) | s (refined) |")
    print("|---|---|---|---|---|---|")
    for s in a.scenes:
        for n in a.noise:
            off, on = ([r for r in rows if (r["scene"], r["noise"], r["refine"]) == (s, n, f)] for f in (False, True))
            rot = [f"{np.mean([r[k] for r in on]):.3f}" for k in ("rot_before", "rot_after")]
            print(
                f"| {s} | {n:g} | {spread(off, 'psnr')} | {spread(on, 'psnr')} | {rot[0]} -> {rot[1]} | "
                f"{np.mean([r['wall_s'] for r in on]):.0f} |"
            )


def spread(rows: list[dict], key: str) -> str:
    """Mean (± std, ddof 1, over seeds when several) of ``key``; "–" when not run."""
    if not rows:
        return "–"
    v = [r[key] for r in rows]
    return f"{np.mean(v):.2f}" + (f" ± {np.std(v, ddof=1):.2f}" if len(v) > 1 else "")


if __name__ == "__main__":
    main()
