rule augment_scene:
    """Zoom / rotation / shear / flip training pairs (RGB + SPC frames) of one training scene."""
    input:
        scene="results/scenes/{scene}",
        spc="results/spc/{scene}{rep}",
    output:
        directory("results/augment/{scene}{rep}"),
    params:
        n_pairs=get_augment_count,
        settings=config["augment"],
        seed=get_seed,
    log:
        "logs/augment_scene/{scene}{rep}.log",
    benchmark:
        "benchmarks/augment_scene/{scene}{rep}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/augment_scene.py"
