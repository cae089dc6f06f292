"""The library's layering, read from the source: stage 1 (spc3d.translate) and stage 2
(spc3d.reconstruct and the modules that drive it) never import each other; both may use the neutral
modules (training, checkpoints, io, metrics, ...). The workflow vocabulary stays torch-free."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO

PACKAGE = REPO / "workflow" / "spc3d"
STAGE1 = ("spc3d.translate",)
STAGE2 = ("spc3d.reconstruct", "spc3d.stage2", "spc3d.sources")


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports (relative imports resolved; ``from x import y`` also counts x.y)."""
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def modules_of(prefix: str) -> list[Path]:
    head = PACKAGE.joinpath(*prefix.split(".")[1:])
    return sorted(head.rglob("*.py")) if head.is_dir() else [head.with_suffix(".py")]


def inside(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def test_import_resolution_on_known_modules():
    """The resolver itself: relative imports of a subpackage module and of an __init__."""
    assert "spc3d.training" in imported_modules(PACKAGE / "translate" / "train.py")
    assert "spc3d.translate.pix2pixhd" in imported_modules(PACKAGE / "translate" / "__init__.py")
    assert "spc3d.reconstruct" in imported_modules(PACKAGE / "stage2.py")


@pytest.mark.parametrize("side,other", [(STAGE1, STAGE2), (STAGE2, STAGE1)], ids=["stage1", "stage2"])
def test_stage1_and_stage2_do_not_import_each_other(side, other):
    offenders = {}
    for prefix in side:
        for path in modules_of(prefix):
            bad = sorted(m for m in imported_modules(path) if inside(m, other))
            if bad:
                offenders[str(path.relative_to(REPO))] = bad
    assert not offenders, f"imports across the stages (use the neutral modules instead): {offenders}"


def test_workflow_vocabulary_does_not_import_torch():
    """Parsing the Snakefile imports spc3d.workflow and spc3d.config: they must stay torch-free."""
    code = (
        "import sys; sys.path.insert(0, 'workflow'); import spc3d.workflow, spc3d.config, spc3d.scenes; "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
