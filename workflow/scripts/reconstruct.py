"""Adapter: rule reconstruct -> spc3d.reconstruct.stage2.reconstruct."""

from pathlib import Path

from spc3d.checkpoints import CheckpointPolicy
from spc3d.jobs import logged
from spc3d.reconstruct.stage2 import reconstruct

with logged(snakemake.log[0]):
    w, p, inp = snakemake.wildcards, snakemake.params, snakemake.input
    translated = inp.get("translated")
    reconstruct(
        inp.scene,
        snakemake.output[0],
        w.source,
        w.model,
        p.settings,
        p.seed,
        spc_dir=inp.get("spc"),
        image_dir=str(Path(translated) / "images") if translated else None,
        display_dir=inp.get("display"),
        checkpoint=p.checkpoint,
        frames=p.frames,
        threads=snakemake.threads,
        points_dir=inp.get("colmap"),
        policy=CheckpointPolicy(**p.policy),
        init_setting=p.init,
        poses_dir=inp.get("poses"),
    )
