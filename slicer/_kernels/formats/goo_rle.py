"""Decoding of GOO run-length layers (Elegoo's open format, V1.2).

A layer payload is a sequence of chunks; the top two bits of a chunk's first
byte give its type: ``00`` a run of 0x00, ``11`` a run of 0xFF, ``01`` a run
of the grey in the next byte, ``10`` a difference from the previous grey.
Runs of types 00, 01 and 11 carry their length in 4 + 8 x (0..3) bits (the
low four bits of byte 0, then the following bytes, most significant first);
a difference chunk changes the grey by the low four bits (sign in bit 5)
for one pixel, or for the count in the next byte when bit 4 is set.
"""
from __future__ import annotations

import numpy as np

from slicer._jit import kernel

#: status codes of :func:`decode_goo`
OK, OVERFLOW, TRUNCATED, SHORT, ZERO_RUN = 0, 1, 2, 3, 4


@kernel
def decode_goo(data, out):
    """Decode a GOO layer payload into ``out``.

    Parameters
    ----------
    data : (n,) uint8
        The payload (without the 0x55 magic and the checksum).
    out : (p,) uint8
        The layer's pixels, row-major; filled.

    Returns
    -------
    status : int
        ``OK``; ``OVERFLOW`` (runs past the image), ``TRUNCATED`` (a chunk
        cut off), ``SHORT`` (runs cover fewer pixels) or ``ZERO_RUN``.
    where : int
        Byte offset of the offending chunk (pixels covered for ``SHORT``).
    """
    n = data.shape[0]
    p = out.shape[0]
    pos = 0
    i = 0
    colour = np.int64(0)
    while i < n:
        at = i
        b0 = np.int64(data[i])
        kind = b0 >> 6
        width = (b0 >> 4) & 3
        i += 1
        if kind == 2:
            step = b0 & 0xF
            colour = colour - step if (b0 & 0x20) else colour + step
            colour &= 0xFF
            length = 1
            if b0 & 0x10:
                if i >= n:
                    return TRUNCATED, at
                length = np.int64(data[i])
                i += 1
        else:
            if kind == 1:
                if i >= n:
                    return TRUNCATED, at
                colour = np.int64(data[i])
                i += 1
            else:
                colour = 0 if kind == 0 else 255
            length = b0 & 0xF
            if i + width > n:
                return TRUNCATED, at
            for e in range(width):
                length += np.int64(data[i]) << (4 + 8 * (width - 1 - e))
                i += 1
        if length <= 0:
            return ZERO_RUN, at
        if pos + length > p:
            return OVERFLOW, at
        for q in range(pos, pos + length):
            out[q] = colour
        pos += length
    if pos != p:
        return SHORT, pos
    return OK, 0
