# Sweeps: the speed–accuracy trade-off (target `tradeoff`) and quality against the photon level
# (target `photon_level`). A point is one combination at one setting (a row of a Paramspace table),
# built by the grid's own rules under the point's settings overlay (the {overlay} wildcard of
# common.smk: results/sweeps/{sweep}/{knob~value/...}/..., spc3d.sweeps.plan); the reports gather
# the points' metrics and the benchmarks of their jobs.
from snakemake.utils import Paramspace

from spc3d.sweeps.knobs import parse_combinations, photon_table, read_table
from spc3d.sweeps.plan import point_inputs, sweep_points

SWEEP_SOURCES = PLAIN_SOURCES + STAGE1_METHODS + JOINT_SOURCES
TRADEOFF_COMBOS = parse_combinations(config["tradeoff"]["combinations"], config["stage2"]["nerf_variant"],
                                     SWEEP_SOURCES, "tradeoff.combinations")
PHOTON_COMBOS = parse_combinations(config["photon_level"]["combinations"], config["stage2"]["nerf_variant"],
                                   SWEEP_SOURCES, "photon_level.combinations")
TRADEOFF_SPACE = Paramspace(read_table(config["tradeoff"]["table"]))
PHOTON_SPACE = Paramspace(photon_table(config["photon_level"]["detection"], config["photon_level"]["frames"],
                                       "photon_level.detection/frames"))
TRADEOFF_POINTS = sweep_points("tradeoff", TRADEOFF_SPACE.dataframe, list(TRADEOFF_SPACE.instance_patterns),
                               TRADEOFF_COMBOS, POINTS, SWEEP_SCENE)
PHOTON_POINTS = sweep_points("photon_level", PHOTON_SPACE.dataframe, list(PHOTON_SPACE.instance_patterns),
                             PHOTON_COMBOS, POINTS, SWEEP_SCENE)


rule tradeoff_report:
    """The trade-off table (every point, Pareto flags) and figure (quality against wall time)."""
    input:
        lambda wildcards: point_inputs(TRADEOFF_POINTS),  # a function: checked only when the report is asked for
    output:
        csv="results/tables/tradeoff.csv",
        png=report("results/figures/tradeoff.png", caption="../report/tradeoff.rst", category="5. Trade-off",
                   labels={"figure": "speed–accuracy trade-off"}),
    params:
        job=lambda wildcards: sweep_report(TRADEOFF_POINTS, TRADEOFF_COMBOS, config["tradeoff"]["clock"]),
    log:
        "logs/tradeoff/tradeoff_report.log",
    conda:
        ENV
    script:
        "../scripts/tradeoff_report.py"


rule tradeoff:
    """Target: `snakemake --cores 2 tradeoff` runs the speed–accuracy sweep and writes its table and figure."""
    input:
        rules.tradeoff_report.output,
    localrule: True


rule photon_level_report:
    """The photon-level table and figure (quality against mean detection probability, per K)."""
    input:
        lambda wildcards: point_inputs(PHOTON_POINTS),  # a function: checked only when the report is asked for
    output:
        csv="results/tables/photon_level.csv",
        png=report("results/figures/photon_level.png", caption="../report/photon_level.rst", category="5. Trade-off",
                   labels={"figure": "quality against photon level"}),
    params:
        job=lambda wildcards: sweep_report(PHOTON_POINTS, PHOTON_COMBOS),
    log:
        "logs/photon_level/photon_level_report.log",
    conda:
        ENV
    script:
        "../scripts/photon_level_report.py"


rule photon_level:
    """Target: `snakemake --cores 2 photon_level` runs the photon-level sweep and writes its table and figure."""
    input:
        rules.photon_level_report.output,
    localrule: True
