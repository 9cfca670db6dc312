"""A minimal reader for the EXR files Blender writes for us: scanline, uncompressed (codec NONE),
single- or multi-part, half / float / uint channels. No dependency beyond numpy.

Blender 5.0 writes a multilayer render as a multi-part EXR, one part per pass
(`ViewLayer.Combined`, `ViewLayer.Depth`, `ViewLayer.Object Index`, ...). `read_exr` returns
every channel by its full name, e.g. `ViewLayer.Depth.Z`, as a (height, width) float32 array.
"""

import struct

import numpy as np

_MAGIC = 20000630
_TILED, _MULTIPART, _NON_IMAGE = 0x200, 0x1000, 0x800
_PIXEL_TYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}


class ExrError(ValueError):
    pass


def _read_header(data: bytes, pos: int) -> tuple[dict, int]:
    attrs = {}
    while data[pos] != 0:
        end = data.index(b"\0", pos)
        name = data[pos:end].decode()
        tend = data.index(b"\0", end + 1)
        kind = data[end + 1 : tend].decode()
        (size,) = struct.unpack_from("<i", data, tend + 1)
        value = data[tend + 5 : tend + 5 + size]
        attrs[name] = (kind, value)
        pos = tend + 5 + size
    return attrs, pos + 1


def _channels(value: bytes) -> list[tuple[str, int]]:
    out, pos = [], 0
    while value[pos] != 0:
        end = value.index(b"\0", pos)
        name = value[pos:end].decode()
        pixel_type, _linear, xs, ys = struct.unpack_from("<iB3xii", value, end + 1)
        if (xs, ys) != (1, 1):
            raise ExrError(f"channel {name}: subsampled channels are not supported")
        out.append((name, pixel_type))
        pos = end + 1 + 16
    return out


def read_exr(data: bytes) -> dict[str, np.ndarray]:
    """Every channel of an uncompressed scanline EXR (bytes), as float32 (height, width) arrays."""
    magic, version = struct.unpack_from("<ii", data, 0)
    if magic != _MAGIC:
        raise ExrError("not an OpenEXR file")
    flags = version & ~0xFF
    if flags & (_TILED | _NON_IMAGE):
        raise ExrError("tiled or deep EXR files are not supported")
    pos, headers = 8, []
    if flags & _MULTIPART:
        while data[pos] != 0:
            header, pos = _read_header(data, pos)
            headers.append(header)
        pos += 1
    else:
        header, pos = _read_header(data, pos)
        headers.append(header)
    out: dict[str, np.ndarray] = {}
    parts = []
    for header in headers:
        if header["compression"][1] != b"\0":
            raise ExrError("only uncompressed EXR (codec NONE) is supported")
        x0, y0, x1, y1 = struct.unpack("<iiii", header["dataWindow"][1])
        height, width = y1 - y0 + 1, x1 - x0 + 1
        count = (
            struct.unpack("<i", header["chunkCount"][1])[0] if "chunkCount" in header else height
        )
        parts.append((header, y0, height, width, count))
        pos += 8 * count  # offset table; uncompressed chunks follow in file order
    for number, (header, y0, height, width, _count) in enumerate(parts):
        channels = _channels(header["channels"][1])
        arrays = {name: np.empty((height, width), np.float32) for name, _ in channels}
        line_bytes = sum(_PIXEL_TYPES[t].itemsize for _, t in channels) * width
        out.update(arrays)
        parts[number] = (channels, arrays, y0, width, line_bytes)
    # Chunks: [part number (multi-part only)] y, size, data; any order.
    while pos < len(data):
        if flags & _MULTIPART:
            (number,) = struct.unpack_from("<i", data, pos)
            pos += 4
        else:
            number = 0
        channels, arrays, y0, width, line_bytes = parts[number]
        y, size = struct.unpack_from("<ii", data, pos)
        pos += 8
        lines = size // line_bytes
        block = data[pos : pos + size]
        pos += size
        for line in range(lines):
            off = line * line_bytes
            for name, pixel_type in channels:
                dt = _PIXEL_TYPES[pixel_type]
                arrays[name][y - y0 + line] = np.frombuffer(block, dt, width, off)
                off += dt.itemsize * width
    return out
