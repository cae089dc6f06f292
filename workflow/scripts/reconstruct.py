"""Adapter: rule reconstruct -> spc3d.reconstruct.stage2.reconstruct (the job built here, once; a joint
row's weight chosen by its fold where stage2.joint.choose lists candidates, spc3d.choices)."""

from pathlib import Path

from spc3d.checkpoints import CheckpointPolicy
from spc3d.choices import chosen_joint
from spc3d.jobs import logged
from spc3d.reconstruct.stage2 import ReconstructJob, reconstruct

with logged(snakemake.log[0]):
    w, p, inp = snakemake.wildcards, snakemake.params.job, snakemake.input
    translated = inp.get("translated")
    job = ReconstructJob(
        inp.scene,
        snakemake.output[0],
        w.source,
        w.model,
        p.settings,
        p.seed,
        frames=p.frames,
        spc_dir=inp.get("spc"),
        image_dir=str(Path(translated) / "images") if translated else None,
        display_dir=inp.get("display"),
        points_dir=inp.get("colmap"),
        poses_dir=inp.get("poses"),
        init_setting=p.init,
        observe_plateau=p.observe,
        checkpoint=p.checkpoint,
        policy=CheckpointPolicy(**p.policy),
        threads=snakemake.threads,
        joint=chosen_joint(p.joint, inp.get("choice")),  # the fold's weight, where chosen
    )
    reconstruct(job)
