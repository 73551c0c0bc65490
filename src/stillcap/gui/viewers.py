"""What the pitch and hand viewers share: finding results and captures in the opened folder,
serving its photos (decoded safely, shrunk, as JPEG), the cameras' frusta, and errors as JSON.

Every path a request names is relative to the opened folder and goes through
:meth:`stillcap.gui.context.GuiContext.resolve` (refused when it leaves the folder); a bad
request gets status 400 with one line ``{"error": "..."}``, a missing file 404.
"""

from __future__ import annotations

import functools
import json
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np
from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from stillcap.gui.context import GuiContext

__all__ = ["ApiError", "api", "query_path", "json_body", "rel_of", "scan_json", "read_small_json",
           "photo_response", "frusta", "find_capture_for", "is_capture_of", "capture_folder",
           "start_capture_job"]

#: Folders deeper than this below the opened folder are not searched for captures and results.
MAX_DEPTH = 3
#: JSON files larger than this are not opened as results (a result is tens of kB).
MAX_JSON_BYTES = 50 * 1024 * 1024
#: Files a folder scan looks at, at most (a session of captures has a few hundred).
MAX_SCAN = 5000
#: Photo extensions the viewers serve (the capture folder's formats).
PHOTO_EXTENSIONS = (".png", ".jpg", ".jpeg")
#: Largest photo width asked for (a request for more gets this; the studio's photos are 2560 px).
MAX_PHOTO_WIDTH = 8192


class ApiError(Exception):
    """A request the viewer refuses: its HTTP status and one line for the page."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def api(fn):
    """Wrap a route: ``ValueError`` and :class:`ApiError` become ``{"error": line}`` with 400 (or
    the error's status), a missing file 404; anything else is a bug and propagates (500)."""

    @functools.wraps(fn)
    async def route(request: Request):
        try:
            return await fn(request)
        except ApiError as e:
            return JSONResponse({"error": str(e)}, status_code=e.status)
        except FileNotFoundError as e:
            name = e.filename if e.filename is not None else str(e)
            return JSONResponse({"error": f"no such file: {name}"}, status_code=404)
        except ValueError as e:
            return JSONResponse({"error": str(e)}, status_code=400)

    return route


def query_path(ctx: GuiContext, request: Request, key: str = "path", *, required: bool = True,
               default: str = "") -> tuple[str, Path]:
    """The query parameter ``key`` as ``(relative path, confined absolute path)``."""
    rel = request.query_params.get(key)
    if rel is None:
        if required:
            raise ApiError(f"query parameter {key!r} is missing (a path relative to the opened folder)")
        rel = default
    return rel, confined(ctx, rel)


def confined(ctx: GuiContext, rel: str) -> Path:
    """``ctx.resolve(rel)``; ``""`` and ``"."`` are the opened folder itself."""
    if not isinstance(rel, str):
        raise ApiError(f"a path must be a string, got {rel!r}")
    if rel in ("", "."):
        return Path(ctx.root)
    return ctx.resolve(rel)


async def json_body(request: Request, max_bytes: int = 1024 * 1024) -> dict:
    """The request's JSON object (refused when larger than ``max_bytes`` or not an object)."""
    body = await request.body()
    if len(body) > max_bytes:
        raise ApiError(f"request body of {len(body)} bytes is larger than {max_bytes}", 413)
    try:
        data = json.loads(body or b"{}")
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ApiError(f"request body is not JSON: {e}") from None
    if not isinstance(data, dict):
        raise ApiError(f"request body must be a JSON object, got {type(data).__name__}")
    return data


def rel_of(ctx: GuiContext, path: Path) -> str:
    """``path`` relative to the opened folder, POSIX separators (``""`` for the folder)."""
    rel = Path(path).resolve().relative_to(Path(ctx.root).resolve()).as_posix()
    return "" if rel == "." else rel


def read_small_json(path: Path):
    """A JSON file's content, or None when it is too large, unreadable or not JSON."""
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            return None
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None


def is_capture_of(folder: Path, kind: str) -> bool:
    """``folder`` holds a ``capture.json`` of ``kind`` (peeked at; the pipeline validates it)."""
    d = read_small_json(folder / "capture.json") if (folder / "capture.json").is_file() else None
    return isinstance(d, dict) and d.get("kind") == kind


def capture_folder(ctx: GuiContext, rel: str, kind: str) -> Path:
    """The capture folder ``rel`` (confined), or ``ValueError`` (400) when it is not one of ``kind``."""
    folder = confined(ctx, rel)
    if not folder.is_dir() or not is_capture_of(folder, kind):
        raise ValueError(f"{rel or '.'}: not a {kind} capture folder (no capture.json of kind '{kind}')")
    return folder


async def start_capture_job(ctx: GuiContext, request: Request, kind: str, analyse) -> Response:
    """``POST {"path": REL}``: analyse the ``kind`` capture ``REL`` in the background
    (``analyse(ctx, rel, progress)``); the job's JSON."""
    from stillcap.gui.jobs import job_manager, job_response

    rel = (await json_body(request)).get("path", "")
    capture_folder(ctx, rel, kind)  # refused before a job starts
    job = job_manager(ctx).submit(lambda progress: analyse(ctx, rel, progress),
                                  label=f"{kind} {rel or Path(ctx.root).name}")
    return job_response(job)


def scan_json(root: Path, max_depth: int = MAX_DEPTH):
    """``*.json`` files under ``root`` (at most ``max_depth`` folders down, symlinks not followed,
    hidden folders skipped), sorted by path."""
    root = Path(root)
    out, seen = [], 0
    stack = [(root, 0)]
    while stack:
        folder, depth = stack.pop()
        try:
            entries = sorted(folder.iterdir())
        except OSError:
            continue
        for p in entries:
            seen += 1
            if seen > MAX_SCAN:
                return sorted(out)
            if p.name.startswith(".") or p.is_symlink():
                continue
            if p.is_dir():
                if depth < max_depth:
                    stack.append((p, depth + 1))
            elif p.suffix.lower() == ".json":
                out.append(p)
    return sorted(out)


# --------------------------------------------------------------------------------------------
# photos
# --------------------------------------------------------------------------------------------
class _PhotoCache:
    """The last few encoded photos (decoding a 2560 px PNG takes a few tenths of a second)."""

    def __init__(self, size: int = 24):
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        self._size = size

    def get(self, key):
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        return None

    def put(self, key, value):
        with self._lock:
            self._items[key] = value
            while len(self._items) > self._size:
                self._items.popitem(last=False)


def photo_response(ctx: GuiContext, rel: str, width: int | None) -> Response:
    """A photo of the opened folder as JPEG, at most ``width`` px wide (its own size when None).

    The file is checked (extension, header, size) and decoded by :func:`stillcap.files.images.read_image`
    before anything is sent, so only pixels the server decoded itself reach the page."""
    import cv2

    from stillcap.files.images import read_image

    path = confined(ctx, rel)
    if path.suffix.lower() not in PHOTO_EXTENSIONS:
        raise ApiError(f"{rel}: not a photo (the viewers serve {', '.join(PHOTO_EXTENSIONS)})")
    if not path.is_file():
        raise FileNotFoundError(2, "no such photo", rel)
    if width is not None and not 16 <= width <= MAX_PHOTO_WIDTH:
        raise ApiError(f"width must be from 16 to {MAX_PHOTO_WIDTH} px, got {width}")
    st = path.stat()
    cache = ctx.state.setdefault("viewer_photos", _PhotoCache())
    key = (str(path), st.st_mtime_ns, st.st_size, width)
    data = cache.get(key)
    if data is None:
        img = read_image(path)
        h, w = img.shape[:2]
        if width is not None and width < w:
            img = cv2.resize(img, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        if not ok:
            raise ApiError(f"{rel}: could not encode the photo as JPEG", 500)
        data = buf.tobytes()
        cache.put(key, data)
    return Response(data, media_type="image/jpeg", headers={"Cache-Control": "private, max-age=60"})


def photo_width(request: Request) -> int | None:
    """The ``w`` query parameter (a positive whole number of pixels), None when absent."""
    w = request.query_params.get("w")
    if w is None:
        return None
    try:
        return int(w)
    except ValueError:
        raise ApiError(f"w must be a whole number of pixels, got {w!r}") from None


# --------------------------------------------------------------------------------------------
# cameras
# --------------------------------------------------------------------------------------------
def frusta(rig, depth_m: float) -> list[dict]:
    """Each camera as the 3D view draws it: its centre and the four image corners' rays at
    ``depth_m`` along the optical axis (world frame, m), in the rig's order."""
    out = []
    for cam in rig:
        w, h = cam.image_size
        corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
        origins, dirs = cam.rays(corners)
        axis = cam.R[2]  # the optical axis in the world frame
        scale = depth_m / np.maximum(dirs @ axis, 1e-6)
        pts = origins + dirs * scale[:, None]
        out.append({"name": cam.name, "center": cam.center.tolist(), "corners": pts.tolist(),
                    "image_size": [int(w), int(h)]})
    return out


def find_capture_for(ctx: GuiContext, result_path: Path, recorded: str | None, kind: str) -> Path | None:
    """The capture folder of a result file, inside the opened folder: the one the result names
    when it lies inside, else the result's own folder or its parent when it holds a
    ``capture.json`` of ``kind``, else a folder of the recorded name next to the result's folder.
    None when there is none (the viewer then shows the result without photos and cameras)."""
    root = Path(ctx.root).resolve()
    cands = []
    if recorded:
        rec = Path(recorded)
        if rec.is_absolute():
            cands.append(rec)
        else:
            cands += [result_path.parent / rec, root / rec]
    cands += [result_path.parent, result_path.parent.parent]
    if recorded:
        cands += [result_path.parent.parent / Path(recorded).name, root / Path(recorded).name]
    for c in cands:
        try:
            c = c.resolve()
        except OSError:
            continue
        if not c.is_relative_to(root):
            continue
        d = read_small_json(c / "capture.json") if (c / "capture.json").is_file() else None
        if isinstance(d, dict) and d.get("kind") == kind:
            return c
    return None
