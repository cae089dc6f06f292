"""How far the findings moved between two runs of the findings preset (old code, new code).

A change meant to leave the science alone (a faster kernel, a stopping rule) is checked by running
the findings preset before and after it and asking, entry by entry:

- **rows**: the PSNR change of every row both runs scored (new − old), paired over the runs
  (scene, seed) both have and averaged per scene (the findings' unit), with the findings' own test
  and interval (:func:`spc3d.evaluation.findings.interval`). Both runs draw the same SPC frames for
  a given scene and seed, so the pairing removes the scene and the noise draw; what is left is the code.
- **claims** and the **Δ-over-baseline** entries of both runs' ``findings.json``: whether the verdict
  changed, and whether the new estimate lies outside the old 95 % interval ("moved beyond it").

The result is ``tables/findings_shift.md`` in the new run's results folder
(``workflow/tools/findings_shift.py``), so that ``readme_results.py`` can copy it into the docs.
"""

from __future__ import annotations

import math
from pathlib import Path

from spc3d import io
from spc3d.evaluation.findings import Row, interval, md_table, p_text, paired, read_rows, read_stage1, sign_flip_p

STAGE1_PREFIX = "stage 1: "  # stage-1 rows share names with the translators' stage-2 sources


def read_run(results: str | Path) -> tuple[dict[str, Row], dict]:
    """A findings run's rows (stage 2, and stage 1 under ``STAGE1_PREFIX``) and its findings.json."""
    results = Path(results)
    findings = results / "tables" / "findings.json"
    if not findings.is_file():
        raise FileNotFoundError(
            f"{findings}: no findings table; pass the results/ folder of a finished run of "
            "workflow/presets/findings.yaml"
        )
    rows = read_rows(sorted(results.glob("eval/*/*/metrics.json")))
    stage1 = read_stage1(sorted(results.glob("stage1/*/*.json")))
    rows |= {STAGE1_PREFIX + name: row for name, row in stage1.items()}
    return rows, io.read_json(findings)


def row_shifts(old: dict[str, Row], new: dict[str, Row]) -> list[dict]:
    """New − old PSNR of every row both runs scored, paired over their shared scenes (seeds averaged)."""
    out = []
    for name in sorted(old.keys() & new.keys()):
        d = paired(new[name], old[name])
        if d.size == 0:
            continue
        low, high = interval(d)
        out.append({"row": name, "n": d.size, "mean": d.mean(), "low": low, "high": high, "p": sign_flip_p(d)})
    return out


def _entries(findings: dict) -> dict[str, dict]:
    entries = findings.get("claims", []) + findings.get("over_prior", []) + findings.get("over_classical", [])
    return {e["id"]: e for e in entries}


def _same_pair(entry: dict, comparison: dict) -> dict | None:
    """``entry``'s comparison of the same two rows as ``comparison`` (a claim's decisive pair can change)."""
    pair = (comparison["better"], comparison["worse"])
    return next((c for c in entry["comparisons"] if (c["better"], c["worse"]) == pair), None)


def claim_shifts(old: dict, new: dict) -> list[dict]:
    """Every claim and Δ-over-baseline entry of ``new`` beside the same entry of ``old`` (matched by id):
    the new decisive comparison against the old run's comparison of the same two rows. "Beyond" is
    None where the old run has no such comparison or only a range (fewer than MIN_SCENES scenes)."""
    before, out = _entries(old), []
    for key, now in _entries(new).items():
        was = before.get(key)
        shift = {"id": key, "claim": now["claim"], "new": now["verdict"], "new_d": now["decisive"]}
        if was is None:
            out.append(shift | {"old": "not in the old run", "old_d": None, "beyond": None})
            continue
        same = _same_pair(was, now["decisive"]) if now["decisive"] else None
        beyond = None
        if same is not None and same.get("bounds") == "interval" and math.isfinite(now["decisive"]["mean"]):
            beyond = not same["low"] <= now["decisive"]["mean"] <= same["high"]
        out.append(shift | {"old": was["verdict"], "old_d": same, "beyond": beyond})
    return out


def _dB(d: dict | None) -> str:
    if d is None:
        return "–"
    return f"{d['mean']:+.2f} [{d['low']:+.2f}, {d['high']:+.2f}]"


CLAIM_COLUMNS = [
    "claim",
    "comparison (new decisive)",
    "old verdict",
    "new verdict",
    "old Δ [95 %]",
    "new Δ [95 %]",
    "beyond",
]
ROW_COLUMNS = ["row", "n (scenes)", "Δ PSNR (dB)", "95 % interval", "p"]


def claim_cells(c: dict) -> list[str]:
    """One claim's line: verdicts (bold where they differ), both estimates, whether it moved beyond."""
    old, new = (c["old"], c["new"]) if c["old"] == c["new"] else (f"**{c['old']}**", f"**{c['new']}**")
    pair = f"{c['new_d']['better']} vs {c['new_d']['worse']}" if c["new_d"] else "–"
    beyond = "–" if c["beyond"] is None else ("**yes**" if c["beyond"] else "no")
    return [c["claim"], pair, old, new, _dB(c["old_d"]), _dB(c["new_d"]), beyond]


def row_cells(r: dict) -> list[str]:
    return [r["row"], str(r["n"]), f"{r['mean']:+.2f}", f"[{r['low']:+.2f}, {r['high']:+.2f}]", p_text(r["p"])]


def markdown(rows: list[dict], claims: list[dict], old_name: str, new_name: str) -> str:
    """The two tables, with a line counting what changed."""
    changed = sum(c["old"] != c["new"] for c in claims)
    moved = sum(bool(c["beyond"]) for c in claims)
    lines = [
        "# Findings shift",
        "",
        f"Old: {old_name}; new: {new_name}. Of {len(claims)} claims and Δ-over-baseline entries, "
        f"{changed} changed verdict and {moved} moved beyond the old 95 % interval (new estimate outside it).",
        "",
        *md_table(CLAIM_COLUMNS, [claim_cells(c) for c in claims]),
        "",
        "## Rows: new − old PSNR, paired over the scenes both have (seeds averaged)",
        "",
        *md_table(ROW_COLUMNS, [row_cells(r) for r in rows]),
    ]
    return "\n".join(lines) + "\n"


def write_shift(
    old: str | Path, new: str | Path, out: str | Path | None = None, names: tuple[str, str] | None = None
) -> str:
    """Compare two findings runs' results folders; write ``out`` (default: NEW/tables/findings_shift.md).
    ``names`` label the runs in the table (default: the folders)."""
    old_rows, old_findings = read_run(old)
    new_rows, new_findings = read_run(new)
    old_name, new_name = names or (str(old), str(new))
    text = markdown(row_shifts(old_rows, new_rows), claim_shifts(old_findings, new_findings), old_name, new_name)
    io.write_text(Path(out) if out else Path(new) / "tables" / "findings_shift.md", text)
    return text
