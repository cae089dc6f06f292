# Sweeps: the speed–accuracy trade-off (target `tradeoff`) and quality against the photon level
# (target `photon_level`). A point is ONE job running the whole pipeline of one combination at one
# budget in its own folder (spc3d.sweeps.point.run_point); the budgets are rows of a Paramspace table.
import re

from snakemake.utils import Paramspace

from spc3d.sweeps.knobs import KNOBS, parse_combinations, photon_table, read_table
from spc3d.sweeps.plan import ByCombination, photon_budget, point_base, point_paths, scene_inputs, sweep_scenes

TRADEOFF_COMBOS = parse_combinations(config["tradeoff"]["combinations"], config["stage2"]["nerf_variant"],
                                     PLAIN_SOURCES + STAGE1_METHODS, "tradeoff.combinations")
PHOTON_COMBOS = parse_combinations(config["photon_level"]["combinations"], config["stage2"]["nerf_variant"],
                                   PLAIN_SOURCES + STAGE1_METHODS, "photon_level.combinations")
TRADEOFF_SPACE = Paramspace(read_table(config["tradeoff"]["table"]))
PHOTON_SPACE = Paramspace(photon_table(config["photon_level"]["detection"], config["photon_level"]["frames"],
                                       "photon_level.detection/frames"))
PHOTON_BUDGET = photon_budget(config["photon_level"]["budget"])
SWEEP_SCENE, SWEEP_TRAIN = sweep_scenes(config["tradeoff"]["scene"], config["tradeoff"]["train_scenes"], EVAL_SCENES,
                                        TRAIN_SCENES, sorted(LAYOUTS) + sorted(config["llff_scenes"]))
SWEEP_SPECS = scene_specs(config | {"scenes": {"train": SWEEP_TRAIN, "eval": [SWEEP_SCENE]}}, sorted(LAYOUTS))
# Per combination: the config values a point starts from (spc3d.sweeps.budget) and the LLFF files it reads.
SWEEP_BASES = ByCombination({c: point_base(c, config, SWEEP_SCENE, SWEEP_TRAIN, SWEEP_SPECS,
                                           {m: translator_settings(config["stage1"], m) for m in STAGE1_METHODS})
                             for c in TRADEOFF_COMBOS + PHOTON_COMBOS})
SWEEP_INPUTS = ByCombination({c: scene_inputs(base) for c, base in SWEEP_BASES.items()})
KNOB_PATTERNS = {k: "[0-9]+" if kind is int else "[0-9.e-]+" for k, (kind, _) in KNOBS.items()}


rule tradeoff_point:
    """One trade-off point: the whole pipeline (scenes, SPC, stage 1, stage 2, scores) at one budget."""
    input:
        lpips=list(LPIPS_WEIGHTS.values()),
        scenes=SWEEP_INPUTS,
    output:
        f"results/tradeoff/{{combo}}/{TRADEOFF_SPACE.wildcard_pattern}/metrics.json",
    params:
        setting=TRADEOFF_SPACE.instance,
        budget={},
        base=SWEEP_BASES,
        keep_work=config["tradeoff"]["keep_work"],
        # outside the point's folder: a killed point resumes its trainings (deleted at its end unless keep_work)
        checkpoints=f"results/checkpoints/tradeoff/{{combo}}/{TRADEOFF_SPACE.wildcard_pattern}",
        policy=config["checkpoints"],
    log:
        f"logs/tradeoff/{{combo}}/{TRADEOFF_SPACE.wildcard_pattern}.log",
    wildcard_constraints:
        combo="|".join(map(re.escape, TRADEOFF_COMBOS)),
        **KNOB_PATTERNS,
    threads: 1
    conda:
        ENV
    script:
        "../scripts/tradeoff_point.py"


rule tradeoff_report:
    """The trade-off table (every point, Pareto flags) and figure (quality against wall time)."""
    input:
        point_paths("results/tradeoff", TRADEOFF_SPACE.dataframe, list(TRADEOFF_SPACE.instance_patterns),
                    TRADEOFF_COMBOS),
    output:
        csv="results/tables/tradeoff.csv",
        png=report("results/figures/tradeoff.png", caption="../report/tradeoff.rst", category="5. Trade-off",
                   labels={"figure": "speed–accuracy trade-off"}),
    params:
        combos=TRADEOFF_COMBOS,
        clock=config["tradeoff"]["clock"],
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


rule photon_level_point:
    """One photon-level point: the whole pipeline at photon_level.budget, one exposure and K."""
    input:
        lpips=list(LPIPS_WEIGHTS.values()),
        scenes=SWEEP_INPUTS,
    output:
        f"results/photon_level/{{combo}}/{PHOTON_SPACE.wildcard_pattern}/metrics.json",
    params:
        setting=PHOTON_SPACE.instance,
        budget=PHOTON_BUDGET,
        base=SWEEP_BASES,
        keep_work=config["tradeoff"]["keep_work"],
        # outside the point's folder: a killed point resumes its trainings (deleted at its end unless keep_work)
        checkpoints=f"results/checkpoints/photon_level/{{combo}}/{PHOTON_SPACE.wildcard_pattern}",
        policy=config["checkpoints"],
    log:
        f"logs/photon_level/{{combo}}/{PHOTON_SPACE.wildcard_pattern}.log",
    wildcard_constraints:
        combo="|".join(map(re.escape, PHOTON_COMBOS)),
        **KNOB_PATTERNS,
    threads: 1
    conda:
        ENV
    script:
        "../scripts/tradeoff_point.py"


rule photon_level_report:
    """The photon-level table and figure (quality against mean detection probability, per K)."""
    input:
        point_paths("results/photon_level", PHOTON_SPACE.dataframe, list(PHOTON_SPACE.instance_patterns),
                    PHOTON_COMBOS),
    output:
        csv="results/tables/photon_level.csv",
        png=report("results/figures/photon_level.png", caption="../report/photon_level.rst", category="5. Trade-off",
                   labels={"figure": "quality against photon level"}),
    params:
        combos=PHOTON_COMBOS,
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
