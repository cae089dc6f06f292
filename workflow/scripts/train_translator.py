"""Adapter: rule train_translator -> spc3d.translate.train.train_translator.

The rule's inputs, params, output and threads become one TranslatorJob, built here and nowhere else;
the perceptual loss's VGG weights (arrays, not settings) are passed beside it. Where and how often it
checkpoints come from the output path and the config, not params: they do not change the weights, so
they stay out of the between-workflow cache's key (params.code is in it: the library code)."""

from spc3d.checkpoints import CheckpointPolicy
from spc3d.evaluation.lpips_weights import load_npz
from spc3d.jobs import logged, translator_checkpoint
from spc3d.translate.train import TranslatorJob, train_translator, training_data

with logged(snakemake.log[0]):
    p, inputs = snakemake.params.job, snakemake.input
    job = TranslatorJob(
        p.method,
        training_data(
            p.data, inputs.get("pairs", []), inputs.get("scenes", []), inputs.get("spc", []), p.augment, p.sensor
        ),
        snakemake.output[0],
        p.settings,
        p.train,
        seed=p.seed,
        frames=p.frames,
        validation=p.validation,
        checkpoint=translator_checkpoint(snakemake.output[0]),
        policy=CheckpointPolicy(**snakemake.config["checkpoints"]),
        threads=snakemake.threads,
    )
    train_translator(job, vgg_weights=load_npz(snakemake.input.vgg, "vgg"))
