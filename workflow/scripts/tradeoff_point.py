"""Adapter: rules tradeoff_point and photon_level_point -> spc3d.sweeps.point.run_point."""

from pathlib import Path

from spc3d.checkpoints import CheckpointPolicy
from spc3d.jobs import logged
from spc3d.sweeps.point import run_point

with logged(snakemake.log[0]):
    p = snakemake.params
    run_point(
        Path(snakemake.output[0]).parent,
        snakemake.wildcards.combo,
        {**p.budget, **p.setting},
        p.base,
        lpips_dir=Path(snakemake.input.lpips[0]).parent,
        threads=snakemake.threads,
        keep_work=p.keep_work,
        checkpoints=p.checkpoints,
        policy=CheckpointPolicy(**p.policy),
    )
