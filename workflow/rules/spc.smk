rule spc_simulate:
    """K binary SPC frames per view, with the binary / average / MLE images derived from them."""
    input:
        "results/scenes/{scene}",
    output:
        directory("results/spc/{scene}"),
    params:
        settings=get_spc_settings,
    log:
        "logs/spc_simulate/{scene}.log",
    benchmark:
        "benchmarks/spc_simulate/{scene}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/spc_simulate.py"
