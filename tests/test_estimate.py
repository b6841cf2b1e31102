"""Print time and resin volume (:mod:`formats.estimate`) and the formats that store them.

* Known answers: a slab with fractional edge and top coverage (its exact
  volume by hand) written by every printer format, each file read back here;
  the print time of each profile worked out by hand from its exposures, lift
  moves and waits (Prusa: faded exposures and slow tilts).
* End to end: ``--aa-z`` layers hold the exact coverage, so the volume in the
  file equals the integral of the tracer's inside spans, to half a grey
  level per partly covered voxel.
* The CLI prints the estimate in the slice summary and in ``--dry-run``.
"""
from __future__ import annotations

import configparser
import json
import zipfile

import numpy as np
import pytest

from format_readers import read_ctb, read_goo_lazy, read_photon
from formats import WRITERS
from formats.estimate import LayerMeter, PrintEstimate, duration, exposure_times, print_estimate
from formats.printer_profiles import PRINTERS, PrintSettings
from helpers import run
from slicer import Skeleton, load_scene
from slicer.tracer.grid import SliceGrid

H = 0.1
#: full columns and rows of the slab, its layers (the last one 60 % covered)
COLS, ROWS, LAYERS = 2000, 1000, 4
EDGE, TOP = 51, 153                                   # 51 / 255 = 0.2 and 153 / 255 = 0.6 exactly


def slab_layers(printer):
    """Plate images of a slab: COLS x ROWS full pixels, one more column of 20 %
    coverage on each side (not in the top layer), the top layer 60 % covered."""
    rows, cols = printer.plate_shape
    r0, c0 = (rows - ROWS) // 2, (cols - COLS) // 2
    out = []
    for k in range(LAYERS):
        img = np.zeros((rows, cols), np.uint8)
        if k < LAYERS - 1:
            img[r0:r0 + ROWS, c0:c0 + COLS] = 255
            img[r0:r0 + ROWS, [c0 - 1, c0 + COLS]] = EDGE
        else:
            img[r0:r0 + ROWS, c0:c0 + COLS] = TOP
        out.append(img)
    return out


def slab_volume_ml(printer) -> float:
    """The slab's exact volume: (COLS + 2 x 0.2) x ROWS x (LAYERS - 1) + COLS x ROWS x 0.6 voxels."""
    px, py = printer.pixel_size
    voxels = (COLS + 0.4) * ROWS * (LAYERS - 1) + COLS * ROWS * 0.6
    return voxels * px * py * H / 1000.0


def write(fmt, printer, path, settings):
    p = printer
    grid = SliceGrid((0.5 * p.pixel_size[0], p.display[1] - 0.5 * p.pixel_size[1], 0.5 * H), p.pixel_size, H,
                     p.pixels[0], p.pixels[1], LAYERS)
    with WRITERS[fmt](path, grid, {"generator": "skelslice test"}, settings=settings) as w:
        for k, img in enumerate(slab_layers(p)):
            w.write_layer(k, img)
    return w.estimate


def stored(fmt, path) -> tuple[float, float]:
    """(print time s, volume ml) as the file stores them, read back with the format's own reader."""
    if fmt == "goo":
        h, _ = read_goo_lazy(path)
        return h["time"], h["volume"] / 1000.0               # mm³ in GOO
    if fmt == "ctb":
        f = read_ctb(path)
        return f["print_time"], f["params"]["volume"]
    if fmt in ("pwmx", "pm5s"):
        f = read_photon(path, LAYERS)
        return f["print_time"], f["volume"]
    if fmt == "sl1s":
        with zipfile.ZipFile(path) as z:
            cfg = configparser.ConfigParser()
            cfg.read_string("[c]\n" + z.read("config.ini").decode())
            return float(cfg["c"]["printTime"]), float(cfg["c"]["usedMaterial"])
    with zipfile.ZipFile(path) as z:                          # nanodlp
        plate = json.loads(z.read("plate.json"))
        return plate["PrintEst"], plate["TotalSolidArea"]


def by_hand(printer, exposure, bottom, n_bottom, fade=False, slow=0) -> float:
    """The profile's print time for LAYERS layers, written out."""
    if fade:
        exp = sum(bottom - (bottom - exposure) * k / n_bottom for k in range(n_bottom))
    else:
        exp = n_bottom * bottom
    exp += (LAYERS - n_bottom) * exposure
    d, v, rd, rv = printer.lift
    return exp + LAYERS * (60 * (d / v + rd / rv) + printer.layer_overhead) + slow * printer.slow_overhead


@pytest.mark.parametrize("fmt, printer, fade, slow", [
    ("goo", "elegoo-saturn-3-ultra", False, 0), ("ctb", "elegoo-saturn", False, 0),
    ("pwmx", "anycubic-photon-mono-x", False, 0), ("pm5s", "anycubic-photon-mono-m5s", False, 0),
    ("sl1s", "prusa-sl1s", True, 0), ("nanodlp", "phrozen-sonic-mini-4k", False, 0)])
def test_slab_volume_and_profile_time_in_every_format(tmp_path, fmt, printer, fade, slow):
    p = PRINTERS[printer]
    s = PrintSettings(p, H, exposure=2.5, bottom_exposure=30.0, bottom_layers=2, aa=2)
    est = write(fmt, p, tmp_path / f"slab.{fmt}", s)
    seconds, ml = stored(fmt, tmp_path / f"slab.{fmt}")
    exact = slab_volume_ml(p)
    assert est.volume_ml == pytest.approx(exact, rel=1e-12)
    assert ml == pytest.approx(exact, rel=1e-6, abs=1e-6)            # f32 fields; SL1 prints 6 decimals
    want = by_hand(p, 2.5, 30.0, 2, fade, slow)
    assert est.seconds == pytest.approx(want, rel=1e-12)
    assert seconds == (pytest.approx(want, abs=1e-6) if fmt == "sl1s" else round(want))


def test_profile_times_worked_out():
    """Three profiles, every term by hand (4 layers, 2 of them bottom layers)."""
    def est(name, **kw):
        return print_estimate(PrintSettings(PRINTERS[name], H, exposure=2.5, bottom_exposure=30.0, bottom_layers=2),
                              LAYERS, **kw)

    e = est("elegoo-saturn")                      # lift 7 mm at 70 mm/min, retract at 210 mm/min: 6 + 2 s
    assert (e.exposure, e.motion, e.waits) == pytest.approx((65.0, 4 * 8.0, 0.0))
    e = est("anycubic-photon-mono-x")             # 8 mm up and down at 120 mm/min: 8 s; wait 2.5 s
    assert (e.exposure, e.motion, e.waits) == pytest.approx((65.0, 4 * 8.0, 4 * 2.5))
    e = est("prusa-sl1s", fade=True, slow_layers=3)   # tilt: 8 s a layer, +3 s per slow layer; faded bottom
    assert (e.exposure, e.motion, e.waits) == pytest.approx((30 + 16.25 + 2 * 2.5, 0.0, 4 * 8 + 3 * 3))
    assert e.seconds == pytest.approx(51.25 + 41)


def test_sl1_slow_tilts_count_in_the_time(tmp_path):
    """A layer over 50 % of the display tilts slowly: numSlow and 3 s more each."""
    p = PRINTERS["prusa-sl1s"]
    big = np.full(p.plate_shape, 255, np.uint8)
    big[:, : p.plate_shape[1] // 3] = 0                                     # 2/3 of the display: slow
    grid = SliceGrid((0.025, 80.975, 0.05), p.pixel_size, H, p.pixels[0], p.pixels[1], 3)
    s = PrintSettings(p, H, exposure=2.0, bottom_exposure=20.0, bottom_layers=2)
    with WRITERS["sl1s"](tmp_path / "big.sl1s", grid, settings=s) as w:
        for k, img in enumerate([big, np.zeros_like(big), big]):
            w.write_layer(k, img)
    with zipfile.ZipFile(tmp_path / "big.sl1s") as z:
        cfg = dict(line.split(" = ", 1) for line in z.read("config.ini").decode().splitlines())
    assert (cfg["numSlow"], cfg["numFast"]) == ("2", "1")
    assert float(cfg["printTime"]) == pytest.approx(20 + 11 + 2 + 3 * 8 + 2 * 3)


def test_exposures_fade_and_bottom_layers():
    s = PrintSettings(None, H, exposure=2.0, bottom_exposure=12.0, bottom_layers=5)
    assert exposure_times(s, 7).tolist() == [12.0] * 5 + [2.0] * 2
    assert exposure_times(s, 7, fade=True) == pytest.approx([12, 10, 8, 6, 4, 2, 2])
    assert exposure_times(s, 3).tolist() == [12.0] * 3
    e = print_estimate(s, 7)
    assert (e.seconds, e.motion, e.waits, e.volume_ml) == (64.0, 0.0, 0.0, None)   # no printer: exposures only


def test_meter_counts_grey_and_slow_layers():
    m = LayerMeter()
    img = np.zeros((10, 10), np.uint8)
    img[2:4, 1:9] = 200
    m.add(img)
    m.add(np.zeros_like(img))
    full = np.zeros((10, 10), np.uint8)
    full.ravel()[:51] = 128                            # 51 % solid: slow
    m.add(full)
    half = np.full((10, 10), 255, np.uint8)
    half[:5] = 127                                     # exactly 50 %: not slow
    m.add(half)
    assert (m.layers, m.slow_layers) == (4, 1)
    assert m.grey_sum == 16 * 200 + 51 * 128 + 50 * 255 + 50 * 127


def test_duration_text_and_round_trip():
    assert duration(11100.2) == "3 h 05 min" and duration(247) == "4 min 07 s" and duration(12.5) == "12.5 s"
    e = PrintEstimate(12, 30.0, 20.0, 5.5, 1.25, 2)
    assert PrintEstimate.from_dict(e.to_dict()) == e
    assert e.describe() == "print time 55.5 s (exposure 30 s, lift 20 s, waits 5.5 s) for 12 layers; resin 1.25 ml"


# ---------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A leaning strut and a node: sloped surfaces cut every layer at a fraction."""
    p = tmp_path_factory.mktemp("estimate") / "y.json"
    Skeleton([[0, 0, 0], [0.4, 0.2, 1.5], [1.4, 0.2, 2.1], [-0.8, 0.6, 2.3]], [[0, 1], [1, 2], [1, 3]],
             [[0.5, 0.35], [0.35, 0.3], [0.35, 0.25]]).save(p)
    return p


def test_aa_z_volume_is_the_span_integral(scene, tmp_path):
    """--aa-z greys are the exact z coverage: the NanoDLP volume equals the
    tracer's inside spans integrated over the grid, to half a grey level per
    partly covered voxel."""
    from slicer.tracer.slicing import slice_skeleton

    out = tmp_path / "y.nanodlp"
    assert run("slice", scene, "-o", out, "--pixel-size", "0.05", "--layer-height", "0.2", "--aa-z",
               "-q").exit_code == 0
    res = slice_skeleton(load_scene(scene), 0.05, None, 0.2, spans=True)
    exact_mm3 = float(np.sum(res.span_t1 - res.span_t0)) * 0.05 * 0.05
    partial = sum(int(np.count_nonzero((c > 0) & (c < 1))) for c in res.iter_coverage())
    with zipfile.ZipFile(out) as z:
        ml = json.loads(z.read("plate.json"))["TotalSolidArea"]
    assert partial > 1000                                        # the test has partial voxels to get wrong
    assert abs(ml * 1000 - exact_mm3) <= partial * 0.5 / 255 * 0.05 * 0.05 * 0.2
    binary = sum(int(np.count_nonzero(i)) for i in res.iter_layers()) * 0.05 * 0.05 * 0.2
    assert abs(binary - exact_mm3) > 10 * abs(ml * 1000 - exact_mm3)     # centre sampling is much coarser


def test_summary_and_dry_run_print_the_estimate(scene, tmp_path):
    out = tmp_path / "y.ctb"
    r = run("slice", scene, "-o", out, "--printer", "elegoo-saturn", "--layer-height", "0.1", "--bottom-layers", "3")
    assert r.exit_code == 0, r.output
    f = read_ctb(out)
    n = f["layers"]
    seconds = 3 * 35 + (n - 3) * 2.5 + n * 60 * (7 / 70 + 7 / 210)
    line = r.output.splitlines()[1]
    assert line.startswith(f"print time {duration(seconds)} (exposure {duration(3 * 35 + (n - 3) * 2.5)}, "
                           f"lift {duration(n * 8.0)}) for {n} layers; resin ")
    assert line.endswith(f"resin {f['params']['volume']:.4g} ml")
    r = run("slice", scene, "-o", tmp_path / "d.ctb", "--printer", "elegoo-saturn", "--layer-height", "0.1",
            "--dry-run")
    assert r.exit_code == 0 and not (tmp_path / "d.ctb").exists()
    est = [ln for ln in r.output.splitlines() if ln.startswith("estimate:  print time ")]
    assert len(est) == 1 and "resin once sliced" in est[0]
    m = int(est[0].split(" for ")[1].split()[0])
    assert n <= m                                               # the traced grid's layers bound the model's
    assert duration(5 * 35 + (m - 5) * 2.5 + m * 8.0) in est[0]
    r = run("slice", scene, "-o", tmp_path / "p", "--pixel-size", "0.1", "-q")
    assert r.exit_code == 0 and r.output == ""                   # -q: nothing, estimate included
