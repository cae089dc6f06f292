# Stage 1: train the translators on the training scenes, apply them to the evaluation scenes,
# and score their images (and the training-free MLE / binary images) before any 3D.


rule train_translator:
    """Train one stage-1 method on the training scenes (fixed pairs or online samples), validated
    on their held-out views; "-<sensor>": with the inputs as a captured scene's sensor records them."""
    input:
        unpack(setting("translator_inputs")),
        vgg=LPIPS_WEIGHTS["vgg"],
        pretrained=setting("translator_pretrained"),
    output:
        report(
            directory("results/{overlay}models{sensor}{fold}/{method}{rep}"),
            patterns=["{figure,curve}.png"],
            caption="../report/curve.rst",
            category="4. Stage 1 training",
            labels={"translator": "{method}{sensor}{fold}", "figure": "training curve"},
        ),
    params:
        job=setting("translator_params"),  # with the code key: a change of the library code retrains
    log:
        "logs/train_translator/{overlay}{method}{sensor}{fold}{rep}.log",
    # `snakemake --cache` (SNAKEMAKE_OUTPUT_CACHE, else ~/.cache/spc3d/outputs): trained once per
    # settings, training content, seed and code, then reused by any workflow directory
    cache: True
    threads: 1
    resources:
        gpu=get_translator_gpus,  # CUDA when present; locally unlimited unless `--resources gpu=N` caps it
    priority: 10  # eight stage-2 jobs wait on the translators: start them before other training
    conda:
        ENV
    script:
        "../scripts/train_translator.py"


rule translate_scene:
    """Every view of a scene through a trained stage-1 method (stage 2 reads these as a source)."""
    input:
        model=setting("translator_model"),
        spc="results/{overlay}spc/{scene}{rep}",
        scene="results/{overlay}scenes/{scene}",
    output:
        directory("results/{overlay}translate/{scene}/{method}{rep}"),
    params:
        job=setting("translate_params"),
    log:
        "logs/translate_scene/{overlay}{scene}/{method}{rep}.log",
    threads: 1
    priority: 10
    conda:
        ENV
    script:
        "../scripts/translate_scene.py"


rule score_images:
    """PSNR / SSIM / LPIPS of a source's held-out views before 3D (stage-1 error alone)."""
    input:
        images=setting("source_images"),
        scene="results/{overlay}scenes/{scene}",
        lpips=list(LPIPS_WEIGHTS.values()),
    output:
        "results/{overlay}stage1/{scene}/{source}{rep}.json",
    params:
        job=setting("score_params"),
    log:
        "logs/score_images/{overlay}{scene}/{source}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/score_images.py"
