"""Adapter: rule choose_joint_weight -> spc3d.choices.choose_joint_weight."""

from pathlib import Path

from spc3d.choices import choose_joint_weight
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    w, p, inp = snakemake.wildcards, snakemake.params.job, snakemake.input
    choose_joint_weight(
        inp.model,
        list(zip(inp.scenes, inp.spc)),
        inp.calibration,
        snakemake.output[0],
        method=w.method,
        model=w.model,
        settings=p.settings,
        joint=p.joint,
        candidates=p.candidates,
        seed=p.seed,
        frames=p.frames,
        display=tuple(p.display[:2]),
        lpips_dir=Path(inp.lpips[0]).parent,
    )
