"""The work of one capture on a worker: analyse it, return its row and its JSON text.

A task gets the capture's folder (a path) and reads the files itself, so photos never travel
between machines; what comes back is a small dict (the table row and the result JSON, tens to
a couple of hundred kilobytes). Every failure of the analysis is caught here and returned as a
row with ``status = "error"`` and one line saying why, so that one bad capture never stops a
batch.

Each kind runs the entry point its own command runs, with that command's default options, and
its JSON text is what the command prints with ``--json``:

========  ===============================================  ==========================
kind      analysis                                         JSON file (per capture)
========  ===============================================  ==========================
pitch     :func:`stillcap.pipelines.pitch.analyse_pitch`   ``pitch.json``
hand      :func:`stillcap.pipelines.hand.analyse_hand`     ``hand.json``
puppet    :func:`stillcap.pipelines.puppet.analyse_puppet` ``result.json``
markers   :func:`stillcap.pipelines.markers.reconstruct_markers`  ``markers.json``
========  ===============================================  ==========================

``finish`` (optional, given by the caller): ``finish(kind, source, result) -> dict`` turns a
result into its JSON document, e.g. with a comparison against a studio truth (the CLI passes
:func:`stillcap.cli.batch.finish_with_truth`; this package never reads a truth). ``source`` is
the loaded :class:`~stillcap.io.capture.Capture` for pitch and markers, the folder otherwise.
"""

from __future__ import annotations

import json
import math
import os
import socket
import time
from pathlib import Path

__all__ = ["JSON_FILES", "analyse_capture", "metrics_row", "options_of", "problem_line"]

#: The per-capture JSON file of each kind (the name its own command gives it).
JSON_FILES = {"pitch": "pitch.json", "hand": "hand.json", "puppet": "result.json", "markers": "markers.json"}


def options_of(kind: str, threads: int = 1) -> dict:
    """The options a batch analyses a capture of ``kind`` with, as JSON-able data (part of the
    content hash). They are the defaults of the kind's own command; ``threads`` (threads of one
    pitch capture) only schedules work and is left out."""
    if kind == "pitch":
        from stillcap.pipelines.pitch import PitchOptions

        d = PitchOptions().to_dict()
        return {k: v for k, v in d.items() if k not in ("workers", "processes")}
    if kind == "hand":
        from dataclasses import asdict

        from stillcap.pipelines.hand import HandOptions

        return {k: (str(v) if v is not None and not isinstance(v, (int, float, str, bool)) else v)
                for k, v in asdict(HandOptions()).items()}
    if kind == "puppet":
        from stillcap.pipelines.puppet import DEFAULT

        return DEFAULT.to_dict()
    if kind == "markers":
        return {"palette": "default", "max_px": 2.0}
    raise ValueError(f"unknown capture kind {kind!r}")


def problem_line(e: BaseException) -> str:
    """One line for a capture that failed: the library's message (bad input), the file and
    reason (a file that cannot be read), else the error's kind and text."""
    if isinstance(e, OSError) and not isinstance(e, (TimeoutError, ConnectionError)):
        why = e.strerror or str(e) or type(e).__name__
        text = f"{e.filename}: {why}" if e.filename else why
    elif isinstance(e, ValueError):
        text = str(e)
    else:
        text = f"{type(e).__name__}: {e}"
    lines = [s for s in text.splitlines() if s.strip()]
    return lines[0] if lines else type(e).__name__


def _number(v):
    """A finite float, an int or None (booleans and non-finite numbers: None)."""
    if isinstance(v, bool) or v is None:
        return None
    if isinstance(v, int):
        return v
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    return None


def metrics_row(kind: str, doc: dict) -> dict:
    """The metrics of a result document (its JSON) for the batch table: ``{column: value}``,
    units in the column names, a metric's 1-sigma in ``COLUMN_sigma``.

    pitch: every metric of ``metrics`` (Statcast names: ``release_speed_mph``, ...) and its
    ``metrics_sigma``, the number of ball positions and the spin's source. hand: the release
    (time, speed, direction) with sigmas, flashes and poses. puppet: markers identified and
    missing, the pose fit's RMS. markers: how many, reprojection errors.
    """
    row: dict = {}
    if kind == "pitch":
        sig = doc.get("metrics_sigma") or {}
        for k, v in (doc.get("metrics") or {}).items():
            if k in ("nine_parameter", "success", "message"):
                continue
            if isinstance(v, str):
                row[k] = v
            else:
                row[k] = _number(v)
                row[f"{k}_sigma"] = _number(sig.get(k))
        row["ball_positions"] = sum(len(p.get("times_s") or []) for p in doc.get("pairs") or [])
        row["spin_source"] = doc.get("spin_source")
    elif kind == "hand":
        rel = doc.get("release") or {}
        fl = doc.get("flashes") or {}
        row["flashes"] = len(fl.get("times_s") or [])
        row["poses"] = sum(bool(r) for r in fl.get("reconstructed") or [])
        row["markers_3d"] = len((doc.get("points") or {}).get("points") or [])
        row["release_found"] = bool(rel.get("success"))
        for col, key, sig in (("release_time_s", "t0_s", "t0_sigma_s"), ("release_speed_mph", "speed_mph", "speed_sigma_mph"),
                              ("release_horizontal_deg", "horizontal_deg", "direction_sigma_deg"),
                              ("release_vertical_deg", "vertical_deg", "direction_sigma_deg")):
            row[col] = _number(rel.get(key))
            row[f"{col}_sigma"] = _number(rel.get(sig))
    elif kind == "puppet":
        markers = doc.get("markers") or []
        errs = [m.get("reproj_error_px") for m in markers if _number(m.get("reproj_error_px")) is not None]
        row["markers"] = len(markers)
        row["markers_missing"] = len(doc.get("missing") or [])
        fit = doc.get("pose_fit") or {}
        rms = _number(fit.get("rms_m"))
        row["pose_fit_rms_mm"] = None if rms is None else rms * 1e3
        row["reproj_error_mean_px"] = sum(errs) / len(errs) if errs else None
    elif kind == "markers":
        markers = doc.get("markers") or []
        errs = [m["reproj_error_px"] for m in markers if _number(m.get("reproj_error_px")) is not None]
        row["markers"] = len(markers)
        row["reproj_error_mean_px"] = sum(errs) / len(errs) if errs else None
        row["reproj_error_max_px"] = max(errs) if errs else None
    checks = doc.get("self_checks")
    if isinstance(checks, list):
        row["self_checks_failed"] = sum(isinstance(c, dict) and c.get("passed") is False for c in checks)
    row["notes"] = len(doc.get("messages") or [])
    return row


def _analyse(kind: str, folder: Path, finish, threads: int) -> tuple[dict, str]:
    """``(document, JSON text)`` of one capture, as its own command gives them."""
    if kind == "pitch":
        from stillcap.io.capture import Capture
        from stillcap.pipelines.pitch import PitchOptions, analyse_pitch

        cap = Capture.load(folder)
        res = analyse_pitch(cap, PitchOptions(workers=max(1, threads), processes=0))
        doc = finish(kind, cap, res) if finish else res.to_dict()
        return doc, json.dumps(doc, indent=1, allow_nan=False) + "\n"
    if kind == "hand":
        from stillcap.pipelines.hand import HandOptions, analyse_hand

        res = analyse_hand(folder, HandOptions())
        doc = finish(kind, folder, res) if finish else res.to_dict()
        return doc, json.dumps(doc, indent=1, allow_nan=False) + "\n"
    if kind == "puppet":
        from stillcap.io.project import dumps_json
        from stillcap.pipelines.puppet import DEFAULT, analyse_puppet

        res, images = analyse_puppet(folder, DEFAULT)
        del images  # the photos stay here; only the result's numbers go back
        doc = finish(kind, folder, res) if finish else res.to_dict()
        return doc, dumps_json(doc) + "\n"
    if kind == "markers":
        from stillcap.io.capture import Capture
        from stillcap.pipelines.markers import reconstruct_markers

        cap = Capture.load(folder)
        images = []
        for cam in cap.rig:
            shots = cap.images_of(cam.name)
            if not shots:
                raise ValueError(f"capture {folder}: camera {cam.name!r} has no photo")
            images.append(cap.read_image(shots[0]))
        rec = reconstruct_markers(cap.rig, images, None, max_px=2.0)
        del images
        doc = finish(kind, cap, rec) if finish else rec.to_dict()
        return doc, json.dumps(doc, indent=2) + "\n"
    raise ValueError(f"unknown capture kind {kind!r}")


def _where() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def analyse_capture(path: str, kind: str, finish=None, threads: int = 1) -> dict:
    """Analyse the capture folder ``path`` (of ``kind``) here and return
    ``{"status", "error", "seconds", "worker", "metrics", "json"}``: ``status`` ``"ok"`` or
    ``"error"`` (then ``error`` is one line and ``json`` None), ``seconds`` the wall time of the
    analysis, ``metrics`` :func:`metrics_row` of the result, ``json`` its JSON text."""
    t0 = time.perf_counter()
    try:
        import cv2

        cv2.setNumThreads(max(1, threads))  # one worker per core: OpenCV's own threads only compete
        doc, text = _analyse(kind, Path(path), finish, threads)
        metrics = metrics_row(kind, doc)
    except Exception as e:  # noqa: BLE001 - isolated: the capture's row names the problem, the batch goes on
        return {"status": "error", "error": problem_line(e), "seconds": time.perf_counter() - t0,
                "worker": _where(), "metrics": {}, "json": None}
    return {"status": "ok", "error": None, "seconds": time.perf_counter() - t0, "worker": _where(),
            "metrics": metrics, "json": text}
