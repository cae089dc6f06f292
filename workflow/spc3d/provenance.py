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

Parsing and writing back the hundred-odd files of a closure took about as long as the rest of a dry
run, in every Snakemake process (each SLURM job's too). So each file version's analysis (its digest
and its imports) is kept between processes in a small JSON file named by the hash of the file's path
and bytes and of this analysis's version (:data:`ANALYSIS`): ``$SPC3D_CODE_CACHE``, else
``~/.cache/spc3d/code``; ``SPC3D_CODE_CACHE=off`` keeps nothing. An entry is only ever read for the
very bytes it was made from, so a stale entry cannot be read; an unreadable one is made again.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import importlib.util
import os
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from spc3d import io

PACKAGE = "spc3d"
ROOT = Path(__file__).resolve().parent  # the spc3d package folder
# What a kept analysis depends on besides the file: this format, and the Python whose ast.unparse wrote it.
ANALYSIS = f"spc3d-code-analysis-1 python-{sys.version_info[0]}.{sys.version_info[1]}"


def module_file(name: str) -> Path | None:
    """The source of module ``spc3d[.a.b]`` (a ``.py`` file or a package's ``__init__.py``), or None."""
    parts = name.split(".")
    if parts[0] != PACKAGE:
        return None
    base = ROOT.joinpath(*parts[1:])
    candidates = ([base.with_suffix(".py")] if parts[1:] else []) + [base / "__init__.py"]
    return next((c for c in candidates if c.is_file()), None)


def entry_file(module: str) -> Path:
    """The source of a registry's ``module`` (:func:`spc3d.specs.import_module`'s forms: a dotted
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


def imported_names(path: Path) -> frozenset[str]:
    """Every dotted name a file imports when it runs, anywhere in it (imports inside functions count,
    ``if TYPE_CHECKING`` ones do not); relative imports resolved against the file's own package, and
    ``from a import b`` gives both ``a`` and ``a.b`` (``b`` may be a submodule or an attribute)."""
    return analysis(Path(path).resolve()).names


def names_in(tree: ast.AST, path: Path) -> set[str]:
    """:func:`imported_names` of ``path``'s parsed ``tree``."""
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0] if here else None
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


def normalised(tree: ast.AST) -> str:
    """The code of a parsed Python file without its comments, docstrings and formatting: its syntax
    tree, docstrings removed, written back by :func:`ast.unparse` (text, so the key does not depend
    on the ``ast.dump`` layout of the Python version). Changes ``tree``: its docstrings go."""
    return ast.unparse(without_docstrings(tree))


def source_digest(path: str | Path) -> str:
    """sha256 of the file's :func:`normalised` code; computed once per file version."""
    return analysis(Path(path).resolve()).digest


@dataclass(frozen=True)
class Analysis:
    """What the keys need of one file version: the digest of its code and the names it imports."""

    digest: str  # sha256 of normalised
    names: frozenset[str]  # imported_names


def analysis(path: Path) -> Analysis:
    """The file's :class:`Analysis`, made once per file version (in this process, and kept between
    processes: the module docstring)."""
    stat = path.stat()
    return _analysis(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=4096)
def _analysis(path: Path, mtime_ns: int, size: int) -> Analysis:
    data = path.read_bytes()
    here = (module_name(path) or "").encode()  # relative imports resolve against it
    key = hashlib.sha256(b"\0".join([ANALYSIS.encode(), str(path).encode(), here, data])).hexdigest()
    kept = read_kept(key)
    if kept is not None:
        return kept
    tree = ast.parse(data, filename=str(path))
    names = frozenset(names_in(tree, path))  # before normalised(), which drops the docstrings
    made = Analysis(hashlib.sha256(normalised(tree).encode()).hexdigest(), names)
    keep(key, made)
    return made


def analysis_folder() -> Path | None:
    """Where analyses are kept between processes; None: nowhere (``SPC3D_CODE_CACHE=off``)."""
    given = os.environ.get("SPC3D_CODE_CACHE", "")
    if given.lower() == "off":
        return None
    return Path(given) if given else Path.home() / ".cache" / "spc3d" / "code"


def read_kept(key: str) -> Analysis | None:
    folder = analysis_folder()
    if folder is None:
        return None
    try:
        rec = io.read_json(folder / f"{key}.json")
        return Analysis(str(rec["digest"]), frozenset(rec["names"]))
    except (OSError, ValueError, KeyError, TypeError):  # none kept, or unreadable: made again
        return None


def keep(key: str, made: Analysis) -> None:
    """Write the analysis atomically (:func:`spc3d.io.write_json`: a reader sees it whole or not at
    all); a folder that cannot be written keeps nothing, silently: it only costs time."""
    folder = analysis_folder()
    if folder is None:
        return
    with contextlib.suppress(OSError):
        io.write_json(folder / f"{key}.json", {"digest": made.digest, "names": sorted(made.names)})


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
