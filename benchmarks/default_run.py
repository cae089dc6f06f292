"""The default pipeline of two commits, back to back from fresh clones: job CPU and wall, new / base.

    python benchmarks/default_run.py BASE NEW [--repo .] [--workdir DIR] [--cores 2] [--keep] [--dry]
                                     [--only-new --base-summary FILE] [--venv PATH] [--out FILE]

e.g. ``python benchmarks/default_run.py 28a55a7 HEAD`` (about 25 min per commit at ``--cores 2``).
BASE and NEW are commits or refs of ``--repo`` (default: this repository), resolved there first:
``HEAD`` is its committed HEAD, without uncommitted changes. For each commit, BASE first:

1. ``git clone --no-local`` into ``DIR/<short sha>`` and check the commit out: no results/, no
   checkpoints, no numba cache (``NUMBA_CACHE_DIR`` is unset), so every run starts cold.
2. Check that the clone's own ``spc3d`` is what gets imported: the runs use the caller's Python
   environment (or ``--venv``), whose editable install points at another checkout, with
   ``PYTHONPATH=<clone>/workflow`` (the Snakefile also puts that folder first on its own path).
3. Machine reference: ``benchmarks/rasterizer.py --sizes 10000 --repeats 3`` of that clone, the
   native it/s at 10k Gaussians / 128x96, before and after the pipeline (options an old commit's
   script lacks are dropped).
4. ``snakemake --cores N`` in the clone: wall, user and system CPU and peak RSS of the whole run
   (``os.wait4``, as ``/usr/bin/time -v``), output in ``DIR/<short sha>.snakemake.log``.
   The LPIPS weights are downloaded (pip) by the run itself, as in any fresh checkout.
5. Job CPU: the sum over the clone's ``benchmarks/{rule}/**/*.tsv``, which each job writes
   about itself (``spc3d.jobs.write_benchmark``: user_s + sys_s; Snakemake's ``benchmark:``
   TSVs, column ``cpu_time``, are read as well), per rule (the first folder below benchmarks/),
   and over the jobs both commits ran (same TSV path): when a newer default adds rows, that is
   the same work done by both.

Printed: per rule the jobs and job CPU seconds of both commits and their ratio, the totals, the
wall times and the reference it/s, then the new / base ratios of job CPU and of wall, and both
normalised by the reference (ratio x reference_new / reference_base: a machine that ran slower
during NEW's run, lower it/s, would otherwise count against NEW). The reference is each clone's own
rasterizer: when the commits differ in it, a warning says so (the normalisation then also
cancels that change). The last line, ``job_cpu_ratio: <new / base>``, is machine-readable;
``--out FILE`` writes everything as JSON.

The two runs are back to back so that both see the same machine: nothing else should run on it
meanwhile (job CPU time, too, grows on a loaded machine). ``--only-new`` runs NEW alone and
takes BASE's figures from ``--base-summary`` (an earlier ``--out`` file; without it there are
no ratios). ``--dry`` does everything but the pipelines (clone, import check, ``snakemake -n``
job counts, reference), to check the set-up in a few minutes. The clones are removed at the end
unless ``--keep`` (a failed pipeline keeps its clone for its log).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RASTER_OPTIONS = (["--sizes", "10000", "--repeats", "3", "--min-seconds", "0.5"], ["--sizes", "10000"], [])
SPLAT_CODE = ("workflow/spc3d/reconstruct/splat", "benchmarks/rasterizer.py")


def git(*args: str, cwd: Path) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout.strip()


def resolve(repo: Path, ref: str) -> str:
    """Full sha of ``ref`` in ``repo``."""
    return git("rev-parse", "--verify", f"{ref}^{{commit}}", cwd=repo)


def clone(repo: Path, sha: str, dest: Path) -> None:
    """A fresh clone of ``repo`` at ``sha`` (fetched by sha when no branch or tag holds it)."""
    if dest.exists():
        raise SystemExit(f"{dest} exists: the runs need fresh clones (another --workdir, or remove it)")
    subprocess.run(["git", "clone", "--no-local", "--quiet", str(repo), str(dest)], check=True)
    if subprocess.run(["git", "cat-file", "-e", f"{sha}^{{commit}}"], cwd=dest, capture_output=True).returncode:
        git("fetch", "--quiet", str(repo), sha, cwd=dest)
    git("checkout", "--quiet", sha, cwd=dest)


def environment(clone_dir: Path, venv: Path | None) -> tuple[dict, str, str]:
    """(env, python, snakemake) running ``clone_dir``'s own code in the caller's env or ``venv``."""
    bin_dir = venv / "bin" if venv else Path(sys.executable).parent
    env = dict(os.environ, PYTHONPATH=str(clone_dir / "workflow"), PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    env.pop("NUMBA_CACHE_DIR", None)  # numba caches beside the clone's sources: a cold start
    if venv:
        env["VIRTUAL_ENV"] = str(venv)
    python = str(bin_dir / "python") if venv else sys.executable
    snakemake = bin_dir / "snakemake"
    return env, python, str(snakemake) if snakemake.exists() else "snakemake"


def check_import(python: str, clone_dir: Path, env: dict) -> str:
    """The file of the ``spc3d`` imported in the runs' env; exits unless it is the clone's."""
    code = "import spc3d; print(spc3d.__file__)"
    path = subprocess.run([python, "-c", code], cwd=clone_dir, env=env, check=True, capture_output=True, text=True)
    found = Path(path.stdout.strip()).resolve()
    if not found.is_relative_to((clone_dir / "workflow").resolve()):
        raise SystemExit(f"spc3d is imported from {found}, not from the clone {clone_dir}")
    return str(found)


def parse_rasterizer(text: str, n: int = 10000, size: str = "128x96") -> float | None:
    """Native it/s of the row ``n size native ...`` of benchmarks/rasterizer.py's output."""
    for line in text.splitlines():
        m = re.match(rf"\s*{n}\s+{size}\s+([\d.]+)\s", line)
        if m:
            return float(m.group(1))
    return None


def rasterizer_rate(python: str, clone_dir: Path, env: dict) -> float | None:
    """The clone's machine reference (native it/s, 10k Gaussians, 128x96); None if none printed."""
    for options in RASTER_OPTIONS:
        cmd = [python, "benchmarks/rasterizer.py", *options]
        out = subprocess.run(cmd, cwd=clone_dir, env=env, capture_output=True, text=True)
        if "unrecognized arguments" not in out.stderr:
            break
    if out.returncode:
        print(f"  rasterizer.py failed ({out.returncode}): {out.stderr.strip()[-300:]}", file=sys.stderr)
    return parse_rasterizer(out.stdout)


def run_measured(cmd: list[str], cwd: Path, env: dict, log: Path) -> dict:
    """Run ``cmd`` (output to ``log``): wall, user and system CPU and peak RSS of it and its children."""
    t0 = time.perf_counter()
    with open(log, "w") as out:
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return {
        "rc": proc.returncode,
        "wall_s": round(time.perf_counter() - t0, 2),
        "user_s": round(usage.ru_utime, 2),
        "sys_s": round(usage.ru_stime, 2),
        "max_rss_mb": round(usage.ru_maxrss / 1024, 1),  # kilobytes on Linux
    }


def parse_job_stats(text: str) -> dict[str, int]:
    """Rule -> job count from the ``Job stats`` table of ``snakemake -n`` (without ``total``)."""
    counts, inside = {}, False
    for line in text.splitlines():
        inside = inside or line.startswith("Job stats")
        m = re.fullmatch(r"(\w+)\s+(\d+)", line.strip()) if inside else None
        if m and m.group(1) == "total":
            break
        if m:
            counts[m.group(1)] = int(m.group(2))
    return counts


def dry_job_counts(snakemake: str, clone_dir: Path, env: dict, cores: int) -> dict[str, int]:
    cmd = [snakemake, "-n", "--cores", str(cores), "--quiet", "rules"]
    out = subprocess.run(cmd, cwd=clone_dir, env=env, capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(f"snakemake -n failed in {clone_dir}:\n{out.stdout[-2000:]}{out.stderr[-2000:]}")
    return parse_job_stats(out.stdout + out.stderr)


def tsv_cpu(path: Path) -> float:
    """CPU seconds of one job's benchmark TSV: user_s + sys_s (spc3d) or cpu_time (Snakemake), all rows."""
    header, *rows = path.read_text().splitlines()
    names = header.split("\t")
    total = 0.0
    for row in rows:
        values = dict(zip(names, row.split("\t")))
        keys = ("cpu_time",) if "cpu_time" in values else ("user_s", "sys_s")
        for key in keys:
            try:
                total += float(values.get(key, ""))
            except ValueError:  # NA, -, missing
                pass
    return total


def job_cpu(benchmarks: Path) -> dict[str, float]:
    """Job (its TSV's path below ``benchmarks``, the rule first) -> CPU seconds."""
    jobs = {}
    for path in sorted(benchmarks.rglob("*.tsv")):
        rel = path.relative_to(benchmarks)
        if len(rel.parts) >= 2 and not path.name.startswith("."):
            jobs[rel.as_posix()] = round(tsv_cpu(path), 2)
    return jobs


def job_cpu_by_rule(jobs: dict[str, float]) -> dict[str, dict]:
    """Rule (first folder of the job's path) -> {"jobs": TSV files, "cpu_s": their summed CPU}."""
    rules: dict[str, dict] = {}
    for name, cpu in jobs.items():
        rule = rules.setdefault(name.split("/")[0], {"jobs": 0, "cpu_s": 0.0})
        rule["jobs"] += 1
        rule["cpu_s"] = round(rule["cpu_s"] + cpu, 2)
    return rules


def same_jobs(base: dict, new: dict) -> dict | None:
    """Job CPU of the jobs both runs did (same rule, scene and output name): the work both
    defaults share, when a newer default adds rows; None when a run has no per-job record."""
    if "jobs" not in base or "jobs" not in new:
        return None
    common = sorted(set(base["jobs"]) & set(new["jobs"]))
    b, n = (round(sum(x["jobs"][k] for k in common), 2) for x in (base, new))
    return {"jobs": len(common), "base_cpu_s": b, "new_cpu_s": n, "ratio": ratio(n, b)}


def measure(label: str, sha: str, args: argparse.Namespace, workdir: Path, name: str) -> dict:
    """Clone, check, reference, pipeline (or its dry run), reference: one commit's figures."""
    dest = workdir / name
    print(f"{label} {sha[:9]}: cloning into {dest}", file=sys.stderr, flush=True)
    clone(args.repo, sha, dest)
    env, python, snakemake = environment(dest, args.venv)
    res = {"commit": sha, "spc3d": check_import(python, dest, env), "cores": args.cores}
    print(f"  spc3d from {res['spc3d']}; reference (rasterizer.py)", file=sys.stderr, flush=True)
    res["ref_before"] = rasterizer_rate(python, dest, env)
    if args.dry:
        res["planned_jobs"] = dry_job_counts(snakemake, dest, env, args.cores)
    else:
        log = workdir / f"{name}.snakemake.log"
        print(f"  snakemake --cores {args.cores} (log: {log})", file=sys.stderr, flush=True)
        res["run"] = run_measured([snakemake, "--cores", str(args.cores)], dest, env, log)
        if res["run"]["rc"]:
            args.keep = True
            raise SystemExit(f"{label}: snakemake failed ({res['run']['rc']}), see {log}")
    res["ref_after"] = rasterizer_rate(python, dest, env)
    res["jobs"] = job_cpu(dest / "benchmarks")
    res["rules"] = job_cpu_by_rule(res["jobs"])
    return res


def reference(res: dict) -> float | None:
    """Mean of the reference it/s before and after the run."""
    rates = [r for r in (res.get("ref_before"), res.get("ref_after")) if r]
    return sum(rates) / len(rates) if rates else None


def jobs_of(res: dict) -> dict[str, int]:
    """Rule -> jobs: planned by the dry run, else the benchmark TSVs found."""
    return res.get("planned_jobs") or {rule: v["jobs"] for rule, v in res["rules"].items()}


def total_cpu(res: dict) -> float:
    return sum(v["cpu_s"] for v in res["rules"].values())


def ratio(new: float | None, base: float | None) -> float | None:
    return new / base if new and base else None


def ratios(base: dict, new: dict) -> dict:
    """New / base: total job CPU, wall, and both times reference_new / reference_base."""
    cpu = ratio(total_cpu(new), total_cpu(base))
    wall = ratio(new.get("run", {}).get("wall_s"), base.get("run", {}).get("wall_s"))
    ref = ratio(reference(new), reference(base))
    return {
        "job_cpu": cpu,
        "same_jobs": same_jobs(base, new),
        "wall": wall,
        "job_cpu_normalised": cpu * ref if cpu and ref else None,
        "wall_normalised": wall * ref if wall and ref else None,
    }


def fmt(x: float | None, spec: str = ".2f") -> str:
    return "–" if x is None else format(x, spec)


def print_rules(base: dict, new: dict) -> None:
    """Per rule: jobs (done, or planned by the dry run), CPU s of both commits and new / base."""
    jb, jn = jobs_of(base), jobs_of(new)
    rows = {name: (jb.get(name, 0), jn.get(name, 0)) for name in sorted({*jb, *jn, *base["rules"], *new["rules"]})}
    print(f"{'rule':<22} {'jobs':>7} {'CPU s base':>11} {'CPU s new':>10} {'new/base':>9}")
    for name, (nb, nn) in [*rows.items(), ("total", (sum(jb.values()), sum(jn.values())))]:
        if name == "total":
            cb, cn = total_cpu(base), total_cpu(new)
        else:
            cb, cn = (x["rules"].get(name, {}).get("cpu_s") for x in (base, new))
        count = str(nb) if nb == nn else f"{nb}/{nn}"
        print(f"{name:<22} {count:>7} {fmt(cb, '.1f'):>11} {fmt(cn, '.1f'):>10} {fmt(ratio(cn, cb)):>9}")


def print_summary(base: dict, new: dict, r: dict) -> None:
    print_rules(base, new)
    for label, x in (("base", base), ("new", new)):
        run = x.get("run", {})
        print(
            f"{label} {x['commit'][:9]}: wall {fmt(run.get('wall_s'), '.0f')} s, user {fmt(run.get('user_s'), '.0f')}"
            f" s, sys {fmt(run.get('sys_s'), '.0f')} s, peak RSS {fmt(run.get('max_rss_mb'), '.0f')} MB;"
            f" reference {fmt(x.get('ref_before'), '.1f')} -> {fmt(x.get('ref_after'), '.1f')} it/s"
        )
    print(
        f"new/base: job CPU {fmt(r['job_cpu'], '.3f')}, wall {fmt(r['wall'], '.3f')}; normalised by the"
        f" reference: job CPU {fmt(r['job_cpu_normalised'], '.3f')}, wall {fmt(r['wall_normalised'], '.3f')}"
    )
    same = r.get("same_jobs")
    if same:
        print(
            f"jobs both runs did ({same['jobs']}): job CPU base {same['base_cpu_s']:.1f} s, new"
            f" {same['new_cpu_s']:.1f} s, new/base {fmt(same['ratio'], '.3f')}"
        )
    print(f"job_cpu_ratio: {fmt(r['job_cpu'], '.3f') if r['job_cpu'] else 'n/a'}")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base", help="commit or ref of the baseline")
    ap.add_argument("new", help="commit or ref to compare with it")
    ap.add_argument("--repo", type=Path, default=REPO, help="repository to clone (default: this one)")
    ap.add_argument("--workdir", type=Path, help="folder for the clones (default: a new temporary folder)")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--keep", action="store_true", help="keep the clones (results, logs) afterwards")
    ap.add_argument("--only-new", action="store_true", help="run NEW alone (BASE from --base-summary)")
    ap.add_argument("--base-summary", type=Path, help="an earlier --out file whose 'base' is used")
    ap.add_argument("--venv", type=Path, help="virtual environment to run in (default: the caller's)")
    ap.add_argument("--out", type=Path, help="write the summary as JSON")
    ap.add_argument("--dry", action="store_true", help="all but the pipelines (snakemake -n instead)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    args.repo = args.repo.resolve()
    base_sha, new_sha = resolve(args.repo, args.base), resolve(args.repo, args.new)
    workdir = (args.workdir or Path(tempfile.mkdtemp(prefix="spc3d-default-run-"))).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    if subprocess.run(["git", "diff", "--quiet", base_sha, new_sha, "--", *SPLAT_CODE], cwd=args.repo).returncode:
        print("warning: BASE and NEW differ in the rasterizer: the reference is not the machine alone", file=sys.stderr)
    names = (base_sha[:7], new_sha[:7] if new_sha != base_sha else f"{new_sha[:7]}-new")
    try:
        if args.only_new:
            base = json.loads(args.base_summary.read_text())["base"] if args.base_summary else None
        else:
            base = measure("base", base_sha, args, workdir, names[0])
        new = measure("new", new_sha, args, workdir, names[1])
    finally:
        if not args.keep:
            for name in names:
                shutil.rmtree(workdir / name, ignore_errors=True)
            if not args.workdir:
                shutil.rmtree(workdir, ignore_errors=True)
    base = base or {"commit": base_sha, "rules": {}}
    r = ratios(base, new)
    print_summary(base, new, r)
    if args.out:
        args.out.write_text(json.dumps({"base": base, "new": new, "ratios": r, "dry": args.dry}, indent=1) + "\n")


if __name__ == "__main__":
    main()
