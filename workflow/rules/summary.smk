rule write_summary:
    """Table and figure: per scene RGB | binary frame | K-frame average | MLE, exposure, COLMAP."""
    input:
        scenes=[GRID.paths.scene(s) for s in ALL_SCENES],
        spc=[GRID.paths.spc(s) for s in ALL_SCENES],
        colmap=TARGETS.colmap(config["colmap"]["inputs"]),
    output:
        csv="results/summary/data_summary.csv",
        md="results/summary/data_summary.md",
        png=report(
            "results/summary/data_summary.png",
            caption="../report/data_summary.rst",
            category="3. Data",
            labels={"figure": "data summary"},
        ),
    params:
        roles=TARGETS.roles(),
    log:
        "logs/write_summary/data_summary.log",
    conda:
        ENV
    script:
        "../scripts/write_summary.py"
