"""Adapter: rule reconstruct -> spc3d.stage2.reconstruct."""
from spc3d.stage2 import reconstruct
from spc3d.workflow import logged

with logged(snakemake.log[0]):
    w, p = snakemake.wildcards, snakemake.params
    reconstruct(snakemake.input.scene, snakemake.output[0], w.source, w.model, p.settings, p.seed,
                spc_dir=snakemake.input.get("spc"), image_dir=snakemake.input.get("images"),
                checkpoint=p.checkpoint, frames=p.frames, threads=snakemake.threads,
                points_dir=snakemake.input.get("colmap"))
