"""Adapter: rule estimate_poses -> spc3d.poses.estimate.estimate_poses."""

from pathlib import Path

from spc3d.jobs import logged
from spc3d.poses.estimate import estimate_poses

with logged(snakemake.log[0]):
    p = snakemake.params.job
    estimate_poses(
        Path(snakemake.input.images) / p.subdir,
        snakemake.input.scene,
        snakemake.output[0],
        snakemake.wildcards.source,
        p.frames,
        max_features=p.max_features,
        seed=p.seed,
        num_threads=snakemake.threads,
    )
