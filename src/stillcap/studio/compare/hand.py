"""A hand result against the studio's truth (``truth.json`` of ``stillcap studio hand``).

:func:`truth_arrays` reads the truth's arrays, :func:`compare_with_truth` scores flashes, labels,
3D markers, joint angles, the ball and the release (a dict, keys named with their units), and
:func:`compare_with_capture` compares a result with the truth its capture holds. The pipeline
(:mod:`stillcap.pipelines.hand`) never sees a truth: the CLI, the demo and the benchmarks call
these and keep the comparison in :attr:`HandResult.truth <stillcap.pipelines.hand.HandResult>`.
"""

from __future__ import annotations

import numpy as np

from stillcap.body.hand_track import dofs_fixed_by, observed_dofs
from stillcap.files.jsonable import from_jsonable
from stillcap.io.capture import Capture
from stillcap.pipelines.hand import HandResult

__all__ = ["LABEL_TOLERANCE_M", "truth_arrays", "compare_with_truth", "compare_with_capture"]

#: A label is right when the true marker nearest its point is the one it names and within this
#: distance (m); farther, the point is spurious.
LABEL_TOLERANCE_M = 0.010


def truth_arrays(truth: dict) -> dict:
    """The arrays of a hand ``truth.json`` (dict) by name: ``times``, ``markers``, ``angles_deg``,
    ``root2world``, ``joints``, ``visible`` (per camera), ``ball`` (centres); NaN for null."""
    f = truth["flashes"]
    n, nm, nj = len(f["times_s"]), len(truth["marker_names"]), len(truth["joint_names"])
    nc = len(truth["cameras"])
    return {"times": from_jsonable(f["times_s"]).reshape(n),
            "markers": from_jsonable(f["markers"]).reshape(n, nm, 3),
            "angles_deg": from_jsonable(f["angles_deg"]).reshape(n, nj, 3),
            "root2world": from_jsonable(f["root2world"]).reshape(n, 4, 4),
            "joints": from_jsonable(f["joints"]).reshape(n, nj, 3),
            "visible": from_jsonable(f["markers_visible"]).reshape(nc, n, nm).astype(bool),
            "ball": from_jsonable(f["ball2world"]).reshape(n, 4, 4)[:, :3, 3]}


def compare_with_truth(result: HandResult, truth: dict) -> dict:
    """Errors of a hand result against the studio's ``truth.json`` (dict).

    Flashes are matched by time: the result's clock starts at its first hand flash, so the
    offset to the truth's clock is the one that puts the result's flashes on truth flashes
    (the nearest back-of-hand position decides the first). Returns counts and errors in mm,
    deg, ms and mph (keys named with their units).

    Partly hidden markers (:attr:`MarkerPoints.partly_hidden
    <stillcap.geometry.marker_points.MarkerPoints.partly_hidden>`: a view saw part of the marker,
    its centroid shifts) are scored apart: ``marker_rms_mm`` / ``marker_max_mm`` and
    ``markers_recovered_pct`` count the fully seen ones only; ``partly_hidden_labels``,
    ``partly_hidden_labels_right``, ``partly_hidden_rms_mm``, ``partly_hidden_max_mm`` and
    ``markers_recovered_partly_hidden_pct`` the partly hidden ones.
    """
    from stillcap.body.hand import hand_dofs

    tr = truth_arrays(truth)
    lab = result.labels
    names = list(lab.marker_names)
    if names != list(truth["marker_names"]):
        raise ValueError("the result's markers are not the truth's (different marker sets)")
    # match flashes: the result's first flash is the truth flash whose back of the hand is nearest
    back = [names.index(n) for n in ("back.1", "back.2", "back.3")]
    period = 1.0 / result.strobe_hz
    match = np.full(lab.n_flashes, -1)
    best = None
    for k in range(lab.n_flashes):
        b = lab.positions[k, back]
        if np.all(np.isfinite(b)):
            d = np.nanmean(np.linalg.norm(tr["markers"][:, back] - b[None], axis=2), axis=1)
            j = int(np.argmin(d))
            best = (k, j)
            break
    if best is not None:
        k0, j0 = best
        t_off = tr["times"][j0] - lab.times[k0]
        for k in range(lab.n_flashes):
            j = int(np.argmin(np.abs(tr["times"] - (lab.times[k] + t_off))))
            if abs(tr["times"][j] - (lab.times[k] + t_off)) < 0.25 * period:
                match[k] = j
    else:
        t_off = np.nan
    # labels and marker errors: a label is right when the true marker nearest its point (same
    # flash) is the one it names, within LABEL_TOLERANCE_M (farther: a spurious point)
    # partly hidden markers (a view saw part of the marker: its centroid shifts) are scored apart
    # and never counted as recovered with the fully seen ones (issue 12, part 4)
    hidden = result.points.partly_hidden if len(result.points) == len(lab.points) else np.zeros(len(lab.points), bool)
    n_lab = n_right = n_hid = n_hid_right = 0
    errs, hid_errs = [], []
    for k in range(lab.n_flashes):
        if match[k] < 0:
            n_lab += int(np.sum(lab.point_index[k] >= 0))
            continue
        T = tr["markers"][match[k]]
        for j in range(len(names)):
            pi = lab.point_index[k, j]
            if pi < 0:
                continue
            n_lab += 1
            n_hid += bool(hidden[pi])
            d = np.linalg.norm(T - lab.positions[k, j], axis=1)
            if int(np.nanargmin(d)) == j and d[j] <= LABEL_TOLERANCE_M:
                n_right += 1
                if hidden[pi]:
                    n_hid_right += 1
                    hid_errs.append(d[j])
                else:
                    errs.append(d[j])
    errs, hid_errs = np.asarray(errs), np.asarray(hid_errs)
    # markers the truth shows in 2+ cameras, per matched flash
    seen2 = tr["visible"].sum(axis=0) >= 2
    n_seen2 = int(sum(seen2[j].sum() for j in match if j >= 0))
    # joint angles: on the degrees of freedom the seen markers fix, and on all of them; those that
    # only a partly hidden marker fixes (its centroid shifted) are scored apart, as its 3D error is
    ang_err, ang_hid, ang_all, joint_err = [], [], [], []
    seq = result.sequence
    if seq is not None:
        dofs = hand_dofs(seq.skeleton)
        for i, (k, a, p) in enumerate(zip(seq.flashes, seq.angles_deg, seq.poses)):
            j = match[k]
            if j < 0:
                continue
            ang_all.extend(a[q, ax] - tr["angles_deg"][j, q, ax] for q, ax in dofs)
            pi = lab.point_index[k]
            whole = np.isfinite(seq.residuals[i]) & (pi >= 0) & ~hidden[np.maximum(pi, 0)]
            by_whole = {(q, ax) for q, ax, _ in dofs_fixed_by(seq.skeleton, seq.markerset, whole)}
            for q, ax in observed_dofs(seq, i):
                (ang_err if (q, ax) in by_whole else ang_hid).append(a[q, ax] - tr["angles_deg"][j, q, ax])
            joint_err.extend(np.linalg.norm(p.positions - tr["joints"][j], axis=1))
    ang_all, ang_hid = np.asarray(ang_all), np.asarray(ang_hid)
    ang_err, joint_err = np.asarray(ang_err), np.asarray(joint_err)
    back_seen = (tr["visible"][:, :, back].sum(axis=0) >= 2).all(axis=1)
    out = {"flashes_true": len(tr["times"]), "flashes_back_seen_2plus": int(back_seen.sum()),
           "flashes_found": int(lab.n_flashes), "flashes_matched": int(np.sum(match >= 0)),
           "flashes_reconstructed": int(lab.reconstructed.sum()),
           # of the flashes whose back of the hand 2+ cameras see, those with a pose (the others
           # with a pose were posed from their neighbours' markers)
           "flashes_reconstructed_back_seen": int(sum(1 for k, j in enumerate(match)
                                                      if j >= 0 and lab.reconstructed[k] and back_seen[j])),
           "flash_match": match.tolist(), "clock_offset_s": float(t_off),
           "labels": n_lab, "labels_right": n_right,
           "labels_right_pct": 100.0 * n_right / n_lab if n_lab else None,
           "markers_seen_2plus": n_seen2,
           "markers_recovered_pct": 100.0 * (n_right - n_hid_right) / n_seen2 if n_seen2 else None,
           "markers_recovered_partly_hidden_pct": 100.0 * n_hid_right / n_seen2 if n_seen2 else None,
           "marker_rms_mm": float(np.sqrt(np.mean(errs ** 2)) * 1e3) if len(errs) else None,
           "marker_max_mm": float(errs.max() * 1e3) if len(errs) else None,
           "partly_hidden_labels": n_hid, "partly_hidden_labels_right": n_hid_right,
           "partly_hidden_rms_mm": float(np.sqrt(np.mean(hid_errs ** 2)) * 1e3) if len(hid_errs) else None,
           "partly_hidden_max_mm": float(hid_errs.max() * 1e3) if len(hid_errs) else None,
           "joint_angle_rms_deg": float(np.sqrt(np.mean(ang_err ** 2))) if len(ang_err) else None,
           "joint_angle_max_deg": float(np.abs(ang_err).max()) if len(ang_err) else None,
           "joint_angles_compared": len(ang_err),
           "joint_angle_rms_partly_hidden_deg": float(np.sqrt(np.mean(ang_hid ** 2))) if len(ang_hid) else None,
           "joint_angles_compared_partly_hidden": len(ang_hid),
           "joint_angle_rms_all_deg": float(np.sqrt(np.mean(ang_all ** 2))) if len(ang_all) else None,
           "joint_rms_mm": float(np.sqrt(np.mean(joint_err ** 2)) * 1e3) if len(joint_err) else None}
    if result.balls is not None and len(result.balls) and np.isfinite(t_off):
        be = []
        for tb, pb in zip(result.balls.times, result.balls.positions):
            j = int(np.argmin(np.abs(tr["times"] - (tb + t_off))))
            if abs(tr["times"][j] - (tb + t_off)) < 0.25 * period:
                be.append(np.linalg.norm(pb - tr["ball"][j]))
        out["ball_positions"] = len(be)
        out["ball_mean_mm"] = float(np.mean(be) * 1e3) if be else None
        out["ball_max_mm"] = float(np.max(be) * 1e3) if be else None
    rel = result.release
    if rel is not None and rel.success and np.isfinite(t_off):
        tr_rel = truth["release"]
        v_true = np.asarray(tr_rel["v0"], float)
        out["release_time_ms"] = float((rel.t_release + t_off - tr_rel["t0_s"]) * 1e3)
        out["release_point_mm"] = float(np.linalg.norm(rel.position - np.asarray(tr_rel["p0"], float)) * 1e3)
        out["release_speed_mph"] = float(rel.speed_mph - np.linalg.norm(v_true) / 0.44704)
        cosang = rel.velocity @ v_true / (np.linalg.norm(rel.velocity) * np.linalg.norm(v_true))
        out["release_direction_deg"] = float(np.degrees(np.arccos(np.clip(cosang, -1, 1))))
        out["release_time_sigma_ms"] = float(rel.t_release_sigma * 1e3)
        out["release_speed_sigma_mph"] = float(rel.speed_sigma_mph)
    return out


def compare_with_capture(result: HandResult, capture: Capture | None = None) -> dict | None:
    """:func:`compare_with_truth` against the truth of ``capture`` (default the result's own
    capture); None when it holds no hand truth."""
    cap = result.capture if capture is None else capture
    if cap.truth is not None and cap.truth.get("kind") == "hand":
        return compare_with_truth(result, cap.truth)
    return None
