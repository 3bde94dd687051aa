"""PNG files in numpy and the standard library only: writing 8-bit images, reading a PNG's
size, and checking a PNG's integrity (signature, chunk checksums, complete image data) without
decoding its pixels, so that a damaged file is named before anything is built from it."""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"
CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}   # colour type -> samples per pixel


class PngError(ValueError):
    """A PNG file is missing or damaged (one-line message)."""


def write_png(path, image) -> Path:
    """Write an 8-bit grey (H, W) or RGB (H, W, 3) uint8 array as a PNG (numpy + zlib only)."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (3, 4)):
        raise PngError(f"write_png needs uint8 (H, W), (H, W, 3) or (H, W, 4), got {image.dtype} {image.shape}")
    height, width = image.shape[:2]
    colour_type = {1: 0, 3: 2, 4: 6}[1 if image.ndim == 2 else image.shape[2]]
    rows = np.ascontiguousarray(image.reshape(height, -1))
    raw = np.concatenate([np.zeros((height, 1), np.uint8), rows], axis=1).tobytes()  # filter 0 per row

    def chunk(kind, payload):
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(SIGNATURE + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 6))
                     + chunk(b"IEND", b""))
    return path


def png_size(path) -> tuple:
    """(width, height) of a PNG, read from its header."""
    with open(path, "rb") as handle:
        head = handle.read(24)
    if len(head) < 24 or head[:8] != SIGNATURE or head[12:16] != b"IHDR":
        raise PngError(f"{path} is not a PNG file (or its header is damaged)")
    return struct.unpack(">II", head[16:24])


def check_png(path) -> tuple:
    """(width, height) of an intact PNG; PngError for a missing, truncated or corrupt file."""
    path = Path(path)
    if not path.is_file():
        raise PngError(f"missing {path}")
    data = path.read_bytes()
    if data[:8] != SIGNATURE:
        raise PngError(f"{path} is not a PNG file")
    offset, header, compressed, ended = 8, None, [], False
    while offset + 12 <= len(data) and not ended:
        length, kind = struct.unpack(">I4s", data[offset:offset + 8])
        payload = data[offset + 8:offset + 8 + length]
        crc = data[offset + 8 + length:offset + 12 + length]
        if len(payload) < length or len(crc) < 4 or struct.unpack(">I", crc)[0] != zlib.crc32(kind + payload):
            raise PngError(f"{path} is damaged (chunk {kind.decode('latin-1')} fails its checksum or is cut short)")
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", payload)
        elif kind == b"IDAT":
            compressed.append(payload)
        ended = kind == b"IEND"
        offset += 12 + length
    if header is None or not ended:
        raise PngError(f"{path} is damaged (no {'IHDR' if header is None else 'IEND'} chunk: truncated?)")
    width, height, depth, colour, _, _, interlace = header
    try:
        raw = zlib.decompress(b"".join(compressed))
    except zlib.error:
        raise PngError(f"{path} is damaged (its image data does not decompress)") from None
    if not interlace and colour in CHANNELS:
        expected = height * (1 + (width * CHANNELS[colour] * depth + 7) // 8)
        if len(raw) != expected:
            raise PngError(f"{path} is damaged (image data of {len(raw)} bytes, {width}x{height} needs {expected})")
    return width, height
