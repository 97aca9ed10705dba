"""Stages and takes the operator console's picture (``docs/operator_console.png`` by default).

Runs ``telesmooth teleop`` on the planar arm with a 0.5 s delay each way and a telemetry
outage from 17 s on, drives it from headless Chromium (Debian's ``/usr/bin/chromium`` driven
by playwright, on 127.0.0.1 only): Space (the clutch), D for 1 s, then W until 28 s of
simulated time, which takes the hand up into the fixture. The picture then shows all three
robots apart: the planning position in collision (solid, red), the predicted robot where the
collision stop holds it (green), and the telemetry's last word before the outage (wire
frame), with the status panel saying so.

Usage: ``python -m telesmooth.scripts.operator_screenshot [--out docs/operator_console.png]
[--port 7796] [--chromium /usr/bin/chromium]`` (needs the ``test`` extra's playwright).
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

SCENARIO = "{link: {faults: {delay_s: 0.5}, downlink: {delay_s: 0.5, outages: [[17.0, .inf]]}}}"
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


def _simulated_time(log: Path) -> float:
    found = re.findall(r"t =\s+([0-9.]+) s", log.read_text())
    return float(found[-1]) if found else 0.0


def _wait_for(log: Path, text: str, process, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while text not in log.read_text():
        if process.poll() is not None or time.monotonic() > end:
            raise SystemExit(f"operator_screenshot: teleop did not print {text!r}:\n"
                             f"{log.read_text()[-2000:]}")
        time.sleep(0.2)


def take(out: Path, *, port: int, chromium: str) -> list[str]:
    """Stages the session and writes the picture to ``out``; returns the status rows."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as folder:
        log = Path(folder) / "teleop.log"
        with open(log, "w") as sink:
            process = subprocess.Popen(
                [sys.executable, "-m", "telesmooth.scripts.cli", "teleop", "--duration", "60",
                 "--port", str(port), "--scenario-text", SCENARIO],
                stdout=sink, stderr=subprocess.STDOUT)
        try:
            _wait_for(log, "operator console: ", process, 120.0)
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=chromium,
                                                     args=CHROMIUM_ARGS)
                try:
                    page = browser.new_page(viewport={"width": 1280, "height": 720})
                    page.goto(f"http://127.0.0.1:{port}/")
                    page.wait_for_function(
                        "() => window.viewer && viewer.scene_tree && viewer.scene_tree"
                        ".find(['operator','planning','link1']).object", timeout=60_000)
                    page.evaluate("() => viewer.gui.open()")
                    time.sleep(0.5)
                    page.keyboard.press("Space")
                    end = time.monotonic() + 1.0
                    while time.monotonic() < end:
                        page.keyboard.press("KeyD")
                        time.sleep(0.03)
                    while _simulated_time(log) < 28.0:
                        page.keyboard.press("KeyW")
                        time.sleep(0.03)
                    time.sleep(6.0)          # the robot stops, the panel catches up
                    # The DevTools capture: playwright's own screenshot waits for a quiet
                    # page, which software WebGL under a live simulation rarely is.
                    shot = page.context.new_cdp_session(page).send(
                        "Page.captureScreenshot", {"format": "png"})
                    rows = page.evaluate("() => Array.from(document.querySelectorAll("
                                         "'.property-name')).map(e => e.textContent)")
                finally:
                    browser.close()
        finally:
            process.terminate()
            process.wait(timeout=60)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(base64.b64decode(shot["data"]))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--port", type=int, default=7796)
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    args = parser.parse_args(argv)
    rows = take(args.out, port=args.port, chromium=args.chromium)
    print("\n".join(rows[rows.index("Stop (Esc)") + 1:] if "Stop (Esc)" in rows else rows))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
