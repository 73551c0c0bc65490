"""Reading photos: the one reader of every image file stillcap decodes.

Before anything is decoded, the file is checked from its bytes: its format and the size its
header claims (refused above :data:`MAX_PIXELS`, so that a PNG claiming 60000x60000 never
reaches OpenCV), and that it is complete (a PNG has intact chunks up to ``IEND``, a JPEG has its
end-of-image marker after the image data). Decoding stays with OpenCV (``cv2.imdecode``: the same
pixels as ``cv2.imread``), so a truncated JPEG can no longer give half a photo with only a
warning from libjpeg. Every problem is a ``ValueError`` in one line naming the file.

Why PNG and JPEG are walked here rather than opened with Pillow: Pillow's lazy ``Image.open``
gives the size, but warns on stderr above 89 Mpx and refuses above 179 Mpx before saying the
size, and it says nothing about a file cut short. The structure of the two formats stillcap
writes (sizes in ``IHDR`` / ``SOFn``, chunk CRCs, end markers) is a few lines, costs about 1% of
the decoding time, and the same pass gives all three answers. Other formats (BMP, TIFF, WebP,
...) are opened and verified with Pillow.
"""

from __future__ import annotations

import io
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = ["MAX_PIXELS", "ImageHeader", "check_image_bytes", "check_image_file", "decode_image", "read_image"]

#: Largest image accepted, in pixels (width x height): 100 megapixels.
MAX_PIXELS = 100_000_000

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (SOF0..SOF15 without DHT C4, JPG C8 and DAC CC): they hold the size
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


@dataclass(frozen=True)
class ImageHeader:
    """What an image file's header says: its format (``"PNG"``, ``"JPEG"``, or Pillow's name of
    another format) and its size in pixels."""

    format: str
    width: int
    height: int


def _png(data: memoryview) -> tuple[int, int, str | None]:
    """``(width, height, problem)`` of a PNG: chunks walked up to ``IEND``, CRCs checked."""
    n = len(data)
    if n < 33 or bytes(data[12:16]) != b"IHDR":
        return 0, 0, "is cut short or corrupt (no PNG header chunk IHDR)"
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    i = 8
    while i + 12 <= n:
        length = int.from_bytes(data[i:i + 4], "big")
        kind = bytes(data[i + 4:i + 8])
        end = i + 12 + length
        if end > n:
            return w, h, f"is truncated (PNG chunk {kind.decode('latin-1')!r} runs past the end of the file)"
        if zlib.crc32(data[i + 4:end - 4]) != int.from_bytes(data[end - 4:end], "big"):
            return w, h, f"is corrupt (PNG chunk {kind.decode('latin-1')!r} fails its CRC check)"
        if kind == b"IEND":
            return w, h, None
        i = end
    return w, h, "is truncated (no PNG end chunk IEND)"


def _jpeg(data: bytes) -> tuple[int, int, str | None]:
    """``(width, height, problem)`` of a JPEG: marker segments walked to the first scan (the frame
    size on the way), then an end-of-image marker must follow the scan data."""
    w, h, problem, scan = _jpeg_frame(data)
    if problem is None and data.rfind(b"\xff\xd9", scan) < 0:  # rfind: same test, found at the end in microseconds
        problem = "is truncated (no JPEG end-of-image marker)"
    return w, h, problem


def _jpeg_frame(data: bytes) -> tuple[int, int, str | None, int]:
    """``(width, height, problem, scan)`` of a JPEG's marker segments up to its first scan
    (:func:`_jpeg` without the end-of-image test): ``scan`` is where the scan data starts (the
    end-of-image marker must follow it)."""
    n, i, w, h = len(data), 2, 0, 0
    while True:
        if i + 4 > n:
            return w, h, "is truncated (the JPEG ends before its image data)", n
        if data[i] != 0xFF:
            return w, h, "is corrupt (bad JPEG marker structure)", n
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # markers without a length
            i += 2
            continue
        if marker == 0xD9:
            return w, h, "is corrupt (the JPEG ends before its image data)", n
        length = int.from_bytes(data[i + 2:i + 4], "big")
        if marker in _SOF and i + 9 <= n:
            h, w = int.from_bytes(data[i + 5:i + 7], "big"), int.from_bytes(data[i + 7:i + 9], "big")
        if marker == 0xDA:  # start of scan: the entropy-coded data follows; 0xFFD9 cannot occur in it
            break
        i += 2 + length
    if w == 0 or h == 0:
        return w, h, "is corrupt (no JPEG frame header before the image data)", n
    return w, h, None, i + 2 + length


def _other(data: bytes) -> tuple[str, int, int, str | None]:
    """``(format, width, height, problem)`` of another format, from Pillow."""
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # DecompressionBombWarning, "Truncated File Read", ...
            im = Image.open(io.BytesIO(data))
            fmt, (w, h) = im.format or "image", im.size
            if w * h <= MAX_PIXELS:
                im.verify()
    except Image.DecompressionBombError:
        return "image", 0, 0, f"claims more than {MAX_PIXELS / 1e6:g} megapixels"
    except UnidentifiedImageError:
        return "", 0, 0, "is not an image (neither PNG nor JPEG, nor a format Pillow knows)"
    except Exception as e:  # Pillow's verify raises whatever the plugin meets (SyntaxError, OSError, ...)
        return "image", 0, 0, f"is corrupt or truncated ({e})"
    return fmt, w, h, None


def check_image_bytes(data: bytes, name) -> ImageHeader:
    """The header of an image file's content ``data``, after checking it can be decoded safely.

    Parameters
    ----------
    data : bytes
        The whole file.
    name : str or Path
        The file, for messages.

    Raises
    ------
    ValueError
        ``image file NAME ...``: empty, not an image, truncated or corrupt (PNG chunk CRCs and
        ``IEND``, JPEG end marker), no size, or more than :data:`MAX_PIXELS` pixels.
    """
    view = memoryview(data)
    if not len(data):
        raise ValueError(f"image file {name} is empty")
    if bytes(view[:8]) == _PNG_SIGNATURE:
        fmt, (w, h, problem) = "PNG", _png(view)
    elif bytes(view[:3]) == b"\xff\xd8\xff":
        fmt, (w, h, problem) = "JPEG", _jpeg(bytes(data))
    else:
        fmt, w, h, problem = _other(data)
    if w * h > MAX_PIXELS:
        raise ValueError(f"image file {name}: its header claims {w}x{h} px ({w * h / 1e6:.0f} megapixels), "
                         f"more than the {MAX_PIXELS / 1e6:g} megapixels stillcap decodes")
    if problem is None and (w == 0 or h == 0):
        problem = f"is corrupt (its header claims {w}x{h} px)"
    if problem is not None:
        raise ValueError(f"image file {name} {problem}")
    return ImageHeader(fmt, w, h)


def _read_bytes(path: Path) -> bytes:
    if path.is_dir():
        raise ValueError(f"{path} is a folder, not an image file")
    if not path.is_file():
        raise ValueError(f"image file {path} does not exist")
    try:
        return path.read_bytes()
    except OSError as e:
        raise ValueError(f"image file {path} cannot be read: {e.strerror or e}") from None


#: :func:`check_image_file` reads a JPEG's first this many bytes (its marker segments up to the
#: scan: ~0.6 KB in stillcap's own, up to ~64 KB of EXIF with a thumbnail in a camera's) and its
#: last :data:`_TAIL_BYTES` (the end-of-image marker), not the whole file.
_HEAD_BYTES = 1 << 16
_TAIL_BYTES = 1 << 12


def check_image_file(path) -> ImageHeader:
    """:func:`check_image_bytes` of a file (without decoding it); ``ValueError`` naming the file,
    also when it does not exist or cannot be read.

    A JPEG whose marker segments up to the scan lie within its first :data:`_HEAD_BYTES` and
    whose end-of-image marker lies within its last :data:`_TAIL_BYTES` after the scan's start is
    read only there (the same header and the same verdict: every other file, and every problem,
    goes through the whole file's check). Loading a capture checks every photo before the
    pipeline decodes it, which reads the file again: the whole file read twice cost ~0.05 ms
    per 78 KB puppet photo and ~1 ms per 2560x1920 pitch photo."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(_HEAD_BYTES)
            size = f.seek(0, 2)
            if len(head) < size and head[:3] == b"\xff\xd8\xff":
                w, h, problem, scan = _jpeg_frame(head)
                if problem is None and 0 < w * h <= MAX_PIXELS:
                    start = max(scan, size - _TAIL_BYTES)
                    f.seek(start)
                    if f.read(size - start).rfind(b"\xff\xd9") >= 0:
                        return ImageHeader("JPEG", w, h)
    except OSError:
        pass  # _read_bytes names the problem
    return check_image_bytes(_read_bytes(path), path)


def decode_image(data: bytes, name, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """Check (:func:`check_image_bytes`), then decode an image file's content with OpenCV."""
    check_image_bytes(data, name)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if img is None:
        raise ValueError(f"image file {name} could not be decoded (not an image OpenCV reads, or corrupt)")
    return img


def read_image(path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """Decode an image file with OpenCV (BGR uint8 by default; ``flags`` as ``cv2.imread``'s) after
    checking its header's size and that it is complete; ``ValueError`` naming the file."""
    path = Path(path)
    return decode_image(_read_bytes(path), path, flags)
