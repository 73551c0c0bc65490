"""A pitch result against the studio's truth (``truth.json`` of a synthetic pitch capture).

:func:`compare_with_truth` gives the errors in the seed's Table 1 units; :func:`add_truth_comparison`
stores them on the result (``PitchResult.truth``, written as ``truth_comparison`` by
:meth:`~stillcap.pipelines.pitch.PitchResult.to_dict`) when a capture holds a pitch truth. The
CLI, the demo and the benchmarks call it after :func:`~stillcap.pipelines.pitch.analyse_pitch`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from stillcap.ball.metrics import MPH, RPM_PER_RAD_S
from stillcap.ball.physics import flight_model, simulate
from stillcap.ball.uncertainty import ANGLE_KEYS

if TYPE_CHECKING:
    from stillcap.pipelines.pitch import PitchResult

__all__ = ["add_truth_comparison", "compare_with_truth", "truth_flight_model"]


def add_truth_comparison(result: PitchResult, truth) -> PitchResult:
    """Set ``result.truth`` to :func:`compare_with_truth` when ``truth`` (a capture's ``truth``)
    is a pitch truth; a truth file it cannot compare (another version) adds a message instead.

    Returns
    -------
    PitchResult
        ``result`` itself.
    """
    if isinstance(truth, dict) and truth.get("kind") == "pitch":
        try:
            result.truth = compare_with_truth(result, truth)
        except (KeyError, ValueError, TypeError, IndexError) as e:  # a truth file of another version
            result.messages.append(f"truth.json could not be compared: {e}")
    return result


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if not (np.linalg.norm(a) > 0 and np.linalg.norm(b) > 0):
        return float("nan")
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)))


def truth_flight_model(truth: dict):
    """The flight model the studio threw the ball with: the true ball's (``truth["ball"]["file"]``,
    written by ``studio pitch --ball``: its own flight preset, or a baseball's flight with the
    ball's mass and diameter), else ``truth["model"]``'s baseball model.

    (A ball flying as a baseball keeps ``model`` ``"seed"`` or ``"nathan"``, so the model's name
    alone would give the baseball's 145 g and 73.7 mm instead of the ball's.)"""
    file = (truth.get("ball") or {}).get("file")
    if file is not None:
        from stillcap.ball.ballfile import Ball
        kind = truth.get("model")
        ball = Ball.from_dict(file, "truth.json: ball.file")
        return ball.flight_model(kind if kind in ("seed", "nathan") else "seed")
    return flight_model(truth.get("model", "seed"))


def compare_with_truth(result: PitchResult, truth: dict) -> dict:
    """Errors of a result against a studio ``truth.json`` (dict), in the seed's Table 1 units.

    Positions are compared with the true ball centre at the nearest true flash of the same pair;
    the release velocity with the true velocity at the instant of the front pair's first ball
    image; spin with the true spin vector; metrics key by key (``ours - truth``).
    """
    from stillcap.files.jsonable import from_jsonable

    tmodel = truth_flight_model(truth)
    rel = truth["release"]
    tp0, tv0, tw = (np.asarray(rel[k], float) for k in ("p0", "v0", "spin"))
    t_rel = float(rel["t0_s"])
    tpairs = {p["name"]: p for p in truth["pairs"]}
    errs, per_pair, true_t = [], {}, {}
    for p in result.pairs:
        tp = tpairs.get(p.name)
        if tp is None or len(p) == 0:
            continue
        P = from_jsonable(tp["positions"]).reshape(-1, 3)
        T = np.asarray(tp["times_s"], float)
        d = np.linalg.norm(P[None] - p.positions[:, None], axis=2)
        j = np.nanargmin(d, axis=1)
        e = d[np.arange(len(p)), j]
        errs.append(e)
        true_t[p.name] = T[j]
        k_true = np.asarray(tp["flash_index"], int)[j]
        per_pair[p.name] = {"mean_err_mm": float(e.mean() * 1e3), "max_err_mm": float(e.max() * 1e3),
                            "n": len(p), "n_true": int(np.sum(tp.get("rendered", [True] * len(T)))),
                            "flash_index_ok": bool(np.all(np.diff(k_true) == np.diff(p.flash_index)))}
    e = np.concatenate(errs) if errs else np.zeros(0)
    ref = result.pairs[0]
    T0 = float(true_t[ref.name][0]) if ref.name in true_t else float("nan")
    out = {"positions": per_pair, "mean_err_mm": float(e.mean() * 1e3) if len(e) else None,
           "max_err_mm": float(e.max() * 1e3) if len(e) else None}
    if np.isfinite(T0):
        st = simulate(tp0, tv0, tw, [T0], tmodel, t0=t_rel)
        v_true = st.velocities[0]
        for name, v in (("fitted", result.fit.v0), ("two_point", result.velocity_two_point)):
            out[f"velocity_angle_deg_{name}"] = _angle(v, v_true)
            out[f"speed_diff_mph_{name}"] = float((np.linalg.norm(v) - np.linalg.norm(v_true)) / MPH)
        out["true_speed_mph_at_t0"] = float(np.linalg.norm(v_true) / MPH)
        out["true_time_of_t0_s"] = T0
        offs = {}
        for p in result.pairs[1:]:
            if p.name in true_t and len(p):
                # true time of this pair's flash 0 on the reference clock
                true_off = float(true_t[p.name][0] - p.flash_index[0] / p.strobe_hz - T0)
                offs[p.name] = {"fitted_s": p.time_offset_s, "true_s": true_off,
                                "error_ms": (p.time_offset_s - true_off) * 1e3,
                                "sigma_ms": p.time_offset_sigma_s * 1e3}
        out["time_offsets"] = offs
    if result.spin_available:
        w = np.asarray(result.release["spin"], float)
        out["spin_axis_angle_deg"] = _angle(w, tw)
        out["spin_rate_diff_rpm"] = float((np.linalg.norm(w) - np.linalg.norm(tw)) * RPM_PER_RAD_S)
        out["spin_axis_sigma_deg"] = float(result.spin.sigma_axis_deg)
        out["spin_rate_sigma_rpm"] = float(result.spin.sigma_rpm)
    else:
        out["spin_axis_angle_deg"] = out["spin_rate_diff_rpm"] = None
    out["fit_spin_axis_angle_deg"] = _angle(result.fit.spin, tw)
    out["fit_spin_rate_diff_rpm"] = float((np.linalg.norm(result.fit.spin) - np.linalg.norm(tw)) * RPM_PER_RAD_S)
    out["true_speed_mph"] = float(np.linalg.norm(tv0) / MPH)
    out["true_spin_rpm"] = float(np.linalg.norm(tw) * RPM_PER_RAD_S)
    tm = _current_metric_keys(truth.get("metrics") or {})
    ours = result.metrics.to_dict()
    diffs = {}
    for k, tv in tm.items():
        ov = ours.get(k)
        if isinstance(tv, (int, float)) and not isinstance(tv, bool) and isinstance(ov, (int, float)) \
                and not isinstance(ov, bool):
            dv = float(ov) - float(tv)
            if k in ANGLE_KEYS:
                dv = (dv + 180.0) % 360.0 - 180.0
            diffs[k] = {"ours": float(ov), "truth": float(tv), "diff": dv,
                        "sigma": result.metrics_sigma.get(k)}
    out["metrics"] = diffs
    out["table1"] = {
        "mean_err_mm": out["mean_err_mm"], "max_err_mm": out["max_err_mm"],
        "velocity_angle_deg": out.get("velocity_angle_deg_fitted"), "speed_diff_mph": out.get("speed_diff_mph_fitted"),
        "spin_axis_angle_deg": out["spin_axis_angle_deg"], "spin_rate_diff_rpm": out["spin_rate_diff_rpm"],
        "speed_mph": float(np.linalg.norm(result.fit.v0) / MPH),
        "spin_rpm": float(np.linalg.norm(w) * RPM_PER_RAD_S) if result.spin_available else None,
    }
    return out


#: metric keys of truths written before the Statcast movement (issue 14): old key -> today's
_LEGACY_KEYS = {"movement_axis_deg": "pitchfx_spin_dir_deg", "pfx_x_in": "pitchfx_pfx_x_in",
                "pfx_z_in": "pitchfx_pfx_z_in"}


def _current_metric_keys(tm: dict) -> dict:
    """A truth's metrics under today's keys: a capture rendered before the Statcast movement
    holds PITCHf/x movement under ``pfx_x_in``/``pfx_z_in`` and the breaks (and
    ``movement_axis_deg``); those go to the ``pitchfx_`` keys and the breaks are dropped."""
    if "movement_axis_deg" not in tm or "pitchfx_pfx_x_in" in tm:
        return tm
    out = {k: v for k, v in tm.items() if k not in ("induced_vertical_break_in", "horizontal_break_in")}
    for old, new in _LEGACY_KEYS.items():
        if old in out:
            out[new] = out.pop(old)
    return out
