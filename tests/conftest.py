"""Shared fixtures: paths to the repository and to the real LLFF scenes (skipped when absent)."""
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LLFF_ROOT = REPO.parent / "shared" / "data" / "llff"
LLFF_SCENES = ("fern", "flower", "fortress", "trex")


def llff_scene(name: str) -> Path:
    path = LLFF_ROOT / name
    if not (path / "poses_bounds.npy").is_file():
        pytest.skip(f"real LLFF scene {path} not available (needs ../shared next to the repository)")
    return path


@pytest.fixture
def fern() -> Path:
    return llff_scene("fern")
