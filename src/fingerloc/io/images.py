"""Image files (JPEG, PNG, ... through Pillow) with a bound on their size in pixels.

A small compressed file can declare a huge image (a 20 KB PNG of
13000 x 13000 pixels decodes to 500 MB of RGB). :func:`open_image` reads the
header first and refuses an image above ``max_pixels`` before decoding it;
the caller (``fingerloc features --max-pixels``) may raise the bound.
"""

from __future__ import annotations

import threading
import warnings
from pathlib import Path

import numpy as np

from ..errors import DataFormatError, InvalidParameterError

__all__ = ["DEFAULT_MAX_PIXELS", "open_image"]

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
            rgb = im.convert("RGB")
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
    return np.asarray(rgb, dtype=np.uint8)
