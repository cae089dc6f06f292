# The inputs every combination reads: scene folders (prepare_scene), their SPC frames (simulate_scene),
# the MLE displays of the physics rows (calibrate_display, write_display) and the augmented
# training pairs of stage 1 (augment_scene). Library: spc3d.inputs.build, spc3d.inputs.exposure, spc3d.inputs.augment.

rule prepare_scene:
    """Render a built-in scene or import a real LLFF folder into the canonical LLFF layout."""
    input:
        setting("scene_files"),
    output:
        directory("results/{overlay}scenes/{scene}"),
    params:
        spec=setting("scene_spec"),
    log:
        "logs/prepare_scene/{overlay}{scene}.log",
    threads: 1
    priority: 10  # upstream of every translator: first, so training starts early
    conda:
        ENV
    script:
        "../scripts/prepare_scene.py"


rule simulate_scene:
    """K binary SPC frames per view (one draw per seed), with the binary, average and MLE flux derived."""
    input:
        "results/{overlay}scenes/{scene}",
    output:
        directory("results/{overlay}spc/{scene}{rep}"),
    params:
        settings=setting("spc"),
    log:
        "logs/simulate_scene/{overlay}{scene}{rep}.log",
    threads: 1
    priority: 10
    conda:
        ENV
    script:
        "../scripts/simulate_scene.py"


rule calibrate_display:
    """The display level k of the MLE (g = k x the reported exposure's flux), fitted on a fold's training
    scenes at one budget: their first K frames ("k{K}") or their capture-resolution frame ("capture")."""
    input:
        unpack(setting("display_training")),
    output:
        "results/{overlay}calibration{fold}/display-{budget}{rep}.json",
    params:
        job=setting("display_params"),
    log:
        "logs/calibrate_display/{overlay}{budget}{fold}{rep}.log",
    threads: 1
    priority: 10
    conda:
        ENV
    script:
        "../scripts/calibrate_display.py"


rule write_display:
    """A scene's MLE images of one budget (first K frames, or the capture-resolution frame) at the
    gain of its reported exposure and its fold's level (no ground truth: spc3d.inputs.exposure)."""
    input:
        spc="results/{overlay}spc/{scene}{rep}",
        calibration=setting("display_calibration"),
    output:
        directory("results/{overlay}mle/{scene}/{budget}{rep}"),
    params:
        job=setting("display_params"),
    log:
        "logs/write_display/{overlay}{scene}/{budget}{rep}.log",
    threads: 1
    priority: 10
    conda:
        ENV
    script:
        "../scripts/write_display.py"


rule augment_scene:
    """Zoom / rotation / shear / flip training pairs (RGB + SPC frames) of one training scene."""
    input:
        scene="results/{overlay}scenes/{scene}",
        spc="results/{overlay}spc/{scene}{rep}",
    output:
        directory("results/{overlay}augment/{scene}{rep}"),
    params:
        job=setting("augment_params"),
    log:
        "logs/augment_scene/{overlay}{scene}{rep}.log",
    threads: 1
    priority: 10
    conda:
        ENV
    script:
        "../scripts/augment_scene.py"
