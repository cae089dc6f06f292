rule prepare_scene:
    """Render a built-in scene or import a real LLFF folder into the canonical LLFF layout."""
    input:
        get_scene_source,
    output:
        directory("results/scenes/{scene}"),
    params:
        spec=get_scene_spec,
    log:
        "logs/prepare_scene/{scene}.log",
    benchmark:
        "benchmarks/prepare_scene/{scene}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/prepare_scene.py"
