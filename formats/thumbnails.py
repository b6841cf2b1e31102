"""Preview images of a layer stack, built while the layers stream past.

:class:`TopView` keeps, per block of ``step x step`` plate pixels, the
highest layer that has a solid pixel (grey >= 128) in the block: a height
map at reduced resolution, O(plate / step²) memory. At the end it renders a
shaded top view (higher = brighter) cropped to the model and fitted into
each requested thumbnail size.
"""
from __future__ import annotations

import numpy as np

from formats.rle import occupied

#: colour of the model in previews (Prusa orange), RGB
MODEL_RGB = np.array([250.0, 120.0, 30.0])


class TopView:
    """Height map of a stack, accumulated one layer at a time.

    Parameters
    ----------
    shape : (2,) int
        (rows, columns) of the layer images.
    max_side : int
        Longest side of the height map (the block size follows).
    """

    def __init__(self, shape: tuple[int, int], max_side: int = 800):
        self.shape = tuple(shape)
        self.step = max(1, -(-max(self.shape) // max_side))
        s = self.step
        self.height = np.full((-(-shape[0] // s), -(-shape[1] // s)), -1, np.int32)

    def add(self, k: int, image: np.ndarray, box=False) -> None:
        """Record layer k, a (rows, columns) uint8 image.

        ``box``: the image's :func:`formats.rle.occupied` box if known (None:
        empty), so that only it is read; False: found here.
        """
        s = self.step
        if box is False:
            box = occupied(image)
        if box is None:
            return
        R0, R1, C0, C1 = box
        rows = np.flatnonzero(image[R0:R1, C0:C1].max(axis=1) >= 128)
        if rows.size == 0:
            return
        r0, r1 = (R0 + rows[0]) // s * s, R0 + rows[-1] + 1      # then only the solid rows of the box
        cols = np.flatnonzero((image[r0:r1, C0:C1] >= 128).any(axis=0))
        c0, c1 = (C0 + cols[0]) // s * s, C0 + cols[-1] + 1
        band = image[r0:r1, c0:c1] >= 128
        hb, wb = -(-(r1 - r0) // s), -(-(c1 - c0) // s)
        pad = np.zeros((hb * s, wb * s), bool)
        pad[:r1 - r0, :c1 - c0] = band
        # any() over the rows of each block, then over its columns (one 4-D reduction is 6x slower)
        blocks = pad.reshape(hb, s, wb * s).any(axis=1).reshape(hb, wb, s).any(axis=2)
        self.height[r0 // s:r0 // s + hb, c0 // s:c0 // s + wb][blocks] = k

    def render(self, size: tuple[int, int]) -> np.ndarray:
        """A (h, w, 4) uint8 RGBA top view of the model fitted into ``size`` = (w, h)."""
        from PIL import Image

        w, h = size
        out = np.zeros((h, w, 4), np.uint8)
        rows, cols = np.nonzero(self.height >= 0)
        if rows.size == 0:
            return out
        hm = self.height[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
        top = max(int(hm.max()), 1)
        shade = np.where(hm >= 0, 0.35 + 0.65 * hm / top, 0.0)
        rgba = np.zeros(hm.shape + (4,), np.uint8)
        rgba[..., :3] = np.round(shade[..., None] * MODEL_RGB).astype(np.uint8)
        rgba[..., 3] = np.where(hm >= 0, 255, 0)
        scale = min(0.9 * w / hm.shape[1], 0.9 * h / hm.shape[0])
        tw, th = max(1, int(hm.shape[1] * scale)), max(1, int(hm.shape[0] * scale))
        img = np.asarray(Image.fromarray(rgba).resize((tw, th), Image.Resampling.NEAREST))
        r0, c0 = (h - th) // 2, (w - tw) // 2
        out[r0:r0 + th, c0:c0 + tw] = img
        return out


def png_rgba(image: np.ndarray) -> bytes:
    """PNG bytes of a (h, w, 4) uint8 RGBA image."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def rgb565(image: np.ndarray, big_endian: bool = True) -> bytes:
    """RGB565 bytes (row-major, red in the high bits) of a (h, w, 3+) uint8 image:
    big-endian as GOO stores previews, little-endian as Photon Workshop does."""
    rgb = image[..., :3].astype(np.uint16)
    v = ((rgb[..., 0] >> 3) << 11) | ((rgb[..., 1] >> 2) << 5) | (rgb[..., 2] >> 3)
    return v.astype(">u2" if big_endian else "<u2").tobytes()


__all__ = ["TopView", "png_rgba", "rgb565"]
