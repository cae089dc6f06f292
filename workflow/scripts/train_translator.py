"""Adapter: rule train_translator -> spc3d.translate.train.train_translator."""

from spc3d.checkpoints import CheckpointPolicy
from spc3d.evaluation.lpips_weights import load_npz
from spc3d.jobs import logged
from spc3d.translate.train import train_translator, training_data

with logged(snakemake.log[0]):
    p, inputs = snakemake.params, snakemake.input
    data = training_data(
        p.data, inputs.get("pairs", []), inputs.get("scenes", []), inputs.get("spc", []), p.augment, p.sensor
    )
    train_translator(
        p.method,
        data.augment_dirs,
        snakemake.output[0],
        p.settings,
        p.train,
        seed=p.seed,
        frames=p.frames,
        checkpoint=p.checkpoint,
        vgg_weights=load_npz(snakemake.input.vgg, "vgg"),
        threads=snakemake.threads,
        policy=CheckpointPolicy(**p.policy),
        data=data,
        validation=p.validation,
    )
