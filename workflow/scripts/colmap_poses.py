"""Adapter: rule colmap_poses -> spc3d.poses.colmap.colmap_poses."""

from pathlib import Path

from spc3d.jobs import logged
from spc3d.poses.colmap import colmap_poses

with logged(snakemake.log[0]):
    colmap_poses(
        Path(snakemake.input.images) / snakemake.params.job.subdir,
        snakemake.input.scene,
        snakemake.output[0],
        max_features=snakemake.params.job.max_features,
        seed=snakemake.params.job.seed,
    )
