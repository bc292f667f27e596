"""Screenshots of recordings in rerun's web viewer, as a user sees them (issue 30): each .rrd is
served by ``rerun FILE --web-viewer`` on loopback and opened in headless Chromium (Debian's
``chromium`` and ``chromium-driver``, driven by selenium, WebGL), the frame slider left at the end.

    python docs/recordings/screenshot.py OUT.png FILE.rrd [--seconds 25]

A development tool (selenium is not a dependency of priortrack); the PNGs beside it were made so.
"""

import argparse
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def screenshot(rrd: Path, out: Path, seconds: float = 25.0, size=(1600, 1000)) -> None:
    from selenium import webdriver

    web, grpc = _free_port(), _free_port()
    rerun = Path(sys.executable).with_name("rerun")
    server = subprocess.Popen([str(rerun), str(rrd), "--web-viewer", "--web-viewer-port", str(web), "--port", str(grpc)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        time.sleep(4)
        options = webdriver.ChromeOptions()
        for flag in ("--headless=new", "--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader",
                     "--enable-unsafe-swiftshader", f"--window-size={size[0]},{size[1]}"):
            options.add_argument(flag)
        options.binary_location = "/usr/bin/chromium"
        driver = webdriver.Chrome(service=webdriver.ChromeService("/usr/bin/chromedriver"), options=options)
        try:
            url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}/proxy&renderer=webgl"
            driver.get(url)
            time.sleep(seconds)
            driver.save_screenshot(str(out))
        finally:
            driver.quit()
    finally:                                   # the rerun wrapper and the viewer binary it starts
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=10)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="screenshot an .rrd in rerun's web viewer")
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("rrd", type=Path, help="the recording")
    parser.add_argument("--seconds", type=float, default=25.0, help="wait this long for the viewer (default 25)")
    args = parser.parse_args()
    screenshot(args.rrd, args.out, args.seconds)
