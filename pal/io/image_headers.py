"""Image dimensions read from a file's header, so that a reader can refuse a huge image before decoding it.

A PNG of 1 MB can declare 16000 x 16000 pixels; decoding it costs 768 MB (RGB) before any
check on the result could run. :func:`image_size` reads the width and height from the first
bytes of PNG, JPEG, BMP, PNM (PBM/PGM/PPM) and TIFF files, the formats pal's readers accept;
:func:`check_image_size` refuses images over :data:`MAX_IMAGE_PIXELS` (or the caller's limit)
and files of any other format. Errors are :class:`ImageHeaderError` naming the file.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import BinaryIO

from pal.io.files import FileFormatError

__all__ = ["MAX_IMAGE_PIXELS", "ImageHeaderError", "ImageTooLargeError", "check_image_size", "image_size"]

#: Default largest image pal's readers decode, pixels (50 megapixels: 8K UHD is 33 megapixels).
#: An RGB image at this size decodes to 150 MB, a 16-bit depth image to 100 MB.
MAX_IMAGE_PIXELS = 50_000_000
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_JPEG_NO_LENGTH = {0x01, *range(0xD0, 0xDA)}
_TIFF_WIDTH, _TIFF_HEIGHT = 256, 257


class ImageHeaderError(FileFormatError):
    """An image file's header is unreadable, of an unsupported format, or declares too many pixels."""


class ImageTooLargeError(ImageHeaderError):
    """An image file declares more pixels than allowed (checked before decoding)."""


def _read(fh: BinaryIO, n: int, path: Path) -> bytes:
    data = fh.read(n)
    if len(data) != n:
        raise ImageHeaderError(f"{path}: the image header is truncated")
    return data


def _png(fh: BinaryIO, path: Path) -> tuple[int, int]:
    head = _read(fh, 16, path)
    if head[12:16] != b"IHDR":
        raise ImageHeaderError(f"{path}: a PNG whose first chunk is {head[12:16]!r}, not IHDR")
    return struct.unpack(">II", _read(fh, 8, path))


def _jpeg(fh: BinaryIO, path: Path) -> tuple[int, int]:
    _read(fh, 2, path)
    while True:
        byte = _read(fh, 1, path)[0]
        if byte != 0xFF:
            raise ImageHeaderError(f"{path}: a JPEG with the byte {byte:#04x} where a marker should start")
        marker = _read(fh, 1, path)[0]
        while marker == 0xFF:  # fill bytes
            marker = _read(fh, 1, path)[0]
        if marker in _JPEG_NO_LENGTH:
            continue
        (length,) = struct.unpack(">H", _read(fh, 2, path))
        if length < 2:
            raise ImageHeaderError(f"{path}: a JPEG segment of length {length}")
        if marker in _JPEG_SOF:
            _, height, width = struct.unpack(">BHH", _read(fh, 5, path))
            return width, height
        if marker == 0xDA:
            raise ImageHeaderError(f"{path}: a JPEG whose scan starts before its frame header")
        fh.seek(length - 2, 1)


def _bmp(fh: BinaryIO, path: Path) -> tuple[int, int]:
    head = _read(fh, 26, path)
    (size,) = struct.unpack("<I", head[14:18])
    if size == 12:  # BITMAPCOREHEADER
        width, height = struct.unpack("<HH", head[18:22])
    else:
        width, height = struct.unpack("<ii", head[18:26])
    return abs(width), abs(height)


def _pnm(fh: BinaryIO, path: Path) -> tuple[int, int]:
    tokens: list[bytes] = []
    for line in fh.read(4096).splitlines():
        tokens += line.split(b"#", 1)[0].split()
        if len(tokens) >= 3:
            try:
                return int(tokens[1]), int(tokens[2])
            except ValueError:
                break
    raise ImageHeaderError(f"{path}: a PNM file without a readable width and height")


def _tiff(fh: BinaryIO, path: Path) -> tuple[int, int]:
    order = "<" if _read(fh, 2, path) == b"II" else ">"
    magic, offset = struct.unpack(order + "HI", _read(fh, 6, path))
    if magic != 42:
        raise ImageHeaderError(
            f"{path}: a TIFF variant (magic {magic}) that pal does not read; convert it to PNG"
        )
    fh.seek(offset)
    (count,) = struct.unpack(order + "H", _read(fh, 2, path))
    found: dict[int, int] = {}
    for _ in range(count):
        tag, kind, _n, value = struct.unpack(order + "HHI4s", _read(fh, 12, path))
        if tag in (_TIFF_WIDTH, _TIFF_HEIGHT):
            fmt = "H" if kind == 3 else "I"
            found[tag] = struct.unpack(order + fmt, value[: struct.calcsize(fmt)])[0]
    if set(found) != {_TIFF_WIDTH, _TIFF_HEIGHT}:
        raise ImageHeaderError(f"{path}: a TIFF without its image width and length")
    return found[_TIFF_WIDTH], found[_TIFF_HEIGHT]


_FORMATS = (
    (b"\x89PNG\r\n\x1a\n", _png),
    (b"\xff\xd8", _jpeg),
    (b"BM", _bmp),
    (b"II*\x00", _tiff),
    (b"MM\x00*", _tiff),
    *((f"P{k}".encode(), _pnm) for k in range(1, 7)),
)


def image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` in pixels from the header of a PNG, JPEG, BMP, PNM or TIFF file.

    Raises:
        ImageHeaderError: the file is unreadable, truncated, or of another format; names the file.
    """
    try:
        with open(path, "rb") as fh:
            magic = fh.read(8)
            for prefix, parse in _FORMATS:
                if magic.startswith(prefix):
                    fh.seek(0)
                    return parse(fh, path)
    except (OSError, struct.error) as err:
        raise ImageHeaderError(f"{path}: cannot read the image header ({type(err).__name__}: {err})") from err
    raise ImageHeaderError(
        f"{path} starts with {magic[:8]!r}, which is not a PNG, JPEG, BMP, PNM or TIFF image"
    )


def check_image_size(path: Path, max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int]:
    """The image's ``(width, height)`` after checking it against ``max_pixels``, before decoding.

    Raises:
        ImageTooLargeError: more than ``max_pixels`` pixels (the file and size are named).
        ImageHeaderError: see :func:`image_size`.
    """
    width, height = image_size(path)
    if width * height > max_pixels:
        raise ImageTooLargeError(
            f"{path} is {width}x{height} = {width * height} pixels, more than the {max_pixels} "
            "allowed; refused before decoding (pass max_pixels= to read a larger image you trust)"
        )
    return width, height
