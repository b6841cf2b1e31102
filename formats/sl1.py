"""Prusa SL1 / SL1S archives (``.sl1``, ``.sl1s``).

A zip (docs/formats.md §1) with:

* ``config.ini``: what the printer firmware reads (``jobDir``, ``expTime``,
  ``expTimeFirst``, ``layerHeight``, ``numFade``, ``numFast``, ``numSlow``,
  ``printerModel`` ...), ``key = value`` lines, keys sorted.
* ``prusaslicer.ini``: the SLA printer profile PrusaSlicer's importer and
  UVtools need (``display_*``, ``layer_height``, ``initial_layer_height``,
  exposure, ``printer_model`` ...); valid for ``prusa-slicer --load``.
* ``<jobDir>00000.png`` ...: one 8-bit greyscale PNG per layer, ``%05d``
  from 0, in the printer's native layout (:meth:`Printer.to_native`:
  1620 x 2560 for the SL1S, bed X running up the image).
* ``thumbnail/thumbnail<W>x<H>.png``: RGBA top views.

Layers are streamed into the zip; ``config.ini`` (which needs the slow/fast
layer counts and the resin volume) and the thumbnails are added at the end,
then the temporary file is renamed over the target.

``expTime``/``expTimeFirst`` must lie in the firmware's ranges (0.1-60 s and
0.1-120 s) and ``numFade`` (``--bottom-layers``) in 2-200; otherwise the
job is refused before slicing.
"""
from __future__ import annotations

import re

import numpy as np

from slicer.errors import FormatError

from formats.base import build_time, png_bytes
from formats.estimate import AREA_FILL, LayerMeter
from formats.printer_profiles import plate_printer
from formats.rle import occupied
from formats.thumbnails import TopView, png_rgba
from formats.zip_stack import ZipArchiveWriter

#: firmware limits (slafw configs/project.py)
EXPOSURE_RANGE = (0.1, 60.0)
FIRST_EXPOSURE_RANGE = (0.1, 120.0)
FADE_RANGE = (2, 200)


def job_dir(path) -> str:
    """Layer-name prefix from the output file name: letters, digits, ``_-`` only."""
    stem = path.name.split(".")[0] if path.name else "job"
    stem = re.sub(r"[^A-Za-z0-9_-]", "_", stem) or "job"
    return stem


def ini_text(items: dict) -> str:
    """``key = value`` lines sorted by key."""
    return "".join(f"{k} = {items[k]}\n" for k in sorted(items))


def _num(v: float) -> str:
    return f"{v:.6g}"


class Sl1Writer(ZipArchiveWriter):
    """Prusa SL1 archive (``printerModel = SL1``)."""

    name = "sl1"
    printer_model = "SL1"
    default_printer = "prusa-sl1"

    @classmethod
    def check_settings(cls, settings) -> None:
        """Refuse exposures and fade counts the firmware rejects (FormatError)."""
        lo, hi = EXPOSURE_RANGE
        if not lo <= settings.exposure <= hi:
            raise FormatError(f"{cls.name}: exposure {settings.exposure:g} s is outside the printer's {lo:g}-{hi:g} s")
        lo, hi = FIRST_EXPOSURE_RANGE
        if not lo <= settings.bottom_exposure <= hi:
            raise FormatError(f"{cls.name}: bottom exposure {settings.bottom_exposure:g} s is outside the "
                            f"printer's {lo:g}-{hi:g} s")
        lo, hi = FADE_RANGE
        if not lo <= settings.bottom_layers <= hi:
            raise FormatError(f"{cls.name}: bottom (faded) layers {settings.bottom_layers} is outside the "
                            f"printer's {lo}-{hi}")

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        self.printer = plate_printer(self.name, path, grid, settings)
        self.check_settings(settings)
        super().__init__(path, grid, meta, force, settings)
        self.job = job_dir(self.path)
        self._top = TopView(self.printer.plate_shape)
        self._meter = LayerMeter()

    parallel_encode = True

    def encode_layer(self, k: int, image: np.ndarray):
        """PNG bytes of the native image and the plate box of the model (thread-safe)."""
        box = occupied(image)
        return png_bytes(self.printer.to_native(image), box=self.printer.native_box(box)), box

    def write_layer(self, k: int, image: np.ndarray) -> None:
        self.store_layer(k, image, self.encode_layer(k, image))

    def store_layer(self, k: int, image: np.ndarray, payload) -> None:
        self.next_layer(k)
        data, box = payload
        self.add(f"{self.job}{k:05d}.png", data, False)
        self._meter.add(image, box)
        self._top.add(k, image, box)
        self._k += 1

    def config_ini(self) -> dict:
        """The ``config.ini`` keys (docs/formats.md §1.1); ``printTime`` and
        ``usedMaterial`` are :attr:`estimate` (faded exposures, the slow tilt of
        layers over ``area_fill``), set when the last layer is written."""
        s, p, est = self.settings, self.printer, self.estimate
        n = self._k
        slow = est.slow_layers
        return {
            "action": "print",
            "expTime": _num(s.exposure),
            "expTimeFirst": _num(s.bottom_exposure),
            "expUserProfile": 0,
            "fileCreationTimestamp": build_time().strftime("%Y-%m-%d at %H:%M:%S UTC"),
            "hollow": 0,
            "jobDir": self.job,
            "layerHeight": _num(s.layer_height),
            "materialName": f"Generic resin @{_num(s.layer_height)}",
            "numFade": s.bottom_layers,
            "numFast": n - slow,
            "numSlow": slow,
            "printProfile": f"{_num(s.layer_height)} skelslice",
            "printTime": f"{est.seconds:.6f}",
            "printerModel": self.printer_model,
            "printerProfile": p.label,
            "printerVariant": "default",
            "prusaSlicerVersion": f"skelslice-{self.meta.get('generator', 'skelslice').split()[-1]}",
            "usedMaterial": f"{est.volume_ml:.6f}",
        }

    def prusaslicer_ini(self) -> dict:
        """The SLA printer/print/material profile keys PrusaSlicer and UVtools read."""
        s, p = self.settings, self.printer
        W, H = p.display
        return {
            "absolute_correction": 0,
            "area_fill": _num(AREA_FILL),
            "bed_shape": f"0x0,{W:g}x0,{W:g}x{H:g},0x{H:g}",
            "display_height": f"{H:g}",
            "display_mirror_x": int(p.mirror_x),
            "display_mirror_y": int(p.mirror_y),
            "display_orientation": p.orientation,
            "display_pixels_x": p.pixels[0],
            "display_pixels_y": p.pixels[1],
            "display_width": f"{W:g}",
            "elefant_foot_compensation": 0,
            "elefant_foot_min_width": 0.2,
            "exposure_time": _num(s.exposure),
            "faded_layers": s.bottom_layers,
            "fast_tilt_time": 5,
            "gamma_correction": 1 if s.antialiased else 0,
            "high_viscosity_tilt_time": 10,
            "initial_exposure_time": _num(s.bottom_exposure),
            "initial_layer_height": _num(s.layer_height),
            "layer_height": _num(s.layer_height),
            "material_print_speed": "fast",
            "max_exposure_time": _num(EXPOSURE_RANGE[1]),
            "max_initial_exposure_time": _num(FIRST_EXPOSURE_RANGE[1]),
            "max_print_height": f"{p.max_height:g}",
            "min_exposure_time": _num(EXPOSURE_RANGE[0]),
            "min_initial_exposure_time": _num(FIRST_EXPOSURE_RANGE[0]),
            "pad_enable": 0,
            "printer_model": self.printer_model,
            "printer_settings_id": p.label,
            "printer_technology": "SLA",
            "printer_variant": "default",
            "relative_correction": "1,1",
            "relative_correction_x": 1,
            "relative_correction_y": 1,
            "relative_correction_z": 1,
            "slow_tilt_time": 8,
            "supports_enable": 0,
            "thumbnails": ",".join(f"{w}x{h}" for w, h in p.thumbnails),
        }

    def final_members(self):
        self.estimate = self._meter.estimate(self.settings, fade=True)
        yield "config.ini", ini_text(self.config_ini()), True
        yield "prusaslicer.ini", ini_text(self.prusaslicer_ini()), True
        for w, h in self.printer.thumbnails:
            yield f"thumbnail/thumbnail{w}x{h}.png", png_rgba(self._top.render((w, h))), False


class Sl1sWriter(Sl1Writer):
    """Prusa SL1S SPEED archive (``printerModel = SL1S``)."""

    name = "sl1s"
    printer_model = "SL1S"
    default_printer = "prusa-sl1s"


__all__ = ["Sl1Writer", "Sl1sWriter", "job_dir", "ini_text"]
