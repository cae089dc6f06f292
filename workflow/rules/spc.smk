rule simulate_scene:
    """K binary SPC frames per view (one draw per seed), with the binary, average and MLE flux derived."""
    input:
        "results/scenes/{scene}",
    output:
        directory("results/spc/{scene}{rep}"),
    params:
        settings=get_spc_settings,
    log:
        "logs/simulate_scene/{scene}{rep}.log",
    benchmark:
        "benchmarks/simulate_scene/{scene}{rep}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/simulate_scene.py"


rule calibrate_display:
    """The display level k of the metered MLE (g = mean flux / k), fitted on the training scenes at K frames."""
    input:
        unpack(get_display_training),
    output:
        "results/calibration/display-k{K}{rep}.json",
    log:
        "logs/calibrate_display/k{K}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/calibrate_display.py"


rule write_display:
    """A scene's MLE images of its first K frames at the metered gain (no ground truth: spc3d.exposure)."""
    input:
        spc="results/spc/{scene}{rep}",
        calibration="results/calibration/display-k{K}{rep}.json",
    output:
        directory("results/mle/{scene}/k{K}{rep}"),
    log:
        "logs/write_display/{scene}/k{K}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/write_display.py"
