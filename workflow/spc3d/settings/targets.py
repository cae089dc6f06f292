"""The files a run of the grid makes: what ``snakemake`` builds by default and what its summary,
table and figure rules gather (every configured row on every evaluation scene, for every seed)."""

from __future__ import annotations

from spc3d.names import parse_combination, resolve_combinations, scored_before_3d
from spc3d.settings.grid import Grid

TABLES = ("single_stage", "two_stage", "stage1", "estimated_poses", "no_reference", "stopping")


class Targets:
    """The grid's outputs. ``combinations``: stage2.combinations resolved (spc3d.names); ``reps``: one
    tag per seed, "" for the first (config ``seed``), "-seed{N}" for each repeat (which redraws
    everything random: SPC noise, augmentation, translator init and crops, stage-2 init)."""

    def __init__(self, grid: Grid):
        config = grid.config
        self.grid, self.paths = grid, grid.paths
        self.combinations = resolve_combinations(config["stage2"]["combinations"], config["stage2"]["nerf_variant"])
        seeds = [config["seed"] + k for k in range(config["seeds"])]
        self.reps = ["" if s == config["seed"] else f"-seed{s}" for s in seeds]
        self.scenes = list(dict.fromkeys(grid.train + grid.eval))
        self.scored = [s for s in grid.eval if s not in grid.no_reference]  # scenes with reference views

    def final(self) -> list[str]:
        """What `snakemake` builds by default: the data summary, the tables (with the findings), the figures."""
        return [self.paths.summary("data_summary.md"), *self.tables(), *self.figures()]

    def tables(self) -> list[str]:
        paper = [self.paths.table(t, ext) for t in TABLES for ext in ("csv", "md", "tex", "html")]
        return paper + [self.paths.table("findings", ext) for ext in ("md", "json", "html")]

    def figures(self) -> list[str]:
        return [self.paths.figure(f"qualitative_{scene}") for scene in self.scored]

    def stage1(self) -> list[str]:
        """Stage-1 scores (before 3D) of every scored source on every scene with reference views."""
        sources = scored_before_3d(self.combinations)
        return [self.paths.stage1(s, source, rep) for s in self.scored for source in sources for rep in self.reps]

    def metrics(self) -> list[str]:
        """metrics.json of every row on every evaluation scene (on a capture without reference
        views, every row but those that read the ground truth before scoring)."""
        return [
            self.paths.metrics(scene, combo, rep)
            for scene in self.grid.eval
            for combo in self.combinations
            for rep in self.reps
            if not (scene in self.grid.no_reference and needs_reference(combo))
        ]

    def eval_spc(self) -> list[str]:
        """Every evaluation scene's SPC folder, per repeat (the tables name those whose frames carry no image)."""
        return [self.paths.spc(scene, rep) for scene in self.grid.eval for rep in self.reps]

    def colmap(self, inputs: list[str]) -> list[str]:
        """The COLMAP runs of the data summary (no RGB run on a capture without reference views)."""
        no_rgb = self.grid.no_reference
        return [self.paths.colmap(s, i) for s in self.scenes for i in inputs if not (s in no_rgb and i == "rgb")]

    def roles(self) -> list[str]:
        """Each scene's role, in :attr:`scenes`' order (leave-one-out: a scene both trains and is evaluated)."""
        sets = (("train", self.grid.train), ("eval", self.grid.eval))
        return [" + ".join(role for role, names in sets if s in names) for s in self.scenes]

    def qualitative(self, w) -> dict:
        """The scene, its SPC folder and the reconstruction of every row (first seed)."""
        recons = [self.paths.recon(w.scene, combo) for combo in self.combinations]
        return {"scene": self.paths.scene(w.scene), "spc": self.paths.spc(w.scene), "recons": recons}


def needs_reference(combo: str) -> bool:
    """Rows that read the ground truth before scoring (the oracle source or its poses)."""
    source, _, poses = parse_combination(combo)
    return source == "gt" or poses == "gt"
