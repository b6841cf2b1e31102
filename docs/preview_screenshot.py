"""Make the viewer screenshot of docs/check-and-preview.md with the browser-test tooling.

Writes a preview of a scene (``skelslice preview``), opens it in headless
Chromium (tests/browser.py: Debian's chromium and chromium-driver, selenium)
at a layer, and saves a screenshot::

    python docs/preview_screenshot.py sample_lattices/jellyfish.json docs/images/preview.png \
        --pixel-size 0.05 --layer first-finding
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import browser  # noqa: E402  (tests/browser.py)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("png")
    ap.add_argument("--pixel-size", default="0.05")
    ap.add_argument("--layer", default="first-finding",
                    help="layer to show: a number, 'first-finding' or 'middle'")
    ap.add_argument("--size", type=int, nargs=2, default=(1400, 1000))
    ap.add_argument("--zoom", type=float, default=1.0, help="zoom factor after fitting")
    a = ap.parse_args(argv)
    why = browser.missing()
    if why:
        print(f"cannot take the screenshot: {why}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        html = Path(tmp) / "view.html"
        subprocess.run([sys.executable, "-m", "slicer", "preview", a.scene, "-o", str(html),
                        "--pixel-size", a.pixel_size], check=True)
        d = browser.chromium(*a.size)
        try:
            browser.open_viewer(d, html)
            if a.layer == "first-finding":
                k = d.execute_script("const f = window.skelslice.data.findings;"
                                     "return f.length ? f[0].layer : window.skelslice.data.start")
            elif a.layer == "middle":
                k = d.execute_script("return Math.floor(window.skelslice.data.layers.length / 2)")
            else:
                k = int(a.layer)
            browser.show_layer(d, k)
            if a.zoom != 1.0:
                d.execute_script("const v = document.getElementById('view').getBoundingClientRect();"
                                 "window.skelslice.zoomAt(arguments[0], v.width / 2, v.height / 2);", a.zoom)
                browser.show_layer(d, k)
            Path(a.png).write_bytes(d.get_screenshot_as_png())
        finally:
            d.quit_and_clean()
    print(f"{a.png}: layer {k}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
