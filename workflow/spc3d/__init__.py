"""spc3d: binary single-photon-camera images to colour novel views.

The library behind the Snakemake workflow of this repository. Every module is importable and
testable without Snakemake; values arrive as function arguments, never from the workflow config.

Modules
-------
io        image and binary-frame files (OpenImageIO, packed ``.npz``), atomic writes
cameras   the one internal camera convention and conversions to/from LLFF and COLMAP
llff      reading LLFF folders (``images*/`` + ``poses_bounds.npy``)
colmap_scene  reading COLMAP-format scenes (``images/`` + ``sparse/0/``, binary or text models)
scenes    procedural forward-facing captures written in the LLFF layout
spc       the SPC photon physics: 1-bit frames, exposure calibration, flux estimates
augment   zoom / rotation / shear / flip augmentation of training views
colmap    COLMAP (pycolmap) poses and their error against reference poses
summary   the data summary table and figure
"""

__version__ = "0.1.0"
