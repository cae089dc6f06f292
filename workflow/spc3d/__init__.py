"""spc3d: binary single-photon-camera images to colour novel views.

The library behind the Snakemake workflow of this repository. Every module is importable and
testable without Snakemake; values arrive as function arguments, never from the workflow config.

Rooms, bottom to top (a module imports only its own room and those below it;
``tests/test_architecture.py`` keeps it so). Rule -> script -> function: ``workflow/rules/README.md``.

specs/        the model specs (every translator and reconstructor) and the settings dataclasses of
              every model, training and validation, built and checked without torch (``models``: old name)
names         the vocabulary: sources and their grammar, combinations, labels, settings (torch-free)
io            image and binary-frame files (OpenImageIO, packed ``.npz``), JSON records; atomic writes
cameras       the one internal camera convention and conversions to/from LLFF and COLMAP
llff          the canonical scene folder (LLFF layout): read, write, import LLFF folders
pixels        the sRGB transfer and PSNR, on numpy arrays and torch tensors alike (every stage)
plotting      matplotlib on the Agg back-end and atomic PNG writes
runtime       process settings of a workflow job (freed memory kept for reuse)
checkpoints   fingerprinted checkpoints of both stages: digests, policy, safe resume, lock, watch
training      neutral training utilities of both stages: seeding, devices, peak memory, the loop
physics/      the SPC photon physics, sensors, hot pixels, an SPC folder's record
poses/        COLMAP poses, similarity alignment, poses from the photons
inputs/       built-in scenes, COLMAP-format scenes, scene folders and SPC frames, augmentation, exposure
captures/     real SPAD captures: photon cubes, capture folders, their import
evaluation/   metrics, LPIPS, held-out evaluation, tables, findings (and their shift between runs), figures
translate/    stage 1: binary -> sRGB translators and denoisers (``MODULES``), training, applying
reconstruct/  stage 2: image sources, 3DGS / NeRF / grid NeRF (``RECONSTRUCTORS``), fit and render
settings/     what each job runs with (the grid's answers per job), the results layout, the run's targets
sweeps/       the speed-accuracy trade-off and photon-level sweeps (a sweep point's settings)
config        the workflow config checked before anything runs (schema, paths, typed settings)
jobs          job glue for the rule scripts: logging, per-job benchmarks, scene specs
"""

__version__ = "0.1.0"
