"""Independent readers of the printer formats, written here from their public layouts.

Each reader parses a whole file and checks it as it goes (offsets, lengths,
checksums, run lengths); none decodes with the code of :mod:`formats` (the GOO
reader takes only ``HEADER_SIZE`` from it):

* GOO (Elegoo's spec V1.2; docs/formats.md §2.1): :func:`read_goo`,
  :func:`read_goo_lazy` (one layer at a time), :func:`goo_decode_rle`;
* CTB v2/v3 (catibo's ``cbddlp-ctb.adoc``; docs/printers.md): :func:`read_ctb`,
  with the keystream, layer RLE and preview decoders;
* Anycubic Photon Workshop (UVtools ``AnycubicFile``, PrusaSlicer ``AnycubicSLA``;
  docs/printers.md): :func:`read_photon` (the tables) and :func:`layer_images`
  (the layers), with the pws/pw0 decoders and the layer CRC.

Used by the format tests (tests/test_formats_images.py, test_formats_ctb.py,
test_formats_photon.py) and by tests/test_estimate.py, which reads the print
time and volume each format stores.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from formats.goo import HEADER_SIZE


# ---------------------------------------------------------------- GOO (from the spec)
def goo_decode_rle(data: bytes, n_pixels: int) -> np.ndarray:
    """Decode a GOO layer payload (all four chunk types) to a flat uint8 array."""
    out = np.zeros(n_pixels, np.uint8)
    pos, i, colour = 0, 0, 0
    while i < len(data):
        b0 = data[i]
        kind, width, low = b0 >> 6, (b0 >> 4) & 3, b0 & 0xF
        i += 1
        if kind == 2:                                  # diff from the previous pixel
            diff = low if not (b0 & 0x20) else -low
            colour += diff
            if b0 & 0x10:
                length = data[i]
                i += 1
            else:
                length = 1
        else:
            if kind == 1:
                colour = data[i]
                i += 1
            else:
                colour = 0 if kind == 0 else 255
            length = low
            for e in range(width):                     # big-endian extra bytes, most significant first
                length += data[i] << (4 + 8 * (width - 1 - e))
                i += 1
        assert length > 0, "zero-length run"
        assert pos + length <= n_pixels, "runs overflow the image"
        out[pos:pos + length] = colour
        pos += length
    assert pos == n_pixels, f"runs cover {pos} of {n_pixels} pixels"
    return out


#: a GOO layer record's fields (spec V1.2 "layer content"), in file order
LAYER_FIELDS = ("pause", "pause_z", "z", "exposure", "off_time", "before_lift", "after_lift", "after_retract",
                "lift", "lift_speed", "lift2", "lift2_speed", "retract", "retract_speed", "retract2",
                "retract2_speed", "pwm")


def read_goo(path):
    """Parse a whole GOO file; returns (header dict, list of (record dict, image))."""
    h, layers = read_goo_lazy(path)
    return h, list(layers)


def read_goo_lazy(path):
    """Parse a GOO file: (header dict, iterator of (record dict, image)), one layer at a time."""
    raw = Path(path).read_bytes()
    h = {}
    assert raw[0:4] == b"V3.0"
    assert raw[4:12] == bytes([7, 0, 0, 0, 0x44, 0x4C, 0x50, 0])
    assert raw[27106:27108] == b"\r\n" and raw[195308:195310] == b"\r\n"
    h["printer_name"] = raw[92:124].split(b"\0")[0].decode()
    h["aa"], h["grey"], h["blur"] = struct.unpack_from(">3H", raw, 188)
    h["layers"], h["x_res"], h["y_res"] = struct.unpack_from(">IHH", raw, 195310)
    h["x_mirror"], h["y_mirror"] = struct.unpack_from(">??", raw, 195318)
    h["x_size"], h["y_size"], h["z_size"], h["layer_h"], h["exposure"] = struct.unpack_from(">5f", raw, 195320)
    h["delay_mode"] = raw[195340]
    h["waits"] = struct.unpack_from(">7f", raw, 195341)
    h["bottom_exposure"], h["bottom_layers"] = struct.unpack_from(">fI", raw, 195369)
    h["lift"] = struct.unpack_from(">16f", raw, 195377)
    h["pwm"] = struct.unpack_from(">HH", raw, 195441)
    h["advance"] = raw[195445]
    h["time"], h["volume"] = struct.unpack_from(">If", raw, 195446)
    assert struct.unpack_from(">I", raw, 195470)[0] == HEADER_SIZE
    h["grey_scale_level"] = raw[195474]
    h["transition"] = struct.unpack_from(">H", raw, 195475)[0]
    return h, _goo_layers(raw, h)


def _goo_layers(raw, h):
    off = HEADER_SIZE
    for k in range(h["layers"]):
        f = struct.unpack_from(">H15fH", raw, off)
        rec = dict(zip(LAYER_FIELDS, f))
        off += 2 + 60 + 2
        assert raw[off:off + 2] == b"\r\n"
        (n,) = struct.unpack_from(">I", raw, off + 2)
        assert raw[off + 6] == 0x55
        payload = raw[off + 7:off + 7 + n - 2]
        checksum = raw[off + 7 + n - 2]
        assert checksum == (~sum(payload)) & 0xFF, f"layer {k}: bad checksum"
        assert raw[off + 5 + n + 1:off + 5 + n + 3] == b"\r\n"
        off += 5 + n + 3
        yield rec, goo_decode_rle(payload, h["x_res"] * h["y_res"]).reshape(h["y_res"], h["x_res"])
    assert raw[off:] == bytes([0, 0, 0, 7, 0, 0, 0, 0x44, 0x4C, 0x50, 0]), "ending string"


# ---------------------------------------------------------------- CTB (from the public layout)
def reference_keystream(key: int, index: int, n: int) -> bytes:
    """catibo's "86 cipher" keystream, word by word (constants as UVtools and uv3dp use them)."""
    c = (key * 0x2D83CDAC + 0xD8A83423) % 2**32
    x = ((index * 0x1E1530CD + 0xEC3D47CD) * c) % 2**32
    out = bytearray()
    while len(out) < n:
        out += x.to_bytes(4, "little")
        x = (x + c) % 2**32
    return bytes(out[:n])


def decode_rle7(data: bytes, n_pixels: int) -> np.ndarray:
    """CTB layer RLE to 8-bit greys (0, or 2 c + 1)."""
    vals, lens = [], []
    i = 0
    while i < len(data):
        code = data[i]
        i += 1
        length = 1
        if code & 0x80:
            code &= 0x7F
            b = data[i]
            if b & 0x80 == 0:
                length, extra = b, 0
            elif b & 0xC0 == 0x80:
                length, extra = b & 0x3F, 1
            elif b & 0xE0 == 0xC0:
                length, extra = b & 0x1F, 2
            else:
                assert b & 0xF0 == 0xE0, "bad run-length prefix"
                length, extra = b & 0x0F, 3
            for e in range(extra):                               # big-endian continuation bytes
                length = (length << 8) | data[i + 1 + e]
            i += 1 + extra
        assert length > 0
        vals.append(0 if code == 0 else 2 * code + 1)
        lens.append(length)
    out = np.repeat(np.array(vals, np.uint8), lens)
    assert out.size == n_pixels, f"runs cover {out.size} of {n_pixels} pixels"
    return out


def decode_rgb15(data: bytes, w: int, h: int) -> np.ndarray:
    words = struct.unpack(f"<{len(data) // 2}H", data)
    px, i = [], 0
    while i < len(words):
        v, n = words[i], 1
        if v & 0x20:
            assert words[i + 1] & 0xF000 == 0x3000
            n += words[i + 1] & 0xFFF
            i += 1
        i += 1
        px += [((v >> 11) & 0x1F, (v >> 6) & 0x1F, v & 0x1F)] * n
    assert len(px) == w * h
    return np.array(px, np.uint8).reshape(h, w, 3)


def read_ctb(path) -> dict:
    raw = path.read_bytes()
    f = {}
    (f["magic"], f["version"], *f["bed"]) = struct.unpack_from("<2I3f", raw, 0)
    (f["height"], f["layer_height"], f["exposure"], f["bottom_exposure"], f["light_off"]) = \
        struct.unpack_from("<5f", raw, 0x1C)
    (f["bottom_layers"], f["res_x"], f["res_y"], f["preview_large"], f["table"], f["layers"], f["preview_small"],
     f["print_time"], f["projector"], f["params_at"], f["params_size"], f["aa"]) = struct.unpack_from("<12I", raw, 0x30)
    f["pwm"], f["bottom_pwm"], f["key"], f["slicer_at"], f["slicer_size"] = struct.unpack_from("<2H3I", raw, 0x60)
    assert f["params_size"] == 60 and f["slicer_size"] == 76
    p = struct.unpack_from("<10f5I", raw, f["params_at"])
    f["params"] = dict(zip(["bottom_lift", "bottom_lift_speed", "lift", "lift_speed", "retract_speed", "volume",
                            "weight", "cost", "bottom_light_off", "light_off", "bottom_layers"], p))
    f["params"]["padding"] = p[11:]
    s = f["slicer_at"]
    name_at, name_len = struct.unpack_from("<2I", raw, s + 0x1C)
    f["machine"] = raw[name_at:name_at + name_len].decode()
    f["aa_flag"], f["per_layer"] = raw[s + 0x24], raw[s + 0x27]
    f["minutes"], f["aa_level"], f["software"] = struct.unpack_from("<3I", raw, s + 0x28)
    f["previews"] = {}
    for key in ("preview_large", "preview_small"):
        w, h, at, n = struct.unpack_from("<4I", raw, f[key])
        f["previews"][(w, h)] = decode_rgb15(raw[at:at + n], w, h)
    f["layer_defs"], f["images"], f["ex"] = [], [], []
    for k in range(f["layers"]):
        z, exp, off, at, n, page, size, u3, u4 = struct.unpack_from("<3f6I", raw, f["table"] + 36 * k)
        f["layer_defs"].append({"z": z, "exposure": exp, "light_off": off, "size": size, "zeros": (page, u3, u4)})
        if f["version"] >= 3:
            ex = raw[at - 84:at]
            assert ex[:36] == raw[f["table"] + 36 * k:f["table"] + 36 * k + 36], "v3 record repeats the table entry"
            total, *vals = struct.unpack_from("<I11f", ex, 36)
            assert total == 84 + n
            f["ex"].append(vals)
        plain = bytes(a ^ b for a, b in zip(raw[at:at + n], reference_keystream(f["key"], k, n)))
        f["images"].append(decode_rle7(plain, f["res_x"] * f["res_y"]).reshape(f["res_y"], f["res_x"]))
    return f


# ---------------------------------------------------------------- Anycubic Photon (from the public layout)
def crc_table():
    """CRC-16/ARC of each single byte (bit by bit, reflected polynomial 0xA001)."""
    out = []
    for b in range(256):
        crc = b
        for _ in range(8):
            crc = (crc >> 1) ^ (0xA001 * (crc & 1))
        out.append(crc)
    return out


def reference_crc(data: bytes) -> int:
    """Anycubic's layer checksum as uv3dp documents it: every byte through the table twice."""
    t = crc_table()
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ t[((crc >> 8) ^ t[b]) & 0xFF]) & 0xFFFF
    return (t[crc & 0xFF] * 0x100 + t[crc >> 8]) % 0x10000          # 16-bit words: the sum wraps


def decode_pw0(data: bytes, n: int) -> tuple[np.ndarray, int]:
    """pw0 runs to 8-bit greys; returns (pixels, bytes used)."""
    vals, lens, i, total = [], [], 0, 0
    while total < n:
        b = data[i]
        c, low = b >> 4, b & 0xF
        if c in (0, 15):
            length = low << 8 | data[i + 1]
            i += 2
        else:
            length = low
            i += 1
        assert length > 0
        vals.append(17 * c)
        lens.append(length)
        total += length
    assert total == n
    return np.repeat(np.array(vals, np.uint8), lens), i


def decode_pws(data: bytes, n: int, planes: int) -> np.ndarray:
    count = np.zeros(n, np.int64)
    i = 0
    for _ in range(planes):
        pos = 0
        while pos < n:
            b = data[i]
            i += 1
            length = b & 0x7F
            assert 0 < length <= 125
            if b & 0x80:
                count[pos:pos + length] += 1
            pos += length
        assert pos == n
    assert i == len(data)
    return np.where(count > 0, count * (256 // planes) - 1, 0).astype(np.uint8)


def table(raw, at, name, length=None, with_head=False):
    """Check a named table's name and length; returns (length, offset of its payload)."""
    assert raw[at:at + 12] == name.encode().ljust(12, b"\0"), raw[at:at + 12]
    (n,) = struct.unpack_from("<I", raw, at + 12)
    if length is not None:
        assert n == length + (16 if with_head else 0), (name, n, length)
    return n, at + 16


def read_photon(path, n_layers) -> dict:
    raw = path.read_bytes()
    assert raw[:12] == b"ANYCUBIC\0\0\0\0"
    version, tables = struct.unpack_from("<2I", raw, 12)
    keys = ["header", "software", "preview", "colours", "layerdef", "extra"] + (["machine"] if version >= 516 else []) \
        + ["image"] + (["model"] if version >= 517 else []) + (["sublayers", "preview2"] if version >= 518 else [])
    addr = dict(zip(keys, struct.unpack_from(f"<{len(keys)}I", raw, 20)))
    f = {"version": version, "tables": tables, "addr": addr}
    hlen = {1: 80, 516: 84, 517: 92, 518: 96}[version]
    _, h = table(raw, addr["header"], "HEADER", hlen)
    names = ["pixel_um", "layer_height", "exposure", "wait", "bottom_exposure", "bottom_layers", "lift", "lift_speed",
             "retract_speed", "volume"]
    f.update(zip(names, struct.unpack_from("<10f", raw, h)))
    f["aa"], f["res_x"], f["res_y"] = struct.unpack_from("<3I", raw, h + 40)
    f["weight"], f["price"] = struct.unpack_from("<2f", raw, h + 52)
    f["currency"], f["per_layer"], f["print_time"], f["transition"], f["transition_type"] = \
        struct.unpack_from("<5I", raw, h + 60)
    f["rest"] = raw[h + 80:h + hlen]
    _, p = table(raw, addr["preview"], "PREVIEW", 12 + 224 * 168 * 2, with_head=True)
    f["preview"] = struct.unpack_from("<3I", raw, p)
    if version >= 516:
        use_full, count, *greys, unknown = struct.unpack_from("<2I16BI", raw, addr["colours"])
        f["colours"] = (use_full, count, greys, unknown)
        assert addr["colours"] + 28 == addr["layerdef"]
    else:
        assert addr["colours"] == addr["software"] == addr["extra"] == 0
    _, d = table(raw, addr["layerdef"], "LAYERDEF", 4 + 32 * n_layers)
    assert struct.unpack_from("<I", raw, d)[0] == n_layers
    f["layers"] = [struct.unpack_from("<2I4f2I", raw, d + 4 + 32 * k) for k in range(n_layers)]
    if version >= 516:
        _, e = table(raw, addr["extra"], "EXTRA", 24)
        f["extra"] = struct.unpack_from("<I6fI6f", raw, e)
        _, m = table(raw, addr["machine"], "MACHINE", (156 if version < 518 else 224) - 16, with_head=True)
        f["machine"] = raw[m:m + 96].split(b"\0")[0].decode()
        f["image_format"] = raw[m + 96:m + 112].split(b"\0")[0].decode()
        f["machine_fields"] = struct.unpack_from("<2I3f2I", raw, m + 112)
        if version >= 518:
            f["machine_518"] = struct.unpack_from("<2f8I2I2H4I", raw, m + 140)
    if version >= 517:
        s = addr["software"]
        assert raw[s:s + 9] == b"skelslice" and struct.unpack_from("<I", raw, s + 32)[0] == 164
        _, mo = table(raw, addr["model"], "MODEL", 32, with_head=True)
        f["model"] = struct.unpack_from("<6fIf", raw, mo)
    if version >= 518:
        _, sl = table(raw, addr["sublayers"], "SUBIMGS", 8 + 44 * n_layers, with_head=True)
        f["sublayers"] = [struct.unpack_from("<3I", raw, sl + 8 + 44 * k) for k in range(n_layers)]
        assert struct.unpack_from("<2I", raw, sl) == (n_layers, 1)
        _, p2 = table(raw, addr["preview2"], "PREVIEW2", 12 + 320 * 190 * 2, with_head=True)
        f["preview2"] = struct.unpack_from("<I2HI", raw, p2)
    f["raw"] = raw
    return f


def layer_images(f, encoding, planes):
    n = f["res_x"] * f["res_y"]
    out = []
    for addr, size, *_ in f["layers"]:
        data = f["raw"][addr:addr + size]
        if encoding == "pws":
            img = decode_pws(data, n, planes)
        else:
            img, used = decode_pw0(data, n)
            if f["version"] == 1:                                    # .pw0: CRC-16 of the runs, big-endian
                assert used == size - 2 and struct.unpack(">H", data[used:])[0] == reference_crc(data[:used])
            else:
                assert used == size
        out.append(img.reshape(f["res_y"], f["res_x"]))
    return out
