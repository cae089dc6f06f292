"""Screenshot a Snakemake HTML report in headless Chromium (does the page render in a real browser?).

    python workflow/tools/report_screenshot.py results/report.html results/report.png
    python workflow/tools/report_screenshot.py results/report.html qual.png \
        --show results/figures/qualitative_courtyard.png      # one result opened, with its caption

The report is a single self-contained page whose content is drawn by JavaScript (React), so a
plain HTML parser cannot tell whether it renders; a browser can. Chromium runs headless with a
virtual-time budget so the scripts finish before the picture is taken. Needs Debian's `chromium`
(`apt-get install chromium`) or Chrome on PATH; exits with status 2 and says so when there is none.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


class BrowserMissing(RuntimeError):
    """No Chromium / Chrome executable on PATH (or at $CHROMIUM)."""


def find_browser() -> str:
    """Path of the browser: $CHROMIUM if set, else the first of BROWSERS on PATH."""
    explicit = os.environ.get("CHROMIUM")
    if explicit:
        path = shutil.which(explicit)
        if not path:
            raise BrowserMissing(f"$CHROMIUM={explicit} is not an executable; unset it or point it at Chromium/Chrome")
        return path
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    raise BrowserMissing(f"no headless browser found (looked for {', '.join(BROWSERS)} on PATH and $CHROMIUM); "
                         "install one with `apt-get install chromium` (Debian/Ubuntu) or point $CHROMIUM at Chrome")


# Run after the report's own scripts: open one result as a click on it would (description in the side
# bar; an image also in the main panel). `app` and `results` are the report's globals.
SHOW_SCRIPT = """<script>
(function show() {
  if (typeof app === "undefined" || !app) { setTimeout(show, 50); return; }  // React mounts asynchronously
  const path = %s;
  if (!(path in results)) { document.title = "NO SUCH RESULT " + path; return; }
  const view = {navbarMode: "resultinfo", resultPath: path};
  const entry = results[path];
  if (entry.mime_type.startsWith("image/")) {
    Object.assign(view, {content: "img", contentPath: entry.data_uri});
  }
  app.setView(view);
})();
</script>
</body>"""


def with_result_shown(html: Path, result: str, folder: Path) -> Path:
    """A copy of the report in ``folder`` that opens ``result`` (a path as the report lists it)."""
    text = html.read_text(encoding="utf-8")
    head, sep, tail = text.rpartition("</body>")
    if not sep:
        raise ValueError(f"{html}: no </body>; is this a Snakemake report?")
    if f"{json.dumps(result)}: {{" not in head:
        raise ValueError(f"{result!r} is not a result of {html} (give a path as the report lists it, "
                         "e.g. results/figures/qualitative_courtyard.png)")
    out = folder / html.name
    out.write_text(head + SHOW_SCRIPT % json.dumps(result) + tail, encoding="utf-8")
    return out


def browser_command(browser: str, html: Path, png: Path, size: tuple[int, int], budget_ms: int,
                    profile: Path) -> list[str]:
    """The headless Chromium command line that renders ``html`` into ``png``."""
    return [browser, "--headless", "--disable-gpu", "--no-sandbox", "--hide-scrollbars",
            "--disable-dev-shm-usage", "--no-first-run", "--no-default-browser-check",
            f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
            f"--virtual-time-budget={budget_ms}", f"--screenshot={png}", html.resolve().as_uri()]


def screenshot(html: str | os.PathLike, png: str | os.PathLike, size: tuple[int, int] = (1400, 1000),
               budget_ms: int = 10_000, show: str | None = None, timeout_s: float = 120.0) -> Path:
    """Render ``html`` in headless Chromium and write a ``size`` PNG to ``png``; returns its path.
    ``show``: a result's path (e.g. ``results/figures/qualitative_courtyard.png``) to open first."""
    html, png = Path(html), Path(png).resolve()
    if not html.is_file():
        raise FileNotFoundError(f"{html}: no such report (build it with `snakemake --report {html}`)")
    browser = find_browser()
    png.parent.mkdir(parents=True, exist_ok=True)
    png.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="report-screenshot-") as tmp:  # no browser state left behind
        page = with_result_shown(html, show, Path(tmp)) if show else html
        cmd = browser_command(browser, page, png, size, budget_ms, Path(tmp) / "profile")
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    if not png.is_file():
        raise RuntimeError(f"{browser} wrote no screenshot {png} (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
    return png


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("html", help="the report, e.g. results/report.html")
    ap.add_argument("png", nargs="?", help="output PNG (default: next to the report, .png)")
    ap.add_argument("--size", default="1400x1000", help="window WIDTHxHEIGHT in pixels (default 1400x1000)")
    ap.add_argument("--show", metavar="RESULT", help="open this result first (its path as the report lists it)")
    ap.add_argument("--budget-ms", type=int, default=10_000, help="virtual time for the page's scripts (ms)")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    png = args.png or str(Path(args.html).with_suffix(".png"))
    try:
        out = screenshot(args.html, png, (width, height), args.budget_ms, args.show)
    except BrowserMissing as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (FileNotFoundError, ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
