rule write_summary:
    """Table and figure: per scene RGB | binary frame | K-frame average | MLE, exposure, COLMAP."""
    input:
        scenes=expand("results/scenes/{scene}", scene=ALL_SCENES),
        spc=expand("results/spc/{scene}", scene=ALL_SCENES),
        colmap=get_summary_colmap(),
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
        roles=get_summary_roles(),
    log:
        "logs/write_summary/data_summary.log",
    conda:
        ENV
    script:
        "../scripts/write_summary.py"
