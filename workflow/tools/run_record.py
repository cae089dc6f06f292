"""A finished workflow run's cost, read from its own files, as a Markdown table.

    /usr/bin/time -v snakemake ... > LOG 2>&1        # the run, in a clone
    python benchmarks/rasterizer.py > RASTER          # the machine reference, after it (and before)
    python workflow/tools/run_record.py CLONE --log LOG --raster-after RASTER [--raster-before RASTER0] \
        [--command "snakemake ..."] [--out CLONE/results/tables/run.md]

Reads the clone's commit (git), the wall time, CPU and peak memory of the whole run (``time -v``'s
report at the end of LOG), the jobs Snakemake counted done (LOG), the CPU each job recorded about
itself (``CLONE/benchmarks/{rule}/**/*.tsv``, summed per rule as ``benchmarks/default_run.py``
does) and the machine reference of ``benchmarks/rasterizer.py`` (native it/s at 10k Gaussians,
128x96): a time on this project's machines means something only beside that figure.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from default_run import job_cpu, job_cpu_by_rule, parse_rasterizer  # noqa: E402

from spc3d import io  # noqa: E402

TIME_V = {
    "wall": r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)",
    "user_s": r"User time \(seconds\): ([\d.]+)",
    "sys_s": r"System time \(seconds\): ([\d.]+)",
    "max_rss_kb": r"Maximum resident set size \(kbytes\): (\d+)",
    "exit": r"Exit status: (\d+)",
}


def seconds(clock: str) -> float:
    """h:mm:ss or m:ss (time -v) in seconds."""
    total = 0.0
    for part in clock.split(":"):
        total = total * 60 + float(part)
    return total


def read_log(log: Path) -> dict:
    text = log.read_text(errors="replace")
    found = {k: (m.group(1) if (m := re.search(p, text)) else None) for k, p in TIME_V.items()}
    if found["wall"] is None:
        raise SystemExit(f"{log}: no `time -v` report at its end (run snakemake under /usr/bin/time -v)")
    steps = re.findall(r"(\d+) of (\d+) steps \((\d+)%\) done", text)
    done, planned = (int(steps[-1][0]), int(steps[-1][1])) if steps else (0, 0)
    return {
        "wall_s": seconds(found["wall"]),
        "cpu_s": float(found["user_s"]) + float(found["sys_s"]),
        "max_rss_mb": int(found["max_rss_kb"]) / 1024,
        "exit": int(found["exit"] or 0),
        "jobs_done": done,
        "jobs_planned": planned,
    }


def clock(s: float) -> str:
    h, rest = divmod(round(s), 3600)
    return f"{h} h {rest // 60:02d} min {rest % 60:02d} s" if h else f"{rest // 60} min {rest % 60:02d} s"


def record(clone: Path, log: Path, raster_after: Path, raster_before: Path | None, command: str) -> str:
    run = read_log(log)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True, text=True)
    rules = job_cpu_by_rule(job_cpu(clone / "benchmarks"))
    rates = [parse_rasterizer(p.read_text()) if p else None for p in (raster_before, raster_after)]
    reference = " → ".join(f"{r:.1f}" for r in rates if r is not None) or "not recorded"
    lines = [
        "# Run record",
        f"`{command}` from a clone of `{commit.stdout.strip()}`: exit {run['exit']}, "
        f"{run['jobs_done']} of {run['jobs_planned']} jobs done.",
        "",
        "| wall | CPU of the whole run | peak memory of one process | job CPU (jobs' own records) | "
        "rasterizer it/s (10k, 128×96) |",
        "|---|---|---|---|---|",
        f"| {clock(run['wall_s'])} | {run['cpu_s']:,.0f} s | {run['max_rss_mb']:,.0f} MiB | "
        f"{sum(r['cpu_s'] for r in rules.values()):,.0f} s | {reference} |",
        "",
        "| rule | jobs | job CPU (s) |",
        "|---|---|---|",
    ]
    for rule, r in sorted(rules.items(), key=lambda kv: -kv[1]["cpu_s"]):
        lines.append(f"| {rule} | {r['jobs']} | {r['cpu_s']:,.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clone", type=Path)
    ap.add_argument("--log", type=Path, required=True)
    ap.add_argument("--raster-after", type=Path, required=True)
    ap.add_argument("--raster-before", type=Path)
    ap.add_argument("--command", default="snakemake --cores 2")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    out = args.out or args.clone / "results" / "tables" / "run.md"
    text = record(args.clone, args.log, args.raster_after, args.raster_before, args.command)
    io.write_text(out, text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
