"""The claims a configuration's run will decide, before it runs: each with its comparisons, the
listed rows it does not run, and the scenes a verdict needs (spc3d.evaluation.findings.claim_plan).

    python workflow/tools/claim_plan.py [--configfile PRESET] [--write DOC]

Prints the Markdown table; ``--write DOC`` replaces the block of DOC between
``<!-- claims: PRESET -->`` and ``<!-- /claims -->`` with it (docs/protocol.md freezes the real-scene
preset's claims so; tests/test_protocol_plan.py checks the quote against the preset).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "workflow"))

from spc3d import io  # noqa: E402
from spc3d.config import workflow_config  # noqa: E402
from spc3d.evaluation.findings import claim_plan, plan_markdown, planned_budgets, planned_rows  # noqa: E402
from spc3d.names import resolve_combinations  # noqa: E402


def plan_of(configfile: str | Path | None) -> str:
    """The claims table of config.yaml overlaid by ``configfile`` (as ``--configfile`` merges it)."""
    cfg = workflow_config(*([configfile] if configfile else []))
    nerf = cfg["stage2"]["nerf_variant"]
    combos = resolve_combinations(cfg["stage2"]["combinations"], nerf)
    rivals = {k: resolve_combinations(v, nerf, f"findings.rivals.{k}") for k, v in cfg["findings"]["rivals"].items()}
    frames = (cfg["stage1"]["frames"], cfg["stage2"]["frames"], cfg["spc"]["capture_factor"])
    rows = planned_rows(combos, planned_budgets(combos, *frames))
    return plan_markdown(claim_plan(rows, nerf, rivals))


def write_block(doc: Path, configfile: str, table: str) -> None:
    """Replace ``doc``'s claims block of ``configfile`` with ``table``."""
    block = re.compile(rf"(<!-- claims: {re.escape(configfile)} -->\n).*?(<!-- /claims -->)", re.S)
    text = doc.read_text()
    if not block.search(text):
        raise SystemExit(f"{doc}: no block '<!-- claims: {configfile} -->' ... '<!-- /claims -->' to replace")
    io.write_text(doc, block.sub(lambda m: m.group(1) + table + m.group(2), text))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configfile", help="a preset overlaying config.yaml (path from the repository root)")
    ap.add_argument("--write", type=Path, help="a document whose claims block of this preset is replaced")
    args = ap.parse_args(argv)
    table = plan_of(REPO / args.configfile if args.configfile else None)
    if args.write:
        write_block(args.write, args.configfile or "config.yaml", table)
    else:
        print(table, end="")


if __name__ == "__main__":
    main()
