"""Headless Chromium for the viewer's browser tests and the docs screenshot.

Debian's ``chromium`` and ``chromium-driver`` packages, driven by selenium
(``pip install selenium``, in the test extra), with the paths given
explicitly so that selenium never looks for (or downloads) a browser of its
own. ``.ci/run`` installs both packages.
"""
from __future__ import annotations

import base64
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

#: where Debian's packages put the browser and its driver
CHROMIUM = ("/usr/bin/chromium", "/usr/lib/chromium/chromium")
CHROMEDRIVER = ("/usr/bin/chromedriver", "/usr/lib/chromium/chromedriver")
#: flags for a sandbox-free, network-free headless run
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-dev-shm-usage", "--no-first-run", "--disable-extensions", "--hide-scrollbars",
         "--force-device-scale-factor=1")


def _first(paths) -> str | None:
    for p in paths:
        if Path(p).exists():
            return p
    return shutil.which(Path(paths[0]).name)


def missing() -> str | None:
    """Why a browser cannot be started here (None when it can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "the Python package selenium is not installed (pip install selenium)"
    if _first(CHROMIUM) is None:
        return "Chromium is not installed (apt-get install chromium)"
    if _first(CHROMEDRIVER) is None:
        return "chromedriver is not installed (apt-get install chromium-driver)"
    return None


def chromium(width: int = 1280, height: int = 800):
    """A selenium WebDriver of headless Chromium with a fresh profile folder
    (removed by ``driver.quit_and_clean()``)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="skelslice-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = _first(CHROMIUM)
    for flag in (*FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service(_first(CHROMEDRIVER)), options=opts)

    def quit_and_clean():
        try:
            driver.quit()
        finally:
            shutil.rmtree(profile, ignore_errors=True)

    driver.quit_and_clean = quit_and_clean
    return driver


def wait_for(driver, script: str, timeout: float = 30.0):
    """Poll a JavaScript expression until it is truthy; returns its value."""
    t0 = time.monotonic()
    while True:
        v = driver.execute_script("return " + script)
        if v:
            return v
        if time.monotonic() - t0 > timeout:
            raise TimeoutError(f"{script!r} still false after {timeout:g} s")
        time.sleep(0.05)


def open_viewer(driver, html: Path, timeout: float = 60.0) -> None:
    """Load a preview page and wait until its first layer is drawn."""
    driver.get(Path(html).resolve().as_uri())
    wait_for(driver, "window.skelslice && window.skelslice.ready", timeout)


def show_layer(driver, k: int, timeout: float = 30.0) -> None:
    """Go to layer k and wait until it is drawn."""
    driver.execute_script("window.skelslice.goto(arguments[0])", k)
    wait_for(driver, f"window.skelslice.state.shown === {int(k)}", timeout)


def layer_pixels(driver):
    """The layer canvas as a (height, width, 4) uint8 array (``getImageData``)."""
    w, h, data = driver.execute_script(
        "const c = window.skelslice.layerCanvas, d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        "let s = ''; for (let i = 0; i < d.length; i += 8192)"
        "  s += String.fromCharCode.apply(null, d.subarray(i, i + 8192));"
        "return [c.width, c.height, btoa(s)];")
    return np.frombuffer(base64.b64decode(data), np.uint8).reshape(h, w, 4)
