"""The library code behind a job, for keys that must change when its results could.

Snakemake's between-workflow cache (``cache: True`` rules run with ``--cache``) keys an output on
its rule's script, params and inputs, and those of every job upstream, but not on the library the
scripts import: a changed loss in ``spc3d.translate`` would reuse weights trained before the change.
:func:`closure_digest` closes that gap. It follows the ``spc3d`` imports of the given files
statically (``ast``: imports inside functions count too, and nothing is imported or executed, so it
is cheap at parse time), and hashes every module reached, with its packages' ``__init__``.
A rule passes the digest as a param, so it enters the cache key (and Snakemake's ``params`` rerun
trigger): the translator trainings and every stage-2 fit (:func:`spc3d.settings.grid.job_code`). Code
outside the closure (tables, figures) can change without retraining anything.

Each file counts by its code only (:func:`source_digest`): its syntax tree without docstrings,
written back as text, so a comment, a docstring or a reformatting reruns nothing, while any change
of what runs (a loss constant, an operator) does. The same digest keys the checkpoints
(:func:`spc3d.checkpoints.code_digest`).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
from collections.abc import Iterable
from pathlib import Path

PACKAGE = "spc3d"
ROOT = Path(__file__).resolve().parent  # the spc3d package folder


def module_file(name: str) -> Path | None:
    """The source of module ``spc3d[.a.b]`` (a ``.py`` file or a package's ``__init__.py``), or None."""
    parts = name.split(".")
    if parts[0] != PACKAGE:
        return None
    base = ROOT.joinpath(*parts[1:])
    candidates = ([base.with_suffix(".py")] if parts[1:] else []) + [base / "__init__.py"]
    return next((c for c in candidates if c.is_file()), None)


def entry_file(module: str) -> Path:
    """The source of a registry's ``module`` (:func:`spc3d.models.import_module`'s forms: a dotted
    name or a ``.py`` path), found without importing it."""
    if module.endswith(".py"):
        return Path(module).resolve()
    found = module_file(module)
    if found is None:  # a plugin's module outside spc3d (its parent packages are imported to find it)
        spec = importlib.util.find_spec(module)
        if spec is None or not spec.origin:
            raise ModuleNotFoundError(f"model module {module!r}: not found")
        found = Path(spec.origin)
    return found


def module_name(path: Path) -> str | None:
    """``spc3d.a.b`` for a file of the package; None for a file outside it (a script)."""
    try:
        rel = path.resolve().relative_to(ROOT)
    except ValueError:
        return None
    parts = [PACKAGE, *rel.with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_type_checking(test: ast.expr) -> bool:
    """Whether an ``if`` test names ``TYPE_CHECKING`` (its body: imports for annotations only, never run)."""
    names = (
        n.id if isinstance(n, ast.Name) else n.attr if isinstance(n, ast.Attribute) else "" for n in ast.walk(test)
    )
    return "TYPE_CHECKING" in names


def imported_names(path: Path) -> set[str]:
    """Every dotted name a file imports when it runs, anywhere in it (imports inside functions count,
    ``if TYPE_CHECKING`` ones do not); relative imports resolved against the file's own package, and
    ``from a import b`` gives both ``a`` and ``a.b`` (``b`` may be a submodule or an attribute)."""
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0] if here else None
    tree = ast.parse(path.read_text(), filename=str(path))
    skip, out = set(), set()
    for node in ast.walk(tree):  # breadth first: an ``if`` is met before the statements under it
        if id(node) in skip:
            skip.update(id(child) for child in ast.iter_child_nodes(node))
            continue
        if isinstance(node, ast.If) and is_type_checking(node.test):
            skip.update(id(stmt) for stmt in node.body)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                if package is None:
                    continue
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            out |= {base} | {f"{base}.{a.name}" for a in node.names}
    return out


def imported_modules(path: Path) -> frozenset[str]:
    """The ``spc3d`` modules (files that exist) among :func:`imported_names`; parsed once per file
    version (a workflow digests every translator's closure, and they share most files)."""
    stat = path.stat()
    return _imported_modules(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=4096)
def _imported_modules(path: Path, mtime_ns: int, size: int) -> frozenset[str]:
    return frozenset(name for name in imported_names(path) if module_file(name) is not None)


def closure(files: Iterable[str | Path]) -> list[Path]:
    """The given files and every ``spc3d`` source they reach through imports (packages' ``__init__``
    included: importing ``a.b`` runs ``a``), sorted."""
    todo, seen = [Path(f).resolve() for f in files], set()
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in imported_modules(path):
            parts = name.split(".")
            for i in range(1, len(parts) + 1):  # the module and each package above it
                file = module_file(".".join(parts[:i]))
                if file is not None and file not in seen:
                    todo.append(file)
    return sorted(seen)


def without_docstrings(tree: ast.AST) -> ast.AST:
    """``tree`` with every statement that is a bare string removed (module, class and function
    docstrings, and the attribute docstrings under a field): they never change what the code
    computes. A body left empty gets ``pass``. Changes ``tree`` in place."""
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if not isinstance(body, list):
            continue
        node.body = [stmt for stmt in body if not is_string_statement(stmt)] or [ast.Pass()]
    return tree


def is_string_statement(stmt: ast.stmt) -> bool:
    """A statement that is a string literal alone (a docstring), which computes nothing."""
    return isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str)


def normalised_source(path: Path) -> str:
    """The code of a Python file without its comments, docstrings and formatting: its syntax tree,
    docstrings removed, written back by :func:`ast.unparse` (text, so the key does not depend on
    the ``ast.dump`` layout of the Python version)."""
    return ast.unparse(without_docstrings(ast.parse(path.read_text(), filename=str(path))))


def source_digest(path: str | Path) -> str:
    """sha256 of :func:`normalised_source`; computed once per file version."""
    path = Path(path).resolve()
    stat = path.stat()
    return _source_digest(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=4096)
def _source_digest(path: Path, mtime_ns: int, size: int) -> str:
    return hashlib.sha256(normalised_source(path).encode()).hexdigest()


def files_digest(files: Iterable[Path]) -> str:
    """sha256 over the names (relative to the package, or the file name for a script) and the
    :func:`source_digest` of each file, in the order given."""
    h = hashlib.sha256()
    for path in files:
        name = module_name(path) or path.name
        h.update(name.encode() + b"\0" + source_digest(path).encode() + b"\0")
    return h.hexdigest()


def closure_digest(files: Iterable[str | Path]) -> str:
    """:func:`files_digest` of :func:`closure`'s files: the code key of a job that runs ``files``."""
    return files_digest(closure(files))
