"""The HTML report: `snakemake --report` on a smoke run is one self-contained page with the tables,
figures, captions and run times, and (where Chromium is installed) it renders in a real browser.
.ci/run installs Chromium and sets SPC3D_REQUIRE_BROWSER=1, which turns a missing browser into a failure."""

import base64
import json
import os
import re
import warnings

import numpy as np
import pytest
from matplotlib.image import imread

from conftest import REPO, load_script, run_snakemake

SMOKE = REPO / "workflow" / "presets" / "smoke.yaml"
TOOL = REPO / "workflow" / "tools" / "report_screenshot.py"


def snakemake(workdir, *args, timeout=900, **kw):
    return run_snakemake(workdir, *args, timeout=timeout, **kw)


def load_tool():
    return load_script(TOOL, "report_screenshot")


def embedded_json(html: str, name: str) -> dict:
    """The ``var name = {...};`` object the report embeds for its scripts."""
    match = re.search(rf"var {name} = (\{{.*?\}});\n", html, re.S)
    assert match, f"no `var {name}` in the report"
    return json.loads(match.group(1))


def browser_missing(tool) -> str | None:
    """Why the screenshot tool finds no browser (None when it finds one); a failure instead where
    SPC3D_REQUIRE_BROWSER=1 says one must be there."""
    try:
        tool.find_browser()
    except tool.BrowserMissing as exc:
        if os.environ.get("SPC3D_REQUIRE_BROWSER") == "1":
            pytest.fail(f"{exc} (SPC3D_REQUIRE_BROWSER=1)")
        return str(exc)
    return None


def test_screenshot_tool_names_the_missing_browser(monkeypatch, tmp_path):
    tool = load_tool()
    monkeypatch.delenv("CHROMIUM", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))  # no browser on PATH
    with pytest.raises(tool.BrowserMissing, match=r"apt-get install chromium"):
        tool.find_browser()
    page = tmp_path / "report.html"
    page.write_text("<html><body>x</body></html>")
    assert tool.main([str(page)]) == 2  # a clear error, not a traceback


def test_screenshot_tool_names_what_a_page_never_finished(tmp_path):
    """A page that is not a Snakemake report never mounts the report's app: a clear error, no PNG."""
    tool = load_tool()
    if why := browser_missing(tool):
        pytest.skip(why)
    page = tmp_path / "plain.html"
    page.write_text("<html><body><p>not a report</p></body></html>")
    png = tmp_path / "plain.png"
    with pytest.raises(
        RuntimeError,
        match=r"plain.html: the page did not settle in time "
        r"\(the report's React app has not mounted\)",
    ):
        tool.screenshot(page, png, timeout_s=15)  # Chromium's start counts: under a loaded CI 2 s was too short
    assert not png.exists() and not list(tmp_path.glob("*.part"))
    assert tool.main([str(page), str(png), "--timeout", "1"]) == 1


@pytest.mark.slow
def test_report_of_a_smoke_run(tmp_path, smoke_run):
    """The session's smoke run, then the report: every table, figure and caption embedded; a browser renders it."""
    assert smoke_run.built["full_rc"] == 0, smoke_run.built["full_err"]
    work = smoke_run.copy(tmp_path / "work")
    report = tmp_path / "report.html"
    proc = snakemake(work, "--report", str(report), *smoke_run.configs, timeout=300, env=smoke_run.env)
    assert proc.returncode == 0, proc.stderr[-4000:]

    html = report.read_text(encoding="utf-8")
    assert report.stat().st_size > 500_000  # libraries and figures inline
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=\"https?:", html)  # nothing fetched from the web
    results = embedded_json(html, "results")
    expected = {
        "results/tables/two_stage.html": "1. Paper tables",
        "results/tables/single_stage.html": "1. Paper tables",
        "results/tables/stage1.html": "1. Paper tables",
        "results/figures/qualitative_courtyard.png": "2. Qualitative",
        "results/summary/data_summary.png": "3. Data",
        **{f"results/models/{m}/curve.png": "4. Stage 1 training" for m in ("pix2pixhd", "restormer", "diffusion")},
    }
    assert set(expected) <= set(results), sorted(results)
    categories = embedded_json(html, "categories")
    for path, category in expected.items():
        assert any(path in files for files in categories[category].values()), (path, category)
    # Captions rendered from workflow/report/*.rst, with the run's own values filled in.
    captions = {path: " ".join(results[path]["caption"].split()) for path in expected}
    assert "Table 1 layout" in captions["results/tables/two_stage.html"]
    assert "Table 2 layout" in captions["results/tables/single_stage.html"]
    assert all("Wang et al." in captions[p] for p in expected if p.startswith("results/tables/"))
    assert "nerf-grid" in captions["results/figures/qualitative_courtyard.png"]
    assert "K = 4 stored frames" in captions["results/summary/data_summary.png"]  # smoke: spc.frames 4
    assert "DiffBIR stand-in" in captions["results/models/diffusion/curve.png"]
    assert results["results/models/restormer/curve.png"]["labels"] == {
        "translator": "restormer",
        "figure": "training curve",
    }
    assert "LPIPS v0.1" in html and "spc3d: binary SPC frames to colour novel views" in html  # workflow.rst
    # Files are embedded as data URIs: the figure decodes to the PNG on disk.
    uri = results["results/figures/qualitative_courtyard.png"]["data_uri"]
    figure = work / "results" / "figures" / "qualitative_courtyard.png"
    assert base64.b64decode(uri.split(",", 1)[1]) == figure.read_bytes()
    runtimes = embedded_json(html, "runtimes_spec")["data"]["values"]
    assert {"train_translator", "reconstruct", "evaluate"} <= {r["rule"] for r in runtimes}

    tool = load_tool()
    if why := browser_missing(tool):  # the report is checked; only the browser part is left out
        warnings.warn(f"report not rendered in a browser: {why}", stacklevel=2)
        return
    for name, show in (
        ("landing", None),
        ("qualitative", "results/figures/qualitative_courtyard.png"),
        ("two_stage", "results/tables/two_stage.html"),
    ):
        png = tool.screenshot(report, tmp_path / f"report_{name}.png", show=show)
        img = imread(png)[..., :3]  # (1000, 1400, 3) in [0, 1]
        assert img.shape[:2] == (1000, 1400)
        assert img.std() > 0.05, f"{name}: the screenshot is blank"  # a page that failed to render is one colour
        _, counts = np.unique((img * 255).astype(np.uint8).reshape(-1, 3), axis=0, return_counts=True)
        assert counts.max() / counts.sum() < 0.9 and len(counts) > 500, f"{name}: hardly anything drawn"
        # The side bar is dark only once Tailwind's runtime has written all its CSS. Measured on this
        # smoke report: styled 0.38-0.41; pictures taken too early 0.58 (half styled) and 0.88-0.96.
        assert img[100:900, :250].mean() < 0.5, f"{name}: the side bar is not styled yet"
