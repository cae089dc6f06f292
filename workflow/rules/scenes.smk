rule scene_prepare:
    """Render a built-in scene or import a real LLFF folder into the canonical LLFF layout."""
    input:
        get_scene_source,
    output:
        directory("results/scenes/{scene}"),
    params:
        spec=get_scene_spec,
    log:
        "logs/scene_prepare/{scene}.log",
    benchmark:
        "benchmarks/scene_prepare/{scene}.tsv"
    threads: 1
    conda:
        ENV
    script:
        "../scripts/scene_prepare.py"
