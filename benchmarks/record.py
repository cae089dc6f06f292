"""Run one benchmark script and keep what it printed as a Markdown table file that docs can quote.

    python benchmarks/record.py OUT [--name NAME] [--reference] -- SCRIPT.py [ARGS ...]

e.g. ``python benchmarks/record.py results/bench --reference -- spc_simulator.py``. Runs
``python benchmarks/SCRIPT.py ARGS`` from the repository root and writes ``OUT/tables/NAME.md``
(NAME: the script's stem unless given): the command, the commit, the date, the wall time and the
printed output verbatim. A figure of docs/benchmarks.md is then a block copied from that file
(``workflow/tools/archive_run.py OUT bench``), never a number typed from a terminal, and
``tests/test_generated_blocks.py`` fails when the two differ.

``--reference`` also times ``benchmarks/rasterizer.py`` at 10k Gaussians / 128x96 before and after
the script (native it/s), the machine reference every published time here comes with: the
project's machines differ by up to 2x and drift during a run. A script that fails leaves no file
(its output goes to stderr), and a file is written under a temporary name, then renamed.
"""

from __future__ import annotations

import argparse
import datetime
import shlex
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from default_run import parse_rasterizer  # noqa: E402

from spc3d import io  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
REFERENCE = ["rasterizer.py", "--sizes", "10000", "--repeats", "3"]


def run_script(argv: list[str]) -> tuple[str, float]:
    """(stdout, wall seconds) of ``python benchmarks/ARGV...`` run from the repository root."""
    script = REPO / "benchmarks" / argv[0]
    if not script.is_file():
        raise SystemExit(f"benchmarks/{argv[0]} does not exist: give a script of benchmarks/ (e.g. rasterizer.py)")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, str(script), *argv[1:]], cwd=REPO, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if out.returncode:
        sys.stderr.write(out.stdout + out.stderr)
        raise SystemExit(f"benchmarks/{argv[0]} failed (exit {out.returncode}): nothing recorded")
    return out.stdout, wall


def reference() -> float | None:
    """The machine reference now: native it/s of benchmarks/rasterizer.py at 10k Gaussians, 128x96."""
    return parse_rasterizer(run_script(REFERENCE)[0])


def commit() -> str:
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True)
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO, capture_output=True, text=True
    )
    return (out.stdout.strip() or "unknown") + (" (with uncommitted changes)" if dirty.stdout.strip() else "")


def render(
    name: str, argv: list[str], printed: str, wall: float, refs: tuple[float | None, float | None] | None
) -> str:
    """The Markdown file: a title, how and when it was measured, the printed output verbatim."""
    when = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    lines = [
        f"# {name}",
        "",
        f"`python benchmarks/{shlex.join(argv)}` at commit `{commit()}`, {when}, {wall:.0f} s wall.",
    ]
    if refs is not None:
        shown = ["–" if r is None else f"{r:.1f}" for r in refs]
        lines.append(
            f"Machine reference (`benchmarks/rasterizer.py`, 10k Gaussians, 128×96): {shown[0]} → {shown[1]} it/s."
        )
    return "\n".join([*lines, "", "```text", printed.rstrip("\n"), "```", ""])


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if "--" not in args:
        print(__doc__)
        return 2
    cut = args.index("--")
    parser = argparse.ArgumentParser(description="Record a benchmark's printed output as a table file.")
    parser.add_argument("out", type=Path, help="a results folder: the file goes to OUT/tables/NAME.md")
    parser.add_argument("--name", help="the file's name (default: the script's stem)")
    parser.add_argument("--reference", action="store_true", help="time the rasterizer reference before and after")
    opts = parser.parse_args(args[:cut])
    script = args[cut + 1 :]
    if not script:
        raise SystemExit("give the script after --, e.g. -- rasterizer.py")
    name = opts.name or Path(script[0]).stem
    before = reference() if opts.reference else None
    printed, wall = run_script(script)
    refs = (before, reference()) if opts.reference else None
    path = opts.out / "tables" / f"{name}.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    io.write_text(path, render(name, script, printed, wall, refs))
    print(f"{path}: {len(printed.splitlines())} lines recorded")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
