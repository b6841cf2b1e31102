"""The viewer in a real browser: headless Chromium (Debian packages) driven by selenium.

The page is loaded from disk, moved to a layer (through its API and with
the keyboard), and the pixels of its layer canvas (``getImageData``) are
compared with the PNG layer's, for a binary stack (1-bit PNGs in the page)
and an anti-aliased one (8-bit grey). A missing browser is a failure, not
a skip, unless ``SKELSLICE_BROWSER_OPTIONAL=1`` says the browser is optional
(``.ci/run`` does not set it and installs Chromium).
"""
from __future__ import annotations

import io
import json
import os

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from slicer import Skeleton
from slicer.cli.app import main

import browser

pytestmark = pytest.mark.slow


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def driver():
    why = browser.missing()
    if why is not None:
        if os.environ.get("SKELSLICE_BROWSER_OPTIONAL") == "1":
            pytest.skip(f"browser test skipped (SKELSLICE_BROWSER_OPTIONAL=1): {why}")
        pytest.fail(f"the viewer's browser test needs headless Chromium: {why}")
    d = browser.chromium()
    yield d
    d.quit_and_clean()


@pytest.fixture(scope="module")
def stacks(tmp_path_factory):
    """A post with a hanging branch and a floating strut, as a binary PNG
    stack and an anti-aliased one, and their previews."""
    d = tmp_path_factory.mktemp("browser")
    scene = d / "hang.json"
    r = 0.3
    Skeleton([[0, 0, 0], [0, 0, 3], [2, 0, 3], [2, 0, 1.5], [4, 0, 2], [5, 0, 2]],
             [[0, 1], [1, 2], [2, 3], [4, 5]], [[r, r]] * 4).save(scene)
    out = {}
    for name, args in (("plain", []), ("aa", ["--aa", "2"])):
        stack = d / name
        assert run("slice", scene, "-o", stack, "--pixel-size", "0.05", "-q", *args).exit_code == 0
        html = d / f"{name}.html"
        res = run("preview", stack, "-o", html, "--scene", scene, "-q")
        assert res.exit_code == 0, res.output
        out[name] = (stack, html)
    return out


def png_layer(stack, k):
    files = json.loads((stack / "slices.json").read_text())["files"]
    return np.asarray(Image.open(stack / files[k]))


def assert_shows(driver, stack, k):
    px = browser.layer_pixels(driver)
    want = png_layer(stack, k)
    assert px.shape[:2] == want.shape
    bad = int(np.sum(px[..., 0] != want))
    assert bad == 0, f"layer {k}: the canvas differs from the PNG in {bad} pixels"
    assert np.array_equal(px[..., 1], want) and np.array_equal(px[..., 2], want) and np.all(px[..., 3] == 255)


@pytest.mark.parametrize("name", ["plain", "aa"])
def test_canvas_shows_the_png_layer(driver, stacks, name):
    stack, html = stacks[name]
    browser.open_viewer(driver, html)
    n = driver.execute_script("return window.skelslice.data.layers.length")
    assert n == json.loads((stack / "slices.json").read_text())["layers"]
    for k in (31, 37, n // 2, n - 2):
        browser.show_layer(driver, k)
        assert_shows(driver, stack, k)
    if name == "aa":
        grey = png_layer(stack, 37)
        assert np.any((grey > 0) & (grey < 255)), "the anti-aliased stack has grey pixels"


def test_keyboard_steps_and_zoom_keep_the_pixels(driver, stacks):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    stack, html = stacks["plain"]
    browser.open_viewer(driver, html)
    browser.show_layer(driver, 20)
    keys = ActionChains(driver)
    for key, want in ((Keys.ARROW_UP, 21), (Keys.ARROW_RIGHT, 22), (Keys.PAGE_UP, 32), (Keys.ARROW_DOWN, 31),
                      (Keys.HOME, 0), (Keys.END, None)):
        keys.send_keys(key).perform()
        n = driver.execute_script("return window.skelslice.data.layers.length")
        want = n - 1 if want is None else want
        browser.wait_for(driver, f"window.skelslice.state.shown === {want}")
        assert driver.execute_script("return +document.getElementById('slider').value") == want
        assert_shows(driver, stack, want)
    browser.show_layer(driver, 31)
    z0 = driver.execute_script("return window.skelslice.state.zoom")
    keys.send_keys("+").perform()
    assert driver.execute_script("return window.skelslice.state.zoom") == pytest.approx(z0 * 1.25)
    assert_shows(driver, stack, 31)                 # zoom scales the canvas on screen, not its pixels
    # the island of layer 31 is listed and marked on its layer
    f = driver.execute_script("return window.skelslice.data.findings")
    assert [(x["kind"], x["layer"]) for x in f] == [("island", 31), ("island", 37)]
    text = driver.find_element("id", "findings").text
    assert "layer 31" in text and "layer 37" in text
    # what is on screen: at one screen pixel per layer pixel, overlays off, the screenshot's
    # pixels over the canvas are the layer's (the outermost ring is under the frame line)
    keys.send_keys("c").send_keys("f").perform()
    assert driver.execute_script("return [window.skelslice.state.contours, window.skelslice.state.findings]") \
        == [False, False]
    driver.execute_script("window.skelslice.setView(1, 20, 30)")
    left, top = driver.execute_script("const r = document.getElementById('view').getBoundingClientRect();"
                                      "return [Math.round(r.left), Math.round(r.top)]")
    shot = np.asarray(Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB"))
    want = png_layer(stack, 31)
    h, w = want.shape
    seen = shot[top + 30:top + 30 + h, left + 20:left + 20 + w]
    assert seen.shape[:2] == want.shape
    assert np.array_equal(seen[1:-1, 1:-1, 0], want[1:-1, 1:-1]) and want[1:-1, 1:-1].any()
    # drag pans
    before = driver.execute_script("return [window.skelslice.state.panX, window.skelslice.state.panY]")
    view = driver.find_element("id", "view")
    ActionChains(driver).move_to_element(view).click_and_hold().move_by_offset(40, 25).release().perform()
    after = driver.execute_script("return [window.skelslice.state.panX, window.skelslice.state.panY]")
    assert after == pytest.approx([before[0] + 40, before[1] + 25], abs=1)
