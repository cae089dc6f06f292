"""Adapter: rule score_images -> spc3d.evaluation.stage1.score_images."""

from pathlib import Path

from spc3d.evaluation.stage1 import score_images
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    p = snakemake.params.job
    score_images(
        Path(snakemake.input.images) / p.subdir,
        snakemake.input.scene,
        snakemake.output[0],
        snakemake.wildcards.source,
        lpips_dir=Path(snakemake.input.lpips[0]).parent,
        frames=p.frames,
        seed=p.seed,
        capture_factor=p.capture_factor,
    )
