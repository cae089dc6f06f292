"""Adapter: rule augment_scene -> spc3d.inputs.augment.augment_scene."""

from spc3d.inputs.augment import AugmentSettings, augment_scene
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    s = dict(snakemake.params.job.settings)
    settings = AugmentSettings(
        zoom=tuple(s["zoom"]), rotation_deg=s["rotation_deg"], shear_deg=s["shear_deg"], flip_prob=s["flip_prob"]
    )
    augment_scene(
        snakemake.input.scene,
        snakemake.input.spc,
        snakemake.output[0],
        snakemake.params.job.n_pairs,
        settings,
        snakemake.params.job.seed,
    )
