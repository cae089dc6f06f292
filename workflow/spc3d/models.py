"""The old name of :mod:`spc3d.specs` (the model specs, not the models): a plugin written against
it still imports, with a DeprecationWarning; everything here is :mod:`spc3d.specs`'s own object."""

from __future__ import annotations

import warnings

from spc3d import specs

warnings.warn(
    "spc3d.models is now spc3d.specs (the model specs and their settings); import from spc3d.specs",
    DeprecationWarning,
    stacklevel=2,
)


def __getattr__(name: str):
    return getattr(specs, name)
