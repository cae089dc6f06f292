"""Stage-1 models: binary SPC image -> sRGB, one model per file, found through ``MODULES``.

    pix2pixhd   global generator (+ local enhancer), multiscale LSGAN, feature matching, VGG loss
    pix2pix     U-Net generator, 70x70 PatchGAN, vanilla GAN + L1
    cyclegan    two ResNet generators, LSGAN, cycle + identity losses, image pools (unpaired)
    restormer   MDTA + GDFN transformer denoiser trained with L1 (loads official weights by path)
    diffusion   a compact conditional DDPM/DDIM restorer: the offline stand-in for DiffBIR
    prior       the physics prior alone (blurred MLE at a fitted gain): the others' untrained start
    classical   the best non-learned denoiser: binomial VST, NLM / wavelet / TV / Gaussian, MLE
                (chosen on the training scenes' held-out views; like ``prior``, nothing is trained)

Each module holds ``Translator`` (the contract in :mod:`.base`) and, imported from the torch-free
:mod:`spc3d.specs.translators` where the workflow checks them at parse time, ``Config`` (CPU-budget
defaults) and ``PAPER`` (the published sizes); shared layers live in :mod:`.networks` (the VGG
perceptual loss in :mod:`.vgg`, the physics prior in :mod:`.prior`). The
training loop is :mod:`.train`, a model folder's files :mod:`.model_io` (its curve figure
:mod:`.curves`), applying a model to a scene and stage-1 scoring :mod:`.apply`.
Physics baselines without training (``mle``, the raw binary frame ``none``) are stage-2 sources
(:mod:`spc3d.reconstruct.sources`), scored before 3D alongside the translators.
"""

from __future__ import annotations

from spc3d import specs

# name -> the model's module (Config, PAPER, Translator), from the specs of spc3d.specs
MODULES = {name: specs.import_module(spec.module) for name, spec in specs.TRANSLATORS.items()}


def __getattr__(name: str):
    """``TRANSLATORS``, this registry's old name (a plugin may still import it), with a warning."""
    if name == "TRANSLATORS":
        import warnings

        warnings.warn(
            "spc3d.translate.TRANSLATORS is now spc3d.translate.MODULES (the model modules by method; "
            "spc3d.specs.TRANSLATORS holds their specs)",
            DeprecationWarning,
            stacklevel=2,
        )
        return MODULES
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
