"""Adapter: rule colmap_poses -> spc3d.colmap.colmap_poses."""

from pathlib import Path

from spc3d.colmap import colmap_poses
from spc3d.workflow import logged

with logged(snakemake.log[0]):
    colmap_poses(
        Path(snakemake.input.images) / snakemake.params.subdir,
        snakemake.input.scene,
        snakemake.output[0],
        max_features=snakemake.params.max_features,
        seed=snakemake.params.seed,
    )
