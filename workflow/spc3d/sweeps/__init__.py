"""Budget sweeps: the speed–accuracy trade-off and quality against the photon level.

A *point* is one combination (``source+model``, as in stage 2) at one *setting*: values of the
budget knobs in :data:`knobs.KNOBS` (stage-2 iterations, image width, K frames, translator width
and steps, Gaussian cap, grid resolution, mean detection probability). ``point.run_point`` runs
the whole pipeline for it in one folder with the library's own stage functions (prepare, simulate,
augment + train + translate for a stage-1 source, reconstruct, evaluate) and writes
``metrics.json`` with the wall time of every stage, peak memory, the scores and the resolved
settings. ``pareto`` gathers points into tables and finds each combination's Pareto front (best
quality for the least time); ``report`` draws the figures and writes the tables.

Modules
-------
knobs    the knobs, which knobs a combination uses, sweep tables, combinations (no torch)
plan     the sweeps' config turned into what the rules pass on: scenes, bases, point paths (no torch)
budget   a point's resolved settings of every stage: the config's values with the knobs applied
point    the mini pipeline of one point -> metrics.json
pareto   Pareto fronts and tables of the trade-off and photon-level sweeps (no torch)
report   figures and report files (CSV + PNG) of the trade-off and photon-level sweeps (no torch)

``knobs``, ``plan``, ``pareto`` and ``report`` import neither torch nor Snakemake, so the workflow parses quickly.
"""
