"""Screenshot a Snakemake HTML report in headless Chromium (does the page render in a real browser?).

    python workflow/tools/report_screenshot.py results/report.html results/report.png
    python workflow/tools/report_screenshot.py results/report.html qual.png \
        --show results/figures/qualitative_courtyard.png      # one result opened, with its caption

The report is a single self-contained page whose content is drawn by JavaScript: React mounts the app
asynchronously and Tailwind's runtime then writes the CSS for the classes it finds, also
asynchronously. A plain HTML parser cannot tell whether that works; a browser can. The picture must be
taken only once both have finished, and a fixed wait cannot promise that: with Chromium's
``--virtual-time-budget`` a CI run once caught the landing page before its side bar was styled. So the
tool drives Chromium over the DevTools protocol (``--remote-debugging-pipe``: JSON messages on file
descriptors 3 and 4, no extra Python package, no network port) and asks the page until it is settled:
the app mounted, fonts and images loaded, and the DOM and style sheets unchanged over several polls.
Only then does it capture. Needs Debian's `chromium` (`apt-get install chromium`) or Chrome on PATH;
exits with status 2 and says so when there is none.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
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
    raise BrowserMissing(
        f"no headless browser found (looked for {', '.join(BROWSERS)} on PATH and $CHROMIUM); "
        "install one with `apt-get install chromium` (Debian/Ubuntu) or point $CHROMIUM at Chrome"
    )


# Asked of the page until it is settled: {"wait": why not yet} or {"ready": a signature of what is drawn}.
# %s: the result that must be open (its path, or null). `app` and `results` are the report's globals.
SETTLED_JS = """(async (want) => {
  if (document.readyState !== "complete") return {wait: "the document is still loading"};
  const loading = document.getElementById("loading-screen");
  if (loading && getComputedStyle(loading).display !== "none") return {wait: "the loading screen is still shown"};
  if (typeof app === "undefined" || !app) return {wait: "the report's React app has not mounted"};
  const root = document.getElementById("app");
  if (!root || !root.children.length) return {wait: "the report's React app has drawn nothing"};
  if (want && app.state.resultPath !== want) return {wait: "the result " + want + " is not open yet"};
  await document.fonts.ready;
  const loadingImages = [...document.images].filter(img => !img.complete).length;
  if (loadingImages) return {wait: loadingImages + " image(s) still loading"};
  let rules = 0;  // Tailwind's runtime adds rules as it meets new classes
  for (const sheet of document.styleSheets) { try { rules += sheet.cssRules.length; } catch (e) {} }
  return {ready: document.body.innerHTML.length + ":" + rules};
})(%s)"""

# Opens one result as a click on it would (description in the side bar; an image also in the main panel).
SHOW_JS = """((path) => {
  if (!(path in results)) return false;
  const view = {navbarMode: "resultinfo", resultPath: path};
  const entry = results[path];
  if (entry.mime_type.startsWith("image/")) Object.assign(view, {content: "img", contentPath: entry.data_uri});
  app.setView(view);
  return true;
})(%s)"""


class DevTools:
    """A minimal Chrome DevTools protocol client over ``--remote-debugging-pipe``: the browser reads
    NUL-terminated JSON commands on its fd 3 and writes replies and events on its fd 4."""

    def __init__(self, browser: str, args: list[str], log):
        to_browser, self._commands = os.pipe()
        self._replies, from_browser = os.pipe()
        # bash puts the two pipe ends on fds 3 and 4, then becomes the browser (exec). Not sh: dash
        # only redirects fds 0-9, and these two can be higher (under pytest they are).
        launch = ["bash", "-c", f'exec "$0" "$@" 3<&{to_browser} 4>&{from_browser}', browser, *args]
        self.proc = subprocess.Popen(
            launch, pass_fds=(to_browser, from_browser), stdin=subprocess.DEVNULL, stdout=log, stderr=log
        )
        os.close(to_browser)
        os.close(from_browser)
        self._buffer = bytearray()
        self._last_id = 0
        self.session: str | None = None

    def send(self, method: str, params: dict | None = None, timeout_s: float = 60.0) -> dict:
        """Run one command (in the attached page's session, once there is one) and return its result."""
        self._last_id += 1
        message = {"id": self._last_id, "method": method, "params": params or {}}
        if self.session:
            message["sessionId"] = self.session
        os.write(self._commands, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._receive(deadline, method)
            if reply.get("id") == self._last_id:  # everything else is an event or an older reply
                if "error" in reply:
                    raise RuntimeError(f"DevTools {method} failed: {reply['error'].get('message')}")
                return reply.get("result", {})

    def _receive(self, deadline: float, method: str) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"the browser did not answer DevTools {method} in time")
            if select.select([self._replies], [], [], left)[0]:
                chunk = os.read(self._replies, 1 << 20)
                if not chunk:
                    raise RuntimeError(
                        f"the browser exited during DevTools {method} "
                        f"(exit {self.proc.poll()}); its log is in the error below"
                    )
                self._buffer += chunk
        end = self._buffer.index(b"\0")
        message = json.loads(self._buffer[:end])
        del self._buffer[: end + 1]
        return message

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (promises awaited)."""
        result = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True})
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            raise RuntimeError(
                f"a script in the page failed: {details.get('exception', {}).get('description')}"
                f" ({details.get('text')})"
            )
        return result["result"].get("value")

    def close(self) -> None:
        try:
            self.session = None
            self.send("Browser.close", timeout_s=10)
        except (OSError, RuntimeError, TimeoutError):
            pass  # it has exited already, or will be killed below
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._commands)
        os.close(self._replies)


def browser_args(size: tuple[int, int], profile: Path) -> list[str]:
    """Headless Chromium flags: DevTools over the pipe, a throwaway profile, the window ``size``."""
    return [
        "--headless",
        "--remote-debugging-pipe",
        "--disable-gpu",
        "--no-sandbox",
        "--hide-scrollbars",
        "--disable-dev-shm-usage",
        "--no-first-run",
        "--no-default-browser-check",
        f"--user-data-dir={profile}",
        f"--window-size={size[0]},{size[1]}",
        "about:blank",
    ]


def wait_until_settled(
    tools: DevTools, want: str | None, deadline: float, page: Path, polls: int = 4, interval_s: float = 0.15
) -> None:
    """Poll until the page is ready and its signature is the same ``polls`` times in a row."""
    last, same, reason = None, 0, "it never answered"
    while time.monotonic() < deadline:
        state = tools.evaluate(SETTLED_JS % json.dumps(want))
        if "wait" in state:
            last, same, reason = None, 0, state["wait"]
        elif state["ready"] == last:
            same += 1
            if same >= polls:
                return
        else:
            last, same, reason = state["ready"], 1, "it was still changing"
        time.sleep(interval_s)
    raise TimeoutError(f"{page}: the page did not settle in time ({reason})")


def screenshot(
    html: str | os.PathLike,
    png: str | os.PathLike,
    size: tuple[int, int] = (1400, 1000),
    show: str | None = None,
    timeout_s: float = 120.0,
) -> Path:
    """Render ``html`` in headless Chromium and write a ``size`` PNG to ``png``; returns its path.
    ``show``: a result's path (e.g. ``results/figures/qualitative_courtyard.png``) to open first.
    The PNG is written under a temporary name and renamed, so a failed run leaves no partial file."""
    html, png = Path(html), Path(png).resolve()
    if not html.is_file():
        raise FileNotFoundError(f"{html}: no such report (build it with `snakemake --report {html}`)")
    browser = find_browser()
    png.parent.mkdir(parents=True, exist_ok=True)
    deadline = time.monotonic() + timeout_s
    with tempfile.TemporaryDirectory(prefix="report-screenshot-") as tmp:  # no browser state left behind
        log_path = Path(tmp) / "browser.log"
        with open(log_path, "wb") as log:
            tools = DevTools(browser, browser_args(size, Path(tmp) / "profile"), log)
            try:
                data = capture(tools, html, size, show, deadline)
            except (RuntimeError, TimeoutError) as exc:
                raise RuntimeError(f"{exc}\n{browser} log:\n{log_path.read_text(errors='replace')[-2000:]}") from exc
            finally:
                tools.close()
    part = png.with_name(png.name + ".part")
    part.write_bytes(data)
    part.replace(png)
    return png


def capture(tools: DevTools, html: Path, size: tuple[int, int], show: str | None, deadline: float) -> bytes:
    """Open ``html`` in a new page, wait until it has settled (with ``show`` opened), take the PNG."""
    target = tools.send("Target.createTarget", {"url": "about:blank"})["targetId"]
    tools.session = tools.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
    tools.send(
        "Emulation.setDeviceMetricsOverride",
        {"width": size[0], "height": size[1], "deviceScaleFactor": 1, "mobile": False},
    )
    tools.send("Page.navigate", {"url": html.resolve().as_uri()})
    wait_until_settled(tools, None, deadline, html)
    if show:
        if not tools.evaluate(SHOW_JS % json.dumps(show)):
            raise ValueError(
                f"{show!r} is not a result of {html} (give a path as the report lists it, "
                "e.g. results/figures/qualitative_courtyard.png)"
            )
        wait_until_settled(tools, show, deadline, html)
    return base64.b64decode(tools.send("Page.captureScreenshot", {"format": "png"})["data"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("html", help="the report, e.g. results/report.html")
    ap.add_argument("png", nargs="?", help="output PNG (default: next to the report, .png)")
    ap.add_argument("--size", default="1400x1000", help="window WIDTHxHEIGHT in pixels (default 1400x1000)")
    ap.add_argument("--show", metavar="RESULT", help="open this result first (its path as the report lists it)")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the page to settle (default 120)")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    png = args.png or str(Path(args.html).with_suffix(".png"))
    try:
        out = screenshot(args.html, png, (width, height), args.show, args.timeout)
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
