"""The hand viewer's API, mounted under ``/api/hand`` (page: ``static/hand.html``).

The opened folder may be a hand capture, a folder holding a hand result (``hand.json``, what
``stillcap hand --report`` writes) or a folder of several. Routes (paths relative to the opened
folder, confined to it):

``GET  /items``                      the hand captures and results found
``POST /analyse {"path": P}``        analyse a capture in the background (a job of ``/api/jobs``),
                                     with its label overrides file when there is one
``GET  /view?path=P``                the labelled markers per flash, the skeleton per flash, the
                                     animation's joints over time and the ball with its release
``GET  /overrides?path=P``           the item's label overrides file (its entries; none yet: empty)
``PUT  /overrides {"path": P, "overrides": [...]}``
                                     replace the entries of that file (checked, written atomically)

The label overrides file is the one ``stillcap hand --overrides FILE`` reads (format
``stillcap-label-overrides``, ``docs/hand-labelling.md``): the GUI keeps it as
``label-overrides.json`` in the capture folder (for a result file: beside it), and its analysis
applies it. An entry names a point by its flash (in time order) and its position, and gives it a
marker name (``label``) or deletes it (``"delete": true``).
"""

from __future__ import annotations

import json
import math
import tempfile
import threading
from pathlib import Path

import numpy as np
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Route

from stillcap.gui.context import GuiContext
from stillcap.gui.viewers import (ApiError, api, capture_folder, confined, is_capture_of, start_capture_job, find_capture_for, frusta, json_body, query_path,
                                  read_small_json, rel_of, scan_json)

__all__ = ["routes", "OVERRIDES_FILE", "hand_view", "list_items", "overrides_path", "write_overrides"]

#: The label overrides file the GUI writes and its analysis reads, in the capture folder.
OVERRIDES_FILE = "label-overrides.json"
OVERRIDES_FORMAT = "stillcap-label-overrides"
#: Animation frames sent to the page at most (the 1000 fps animation is thinned evenly).
MAX_FRAMES = 400
#: Overrides entries accepted in one file.
MAX_OVERRIDES = 1000
#: Unlabelled points farther than this from a flash's labelled points are not shown with it, m.
FLASH_RADIUS_M = 0.15
FRUSTUM_DEPTH_M = 0.3


def _state(ctx: GuiContext) -> dict:
    return ctx.state.setdefault("hand", {"results": {}, "lock": threading.Lock()})


def _is_hand_result(d) -> bool:
    return (isinstance(d, dict) and d.get("kind") == "hand" and isinstance(d.get("flashes"), dict)
            and isinstance(d.get("marker_names"), list))


def list_items(ctx: GuiContext) -> list[dict]:
    """Hand captures (``capture.json`` of kind hand) and results (``hand.json`` files)."""
    analysed = _state(ctx)["results"]
    items = []
    for p in scan_json(Path(ctx.root)):
        if p.name == "capture.json":
            if is_capture_of(p.parent, "hand"):
                rel = rel_of(ctx, p.parent)
                items.append({"path": rel, "kind": "capture", "name": p.parent.name or rel, "analysed": rel in analysed})
        elif p.name not in ("rig.json", "truth.json", OVERRIDES_FILE):
            if _is_hand_result(read_small_json(p)):
                rel = rel_of(ctx, p)
                items.append({"path": rel, "kind": "result", "name": p.parent.name if p.name == "hand.json" else p.stem,
                              "analysed": True})
    return items


def overrides_path(ctx: GuiContext, rel: str) -> Path:
    """The label overrides file of an item: in a capture folder, or beside a result file."""
    path = confined(ctx, rel)
    if path.is_dir():
        if not is_capture_of(path, "hand"):
            raise ApiError(f"{rel or '.'}: not a hand capture folder (no capture.json of kind 'hand')")
        return path / OVERRIDES_FILE
    if path.is_file() and path.suffix.lower() == ".json":
        return path.parent / OVERRIDES_FILE
    raise FileNotFoundError(2, "no such hand capture or result", rel)


def read_overrides(path: Path) -> dict:
    """The overrides file as JSON (an empty one when there is none); checked by the hand
    pipeline's own reader (:func:`stillcap.body.hand_label.read_label_overrides`)."""
    from stillcap.body.hand_label import read_label_overrides

    if not path.is_file():
        return {"format": OVERRIDES_FORMAT, "version": 1, "overrides": []}
    read_label_overrides(path)  # a bad file is named with its entry
    return json.loads(path.read_text(encoding="utf-8"))


def _check_entry(e, k: int, marker_names) -> dict:
    where = f"overrides.{k}"
    if not isinstance(e, dict):
        raise ApiError(f"{where}: must be an object, got {type(e).__name__}")
    unknown = set(e) - {"flash", "position_m", "label", "delete", "tolerance_mm", "comment"}
    if unknown:
        raise ApiError(f"{where}: unknown keys {sorted(unknown)}")
    fl = e.get("flash")
    if not isinstance(fl, int) or isinstance(fl, bool) or fl < 0:
        raise ApiError(f"{where}.flash: must be a whole number >= 0, got {fl!r}")
    pos = e.get("position_m")
    if (not isinstance(pos, list) or len(pos) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in pos)):
        raise ApiError(f"{where}.position_m: must be three finite numbers (m), got {pos!r}")
    label, delete = e.get("label"), e.get("delete", False)
    if delete is not False and delete is not True:
        raise ApiError(f"{where}.delete: must be true or false, got {delete!r}")
    if delete == (label is not None):
        raise ApiError(f"{where}: needs either a 'label' or \"delete\": true (not both)")
    if label is not None and (marker_names is not None and label not in marker_names):
        raise ApiError(f"{where}.label: unknown marker {label!r}; markers: {', '.join(marker_names)}")
    out = {"flash": fl, "position_m": [float(v) for v in pos]}
    out.update({"label": label} if label is not None else {"delete": True})
    for key in ("tolerance_mm", "comment"):
        if key in e:
            out[key] = e[key]
    return out


def write_overrides(ctx: GuiContext, rel: str, entries, marker_names=None) -> Path:
    """Replace the overrides file's entries (each checked here and the whole file by the hand
    pipeline's reader before it replaces the old one, atomically); its path."""
    from stillcap.body.hand_label import read_label_overrides
    from stillcap.files.atomic import write_text

    if not isinstance(entries, list):
        raise ApiError(f"'overrides' must be a list of entries, got {type(entries).__name__}")
    if len(entries) > MAX_OVERRIDES:
        raise ApiError(f"{len(entries)} overrides entries: at most {MAX_OVERRIDES}")
    path = overrides_path(ctx, rel)
    old = read_small_json(path) if path.is_file() else None
    top = {"format": OVERRIDES_FORMAT, "version": 1}
    if isinstance(old, dict) and "tolerance_mm" in old:
        top["tolerance_mm"] = old["tolerance_mm"]
    top["overrides"] = [_check_entry(e, k, marker_names) for k, e in enumerate(entries)]
    text = json.dumps(top, indent=1, allow_nan=False) + "\n"
    with tempfile.TemporaryDirectory(prefix="stillcap-gui-") as tmp:  # the pipeline's reader checks it first
        probe = Path(tmp) / OVERRIDES_FILE
        probe.write_text(text, encoding="utf-8")
        try:
            read_label_overrides(probe)
        except ValueError as e:
            raise ApiError(str(e).replace(str(probe), OVERRIDES_FILE)) from None
    return write_text(path, text)


# --------------------------------------------------------------------------------------------
# views
# --------------------------------------------------------------------------------------------
def _clean(a) -> list:
    a = np.asarray(a, float)
    return np.where(np.isfinite(a), np.round(a, 6), np.nan).astype(object).tolist() if a.size else a.tolist()


def _nan_none(x):
    if isinstance(x, list):
        return [_nan_none(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def _skeleton_parents(names) -> list | None:
    from stillcap.body.hand import hand_skeleton

    sk = hand_skeleton()
    if list(sk.names) != list(names):
        return None
    return [int(p) for p in sk.parents]


def _thin(n: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, MAX_FRAMES)).round().astype(int)) if n else np.zeros(0, int)


def view_from_result(res) -> dict:
    """The view of an in-memory :class:`stillcap.pipelines.hand.HandResult` (every 3D point,
    labelled or not, with its flash)."""
    lab = res.labels
    names = list(lab.marker_names)
    pi = lab.point_index
    flashes = []
    joints = {}
    if res.sequence is not None:
        for k, p in zip(res.sequence.flashes, res.sequence.poses):
            joints[int(k)] = p.positions
    assigned = {int(p): k for k in range(lab.n_flashes) for p in lab.members[k]}
    centroids = [np.nanmean(lab.points[np.asarray(list(lab.members[k]), int)], axis=0) if len(lab.members[k])
                 else np.full(3, np.nan) for k in range(lab.n_flashes)]
    for p in lab.unassigned:  # points left over: shown with the nearest flash (to relabel them)
        d = [np.linalg.norm(lab.points[p] - c) if np.all(np.isfinite(c)) else np.inf for c in centroids]
        if d and min(d) <= FLASH_RADIUS_M:
            assigned.setdefault(int(p), int(np.argmin(d)))
    for k in range(lab.n_flashes):
        pts = []
        for p in sorted(q for q, kk in assigned.items() if kk == k):
            j = np.flatnonzero(pi[k] == p)
            pts.append({"point": p, "position": _clean(lab.points[p]), "colour": str(lab.colors[p]),
                        "label": names[int(j[0])] if len(j) else None})
        flashes.append({"flash": k, "order": int(lab.order[k]), "time_s": float(lab.times[k]),
                        "reconstructed": bool(lab.reconstructed[k]), "skipped": lab.skipped[k],
                        "rms_mm": _nan_none(float(lab.rms[k] * 1e3)), "points": pts,
                        "joints": _clean(joints[k]) if k in joints else None})
    anim = None
    if res.animation is not None:
        idx = _thin(res.animation.n_frames)
        anim = {"times_s": _clean(res.animation.times[idx]), "joints": _clean(res.animation.positions[idx])}
    view = {"marker_names": names, "marker_colours": list(lab.marker_colors), "joint_names": list(res.skeleton.names),
            "parents": [int(p) for p in res.skeleton.parents], "strobe_hz": float(res.strobe_hz),
            "flashes": flashes, "animation": anim, "messages": list(res.messages)}
    view.update(_ball(None if res.balls is None else res.balls.to_dict(),
                      None if res.release is None else res.release.to_dict()))
    return view


def view_from_dict(d: dict) -> dict:
    """The view of a ``hand.json`` result: its labelled markers (a result file does not keep
    which flash an unlabelled point belonged to, so only labelled ones are shown)."""
    names = [str(n) for n in d.get("marker_names") or []]
    cols = [str(c) for c in d.get("marker_colours") or []]
    f = d.get("flashes") or {}
    times = f.get("times_s") or []
    markers = np.asarray(f.get("markers") if f.get("markers") is not None else np.zeros((0, len(names), 3)),
                         dtype=float)
    if markers.ndim != 3 or markers.shape[0] != len(times) or markers.shape[1] != len(names):
        raise ApiError(f"hand result: flashes.markers must be (n_flashes, {len(names)}, 3), got {markers.shape}")
    joints = f.get("joints")
    joints = np.asarray(joints, float) if joints is not None else None
    flashes = []
    for k in range(len(times)):
        pts = [{"point": None, "position": _clean(markers[k, j]), "colour": cols[j] if j < len(cols) else "",
                "label": names[j]} for j in range(len(names)) if np.all(np.isfinite(markers[k, j]))]
        jk = joints[k] if joints is not None and joints.ndim == 3 and k < len(joints) else None
        flashes.append({"flash": k, "order": (f.get("order") or list(range(len(times))))[k], "time_s": times[k],
                        "reconstructed": bool((f.get("reconstructed") or [False] * len(times))[k]),
                        "skipped": (f.get("skipped") or [""] * len(times))[k], "rms_mm": (f.get("fit_rms_mm") or
                                                                                      [None] * len(times))[k],
                        "points": pts, "joints": _clean(jk) if jk is not None and np.all(np.isfinite(jk)) else None})
    view = {"marker_names": names, "marker_colours": cols, "joint_names": d.get("joint_names") or [],
            "parents": _skeleton_parents(d.get("joint_names") or []), "strobe_hz": d.get("strobe_hz"),
            "flashes": flashes, "animation": None, "messages": [str(m) for m in d.get("messages") or []]}
    view.update(_ball(d.get("ball"), d.get("release")))
    return view


def _ball(ball: dict | None, release: dict | None) -> dict:
    out = {"ball": None, "release": None}
    if isinstance(ball, dict) and ball.get("positions"):
        held = (release or {}).get("held") or []
        out["ball"] = {"times_s": ball.get("times_s") or [], "positions": _nan_none(ball.get("positions")),
                       "held": [bool(h) for h in held] if len(held) == len(ball.get("positions")) else None}
    if isinstance(release, dict):
        out["release"] = {k: release.get(k) for k in ("success", "t0_s", "t0_sigma_s", "p0", "v0", "speed_mph",
                                                      "speed_sigma_mph", "horizontal_deg", "vertical_deg",
                                                      "direction_sigma_deg", "message")}
    return out


def hand_view(ctx: GuiContext, rel: str) -> dict:
    """Everything the hand page draws for the capture or result ``rel``."""
    from stillcap.io.capture import Capture

    path = confined(ctx, rel)
    view = {"path": rel, "name": path.name, "notes": [], "cameras": []}
    cap = None
    if path.is_dir():
        if not is_capture_of(path, "hand"):
            raise ApiError(f"{rel or '.'}: not a hand capture folder (no capture.json of kind 'hand')")
        cap = Capture.load(path)
        kept = _state(ctx)["results"].get(rel_of(ctx, path))
        if kept is None:
            view.update(analysed=False, notes=["not analysed yet"])
        else:
            view.update(kept["view"], analysed=True, overrides_applied=kept["overrides"])
    elif path.is_file():
        d = read_small_json(path)
        if not _is_hand_result(d):
            raise ApiError(f"{rel}: not a hand result (a JSON object of kind 'hand' with 'flashes')")
        view.update(view_from_dict(d), analysed=True)
        folder = find_capture_for(ctx, path, None, "hand")
        if folder is not None:
            try:
                cap = Capture.load(folder)
            except ValueError as e:
                view["notes"].append(f"its capture could not be loaded: {e}")
    else:
        raise FileNotFoundError(2, "no such file or folder", rel)
    if cap is not None:
        view["cameras"] = frusta(cap.rig, FRUSTUM_DEPTH_M)
    ov = overrides_path(ctx, rel)
    view["overrides_file"] = rel_of(ctx, ov)
    return view


def analyse_capture(ctx: GuiContext, rel: str, progress=None) -> dict:
    """Analyse the hand capture ``rel`` (``stillcap hand``'s defaults, with its overrides file
    when there is one) and keep the view; a short summary."""
    from stillcap.pipelines.hand import HandOptions, analyse_hand

    folder = capture_folder(ctx, rel, "hand")
    ov = folder / OVERRIDES_FILE
    res = analyse_hand(folder, HandOptions(overrides=ov if ov.is_file() else None), progress=progress)
    view = view_from_result(res)
    st = _state(ctx)
    with st["lock"]:
        st["results"][rel_of(ctx, folder)] = {"view": view, "overrides": ov.is_file()}
    return {"path": rel_of(ctx, folder), "flashes": len(view["flashes"]),
            "labelled": int(sum(1 for f in view["flashes"] for p in f["points"] if p["label"]))}


def routes(ctx: GuiContext) -> list:
    """The hand viewer's routes (mounted under ``/api/hand``)."""

    @api
    async def items(request: Request):
        return JSONResponse({"root": Path(ctx.root).name, "items": list_items(ctx)})

    @api
    async def view(request: Request):
        rel, _ = query_path(ctx, request, required=False)
        return JSONResponse(hand_view(ctx, rel))

    @api
    async def analyse(request: Request):
        return await start_capture_job(ctx, request, "hand", analyse_capture)

    @api
    async def get_overrides(request: Request):
        rel, _ = query_path(ctx, request, required=False)
        path = overrides_path(ctx, rel)
        return JSONResponse({"file": rel_of(ctx, path), "exists": path.is_file(), **read_overrides(path)})

    @api
    async def put_overrides(request: Request):
        from stillcap.body.hand import hand_markerset

        body = await json_body(request)
        rel = body.get("path", "")
        if not isinstance(rel, str):
            raise ApiError(f"'path' must be a string, got {rel!r}")
        path = write_overrides(ctx, rel, body.get("overrides"), list(hand_markerset().names))
        return JSONResponse({"file": rel_of(ctx, path), "exists": True, **read_overrides(path)})

    return [Route("/items", items, methods=["GET"]), Route("/view", view, methods=["GET"]),
            Route("/analyse", analyse, methods=["POST"]), Route("/overrides", get_overrides, methods=["GET"]),
            Route("/overrides", put_overrides, methods=["PUT"])]
