"""Budget sweeps: the speed–accuracy trade-off and quality against the photon level.

A *point* is one combination (``source+model``, as in stage 2) at one *setting*: values of the
budget knobs in :data:`knobs.KNOBS` (stage-2 iterations, image width, K frames, translator width
and steps, Gaussian cap, grid resolution, mean detection probability). The workflow's own rules
build it (prepare, simulate, meter the display, augment + train + translate for a stage-1 source,
score the source's images, reconstruct, evaluate) under a *settings overlay*: the ``{overlay}``
wildcard after ``results/``, ``sweeps/{sweep}/{knob~value/...}/`` (``plan``). ``pareto`` reads each
point's scores and the benchmarks of its jobs into tables and finds each combination's Pareto
front (best quality for the least time); ``report`` draws the figures and writes the tables.

Modules
-------
knobs    the knobs, which knobs a combination uses, sweep tables, combinations (no torch)
plan     the overlay, a point's settings object (Point), its jobs and files (no torch)
budget   one stage's settings with the knobs applied (scene width, translator, stage-2 model)
pareto   a point's record from its files, Pareto fronts, the tables of both sweeps (no torch)
report   figures and report files (CSV + PNG) of the trade-off and photon-level sweeps (no torch)

``knobs``, ``plan``, ``pareto`` and ``report`` import neither torch nor Snakemake, so the workflow parses
quickly (``plan`` imports ``budget`` only when a job under an overlay asks for its settings).
"""
