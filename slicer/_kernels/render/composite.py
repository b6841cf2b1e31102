"""Compositing given crossings: shading and front-to-back blending per pixel.

Used for parts (:mod:`slicer.render.parts`), whose crossings come from the
lattice's roots and the meshes' faces; the shading and blending are those of
:func:`slicer._kernels.render.walk.render_ray`.
"""
from __future__ import annotations

import numpy as np
from numba import prange

from slicer._jit import parallel_kernel
from slicer._kernels.render.walk import SH_ALPHA, SH_MAXA, SH_OPAQUE, shade_crossing


@parallel_kernel
def composite_crossings(shade, offsets, dirs, grads, rgba, cut):
    """Shade and composite each pixel's crossings, nearest first.

    Parameters
    ----------
    shade : (NSHADE,) float64
        The shading array of :mod:`slicer._kernels.render.walk`.
    offsets : (npix + 1,) int64
        Crossings of pixel p are ``offsets[p]:offsets[p + 1]``, sorted by distance.
    dirs : (n, 3) float64
        Unit ray direction at each crossing.
    grads : (n, 3) float64
        A vector along the inward normal at each crossing (the field's
        gradient; the outward normal is ``-grads``).
    rgba : (npix, 4) float64
        Output, premultiplied.
    cut : (npix,) bool
        Output: the pixel reached the opacity cut-off.
    """
    npix = offsets.shape[0] - 1
    alpha = shade[SH_ALPHA]
    maxa = shade[SH_MAXA]
    opaque = shade[SH_OPAQUE] != 0.0
    if opaque:
        alpha = 1.0
    for p in prange(npix):
        rgb = np.empty(3)
        ar = 0.0
        ag = 0.0
        ab = 0.0
        aa = 0.0
        for c in range(offsets[p], offsets[p + 1]):
            shade_crossing(shade, dirs[c, 0], dirs[c, 1], dirs[c, 2], grads[c, 0], grads[c, 1], grads[c, 2], rgb)
            w = (1.0 - aa) * alpha
            ar += w * rgb[0]
            ag += w * rgb[1]
            ab += w * rgb[2]
            aa += w
            if opaque or (maxa < 1.0 and aa >= maxa):
                cut[p] = True
                break
        rgba[p, 0] = ar
        rgba[p, 1] = ag
        rgba[p, 2] = ab
        rgba[p, 3] = aa
