"""The claims a configuration will decide, planned before it runs (spc3d.evaluation.findings.claim_plan,
workflow/tools/claim_plan.py), and the frozen copy of the real-scene preset's in docs/protocol.md."""

import re

from spc3d.evaluation.findings import claim_plan, needed_scenes, planned_budgets, planned_rows

from conftest import REPO, load_script

PRESET = "workflow/presets/findings-llff.yaml"
NERF = "nerf-grid"


def test_the_protocol_quotes_the_real_presets_claims_as_the_code_builds_them():
    tool = load_script(REPO / "workflow" / "tools" / "claim_plan.py")
    text = (REPO / "docs" / "protocol.md").read_text()
    block = re.search(rf"<!-- claims: {re.escape(PRESET)} -->\n(.*?)<!-- /claims -->", text, re.S)
    assert block, f"docs/protocol.md: no claims block of {PRESET}"
    assert block.group(1) == tool.plan_of(REPO / PRESET), (
        f"docs/protocol.md's claims differ from {PRESET}'s: run python workflow/tools/claim_plan.py "
        f"--configfile {PRESET} --write docs/protocol.md (and say why the protocol changed)"
    )
    assert "NOT RUN" not in block.group(1)  # every listed rival of the confirmatory run runs


def test_a_plan_names_the_listed_rows_that_will_not_run_and_the_scenes_a_verdict_needs():
    combos = ["pix2pixhd+3dgs", "restormer+3dgs", "bernoulli+3dgs", "mle-k16+3dgs", "none+3dgs", "mle-x1-mse+3dgs"]
    budgets = planned_budgets(combos, 1, 1, 4)
    assert budgets["none+3dgs"] == (1, 4) and budgets["mle-k16+3dgs"] == (16, 1) and budgets["bernoulli+3dgs"] == (1, 1)
    rivals = {"two_stage": ["pix2pixhd+3dgs", "restormer+3dgs", "prior+3dgs"], "mle": ["mle-x1-mse+3dgs"]}
    plan = {c["id"]: c for c in claim_plan(planned_rows(combos, budgets), NERF, rivals)}
    spad = plan["spad-two-stage"]
    assert spad["not_run"] == ["prior+3dgs"] and spad["m"] == 2 and spad["fails_needs"] == needed_scenes(2) == 7
    assert plan["spad-mle"]["not_run"] == [] and plan["spad-mle"]["fails_needs"] == 6
    faithful = plan["two-stage-3dgs-faithful"]  # S = 4 against S = 1: only as a cross-budget claim
    assert faithful["cross_budget"] and faithful["comparisons"] == ["pix2pixhd+3dgs vs none+3dgs"]
    assert plan["best-nerf"]["not_run"] == [f"pix2pixhd+{NERF}"]
