"""A scripted operator in headless Chromium: drives a console page, or stages the picture.

Two uses, both with Debian's Chromium (``/usr/bin/chromium``) driven by playwright (the
``test`` extra; never a browser download), software WebGL, on 127.0.0.1 only:

* ``--url URL --seconds S``: drives a console that is already running (``telesmooth teleop``
  or ``telesmooth operator``): opens the page and its controls, engages the clutch (Space),
  then holds D, W, A, S for ``--leg`` seconds each in turn (the keyboard's auto-repeat, a
  press every 30 ms) until ``S`` seconds have passed, and closes the page (the console
  releases the clutch). A soak test of the seat, and how the figures of docs/operator.md
  were measured.
* ``--screenshot [--out docs/operator_console.png]``: stages the operator console's picture.
  Runs ``telesmooth teleop`` on the planar arm with a 0.5 s delay each way and a telemetry
  outage from 17 s on; Space, D for 1 s, then W until 28 s of simulated time, which takes
  the hand up into the fixture; 6 s later the picture shows all three robots apart: the
  planning position in collision (solid, red), the predicted robot where the collision stop
  holds it (green) and the telemetry's last word before the outage (wire frame), with the
  status panel saying so.

Usage: ``python -m telesmooth.scripts.browser_operator --url http://127.0.0.1:7000/
[--seconds 55] [--leg 3]`` or ``python -m telesmooth.scripts.browser_operator --screenshot
[--out FILE] [--port 7796]``; ``--chromium PATH`` (default /usr/bin/chromium).
"""

from __future__ import annotations

import argparse
import base64
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "operator_console.png"
"""The committed picture, in the repository's ``docs/`` folder."""

SCREENSHOT_SCENARIO = ("{link: {faults: {delay_s: 0.5}, downlink: {delay_s: 0.5, "
                       "outages: [[17.0, .inf]]}}}")
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]
KEY_REPEAT_S = 0.03
"""A held key: one press every 30 ms (the keyboard's auto-repeat)."""


class ConsolePage:
    """A console page open in headless Chromium (a context manager)."""

    def __init__(self, url: str, *, chromium: str = "/usr/bin/chromium",
                 viewport=(1024, 640)):
        self.url, self.chromium, self.viewport = url, chromium, viewport

    def __enter__(self) -> ConsolePage:
        from playwright.sync_api import sync_playwright

        if not Path(self.chromium).exists():
            raise SystemExit(f"browser_operator: {self.chromium} is missing (apt-get install "
                             "chromium, or give --chromium)")
        self._playwright = sync_playwright().start()
        self._browser = self._playwright.chromium.launch(executable_path=self.chromium,
                                                         args=CHROMIUM_ARGS)
        width, height = self.viewport
        self.page = self._browser.new_page(viewport={"width": width, "height": height})
        self.page.goto(self.url)
        self.page.wait_for_function(
            "() => window.viewer && viewer.scene_tree && viewer.scene_tree"
            ".find(['operator','planning','link1']).object", timeout=60_000)
        self.page.evaluate("() => viewer.gui.open()")     # the controls, with the status
        return self

    def __exit__(self, *exc) -> None:
        self._browser.close()
        self._playwright.stop()

    def press(self, key: str) -> None:
        self.page.keyboard.press(key)

    def hold(self, key: str, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.page.keyboard.press(key)
            time.sleep(KEY_REPEAT_S)

    def status_rows(self) -> list[str]:
        """The control panel's rows after the Stop button: the sliders and the status."""
        rows = self.page.evaluate("() => Array.from(document.querySelectorAll("
                                  "'.property-name')).map(e => e.textContent)")
        return rows[rows.index("Stop (Esc)") + 1:] if "Stop (Esc)" in rows else rows

    def screenshot(self) -> bytes:
        # The DevTools capture: playwright's own screenshot waits for a quiet page, which
        # software WebGL under a live simulation rarely is (it took 20 s).
        shot = self.page.context.new_cdp_session(self.page).send(
            "Page.captureScreenshot", {"format": "png"})
        return base64.b64decode(shot["data"])


def drive(url: str, seconds: float, *, leg_s: float = 3.0,
          chromium: str = "/usr/bin/chromium") -> list[str]:
    """Engages the clutch and holds D, W, A, S in turn for ``seconds``; returns the status
    rows at the end."""
    with ConsolePage(url, chromium=chromium) as page:
        page.press("Space")
        end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < end:
            page.hold(("KeyD", "KeyW", "KeyA", "KeyS")[k % 4],
                      min(leg_s, end - time.monotonic()))
            k += 1
        return page.status_rows()


def _simulated_time(log: Path) -> float:
    found = re.findall(r"t =\s+([0-9.]+) s", log.read_text())
    return float(found[-1]) if found else 0.0


def _wait_for(log: Path, text: str, process, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while text not in log.read_text():
        if process.poll() is not None or time.monotonic() > end:
            raise SystemExit(f"browser_operator: teleop did not print {text!r}:\n"
                             f"{log.read_text()[-2000:]}")
        time.sleep(0.2)


def stage_screenshot(out: Path, *, port: int, chromium: str) -> list[str]:
    """Stages the session of the module docstring and writes the picture to ``out``;
    returns the status rows."""
    with tempfile.TemporaryDirectory() as folder:
        log = Path(folder) / "teleop.log"
        with open(log, "w") as sink:
            process = subprocess.Popen(
                [sys.executable, "-m", "telesmooth.scripts.cli", "teleop", "--duration", "60",
                 "--port", str(port), "--scenario-text", SCREENSHOT_SCENARIO],
                stdout=sink, stderr=subprocess.STDOUT)
        try:
            _wait_for(log, "operator console: ", process, 120.0)
            with ConsolePage(f"http://127.0.0.1:{port}/", chromium=chromium,
                             viewport=(1280, 720)) as page:
                time.sleep(0.5)
                page.press("Space")
                page.hold("KeyD", 1.0)
                while _simulated_time(log) < 28.0:
                    page.hold("KeyW", 0.1)
                time.sleep(6.0)          # the robot stops, the panel catches up
                picture = page.screenshot()
                rows = page.status_rows()
        finally:
            process.terminate()
            process.wait(timeout=60)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(picture)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--url", help="drive the console page at this address")
    what.add_argument("--screenshot", action="store_true",
                      help="stage the operator console's picture (runs teleop itself)")
    parser.add_argument("--seconds", type=float, default=55.0,
                        help="how long to drive (default 55)")
    parser.add_argument("--leg", type=float, default=3.0,
                        help="seconds each key is held (default 3)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help="the picture (default docs/operator_console.png)")
    parser.add_argument("--port", type=int, default=7796,
                        help="the staged teleop's page port (default 7796)")
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    args = parser.parse_args(argv)
    if args.url is not None:
        if not args.url.startswith(("http://127.0.0.1:", "http://localhost:")):
            parser.error(f"--url = {args.url!r}: only a page on this machine (127.0.0.1)")
        rows = drive(args.url, args.seconds, leg_s=args.leg, chromium=args.chromium)
    else:
        rows = stage_screenshot(args.out, port=args.port, chromium=args.chromium)
        rows.append(f"wrote {args.out}")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
