"""Uploaded files: read within the application's size limit, images decoded safely.

The body size is already capped by the application's guard (:mod:`stillcap.gui.app`); here each
uploaded image is checked from its bytes (format, the size its header claims, completeness) and
decoded by :func:`stillcap.files.images.decode_image` before anything else sees it.
"""

from __future__ import annotations

import numpy as np
from starlette.requests import Request

from stillcap.files.images import check_image_bytes, decode_image

__all__ = ["uploaded_file", "uploaded_image"]


async def uploaded_file(request: Request, field: str = "file") -> tuple[str, bytes]:
    """``(filename, content)`` of the multipart field ``field``; ``ValueError`` when it is missing."""
    form = await request.form(max_files=1, max_fields=20)
    try:
        item = form.get(field)
        if item is None or isinstance(item, str):
            raise ValueError(f"the upload has no file in its field {field!r}")
        data = await item.read()
        return item.filename or "upload", data
    finally:
        await form.close()


async def uploaded_image(request: Request, field: str = "file") -> tuple[str, bytes, np.ndarray]:
    """``(filename, content, BGR image)`` of an uploaded photo, checked then decoded."""
    name, data = await uploaded_file(request, field)
    check_image_bytes(data, f"upload {name!r}")
    return name, data, decode_image(data, f"upload {name!r}")
