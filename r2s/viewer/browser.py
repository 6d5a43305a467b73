"""Screenshots of a web page in headless Chromium (for ``r2s view --screenshot`` and tests).

Chromium is driven over its DevTools protocol: open the page, then capture the window
every ``poll_s`` until two captures in a row are the same and differ from a blank page
(the viewer's first frame takes seconds with software WebGL), or ``timeout_s`` passes.
WebGL runs on SwiftShader (no GPU needed).
"""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any, Optional

import numpy as np
from PIL import Image

from r2s.errors import R2SError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-first-run",
    "--disable-dev-shm-usage", "--hide-scrollbars",
)


def find_chromium() -> Optional[str]:
    """Path of a Chromium (or Chrome) executable on PATH, or None."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def distinct_colours(image: np.ndarray) -> int:
    """Number of distinct RGB values in an (H, W, 3) uint8 image."""
    flat = np.ascontiguousarray(image[..., :3]).reshape(-1, 3).astype(np.uint32)
    return int(len(np.unique((flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2])))


class _DevTools:
    """A minimal DevTools-protocol client over one page's websocket."""

    def __init__(self, ws_url: str) -> None:
        from websockets.sync.client import connect

        self._ws = connect(ws_url, max_size=None, open_timeout=30)
        self._next = 0

    def call(self, method: str, **params: Any) -> dict:
        self._next += 1
        self._ws.send(json.dumps({"id": self._next, "method": method, "params": params}))
        while True:
            msg = json.loads(self._ws.recv(timeout=60))
            if msg.get("id") == self._next:
                if "error" in msg:
                    raise R2SError(f"chromium: {method} failed: {msg['error'].get('message')}")
                return msg.get("result", {})

    def close(self) -> None:
        self._ws.close()


def _devtools_port(profile: Path, proc: subprocess.Popen, timeout_s: float) -> int:
    marker = profile / "DevToolsActivePort"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise R2SError(f"chromium exited at start (status {proc.returncode})")
        if marker.is_file():
            lines = marker.read_text().split()
            if lines:
                return int(lines[0])
        time.sleep(0.1)
    raise R2SError(f"chromium did not open its DevTools port within {timeout_s:.0f} s")


def screenshot(url: str, out_png: Path, width_px: int = 1024, height_px: int = 768,
               timeout_s: float = 120.0, poll_s: float = 2.0, min_colours: int = 64,
               chromium: Optional[str] = None) -> np.ndarray:
    """Open ``url`` in headless Chromium, wait until the page has drawn, save a PNG.

    Returns the (H, W, 3) uint8 picture. Raises :class:`R2SError` when no Chromium is found
    or it fails to start; a page that never settles is still captured at ``timeout_s``.
    """
    exe = chromium or find_chromium()
    if exe is None:
        raise R2SError("no Chromium found (install Debian's 'chromium' package)")
    # Chromium's helper processes can outlive the main one by a moment and still write into
    # the profile: the browser gets its own process group, killed whole, and a profile
    # file left behind does not fail the capture
    with tempfile.TemporaryDirectory(prefix="r2s-chromium-", ignore_cleanup_errors=True) as profile:
        proc = subprocess.Popen(
            [exe, *CHROMIUM_FLAGS, f"--window-size={width_px},{height_px}",
             "--remote-debugging-port=0", f"--user-data-dir={profile}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            port = _devtools_port(Path(profile), proc, 60.0)
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=30) as resp:
                page = next(t for t in json.load(resp) if t.get("type") == "page")
            tools = _DevTools(page["webSocketDebuggerUrl"])
            try:
                tools.call("Emulation.setDeviceMetricsOverride", width=width_px,
                           height=height_px, deviceScaleFactor=1, mobile=False)
                tools.call("Page.navigate", url=url)
                image = _capture_when_settled(tools, timeout_s, poll_s, min_colours)
            finally:
                tools.close()
        finally:
            _stop_group(proc)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(out_png)
    return image


def _stop_group(proc: subprocess.Popen) -> None:
    """Stop the process group ``proc`` leads: SIGTERM, up to 10 s for the browser to exit,
    then SIGKILL to whatever of the group is left (helpers included)."""
    for sig, wait_s in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            pass


def _capture_when_settled(tools: _DevTools, timeout_s: float, poll_s: float,
                          min_colours: int) -> np.ndarray:
    deadline = time.monotonic() + timeout_s
    previous: Optional[np.ndarray] = None
    while True:
        time.sleep(poll_s)
        data = base64.b64decode(tools.call("Page.captureScreenshot", format="png")["data"])
        image = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
        drawn = distinct_colours(image) >= min_colours
        if drawn and previous is not None and np.array_equal(previous, image):
            return image
        if time.monotonic() > deadline:
            return image
        previous = image if drawn else None
