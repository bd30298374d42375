#!/usr/bin/env python3
"""Hover a point of a Rerun recording's views in the web viewer (headless Chromium, software WebGL) and
screenshot the tooltip: checks that depth and error pixels report metres. Maintainer check, never in the
test suite; set-up as for ../shared/tools/rrd_screenshot.py (Debian chromium + playwright).

    .venv/bin/python tools/rrd_hover.py runs/demo/demo.rrd /tmp/hover --at 1279,328 --at 1279,703
writes /tmp/hover_N.png per --at (viewport 1600 x 1000 pixels; the default layout puts the refined
depth near 1279,328 and the error near 1279,703).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rrd")
    ap.add_argument("prefix")
    ap.add_argument("--at", action="append", default=[], help="x,y in the 1600 x 1000 viewport")
    ap.add_argument("--rerun", default=str(Path(sys.executable).parent / "rerun"))
    ap.add_argument("--wait", type=float, default=60)
    a = ap.parse_args()
    from playwright.sync_api import sync_playwright

    server = subprocess.Popen(
        [a.rerun, "--serve-web", "--bind", "127.0.0.1", "--port", "9877", "--web-viewer-port", "9091", a.rrd],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    url = "http://127.0.0.1:9091/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9877%2Fproxy&renderer=webgl"
    try:
        time.sleep(3)
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=shutil.which("chromium"),
                headless=True,
                args=[
                    "--no-sandbox",
                    "--use-gl=angle",
                    "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader",
                    "--ignore-gpu-blocklist",
                ],
            )
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            page.goto(url)
            time.sleep(a.wait)
            for n, xy in enumerate(a.at):
                x, y = (float(v) for v in xy.split(","))
                page.mouse.move(x, y)
                time.sleep(3)
                page.screenshot(path=f"{a.prefix}_{n}.png")
            browser.close()
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=20)


if __name__ == "__main__":
    main()
