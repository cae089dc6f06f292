"""A scene's inputs: its ground-truth folder and its SPC frames.

scenes        procedural forward-facing built-in scenes (disjoint training / evaluation content)
colmap_scene  COLMAP-format scenes (``images/`` + ``sparse/0/``) read to the canonical scene
build         spec -> scene folder (``prepare_scene``), its simulated SPC frames (``simulate_scene``)
augment       zoom / rotation / shear / flip augmentation of training views (rule ``augment_scene``)
exposure      display gain of the physics rows without ground truth (fitted on training scenes)

The canonical scene folder itself is read and written by :mod:`spc3d.llff` (a bottom module).
"""
