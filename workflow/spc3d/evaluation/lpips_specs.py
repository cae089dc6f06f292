"""LPIPS v0.1 architecture facts: backbone names, layer specs, ScalingLayer constants, weight shapes.

Plain Python (no numpy, no torch), shared by the two LPIPS modules. Import layout, acyclic:
``lpips_specs`` (this module) <- ``lpips_weights`` (obtaining and checking the weights) <-
``lpips_net`` (the torch networks); each imports only the modules to its left, at module level.

The backbones reproduce the tap layers of torchvision's ``alexnet().features`` (relu1..relu5,
i.e. feature indices 1, 4, 7, 9, 11) and ``vgg16().features`` (relu1_2, relu2_2, relu3_3,
relu4_3, relu5_3, i.e. indices 3, 8, 15, 22, 29). ``SHIFT``/``SCALE`` are LPIPS's ScalingLayer.
"""

from __future__ import annotations

_ALIASES = {"alex": "alex", "alexnet": "alex", "vgg": "vgg", "vgg16": "vgg"}

SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)

# Backbone layer specs. ("conv", out_ch, kernel, stride, padding) is conv + ReLU;
# ("pool", kernel, stride) a max-pool; ("tap",) marks the output after the preceding ReLU.
_ALEX_SPEC = (
    ("conv", 64, 11, 4, 2),
    ("tap",),
    ("pool", 3, 2),
    ("conv", 192, 5, 1, 2),
    ("tap",),
    ("pool", 3, 2),
    ("conv", 384, 3, 1, 1),
    ("tap",),
    ("conv", 256, 3, 1, 1),
    ("tap",),
    ("conv", 256, 3, 1, 1),
    ("tap",),
)


def _vgg_spec() -> tuple:
    spec = []
    for stage, (width, n_conv) in enumerate([(64, 2), (128, 2), (256, 3), (512, 3), (512, 3)]):
        if stage:
            spec.append(("pool", 2, 2))
        spec.extend([("conv", width, 3, 1, 1)] * n_conv)
        spec.append(("tap",))
    return tuple(spec)


SPECS = {"alex": _ALEX_SPEC, "vgg": _vgg_spec()}


def canonical_net(net: str) -> str:
    """Map ``alex``/``alexnet``/``vgg``/``vgg16`` to ``alex`` or ``vgg``."""
    try:
        return _ALIASES[str(net).lower()]
    except KeyError:
        raise ValueError(f"unknown LPIPS backbone {net!r}: use 'alex' or 'vgg'") from None


def expected_shapes(net: str) -> dict[str, tuple[int, ...]]:
    """Torch-layout shapes of every weight array of backbone ``net`` (keys as in the .npz)."""
    shapes, in_ch, conv_i, lin_i = {}, 3, 0, 0
    for layer in SPECS[canonical_net(net)]:
        if layer[0] == "conv":
            _, out_ch, k, _, _ = layer
            shapes[f"conv{conv_i}.weight"] = (out_ch, in_ch, k, k)
            shapes[f"conv{conv_i}.bias"] = (out_ch,)
            in_ch, conv_i = out_ch, conv_i + 1
        elif layer[0] == "tap":
            shapes[f"lin{lin_i}.weight"] = (1, in_ch, 1, 1)
            lin_i += 1
    return shapes
