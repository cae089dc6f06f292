rule colmap_poses:
    """COLMAP (pycolmap, CPU) on one image set of a scene, with the pose error against its poses."""
    input:
        scene="results/scenes/{scene}",
        images=setting("colmap_images"),
    output:
        directory("results/colmap/{scene}/{images}"),
    params:
        job=setting("colmap_params"),
    log:
        "logs/colmap_poses/{scene}_{images}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/colmap_poses.py"


rule estimate_poses:
    """COLMAP on a source's images of the training views: the cameras a row '...@{source}' trains on."""
    input:
        scene="results/scenes/{scene}",
        images=setting("source_images"),
    output:
        directory("results/poses/{scene}/{source}{rep}"),
    params:
        job=setting("poses_params"),
    log:
        "logs/estimate_poses/{scene}/{source}{rep}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/estimate_poses.py"
