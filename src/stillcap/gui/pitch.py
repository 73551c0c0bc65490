"""The pitch viewer's API, mounted under ``/api/pitch`` (page: ``static/pitch.html``).

The opened folder may be a pitch capture, a folder holding a result (``pitch.json``, what
``stillcap pitch --report`` writes), or a session folder of several of them. Routes (every path
relative to the opened folder, confined to it):

``GET  /items``                 the pitch captures and results found (three folders deep at most)
``GET  /view?path=P``            everything the page draws for one capture or result (below)
``POST /analyse {"path": P}``    analyse a capture in the background (a job of ``/api/jobs``)
``GET  /photo?path=F&w=W``       a photo of the folder as JPEG, at most ``W`` px wide
``GET  /session?path=D``         the pitches under folder ``D`` compared: metrics rows, flights
``POST /session/analyse``        analyse every capture under a folder not analysed yet (one job)

A view holds: the metrics with their 1-sigma and units, the self-checks (``self_checks`` of the
result, shown when present), the messages, per stereo pair the measured positions with their
error ellipsoids (1-sigma axes from the result's position covariances), the reference trajectory
sampled from the fitted flight (release to the front of the plate, the result's flight model),
the spin axis at release, the plate crossing and movement, the cameras as frusta (from the
capture's rig), and per photo the detected balls (pixel centre and radius), their flash numbers
and, for a capture analysed here, the painted markers found (a result file does not keep them).
"""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Route

from stillcap.gui.context import GuiContext
from stillcap.gui.viewers import (ApiError, api, capture_folder, confined, is_capture_of, start_capture_job, find_capture_for, frusta, json_body, photo_response,
                                  photo_width, query_path, read_small_json, rel_of, scan_json)

__all__ = ["routes", "RESULT_FORMAT", "pitch_view", "session_rows", "list_items"]

RESULT_FORMAT = "stillcap-pitch"
#: The metrics the session table compares (key, label).
SESSION_METRICS = (("release_speed_mph", "release mph"), ("spin_rate_rpm", "spin rpm"),
                   ("spin_efficiency", "efficiency"), ("induced_vertical_break_in", "IVB in"),
                   ("horizontal_break_in", "HB in"), ("plate_x_ft", "plate x ft"), ("plate_z_ft", "plate z ft"),
                   ("vertical_approach_angle_deg", "VAA deg"))
#: Half the plate's width (17 in) and the strike zone's usual bottom and top (ft): the zone is the
#: batter's, so the page labels these as a typical zone.
PLATE_HALF_WIDTH_FT = 17 / 24
ZONE_BOTTOM_FT, ZONE_TOP_FT = 1.5, 3.5
#: Samples of the reference trajectory in a view.
TRAJECTORY_SAMPLES = 160
#: How far in front of each camera its frustum is drawn, m.
FRUSTUM_DEPTH_M = 0.6


def _state(ctx: GuiContext) -> dict:
    st = ctx.state.setdefault("pitch", {"results": {}, "lock": threading.Lock()})
    return st


# --------------------------------------------------------------------------------------------
# finding captures and results
# --------------------------------------------------------------------------------------------
def list_items(ctx: GuiContext, under: Path | None = None) -> list[dict]:
    """The pitch captures (folders with a ``capture.json`` of kind pitch) and results (JSON
    files of format ``stillcap-pitch``) under ``under`` (default: the opened folder)."""
    under = Path(ctx.root) if under is None else under
    analysed = _state(ctx)["results"]
    items = []
    for p in scan_json(under):
        if p.name == "capture.json":
            if is_capture_of(p.parent, "pitch"):
                rel = rel_of(ctx, p.parent)
                items.append({"path": rel, "kind": "capture", "name": p.parent.name or rel,
                              "analysed": rel in analysed})
        elif p.name not in ("rig.json", "truth.json"):
            d = read_small_json(p)
            if isinstance(d, dict) and d.get("format") == RESULT_FORMAT:
                rel = rel_of(ctx, p)
                name = p.parent.name if p.name == "pitch.json" and p.parent != Path(ctx.root) else p.stem
                items.append({"path": rel, "kind": "result", "name": name or rel, "analysed": True})
    return items


def _load(ctx: GuiContext, rel: str) -> tuple[dict | None, object, dict | None, str]:
    """``(result dict or None, Capture or None, markers overlay or None, note)`` of an item."""
    from stillcap.io.capture import Capture

    path = confined(ctx, rel)
    if path.is_dir():
        if not is_capture_of(path, "pitch"):
            raise ApiError(f"{rel or '.'}: not a pitch capture folder (no capture.json of kind 'pitch')")
        cap = Capture.load(path)
        kept = _state(ctx)["results"].get(rel_of(ctx, path))
        if kept is None:
            return None, cap, None, "not analysed yet"
        return kept["result"], cap, kept["markers"], ""
    if not path.is_file():
        raise FileNotFoundError(2, "no such file or folder", rel)
    d = read_small_json(path)
    if not isinstance(d, dict) or d.get("format") != RESULT_FORMAT:
        raise ApiError(f"{rel}: not a pitch result (a JSON object of format {RESULT_FORMAT!r})")
    if not isinstance(d.get("pairs"), list) or not isinstance(d.get("metrics"), dict):
        raise ApiError(f"{rel}: pitch result without 'pairs' or 'metrics'")
    folder = find_capture_for(ctx, path, d.get("capture") if isinstance(d.get("capture"), str) else None, "pitch")
    if folder is None:
        return d, None, None, "the capture of this result is not inside the opened folder: no photos or cameras"
    try:
        return d, Capture.load(folder), None, ""
    except ValueError as e:
        return d, None, None, f"its capture could not be loaded: {e}"


# --------------------------------------------------------------------------------------------
# the view
# --------------------------------------------------------------------------------------------
def _num(v):
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def _vec(v, n=3):
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        return None
    return a.tolist() if a.shape == (n,) and np.all(np.isfinite(a)) else None


def _metrics_rows(d: dict) -> list[dict]:
    from stillcap.report.pitch import metric_unit

    m, s = d.get("metrics") or {}, d.get("metrics_sigma") or {}
    rows = []
    for k, v in m.items():
        if k in ("nine_parameter", "success", "message"):
            continue
        rows.append({"key": k, "value": v if isinstance(v, str) else _num(v), "sigma": _num(s.get(k)),
                     "unit": metric_unit(k)})
    return rows


def _self_checks(d: dict) -> list[dict]:
    from stillcap._selfcheck import checks_from_json, checks_to_json

    items = d.get("self_checks")
    if not isinstance(items, list):
        return []
    try:
        return checks_to_json(checks_from_json([i for i in items if isinstance(i, dict)]))
    except TypeError as e:  # a record without one of the fields
        return [{"name": "self_checks", "passed": False, "value": None, "limit": None, "subject": "",
                 "unit": "", "message": f"the result's self_checks could not be read: {e}"}]


def _ellipsoid_axes(cov_mm2) -> list | None:
    """Three 1-sigma semi-axes (m, world frame) of a position covariance given in mm^2."""
    c = np.asarray(cov_mm2, float)
    if c.shape != (3, 3) or not np.all(np.isfinite(c)):
        return None
    w, v = np.linalg.eigh((c + c.T) / 2 * 1e-6)
    return (v * np.sqrt(np.clip(w, 0, None))).T.tolist()


def _pairs(d: dict) -> list[dict]:
    out = []
    for p in d.get("pairs") or []:
        pos = np.asarray(p.get("positions") or np.zeros((0, 3)), float).reshape(-1, 3)
        covs = p.get("position_covariance_mm2")
        axes = [_ellipsoid_axes(c) for c in covs] if isinstance(covs, list) and len(covs) == len(pos) else \
            [None] * len(pos)
        out.append({"name": p.get("name"), "cameras": p.get("cameras"), "strobe_hz": _num(p.get("strobe_hz")),
                    "flash_index": p.get("flash_index") or [], "times_s": p.get("times_s") or [],
                    "positions": pos.tolist(), "ellipsoid_axes_m": axes,
                    "position_sigma_mm": _num(p.get("position_sigma_mm"))})
    return out


def _trajectory(d: dict) -> tuple[dict | None, str]:
    """The fitted flight sampled from the earliest of release and first ball image to the front
    of the plate (or the last ball image when the flight did not reach it)."""
    from stillcap.ball.physics import flight_model, simulate

    fit = d.get("reference_fit") or {}
    p0, v0, w = _vec(fit.get("p0")), _vec(fit.get("v0")), _vec(fit.get("spin"))
    t0 = _num(fit.get("t0_s"))
    if p0 is None or v0 is None or t0 is None:
        return None, "the result has no reference fit to draw"
    times = [t for p in d.get("pairs") or [] for t in (p.get("times_s") or []) if _num(t) is not None]
    rel_t = _num((d.get("release") or {}).get("t0_s"))
    lo = min([t0] + times + ([rel_t] if rel_t is not None else []))
    hi = max([t0] + times)
    pt = _num((d.get("metrics") or {}).get("plate_time_s"))
    if pt is not None:
        hi = max(hi, (rel_t if rel_t is not None else t0) + pt)
    model_name = d.get("model") or (d.get("options") or {}).get("physics") or "seed"
    try:
        model = flight_model(model_name)
    except (ValueError, KeyError) as e:
        return None, f"flight model {model_name!r} unknown: {e}"
    ts = np.linspace(lo, hi, TRAJECTORY_SAMPLES)
    tr = simulate(p0, v0, w if w is not None else [0.0, 0.0, 0.0], ts, model, t0=t0)
    if not tr.success:
        return None, f"the fitted flight could not be integrated: {tr.message}"
    return {"times_s": ts.tolist(), "positions": tr.positions.tolist(), "model": model_name}, ""


def _spin(d: dict) -> dict | None:
    rep = d.get("spin_reported") or {}
    w = _vec(rep.get("spin")) or _vec(d.get("spin"))
    if w is None or not np.linalg.norm(w):
        return None
    rel = d.get("release") or {}
    at = _vec(rel.get("p0")) or _vec((d.get("reference_fit") or {}).get("p0"))
    return {"axis": (np.asarray(w) / np.linalg.norm(w)).tolist(), "rpm": _num(rep.get("spin_rpm") or d.get("spin_rpm")),
            "sigma_rpm": _num(rep.get("spin_sigma_rpm")), "axis_sigma_deg": _num(rep.get("axis_sigma_deg")),
            "source": rep.get("source"), "transverse_only": bool(rep.get("transverse_only")), "at": at}


def _plate(d: dict) -> dict:
    m, s = d.get("metrics") or {}, d.get("metrics_sigma") or {}
    keys = ("plate_x_ft", "plate_z_ft", "horizontal_break_in", "induced_vertical_break_in", "pfx_x_in", "pfx_z_in",
            "vertical_approach_angle_deg", "horizontal_approach_angle_deg", "plate_time_s")
    return {"values": {k: _num(m.get(k)) for k in keys}, "sigmas": {k: _num(s.get(k)) for k in keys},
            "zone_ft": {"left": -PLATE_HALF_WIDTH_FT, "right": PLATE_HALF_WIDTH_FT, "bottom": ZONE_BOTTOM_FT,
                        "top": ZONE_TOP_FT}}


def _photos(ctx: GuiContext, cap, d: dict | None, markers: dict | None) -> list[dict]:
    """Per photo of the capture: its file, camera, size and what was found on it."""
    balls: dict = {}
    for p in (d or {}).get("pairs") or []:
        cams = p.get("cameras") or []
        c = np.asarray(p.get("centers_px") or [], float)
        r = np.asarray(p.get("radius_px") or [], float)
        fl = p.get("flash_index") or []
        if c.ndim != 3 or c.shape[0] != len(cams) or c.shape[-1] != 2:
            continue
        for i, cam in enumerate(cams):
            balls.setdefault(cam, [])
            for k in range(c.shape[1]):
                x, y = c[i, k]
                if not (np.isfinite(x) and np.isfinite(y)):
                    continue
                rad = float(r[i, k]) if r.shape == c.shape[:2] and np.isfinite(r[i, k]) else None
                balls[cam].append({"x": float(x), "y": float(y), "r": rad,
                                   "flash": int(fl[k]) if k < len(fl) else None, "pair": p.get("name")})
    out = []
    for im in cap.images:
        w, h = cap.rig[im.camera].image_size
        out.append({"file": rel_of(ctx, cap.root / im.file), "camera": im.camera, "width": int(w), "height": int(h),
                    "strobe_hz": im.strobe_hz, "balls": balls.get(im.camera, []),
                    "markers": (markers or {}).get(im.camera, [])})
    return out


def _markers_overlay(res) -> dict:
    """The painted markers each photo showed, from an in-memory result (camera -> list)."""
    out: dict = {}
    for p in res.pairs:
        for cam, mk in zip(p.cameras, p.markers or []):
            rows = out.setdefault(cam, [])
            for k in range(len(mk)):
                bi = int(mk.ball_index[k])
                rows.append({"x": float(mk.centers[k, 0]), "y": float(mk.centers[k, 1]), "type": str(mk.types[k]),
                             "confidence": float(mk.confidences[k]),
                             "flash": int(p.flash_index[bi]) if 0 <= bi < len(p.flash_index) else None})
    return out


def pitch_view(ctx: GuiContext, rel: str) -> dict:
    """Everything the page draws for the capture or result ``rel`` (module docstring)."""
    d, cap, markers, note = _load(ctx, rel)
    view = {"path": rel, "name": Path(rel).name if rel else Path(ctx.root).name, "analysed": d is not None,
            "notes": [note] if note else [], "cameras": [], "photos": []}
    if cap is not None:
        view["cameras"] = frusta(cap.rig, FRUSTUM_DEPTH_M)
        view["photos"] = _photos(ctx, cap, d, markers)
        view["capture"] = rel_of(ctx, cap.root)
        view["description"] = cap.meta.get("description", "")
    if d is None:
        return view
    traj, why = _trajectory(d)
    if why:
        view["notes"].append(why)
    view.update(frame=d.get("frame"), metrics=_metrics_rows(d), self_checks=_self_checks(d),
                messages=[str(m) for m in d.get("messages") or []], pairs=_pairs(d), trajectory=traj, spin=_spin(d),
                plate=_plate(d), release={"p0": _vec((d.get("release") or {}).get("p0")),
                                          "v0": _vec((d.get("release") or {}).get("v0")),
                                          "where": (d.get("release") or {}).get("where")},
                fit={k: _num((d.get("reference_fit") or {}).get(k)) for k in ("rms_error_mm", "max_error_mm",
                                                                              "residual_scale")})
    return view


def session_rows(ctx: GuiContext, folder_rel: str) -> dict:
    """The pitches under a folder compared: one row per item (metrics +- sigma) and its flight."""
    folder = confined(ctx, folder_rel)
    if not folder.is_dir():
        raise ApiError(f"{folder_rel or '.'}: not a folder")
    rows = []
    for it in list_items(ctx, folder):
        row = {"path": it["path"], "name": it["name"], "kind": it["kind"], "analysed": it["analysed"]}
        if it["analysed"]:
            try:
                d, _, _, _ = _load(ctx, it["path"])
            except ValueError as e:
                row.update(analysed=False, error=str(e))
                rows.append(row)
                continue
            m, s = d.get("metrics") or {}, d.get("metrics_sigma") or {}
            row["metrics"] = {k: {"value": _num(m.get(k)), "sigma": _num(s.get(k))} for k, _ in SESSION_METRICS}
            row["n_positions"] = sum(len(p.get("positions") or []) for p in d.get("pairs") or [])
            row["failed_checks"] = sum(1 for c in _self_checks(d) if not c["passed"])
            row["trajectory"], _ = _trajectory(d)
            row["plate"] = _plate(d)["values"]
        rows.append(row)
    return {"path": folder_rel, "columns": [{"key": k, "label": lab} for k, lab in SESSION_METRICS], "rows": rows}


# --------------------------------------------------------------------------------------------
# analysis in the background
# --------------------------------------------------------------------------------------------
def analyse_capture(ctx: GuiContext, rel: str, progress=None) -> dict:
    """Analyse the pitch capture ``rel`` and keep its result for the views (``stillcap pitch``'s
    default options); a short summary."""
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import PitchOptions, analyse_pitch

    folder = capture_folder(ctx, rel, "pitch")
    res = analyse_pitch(Capture.load(folder), PitchOptions(), progress=progress)
    st = _state(ctx)
    with st["lock"]:
        st["results"][rel_of(ctx, folder)] = {"result": res.to_dict(), "markers": _markers_overlay(res)}
    return {"path": rel_of(ctx, folder), "n_positions": int(len(res.times)),
            "release_speed_mph": _num(res.metrics.release_speed_mph)}


def _analyse_session(progress, ctx: GuiContext, rels: list) -> dict:
    done, failed = [], []
    for i, rel in enumerate(rels):
        if progress is not None:
            progress(i, len(rels), rel)
        try:
            sub = None if progress is None else (  # the capture's own steps: a finer bar, and a cancel stops mid-capture
                lambda d, t, step=None, i=i, rel=rel: progress(i + (d / t if t else 0), len(rels),
                                                               f"{rel}: {step}" if step else rel))
            analyse_capture(ctx, rel, sub)
            done.append(rel)
        except ValueError as e:  # one capture that cannot give a flight must not stop the session
            failed.append({"path": rel, "error": str(e)})
    if progress is not None:
        progress(len(rels), len(rels), "done")
    return {"analysed": done, "failed": failed}


def routes(ctx: GuiContext) -> list:
    """The pitch viewer's routes (mounted under ``/api/pitch``)."""

    @api
    async def items(request: Request):
        return JSONResponse({"root": Path(ctx.root).name, "items": list_items(ctx)})

    @api
    async def view(request: Request):
        rel, _ = query_path(ctx, request, required=False)
        return JSONResponse(pitch_view(ctx, rel))

    @api
    async def photo(request: Request):
        rel, _ = query_path(ctx, request)
        return photo_response(ctx, rel, photo_width(request))

    @api
    async def analyse(request: Request):
        return await start_capture_job(ctx, request, "pitch", analyse_capture)

    @api
    async def session(request: Request):
        rel, _ = query_path(ctx, request, required=False)
        return JSONResponse(session_rows(ctx, rel))

    @api
    async def session_analyse(request: Request):
        from stillcap.gui.jobs import job_manager, job_response

        body = await json_body(request)
        rel = body.get("path", "")
        folder = confined(ctx, rel)
        if not folder.is_dir():
            raise ApiError(f"{rel or '.'}: not a folder")
        todo = [it["path"] for it in list_items(ctx, folder) if it["kind"] == "capture" and not it["analysed"]]
        job = job_manager(ctx).submit(_analyse_session, ctx, todo, label=f"pitch session ({len(todo)} captures)")
        return job_response(job)

    return [Route("/items", items, methods=["GET"]), Route("/view", view, methods=["GET"]),
            Route("/photo", photo, methods=["GET"]), Route("/analyse", analyse, methods=["POST"]),
            Route("/session", session, methods=["GET"]), Route("/session/analyse", session_analyse, methods=["POST"])]
