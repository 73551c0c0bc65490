"""Outputs of the pitch pipeline: JSON, CSV, plots and a self-contained HTML report.

Every file is written atomically (:mod:`stillcap.files.atomic`). The HTML report embeds its plots as
PNG data URIs, so the one file can be mailed or archived on its own.

Files of :func:`write_report` (``docs/pitch.md``)::

    report.html     metrics with 1-sigma, the seed's Table 1, velocity, spin, per-flash table, plots
    pitch.json      PitchResult.to_dict()
    positions.csv   one row per ball image (write_positions_csv)
    metrics.csv     one row per metric: key, value, sigma, unit (write_metrics_csv)
    side.png, top.png, spin.png, residuals.png
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stillcap._numeric import RPM_PER_RAD_S
from stillcap.files.atomic import atomic_path, write_bytes, write_text  # noqa: E402

__all__ = ["POSITION_COLUMNS", "METRIC_UNITS", "write_json", "write_positions_csv", "write_metrics_csv",
           "plot_pitch", "write_report", "metric_unit"]

#: Columns of ``positions.csv``.
POSITION_COLUMNS = ("pair", "camera_a", "camera_b", "strobe_hz", "flash_index", "time_s", "x_m", "y_m", "z_m",
                    "sigma_mm", "cov_xx_mm2", "cov_yy_mm2", "cov_zz_mm2", "cov_xy_mm2", "cov_xz_mm2", "cov_yz_mm2",
                    "ref_x_m", "ref_y_m", "ref_z_m", "residual_mm", "reproj_px", "markers", "flags")
#: (column, row, col) of the position covariance entries in ``positions.csv``.
_COV_ENTRIES = (("cov_xx_mm2", 0, 0), ("cov_yy_mm2", 1, 1), ("cov_zz_mm2", 2, 2), ("cov_xy_mm2", 0, 1),
                ("cov_xz_mm2", 0, 2), ("cov_yz_mm2", 1, 2))
#: Unit of each metric key (by suffix where the key names it).
METRIC_UNITS = {"spin_efficiency": "0-1", "spin_tilt": "clock (h:mm)", "spin_direction_clock": "clock (h:mm)", "success": "", "message": ""}
_PAIR_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")


def metric_unit(key: str) -> str:
    """The unit a metric key names (``release_speed_mph`` -> ``mph``)."""
    if key in METRIC_UNITS:
        return METRIC_UNITS[key]
    for suf in ("mph", "ft", "in", "rpm", "deg", "s", "mm", "m", "px"):
        if key.endswith("_" + suf):
            return suf
    return ""


def _fmt(v, digits: int = 3) -> str:
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return "" if not math.isfinite(v) else f"{float(v):.{digits}f}"
    return str(v)


def _g(v) -> str:
    return "" if v is None or not np.isfinite(v) else f"{float(v):.10g}"


def write_json(result, path) -> Path:
    """``result.to_dict()`` as strict JSON (NaN -> null)."""
    return write_text(path, json.dumps(result.to_dict(), indent=1, allow_nan=False) + "\n")


def _position_rows(result):
    fit = result.fit
    rows = []
    for i, p in enumerate(result.pairs):
        counts = (p.observations.counts(len(p)) if p.observations is not None and len(p) else np.zeros(len(p), int))
        cov = (np.full((len(p), 3, 3), np.nan) if p.position_covariance_m2 is None
               else np.asarray(p.position_covariance_m2) * 1e6)  # mm^2
        sel = np.flatnonzero(result.pair_index == i)
        for j in range(len(p)):
            r = sel[j] if j < len(sel) else None
            ref = fit.positions[r] if r is not None else np.full(3, np.nan)
            res = fit.errors[r] * 1e3 if r is not None else np.nan
            rows.append({
                "pair": p.name, "camera_a": p.cameras[0], "camera_b": p.cameras[1], "strobe_hz": _g(p.strobe_hz),
                "flash_index": int(p.flash_index[j]), "time_s": _g(p.times[j]),
                "x_m": _g(p.positions[j, 0]), "y_m": _g(p.positions[j, 1]), "z_m": _g(p.positions[j, 2]),
                "sigma_mm": _g(p.position_sigma_m * 1e3),
                **{name: _g(cov[j, a, b]) for name, a, b in _COV_ENTRIES},
                "ref_x_m": _g(ref[0]), "ref_y_m": _g(ref[1]), "ref_z_m": _g(ref[2]), "residual_mm": _g(res),
                "reproj_px": _g(p.reproj_error_px[j]), "markers": int(counts[j]), "flags": int(p.flags[j]),
            })
    return rows


def write_positions_csv(result, path) -> Path:
    """One row per ball image (columns :data:`POSITION_COLUMNS`; empty cell = not available)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=POSITION_COLUMNS, lineterminator="\n")
    w.writeheader()
    for row in _position_rows(result):
        w.writerow(row)
    return write_text(path, buf.getvalue())


def _metric_rows(result):
    m = result.metrics.to_dict()
    sig = result.metrics_sigma or {}
    rows = []
    for k, v in m.items():
        if k in ("nine_parameter", "success", "message"):
            continue
        rows.append((k, v, sig.get(k), metric_unit(k)))
    return rows


def write_metrics_csv(result, path) -> Path:
    """``key,value,sigma,unit`` per metric (PitchMetrics keys, the truth file's ``metrics`` keys)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["key", "value", "sigma", "unit"])
    for k, v, s, u in _metric_rows(result):
        w.writerow([k, v if isinstance(v, str) else _g(v), _g(s), u])
    return write_text(path, buf.getvalue())


# --------------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------------
def _reference_path(result, n: int = 300):
    """The fitted flight from the first ball image (or the release, if earlier) to the plate."""
    from stillcap.ball.physics import simulate
    from stillcap.ball.physics import flight_model

    fit = result.fit
    t_lo = min(float(result.release.get("t0_s", fit.t0)), float(np.nanmin(result.times)))
    t_hi = float(np.nanmax(result.times))
    pt = result.metrics.plate_time_s
    if np.isfinite(pt):
        t_hi = max(t_hi, float(result.release.get("t0_s", fit.t0)) + pt)
    ts = np.linspace(t_lo, t_hi, n)
    tr = simulate(fit.p0, fit.v0, fit.spin, ts, flight_model(result.options.physics), t0=fit.t0)
    return ts, tr.positions


def _save(fig, path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return Path(path)


def _view(result, path, axes: tuple, labels: tuple, title: str) -> Path:
    ts, ref = _reference_path(result)
    fig, ax = plt.subplots(figsize=(10, 3.6))
    ax.plot(ref[:, axes[0]], ref[:, axes[1]], "k-", lw=1, label=f"reference path ({result.options.physics} physics)")
    for i, p in enumerate(result.pairs):
        if not len(p):
            continue
        sig = p.position_sigma_m
        ax.errorbar(p.positions[:, axes[0]], p.positions[:, axes[1]],
                    yerr=np.full(len(p), sig) if np.isfinite(sig) else None, fmt="o", ms=4,
                    color=_PAIR_COLORS[i % len(_PAIR_COLORS)],
                    label=f"pair {p.name} ({p.strobe_hz:g} Hz, {len(p)} images)")
    rel = result.release
    if rel.get("p0") is not None:
        p0 = np.asarray(rel["p0"], float)
        ax.plot(p0[axes[0]], p0[axes[1]], "k*", ms=10, label="release (metrics)")
    if result.frame == "field":
        from stillcap.ball.metrics import PLATE_FRONT_Y_FT, FT

        if axes[0] == 1:
            ax.axvline(PLATE_FRONT_Y_FT * FT, color="0.6", ls="--", lw=0.8)
            ax.text(PLATE_FRONT_Y_FT * FT, ax.get_ylim()[1], " front of plate", fontsize=7, va="top", color="0.4")
        ax.invert_xaxis()  # pitcher on the left, catcher on the right
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return _save(fig, path)


def _plot_spin(result, path) -> Path:
    """The Statcast spin axis on a clock face (catcher's view) with its 1-sigma wedge, and the
    alias candidates."""
    fig = plt.figure(figsize=(9, 4.2))
    ax = fig.add_subplot(1, 2, 1, projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_xticks(np.radians(np.arange(0, 360, 30)))
    ax.set_xticklabels([str(h) for h in [12] + list(range(1, 12))])
    ax.set_yticks([])
    m = result.metrics
    if result.spin_available and np.isfinite(m.spin_axis_deg):
        # clock angle: 180 deg (12:00) at the top, turning clockwise by 30 deg per hour
        ang = np.radians(m.spin_axis_deg - 180.0)
        s = result.metrics_sigma.get("spin_axis_deg") or 0.0
        ax.annotate("", xy=(ang, 1.0), xytext=(0, 0), arrowprops=dict(arrowstyle="->", color="tab:red", lw=2))
        if s > 0:
            th = np.linspace(ang - np.radians(2 * s), ang + np.radians(2 * s), 30)
            ax.fill_between(th, 0, 1.0, color="tab:red", alpha=0.2, label="2 sigma")
        ax.set_title(f"spin axis {m.spin_axis_deg:.1f} deg ({m.spin_tilt}), catcher's view", fontsize=9)
        eff = m.spin_efficiency
        ax.text(np.radians(180), 0.55, f"efficiency {eff:.2f}", ha="center", fontsize=8)
    else:
        ax.set_title("spin unavailable", fontsize=9)
    ax.set_ylim(0, 1.05)
    ax2 = fig.add_subplot(1, 2, 2)
    al = result.alias
    if al is not None and getattr(al, "candidates", None):
        c = al.candidates[:6]
        ax2.barh([f"{x.spin_rpm:.0f} rpm" for x in c][::-1], [x.probability for x in c][::-1], color="tab:gray")
        ax2.set_xlim(0, 1)
        ax2.set_xlabel("probability")
        ax2.set_title("alias candidates (" + ", ".join(al.evidence) + ")"
                      + (" AMBIGUOUS" if al.ambiguous else ""), fontsize=8)
    elif result.spin_available:
        ax2.text(0.5, 0.5, "no alias ranking", ha="center", va="center")
        ax2.set_axis_off()
    else:
        notes = [m for m in result.messages if "spin" in m or "marker" in m] or ["no markers"]
        st = result.fit_positions_only.spin_transverse
        notes.append(f"spin seen by the flight's curvature alone (Magnus force, {result.options.physics} physics): "
                     f"{np.linalg.norm(st) * RPM_PER_RAD_S:.0f} rpm transverse to the flight")
        ax2.text(0.0, 0.5, "\n\n".join(textwrap.fill(m, 48) for m in notes), ha="left", va="center", fontsize=8)
        ax2.set_axis_off()
    fig.tight_layout()
    return _save(fig, path)


def _plot_residuals(result, path) -> Path:
    """Per-flash residuals: position to the reference path (mm), and marker angles (deg)."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.4))
    fit = result.fit
    for i, p in enumerate(result.pairs):
        sel = result.pair_index == i
        if not sel.any():
            continue
        col = _PAIR_COLORS[i % len(_PAIR_COLORS)]
        a1.plot(fit.times[sel], fit.errors[sel] * 1e3, "o-", ms=4, color=col, label=f"pair {p.name}")
    a1.set_xlabel("time on the reference clock, s")
    a1.set_ylabel("|position - reference| mm")
    a1.set_title(f"positions: RMS {fit.rms_error * 1e3:.2f} mm, max {fit.max_error * 1e3:.2f} mm", fontsize=9)
    a1.grid(alpha=0.3)
    a1.legend(fontsize=7)
    sp = result.spin
    x = result.spin_obs_times
    if sp is not None and len(sp.residuals_deg) and x is not None and len(x) == len(sp.residuals_deg):
        inl = sp.inliers & np.isfinite(sp.residuals_deg)
        a2.plot(x[inl], sp.residuals_deg[inl], "o", ms=3, color="tab:green", label="inliers")
        out = ~sp.inliers & np.isfinite(sp.residuals_deg)
        if out.any():
            a2.plot(x[out], np.minimum(sp.residuals_deg[out], 30), "x", ms=4, color="tab:red",
                    label="outliers (capped at 30)")
        a2.set_title(f"markers ({sp.method} spin fit): RMS {sp.rms_deg:.2f} deg, {sp.n_inliers}/{sp.n_observations}",
                     fontsize=9)
        a2.legend(fontsize=7)
    else:
        a2.set_title("markers: no spin fit", fontsize=9)
    a2.set_xlabel("time on the reference clock, s")
    a2.set_ylabel("marker angle residual, deg")
    a2.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, path)


def plot_pitch(result, out_dir) -> dict:
    """Side view, top view (with the reference path), spin axis and per-flash residuals as PNGs.

    Returns ``{name: path}``."""
    out = Path(out_dir)
    field = result.frame == "field"
    side = ("y (toward the pitcher), m", "z (up), m") if field else ("y, m", "z, m")
    top = ("y (toward the pitcher), m", "x (catcher's right), m") if field else ("y, m", "x, m")
    return {
        "side": _view(result, out / "side.png", (1, 2), side, "side view"),
        "top": _view(result, out / "top.png", (1, 0), top, "top view"),
        "spin": _plot_spin(result, out / "spin.png"),
        "residuals": _plot_residuals(result, out / "residuals.png"),
    }


# --------------------------------------------------------------------------------------------
# HTML
# --------------------------------------------------------------------------------------------
_CSS = """body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:0.6em 0 1.4em}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}
th{background:#f3f3f3}td.n{text-align:right;font-variant-numeric:tabular-nums}
.warn{background:#fff4e0;border-left:4px solid #e90;padding:6px 10px;margin:4px 0}
img{max-width:100%;border:1px solid #ddd;margin:4px 0}.small{color:#666;font-size:12px}"""


def _table(header, rows, numeric_from: int = 1) -> str:
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
    body = []
    for r in rows:
        cells = []
        for i, c in enumerate(r):
            cls = ' class="n"' if i >= numeric_from else ""
            cells.append(f"<td{cls}>{html.escape(str(c))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><tr>{h}</tr>{''.join(body)}</table>"


def _img(path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(Path(path).stem)}">'


def report_html(result, images: dict) -> str:
    """The report as one HTML string (plots embedded)."""
    from stillcap.pipelines.pitch import TABLE1_COLUMNS

    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>stillcap pitch report</title>"
             f"<style>{_CSS}</style></head><body>",
             "<h1>Pitch report</h1>",
             f"<p class='small'>capture: {html.escape(str(result.capture_root))}; frame: {html.escape(result.frame)}; "
             f"spin method: {result.options.spin_method}; physics: {result.options.physics}; fit: "
             f"{result.options.fit_method}; release evaluated {html.escape(str(result.release.get('where')))}. "
             "Uncertainties are 1-sigma (docs/pitch.md).</p>"]
    for m in result.messages:
        parts.append(f"<div class='warn'>{html.escape(m)}</div>")
    truth = (result.truth or {}).get("metrics", {})
    parts.append("<h2>Pitch metrics (field frame)</h2>")
    header = ["metric", "value", "± 1 sigma", "unit"] + (["truth", "error"] if truth else [])
    rows = []
    for k, v, s, u in _metric_rows(result):
        row = [k, _fmt(v, 3) if not isinstance(v, str) else v, _fmt(s, 3), u]
        if truth:
            t = truth.get(k)
            row += [_fmt(t["truth"], 3), _fmt(t["diff"], 3)] if t else ["", ""]
        rows.append(row)
    parts.append(_table(header, rows))
    parts.append("<h2>Seed Table 1 (reference trajectory against the measured initial parameters)</h2>")
    t1 = result.table1
    cols = [c for c, _ in TABLE1_COLUMNS]
    parts.append(_table([f"{c}" for c in cols], [[_fmt(t1.get(c), 2) for c in cols]], 0))
    if result.truth and result.truth.get("table1"):
        tt = result.truth["table1"]
        parts.append("<p>Against the truth (positions vs true centres, fitted velocity vs true velocity, "
                     "measured spin vs true spin):</p>")
        parts.append(_table(cols, [[_fmt(tt.get(c), 2) for c in cols]], 0))
    d = result.to_dict()
    v = d["velocity"]
    parts.append("<h2>Release velocity (at the front pair's first ball image)</h2>")
    parts.append(_table(["estimate", "vx m/s", "vy m/s", "vz m/s", "speed mph", "± mph"], [
        ["two-point (seed)", *(_fmt(x, 3) for x in v["two_point"]), _fmt(v["two_point_speed_mph"], 2),
         _fmt(v["two_point_speed_sigma_mph"], 3)],
        ["fitted (reference trajectory)", *(_fmt(x, 3) for x in v["fitted"]), _fmt(v["fitted_speed_mph"], 2),
         _fmt(v["fitted_speed_sigma_mph"], 3)]]))
    parts.append("<h2>Spin</h2>")
    if result.spin_available:
        s = result.spin
        axis = ", ".join(_fmt(a, 3) for a in s.axis)
        parts.append(_table(["method", "rate at release rpm", "± rpm", "axis (world)", "± axis deg", "marker RMS deg",
                             "markers used", "message"],
                            [[s.method, _fmt(result.release.get("spin_rpm"), 1), _fmt(s.sigma_rpm, 2), axis,
                              _fmt(s.sigma_axis_deg, 2), _fmt(s.rms_deg, 2), f"{s.n_inliers}/{s.n_observations}",
                              s.message]]))
        if result.alias is not None:
            parts.append(f"<p>Alias check: {html.escape(result.alias.message)}</p>")
    else:
        parts.append("<p>Spin unavailable: " + html.escape("; ".join(
            m for m in result.messages if "spin" in m or "marker" in m) or "no markers") + "</p>")
    fr = d["reference_fit"]
    parts.append(f"<p>Spin from the flight's curvature alone (transverse part): "
                 f"{_fmt(d['reference_fit_positions_only']['spin_transverse_rpm'], 0)} rpm.</p>")
    parts.append("<h2>Pairs and clocks</h2>")
    parts.append(_table(["pair", "cameras", "strobe Hz", "ball images", "dropped", "clock offset s", "± ms",
                         "position sigma mm", "markers 3D / 1 camera"],
                        [[p.name, " + ".join(p.cameras), _fmt(p.strobe_hz, 1), str(len(p)), str(p.n_dropped),
                          _fmt(p.time_offset_s, 5), _fmt(p.time_offset_sigma_s * 1e3, 3),
                          _fmt(p.position_sigma_m * 1e3, 2), f"{p.n_markers_3d} / {p.n_markers_ray}"]
                         for p in result.pairs]))
    parts.append(f"<p class='small'>Reference fit: {fr['method']}, RMS {fr['rms_error_mm']:.2f} mm, "
                 f"{'converged' if fr['success'] else 'NOT converged: ' + html.escape(fr['message'])}.</p>")
    for name in ("side", "top", "spin", "residuals"):
        if name in images:
            parts.append(f"<h3>{name}</h3>" + _img(images[name]))
    parts.append("<h2>Ball positions per flash</h2>")
    rows = [[r[c] for c in POSITION_COLUMNS] for r in _position_rows(result)]
    parts.append(_table(POSITION_COLUMNS, rows, 3))
    if result.truth:
        tc = result.truth
        parts.append("<h2>Comparison with the truth (synthetic capture)</h2>")
        rows = [[k, _fmt(tc.get(k), 3)] for k in (
            "mean_err_mm", "max_err_mm", "velocity_angle_deg_fitted", "speed_diff_mph_fitted",
            "velocity_angle_deg_two_point", "speed_diff_mph_two_point", "spin_axis_angle_deg", "spin_rate_diff_rpm",
            "fit_spin_axis_angle_deg", "fit_spin_rate_diff_rpm") if k in tc]
        for name, o in (tc.get("time_offsets") or {}).items():
            rows.append([f"clock offset error, pair {name} (ms)", _fmt(o["error_ms"], 3)])
        parts.append(_table(["quantity", "value"], rows))
    parts.append("<p class='small'>stillcap pitch pipeline; see docs/pitch.md for definitions.</p></body></html>")
    return "\n".join(parts)


def write_report(result, out_dir) -> dict:
    """Write the report folder: ``report.html`` (self-contained), ``pitch.json``,
    ``positions.csv``, ``metrics.csv`` and the plots. Returns ``{name: path}``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    images = plot_pitch(result, out)
    paths = dict(images)
    paths["json"] = write_json(result, out / "pitch.json")
    paths["positions_csv"] = write_positions_csv(result, out / "positions.csv")
    paths["metrics_csv"] = write_metrics_csv(result, out / "metrics.csv")
    paths["html"] = write_bytes(out / "report.html", report_html(result, images).encode("utf-8"))
    return paths
