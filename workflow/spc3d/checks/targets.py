"""The targets asked for on the command line, answered in the project's words when no rule makes them.

Snakemake says "No rule to produce results/eval/mars/gt+3dgs/metrics.json" or "... tradeof" and
lists nothing; :func:`explain_target` says which part is unknown (the scene, the row, the named
target) with the configured ones and the nearest match. The Snakefile calls :func:`check_targets`
after its rules are defined, with the targets of its command line (:func:`command_line_targets`).
Nothing here imports Snakemake.
"""

from __future__ import annotations

import re
import sys
from pathlib import PurePosixPath

from spc3d.names import ConfigError, combination_problem, nearest

# results/<kind>/<scene>/...: the folders whose first level is a scene (workflow/rules/*.smk outputs).
SCENE_FOLDERS = ("scenes", "spc", "mle", "augment", "translate", "stage1", "recon", "eval", "checkpoints", "colmap")
ROW_FOLDERS = ("recon", "eval", "checkpoints")  # ... whose second level is a row (source+model[@poses][-seedN])
SWEEP_PREFIX = re.compile(r"sweeps/[^/]+/([^/]+~[^/]+/)+")


def command_line_targets(argv: list[str] | None = None) -> list[str]:
    """The positional arguments of a ``snakemake`` command line (its targets); [] when this process
    is not the Snakemake command line (a test parsing the Snakefile, an API call)."""
    argv = sys.argv if argv is None else argv
    program = argv[0] if argv else ""
    if not (program.endswith("snakemake") or program.endswith("snakemake/__main__.py")):
        return []
    from snakemake.cli import get_argument_parser

    try:
        args, _ = get_argument_parser().parse_known_args(argv[1:])
    except SystemExit:  # Snakemake already accepted this command line; never fail on our reading of it
        return []
    return list(getattr(args, "targets", None) or [])


def explain_target(target: str, named: list[str], scenes: list[str], rows: list[str], rules: list[str] = ()) -> str:
    """Why no rule makes ``target``: an unknown named target (``named``: the targets a user asks
    for by name; the nearest match is sought among every rule name, ``rules``, too), or a file whose
    scene (``scenes``) or row (``rows``, the configured combinations) is not configured; each with
    the valid ones and the nearest match."""
    if "/" not in target and "." not in target:
        hint = nearest(target, named, "target")
        if "did you mean" not in hint and "did you mean" in (other := nearest(target, rules, "target")):
            hint = other.split("valid:")[0] + "named targets: " + ", ".join(named)
        return f"{hint.replace('valid:', 'named targets:')} (or a file under results/)"
    path = PurePosixPath(target)
    parts = list(path.parts)
    if not parts or parts[0] != "results":
        return f"target {target!r}: the workflow makes files under results/, or the named targets {', '.join(named)}"
    rest = "/".join(parts[1:])
    rest = SWEEP_PREFIX.sub("", rest, count=1)
    parts = rest.split("/")
    if parts[0] == "figures" and len(parts) == 2 and parts[1].startswith("qualitative_"):
        scene = PurePosixPath(parts[1]).stem.removeprefix("qualitative_")
        if scene not in scenes:
            return f"target {target!r}: " + nearest(scene, scenes, "scene")
    if parts[0] in SCENE_FOLDERS and len(parts) >= 2 and parts[1] not in scenes:
        return f"target {target!r}: " + nearest(parts[1], scenes, "scene") + " (scenes.train, scenes.eval, tradeoff)"
    if parts[0] in ROW_FOLDERS and len(parts) >= 3:
        row = re.sub(r"-seed[0-9]+$", "", parts[2])
        problem = combination_problem(row)
        if problem:
            return f"target {target!r}: {problem}"
        if row not in rows:
            hint = nearest(row, rows, "row").replace("unknown row", "row", 1).replace("valid:", "configured rows:")
            return f"target {target!r}: " + hint.replace("; ", " is not configured (stage2.combinations); ", 1)
    return (
        f"target {target!r}: no rule makes this file; named targets: {', '.join(named)}; files are made under "
        "results/ for the configured scenes and rows (snakemake --list-target-rules lists the rules)"
    )


def check_targets(targets: list[str], producible, named: list[str], scenes: list[str], rows: list[str], rules=()):
    """Raise :class:`ConfigError` for the first of ``targets`` that is neither a rule (``rules``,
    ``named``), nor a file some rule makes (``producible(target)``) or that exists, explained by
    :func:`explain_target`."""
    import os
    from pathlib import Path

    for target in targets:
        if os.path.isabs(target) or target.startswith("."):  # as Snakemake reads it: relative to --directory
            target = os.path.relpath(target) if not os.path.relpath(target).startswith("..") else target
        if target in named or target in rules or Path(target).exists() or producible(target):
            continue
        if os.path.isabs(target):  # outside the working directory: Snakemake's own answer
            continue
        raise ConfigError(explain_target(target, named, scenes, rows, list(rules)))


def process_start() -> float:
    """When this process started (epoch seconds, to the kernel's clock tick: /proc/self/stat's start
    time after boot, against the boot-time clock), for :func:`is_fresh_folder`."""
    import os
    import time

    with open("/proc/self/stat") as f:
        ticks = int(f.read().rsplit(")", 1)[1].split()[19])
    boot = time.time() - time.clock_gettime(time.CLOCK_BOOTTIME)
    return boot + ticks / os.sysconf("SC_CLK_TCK")


def is_fresh_folder(folder, started: float | None = None) -> bool:
    """Whether ``folder`` is empty and was made after ``started`` (default: this process's start):
    the --directory Snakemake creates before it reads the Snakefile (snakemake.common.workdir_handler).
    A folder the user made before the command is not fresh."""
    from pathlib import Path

    folder = Path(folder)
    try:
        started = process_start() if started is None else started
    except (OSError, ValueError, IndexError, AttributeError):  # no /proc (not Linux): keep every folder
        return False
    return folder.is_dir() and not any(folder.iterdir()) and folder.stat().st_mtime > started


def remove_if_unused(folder) -> bool:
    """Remove ``folder`` when it holds no file (only empty folders, if any): what a run refused at
    parse time leaves of the --directory it was given. Called at exit for a folder
    :func:`is_fresh_folder` found new; a folder with any file in it is kept whole."""
    import shutil
    from pathlib import Path

    folder = Path(folder)
    if not folder.is_dir() or any(p.is_file() or p.is_symlink() for p in folder.rglob("*")):
        return False
    shutil.rmtree(folder, ignore_errors=True)
    return not folder.exists()
