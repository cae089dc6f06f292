"""What each job runs with: one settings object per job, resolved from the configuration and the job's
wildcards, and the results layout its inputs are read from.

:class:`grid.Grid` answers for the grid's jobs; a sweep point's jobs ask
:class:`spc3d.sweeps.plan.Point`, the same questions answered with the point's knobs applied. The
rules pick one by the ``{overlay}`` wildcard (:meth:`spc3d.sweeps.plan.Settings.at`) and ask it by
name, so no rule helper has a branch for the sweeps. Neither module imports torch or Snakemake.

Modules
-------
grid    the grid's settings per job (frames, scenes, folds, translator and stage-2 settings)
params  one typed params object per rule, built by grid (NamedTuples: Snakemake compares them)
paths   the results layout: every folder and file a job reads, under a root (``results/`` or a point's)
targets the files a run of the grid makes (default target, tables, summary, figures)
"""

from spc3d.settings.grid import Grid
from spc3d.settings.paths import Paths
from spc3d.settings.targets import Targets

__all__ = ["Grid", "Paths", "Targets"]
