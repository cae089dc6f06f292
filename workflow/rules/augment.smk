rule augment:
    """Zoom / rotation / shear / flip training pairs (RGB + SPC frames) of one training scene."""
    input:
        scene="results/scenes/{scene}",
        spc="results/spc/{scene}",
    output:
        directory("results/augment/{scene}"),
    params:
        n_pairs=get_augment_count,
        settings=config["augment"],
        seed=config["seed"],
    log:
        "logs/augment/{scene}.log",
    benchmark:
        "benchmarks/augment/{scene}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/augment.py"
