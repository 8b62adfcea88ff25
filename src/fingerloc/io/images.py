"""Image files (JPEG, PNG, ... through Pillow) with a bound on their size in pixels, read as they are meant.

A small compressed file can declare a huge image (a 20 KB PNG of
13000 x 13000 pixels decodes to 500 MB of RGB). :func:`open_image` reads the
header first and refuses an image above ``max_pixels`` before decoding it;
the caller (``fingerloc features --max-pixels``) may raise the bound, and
:func:`check_pixels` bounds the arrays a pipeline derives from an image too.

What an image means, not only its bytes:

* a 16-bit (or 32-bit, or float) grey image is scaled to 8 bits (its
  full range), not clipped (Pillow's conversion makes every value above
  255 white);
* the EXIF orientation tag is applied (a phone's portrait photo is upright);
* truncated data is refused: Pillow refuses a file that ends early, but
  decodes a PNG whose compressed data holds fewer rows than its header says
  (zeros) and a JPEG whose data was cut before its end marker (a band of
  libjpeg's mid-grey fill) without a word; both are checked here.
"""

from __future__ import annotations

import struct
import threading
import warnings
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataFormatError, InvalidParameterError

__all__ = ["DEFAULT_MAX_PIXELS", "check_pixels", "open_image"]

#: Default bound on width x height: 64 Mpx (a 11,300 x 5,650 panorama; 192 MB as RGB).
DEFAULT_MAX_PIXELS = 64_000_000

_pillow_limit = threading.Lock()


def open_image(path: str | Path, *, max_pixels: int = DEFAULT_MAX_PIXELS) -> np.ndarray:
    """Read an image file as an ``(h, w, 3)`` ``uint8`` RGB array, at most ``max_pixels`` pixels.

    Parameters
    ----------
    path : str or Path
    max_pixels : int
        Largest width x height accepted; checked on the header, before decoding.

    Raises
    ------
    DataFormatError
        Naming the path: missing, not an image, corrupt, or larger than ``max_pixels``.
    InvalidParameterError
        When ``max_pixels`` is not a positive integer.
    """
    from PIL import Image, UnidentifiedImageError

    if isinstance(max_pixels, bool) or not isinstance(max_pixels, (int, np.integer)) or max_pixels < 1:
        raise InvalidParameterError(f"max_pixels must be a positive integer, got {max_pixels!r}")
    p = Path(path)
    try:
        # Pillow's own bomb check is global state: ours replaces it for this call only.
        with _pillow_limit:
            saved = Image.MAX_IMAGE_PIXELS
            Image.MAX_IMAGE_PIXELS = None
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                    im = Image.open(p)
            finally:
                Image.MAX_IMAGE_PIXELS = saved
        with im:
            w, h = im.size
            if w * h > max_pixels:
                raise DataFormatError(
                    f"image of {w}x{h} = {w * h:,} pixels, above the limit of {int(max_pixels):,} "
                    "(raise it with --max-pixels)",
                    path=p,
                )
            im.load()
            if im.format == "PNG" and not getattr(im, "is_animated", False):
                _check_png_data(p, im)
            from PIL import ImageOps

            if im.format == "JPEG" and im.mode in ("L", "RGB"):
                _check_jpeg_fill(p, np.asarray(im).reshape(im.size[1], im.size[0], -1))  # as stored: cut at the bottom
            upright = ImageOps.exif_transpose(im) or im
            rgb = _to_rgb(upright)
    except DataFormatError:
        raise
    except FileNotFoundError as err:
        raise DataFormatError("no such file", path=p) from err
    except IsADirectoryError as err:
        raise DataFormatError("is a directory, not an image", path=p) from err
    except UnidentifiedImageError as err:
        raise DataFormatError("not an image file Pillow can read (JPEG, PNG, ...)", path=p) from err
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as err:
        raise DataFormatError(f"cannot read image: {err}", path=p) from err
    return rgb


def check_pixels(width: int, height: int, max_pixels: int, what: str, path: str | Path | None = None) -> None:
    """Refuse an array of ``width x height`` pixels above ``max_pixels`` (one line naming ``what``).

    Raises
    ------
    DataFormatError
        ``what`` would be larger than the bound.
    """
    if width * height > max_pixels:
        raise DataFormatError(
            f"{what} would be {width}x{height} = {width * height:,} pixels, above the limit of {int(max_pixels):,} "
            "(an image far taller than wide is not a panorama; raise the limit with --max-pixels)",
            path=path,
        )


#: Pillow modes of grey images with more than 8 bits, and the top of their range.
_WIDE_GREY = {"I;16": 65535.0, "I;16L": 65535.0, "I;16B": 65535.0, "I;16N": 65535.0}


def _to_rgb(im: Any) -> np.ndarray:
    """An ``(h, w, 3)`` uint8 RGB array: 16/32-bit and float grey scaled over their range, not clipped."""
    mode = im.mode
    if mode in _WIDE_GREY or mode in ("I", "F"):
        a = np.asarray(im, dtype=np.float64)
        if mode in _WIDE_GREY:
            top = _WIDE_GREY[mode]
        elif mode == "F" and a.size and np.nanmax(a) <= 1.0 and np.nanmin(a) >= 0.0:
            top = 1.0
        else:
            finite = a[np.isfinite(a)]
            lo = float(finite.min()) if finite.size else 0.0
            if lo < 0:
                a = a - lo
            hi = float(finite.max() - min(lo, 0.0)) if finite.size else 1.0
            top = hi if hi > 255.0 or mode == "F" else 255.0
            top = top if top > 0 else 1.0
        g = np.clip(np.rint(np.nan_to_num(a, nan=0.0) * (255.0 / top)), 0, 255).astype(np.uint8)
        return np.repeat(g[:, :, None], 3, axis=2)
    return np.asarray(im.convert("RGB"), dtype=np.uint8)


_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}


def _check_png_data(path: Path, im: Any) -> None:
    """A PNG's compressed data must inflate to every row its header promises (Pillow fills missing rows with 0)."""
    try:
        data = path.read_bytes()
    except OSError:
        return
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        return
    at, idat, ihdr = 8, [], None
    while at + 8 <= len(data):
        (n,) = struct.unpack(">I", data[at : at + 4])
        kind = data[at + 4 : at + 8]
        body = data[at + 8 : at + 8 + n]
        if kind == b"IHDR":
            ihdr = body
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        at += 12 + n
    if ihdr is None or len(ihdr) < 13:
        return
    w, h, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", ihdr[:13])
    bits = _PNG_CHANNELS.get(colour, 0) * depth
    if not bits:
        return

    def row(width: int) -> int:
        return (width * bits + 7) // 8

    if interlace:
        need = 0
        for x0, y0, dx, dy in _ADAM7:
            pw, ph = (w - x0 + dx - 1) // dx if w > x0 else 0, (h - y0 + dy - 1) // dy if h > y0 else 0
            need += ph * (1 + row(pw)) if pw and ph else 0
    else:
        need = h * (1 + row(w))
    got = 0
    d = zlib.decompressobj()
    try:
        for piece in idat:
            chunk = d.decompress(piece, 1 << 20)
            got += len(chunk)
            while d.unconsumed_tail and got < need:
                chunk = d.decompress(d.unconsumed_tail, 1 << 20)
                got += len(chunk)
            if got >= need:
                break
        if got < need:
            got += len(d.flush())
    except zlib.error as err:
        raise DataFormatError(f"corrupt PNG data ({err})", path=path) from None
    if got < need:
        raise DataFormatError(
            f"truncated image: its PNG data holds {got:,} of the {need:,} bytes its {w}x{h} header needs "
            "(the rest would be black)",
            path=path,
        )


#: libjpeg's fill for the blocks of a JPEG whose data ends before its end marker: every channel 128.
_JPEG_FILL = 128
#: Rows of that fill at the bottom that mark a cut JPEG (two rows of 8x8 blocks at least... and a whole band).
_JPEG_FILL_ROWS = 16


def _check_jpeg_fill(path: Path, rgb: np.ndarray) -> None:
    """A JPEG cut before its end marker decodes with its missing rows in libjpeg's flat mid-grey: refuse it."""
    h = rgb.shape[0]
    if h < 2 * _JPEG_FILL_ROWS:
        return
    if not np.all(rgb[-_JPEG_FILL_ROWS:] == _JPEG_FILL):
        return
    rows = int(np.argmin(np.all(rgb[::-1] == _JPEG_FILL, axis=(1, 2))))  # flat rows counted from the bottom
    if rows == 0:  # the whole image is the fill
        rows = h
    raise DataFormatError(
        f"truncated image: its last {rows} of {h} rows are libjpeg's flat grey fill (the JPEG data ends early)",
        path=path,
    )
