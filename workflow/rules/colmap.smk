rule colmap_poses:
    """COLMAP (pycolmap, CPU) on one image set of a scene, with the pose error against its poses."""
    input:
        scene="results/scenes/{scene}",
        images=get_colmap_images,
    output:
        directory("results/colmap/{scene}/{images}"),
    params:
        subdir=get_colmap_subdir,
        max_features=config["colmap"]["max_features"],
        seed=config["seed"],
    log:
        "logs/colmap_poses/{scene}_{images}.log",
    threads: 1
    conda:
        ENV
    script:
        "../scripts/colmap_poses.py"
