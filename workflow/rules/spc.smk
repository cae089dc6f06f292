rule spc_simulate:
    """K binary SPC frames per view (one draw per seed), with the binary, average and MLE flux derived."""
    input:
        "results/scenes/{scene}",
    output:
        directory("results/spc/{scene}{rep}"),
    params:
        settings=get_spc_settings,
    log:
        "logs/spc_simulate/{scene}{rep}.log",
    benchmark:
        "benchmarks/spc_simulate/{scene}{rep}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/spc_simulate.py"


rule display_calibration:
    """The display level k of the metered MLE (g = mean flux / k), fitted on the training scenes at K frames."""
    input:
        unpack(get_display_training),
    output:
        "results/calibration/display-k{K}{rep}.json",
    log:
        "logs/display_calibration/k{K}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/display_calibration.py"


rule mle_display:
    """A scene's MLE images of its first K frames at the metered gain (no ground truth: spc3d.exposure)."""
    input:
        spc="results/spc/{scene}{rep}",
        calibration="results/calibration/display-k{K}{rep}.json",
    output:
        directory("results/mle/{scene}/k{K}{rep}"),
    log:
        "logs/mle_display/{scene}/k{K}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/mle_display.py"
