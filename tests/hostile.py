"""Small hostile files for the memory tests: deflate bombs in ``.npz`` archives and PNG images.

Each builder writes a file of at most a few MB whose declared content is huge. The deflate
streams are assembled from one repeated segment (compressed once, then flushed so that every
copy is independent), so building a 2 GB bomb takes well under a second.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

_SEGMENT = 1 << 20  # bytes of zeros per repeated deflate segment


def _deflate_zeros(prefix: bytes, n_zero_segments: int, segment: bytes) -> tuple[bytes, int]:
    """A raw deflate stream of ``prefix`` then ``n_zero_segments`` copies of ``segment``; and its CRC-32."""
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    head = c.compress(prefix) + c.flush(zlib.Z_FULL_FLUSH)
    body = c.compress(segment) + c.flush(zlib.Z_FULL_FLUSH)
    tail = c.flush(zlib.Z_FINISH)
    crc = zlib.crc32(prefix)
    for _ in range(n_zero_segments):
        crc = zlib.crc32(segment, crc)
    return head + body * n_zero_segments + tail, crc


def _npy_header(dtype: str, shape: tuple[int, ...]) -> bytes:
    header = f"{{'descr': '{dtype}', 'fortran_order': False, 'shape': {shape}, }}".encode("latin1")
    pad = 64 - (10 + len(header) + 1) % 64
    header += b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header


def write_zip(path: Path, entries: list[tuple[str, bytes, int, int, int]]) -> Path:
    """A zip of ``(name, deflated data, crc, uncompressed size, method)`` entries (no zip64)."""
    out, central = bytearray(), bytearray()
    for name, data, crc, size, method in entries:
        offset = len(out)
        fields = struct.pack("<HHHHHIII", 20, 0, method, 0, 33, crc, len(data), size)
        out += b"PK\x03\x04" + fields + struct.pack("<HH", len(name), 0) + name.encode() + data
        central += b"PK\x01\x02" + struct.pack("<H", 20) + fields
        central += struct.pack("<HHHHHII", len(name), 0, 0, 0, 0, 0o644 << 16, offset) + name.encode()
    end = struct.pack("<HHHHIIH", 0, 0, len(entries), len(entries), len(central), len(out), 0)
    path.write_bytes(bytes(out + central) + b"PK\x05\x06" + end)
    return path


def _stored_npy(name: str, a: np.ndarray) -> tuple[str, bytes, int, int, int]:
    import io

    buf = io.BytesIO()
    np.lib.format.write_array(buf, a, allow_pickle=False)
    raw = buf.getvalue()
    return name, raw, zlib.crc32(raw), len(raw), 0


def npz_bomb(
    path: Path, name: str, n_bytes: int = 1900 * _SEGMENT, extra: dict[str, np.ndarray] | None = None
) -> Path:
    """An ``.npz`` whose entry ``name`` is a deflated bool array of ``n_bytes`` zeros (about 2 MB on disk)."""
    header = _npy_header("|b1", (n_bytes,))
    segments = n_bytes // _SEGMENT
    if segments * _SEGMENT != n_bytes:
        raise ValueError(f"n_bytes {n_bytes} must be a multiple of {_SEGMENT}")
    data, crc = _deflate_zeros(header, segments, bytes(_SEGMENT))
    entries = [(f"{name}.npy", data, crc, len(header) + n_bytes, 8)]
    entries += [_stored_npy(f"{k}.npy", v) for k, v in (extra or {}).items()]
    return write_zip(path, entries)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_bomb(path: Path, side: int = 16000, *, depth: bool = False) -> Path:
    """A valid ``side`` x ``side`` PNG of about 1 MB: 8-bit RGB black, or with ``depth`` 16-bit grey at 1000."""
    bit_depth, colour, pixel = (16, 0, b"\x03\xe8") if depth else (8, 2, b"\0\0\0")
    row = b"\0" + pixel * side  # filter byte 0, then the pixels
    rows_per_segment = 64
    if side % rows_per_segment:
        raise ValueError(f"side {side} must be a multiple of {rows_per_segment}")
    c = zlib.compressobj(9)
    segment = c.compress(row * rows_per_segment) + c.flush(zlib.Z_FULL_FLUSH)
    head = segment  # the first segment carries the zlib header
    body = zlib.compressobj(9, zlib.DEFLATED, -15)
    repeat = body.compress(row * rows_per_segment) + body.flush(zlib.Z_FULL_FLUSH)
    n = side // rows_per_segment - 1
    adler = zlib.adler32(row * rows_per_segment)
    for _ in range(n):
        adler = zlib.adler32(row * rows_per_segment, adler)
    idat = head + repeat * n + b"\x03\x00" + struct.pack(">I", adler)  # an empty final block, then Adler-32
    ihdr = struct.pack(">IIBBBBB", side, side, bit_depth, colour, 0, 0, 0)
    png = (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", ihdr)
        + _png_chunk(b"IDAT", idat)
        + _png_chunk(b"IEND", b"")
    )
    path.write_bytes(png)
    return path
