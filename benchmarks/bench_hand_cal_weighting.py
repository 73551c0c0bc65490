"""The hand calibration with every labelled marker at its own noise (partly hidden markers weighed
less, as the throw's pose fit weighs them) against the calibration at one common noise, per
person (issue 12, the hand goal: joint angles <= 2 deg on another person's hand).

    python benchmarks/bench_hand_cal_weighting.py --cache DIR --work DIR [--persons 5 6 7 8 10 11 12 13 14]
        [--motion curl|protocol|curl+protocol] [--labels own|cal-curl] [--jsonl FILE] [--joints]
        [--arms two|all|own]

``--cache DIR`` holds per person ``p`` the rendered captures ``p{p}/cal-{motion}`` (the
calibration capture, ``hand_capture(200 + p, person=another_hand(p), calibration_pose="flat",
calibration_motion=motion)``) and ``p{p}/throw`` (``hand_capture(100 + p, person=...)``), both
JPEG 92 at 1280x960 as ``bench_hand_calibration.py`` writes them; it is only read. When
``p{p}/res-{labels}.pkl`` (a pickled ``HandResult`` of the throw) is there it is used, else
the throw is analysed with ``analyse_hand`` and the model named by ``--labels`` (``own``: the
person's true model, ``p{p}/own.json``) and pickled in ``--work``. Every step's product is
pickled in ``--work`` (the calibration capture's 3D markers, each arm's calibration), so a
second run only scores.

``--motion curl+protocol``: both calibration captures of the person fitted together (as
``stillcap hand-calibrate CURL_CAPTURE PROTOCOL_CAPTURE``).

Arms (both as ``stillcap hand-calibrate`` does, :func:`calibrate_hand_capture`'s stages):

- ``common``: every labelled marker at ``hand_calibrate.NOISE_M`` (``--marker-noise common``);
- ``own noise`` (``--marker-noise own``, the default): each marker at its own noise from what the photos show
  (:func:`stillcap.pipelines.hand.stages.marker_sigma`: fully seen markers at ``NOISE_M``,
  partly hidden ones at ``HIDDEN_SIGMA_M`` divided by the share of their light the worst view
  got), and partly hidden two-view points need a second labelled marker on their digit
  (``unconfirmed``), as the throw's labelling does.

Score: the throw's labelled markers (the same labels for both arms, so the difference is the
model's shape) fitted with ``fit_hand_sequence`` as the pipeline's stage 5 does (each point at
its own noise), compared with the truth (``compare_with_capture``): joint angles RMS and max on
the degrees of freedom the fully seen markers fix, RMS on those fixed only by partly hidden ones,
and (``--joints``) the RMS per joint degree of freedom; per hand, the labelled partly hidden
markers' 3D errors against their stated noise (3 mm over the share of the light). Labels and marker RMS do not depend on
the model here (fixed labels): end to end is ``bench_hand_calibration.py``.

Times (process CPU, a loaded machine, no quiet time measured): 12-42 s per arm's calibration on
hands 5, 7 and 8; the calibrations of hands 6, 10-12 and 14 took longer than the session allowed at
load 25-40 (20-40 minutes of wall time each).
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ARMS = ("common", "own noise")
#: ``--arms all`` also: the two parts of ``own noise`` apart
ALL_ARMS = ARMS + ("weights only", "unconfirmed only")


def _pickled(path: Path, make):
    if path.exists():
        with path.open("rb") as f:
            return pickle.load(f)
    out = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        pickle.dump(out, f)
    return out


def calibration_points(cache: Path, work: Path, p: int, motion: str):
    """``(MarkerPoints, strobe_hz)`` of the calibration capture (stages 1-3 of hand-calibrate)."""
    from stillcap.io.capture import Capture
    from stillcap.pipelines.hand.options import HandOptions
    from stillcap.pipelines.hand.stages import (find_glove_markers, hand_setup, read_hand_photos,
                                                triangulate_glove_markers)

    def make():
        cap = Capture.load(cache / f"p{p}" / f"cal-{motion}")
        setup = hand_setup(cap, None)
        images = read_hand_photos(cap, setup.pairs)
        blobs = find_glove_markers(images, None, cap.rig)
        pts = triangulate_glove_markers(cap.rig, setup.pairs, blobs, setup.light, HandOptions(), [], setup.where)
        return pts, setup.strobe_hz

    return _pickled(work / f"p{p}" / f"cal-{motion}.points.pkl", make)


def calibrate(points, strobe_hz: float, arm: str):
    from stillcap.body.hand_calibrate import calibrate_hand_from_points
    from stillcap.pipelines.hand.calibration import calibration_weights

    kw = calibration_weights(points) if arm != "common" else {}
    if arm == "weights only":
        kw.pop("unconfirmed")
    elif arm == "unconfirmed only":
        kw.pop("point_sigma_m")
    return calibrate_hand_from_points(points.points, points.colors, strobe_hz=strobe_hz,
                                      reprojection_px=points.reprojection_px, **kw)


def calibrate_sets(point_sets, arm: str):
    """Several calibration captures of one hand fitted together (``--motion curl+protocol``), as
    ``stillcap hand-calibrate CAPTURE CAPTURE ...`` does; ``point_sets``: ``(MarkerPoints,
    strobe_hz)`` per capture."""
    from stillcap.body.hand_calibrate import CalibrationPoints, calibrate_hand_from_point_sets
    from stillcap.pipelines.hand.calibration import calibration_weights

    if arm not in ARMS:
        raise ValueError(f"--arms {arm!r} is not measured for several captures")
    sets = []
    for pts, hz in point_sets:
        w = calibration_weights(pts) if arm != "common" else {}
        sets.append(CalibrationPoints(pts.points, pts.colors, hz, pts.reprojection_px, w.get("point_sigma_m"),
                                      w.get("unconfirmed")))
    return calibrate_hand_from_point_sets(sets)


def throw_result(cache: Path, work: Path, p: int, labels: str):
    have = cache / f"p{p}" / f"res-{labels}.pkl"
    if have.exists():
        with have.open("rb") as f:
            return pickle.load(f)

    def make():
        from stillcap.io.capture import Capture
        from stillcap.pipelines.hand import analyse_hand

        d = cache / f"p{p}"
        kw = {"hand_model": str(d / "own.json"), "hand_markers": str(d / "own.markers.json")} if labels == "own" else {}
        return analyse_hand(Capture.load(d / "throw"), **kw)

    return _pickled(work / f"p{p}" / f"res-{labels}.pkl", make)


def per_joint(res, seq, truth_angles, match) -> dict:
    """RMS (deg) per ``joint axis`` over the degrees of freedom the fully seen markers fix."""
    from stillcap.body.hand_track import dofs_fixed_by, observed_dofs

    lab, hidden = res.labels, res.points.partly_hidden
    errs: dict = {}
    for i, (k, a) in enumerate(zip(seq.flashes, seq.angles_deg)):
        j = match[k]
        if j < 0:
            continue
        pi = lab.point_index[k]
        whole = np.isfinite(seq.residuals[i]) & (pi >= 0) & ~hidden[np.maximum(pi, 0)]
        by_whole = {(q, ax) for q, ax, _ in dofs_fixed_by(seq.skeleton, seq.markerset, whole)}
        for q, ax in observed_dofs(seq, i):
            if (q, ax) in by_whole:
                errs.setdefault(f"{seq.skeleton.names[q]} {'xyz'[ax]}", []).append(a[q, ax] - truth_angles[j, q, ax])
    return {n: float(np.sqrt(np.mean(np.square(v)))) for n, v in errs.items()}


def score(res, skeleton, markerset, joints: bool) -> dict:
    from stillcap.body.hand_track import fit_hand_sequence
    from stillcap.pipelines.hand.stages import marker_sigma

    lab = res.labels
    sig = marker_sigma(res.points)
    seq = fit_hand_sequence(lab, skeleton, markerset, times=lab.times, point_sigma_m=sig)
    out = score_result(replace(res, sequence=seq), joints)
    out.update(hidden_noise(res, seq, sig))
    return out


def hidden_noise(res, seq, stated) -> dict:
    """The labelled, partly hidden markers' 3D errors against their stated noise (``marker_sigma``,
    per axis): median error and noise, how often the error lies within the noise's 95 % sphere
    (``sqrt(chi2.ppf(0.95, 3))`` sigmas) and the fit's residuals in sigmas (RMS per axis); labels
    farther than 8 mm from their marker (wrong labels) are left out."""
    from scipy.stats import chi2

    from stillcap.studio.compare.hand import compare_with_capture, truth_arrays

    match = np.asarray(compare_with_capture(res)["flash_match"])
    truth = truth_arrays(res.capture.truth)["markers"]
    e, s, r = [], [], []
    for i, k in enumerate(seq.flashes):
        for m, q in enumerate(res.labels.point_index[k]):
            if q >= 0 and match[k] >= 0 and res.points.partly_hidden[q]:
                d = float(np.linalg.norm(res.labels.positions[k, m] - truth[match[k], m]))
                if d <= 0.008:
                    e.append(d), s.append(stated[q]), r.append(seq.residuals[i, m])
    if not e:
        return {}
    e, s, r = map(np.asarray, (e, s, r))
    return {"hidden_n": len(e), "hidden_err_mm": float(np.median(e) * 1e3),
            "hidden_sigma_mm": float(np.median(s) * 1e3),
            "hidden_cover_pct": 100.0 * float(np.mean(e <= np.sqrt(chi2.ppf(0.95, 3)) * s)),
            "hidden_err_sigmas": float(np.sqrt(np.mean((e / s) ** 2) / 3)),
            "hidden_resid_sigmas": float(np.sqrt(np.nanmean((r / s) ** 2) / 3))}


def score_result(res, joints: bool) -> dict:
    """The joint-angle score of ``res``'s own pose sequence (``built-in``: the throw as
    ``stillcap hand`` gives it without a calibration)."""
    from stillcap.studio.compare.hand import compare_with_capture, truth_arrays

    c = compare_with_capture(res)
    out = {k: c.get(k) for k in ("joint_angle_rms_deg", "joint_angle_max_deg", "joint_angle_rms_partly_hidden_deg",
                                 "joint_angles_compared", "labels_right_pct", "markers_recovered_pct", "marker_rms_mm")}
    if joints:
        out["per_joint"] = per_joint(res, res.sequence, truth_arrays(res.capture.truth)["angles_deg"],
                                     np.asarray(c["flash_match"]))
    return out


def model_errors(cal, own_skeleton) -> dict:
    """Per joint offset, the calibrated model's error against the person's true one (mm)."""
    e = np.linalg.norm(cal.skeleton.offsets - own_skeleton.offsets, axis=1) * 1e3
    return {n: float(v) for n, v in zip(cal.skeleton.names, e) if v > 0}


def run_person(cache: Path, work: Path, p: int, motion: str, labels: str, joints: bool, arms=ARMS) -> dict:
    from stillcap.body.markerset import MarkerSet
    from stillcap.body.skeleton import Skeleton

    row = {"person": p, "motion": motion, "labels": labels}
    t = time.process_time()
    motions = motion.split("+")  # several calibration captures fitted together: curl+protocol
    point_sets = [calibration_points(cache, work, p, m) for m in motions]
    row["cpu_points_s"] = round(time.process_time() - t, 1)
    res = throw_result(cache, work, p, labels)
    own = Skeleton.load(cache / f"p{p}" / "own.json")
    # the reference: the same labels fitted with the person's true model (no calibration error)
    row["own"] = score(res, own, MarkerSet.load(cache / f"p{p}" / "own.markers.json"), joints)
    if labels == "cal-curl" and not (cache / f"p{p}" / "res-cal-curl.pkl").exists():
        row["built-in"] = score_result(res, joints)  # the throw analysed with the built-in model
    for arm in arms:
        t = time.process_time()
        try:
            make = ((lambda arm=arm: calibrate(*point_sets[0], arm)) if len(point_sets) == 1 else
                    (lambda arm=arm: calibrate_sets(point_sets, arm)))
            cal = _pickled(work / f"p{p}" / f"cal-{motion}.{arm.replace(' ', '-')}.pkl", make)
        except ValueError as e:
            row[arm] = {"refused": str(e)}
            continue
        s = score(res, cal.skeleton, cal.markerset, joints)
        s.update({"cal_rms_mm": cal.rms * 1e3, "n_free": cal.n_free,
                  "unfixed": [q.name for q in cal.parameters if q.kind != "height" and q.fixed > 0.7],
                  "cpu_s": round(time.process_time() - t, 1)})
        if joints:
            s["model_err_mm"] = model_errors(cal, own)
        row[arm] = s
    return row


def _f(v, d=2):
    return "-" if v is None else f"{v:.{d}f}"


def report(rows, joints: bool, arms=ARMS) -> None:
    print(f"{'person':>6} {'arm':>10} {'joints RMS':>10} {'max':>6} {'partly hidden':>13} {'n':>5} {'cal fit mm':>10}"
          "  not fixed")
    for r in rows:
        for arm in arms + ("own", "built-in"):
            v = r.get(arm)
            if arm in ("own", "built-in") and v is not None:
                print(f"{r['person']:>6} {arm:>10} {_f(v['joint_angle_rms_deg']):>10} {_f(v['joint_angle_max_deg'], 1):>6} "
                      f"{_f(v['joint_angle_rms_partly_hidden_deg']):>13} {v['joint_angles_compared']:>5}")
                continue
            if v is None:
                continue
            if "refused" in v:
                print(f"{r['person']:>6} {arm:>10} refused: {v['refused']}")
                continue
            print(f"{r['person']:>6} {arm:>10} {_f(v['joint_angle_rms_deg']):>10} {_f(v['joint_angle_max_deg'], 1):>6} "
                  f"{_f(v['joint_angle_rms_partly_hidden_deg']):>13} {v['joint_angles_compared']:>5} "
                  f"{_f(v['cal_rms_mm']):>10}  {', '.join(v['unfixed']) or '-'}")
    for arm in arms + ("own", "built-in"):
        v = [r[arm]["joint_angle_rms_deg"] for r in rows if "joint_angle_rms_deg" in r.get(arm, {})]
        h = [r[arm]["joint_angle_rms_partly_hidden_deg"] for r in rows
             if (r.get(arm, {}).get("joint_angle_rms_partly_hidden_deg")) is not None]
        if v:
            print(f"{arm}: joints RMS over persons (RMS of RMS) {np.sqrt(np.mean(np.square(v))):.2f} deg, worst "
                  f"{max(v):.2f}, <= 2 deg on {sum(x <= 2 for x in v)} of {len(v)}; partly hidden "
                  f"{np.sqrt(np.mean(np.square(h))):.2f} deg" if h else "")
    for r in rows:
        for arm in arms + ("own",):
            v = r.get(arm, {})
            if "hidden_n" in v:
                print(f"{r['person']:>3} {arm:>10} partly hidden labels {v['hidden_n']}: 3D error {v['hidden_err_mm']:.2f} mm "
                      f"against {v['hidden_sigma_mm']:.2f} mm stated (medians); 95 % sphere covers "
                      f"{v['hidden_cover_pct']:.0f} %; error {v['hidden_err_sigmas']:.2f}, residual "
                      f"{v['hidden_resid_sigmas']:.2f} sigmas per axis (RMS)")
    if joints:
        for r in rows:
            for arm in arms + ("own", "built-in"):
                pj = r.get(arm, {}).get("per_joint")
                if pj:
                    worst = sorted(pj.items(), key=lambda kv: -kv[1])[:6]
                    me = sorted(r[arm].get("model_err_mm", {}).items(), key=lambda kv: -kv[1])[:5]
                    print(f"{r['person']:>3} {arm:>10} worst joints: " + ", ".join(f"{n} {v:.1f}" for n, v in worst)
                          + " | worst offsets mm: " + ", ".join(f"{n} {v:.1f}" for n, v in me))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--persons", type=int, nargs="+", default=[5, 6, 7, 8, 10, 11, 12, 13, 14])
    ap.add_argument("--motion", default="curl")
    ap.add_argument("--labels", default="cal-curl")
    ap.add_argument("--jsonl", type=Path)
    ap.add_argument("--joints", action="store_true")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--arms", choices=("two", "all", "own"), default="two",
                    help="two: common and own noise; all: also the weights and the unconfirmed flags apart; "
                         "own: own noise alone (the default weighting of hand-calibrate)")
    a = ap.parse_args()
    rows = []
    if a.jsonl is not None and a.jsonl.exists():
        rows = [json.loads(s) for s in a.jsonl.read_text().splitlines() if s.strip()]
        rows = [r for r in rows if r["motion"] == a.motion and r["labels"] == a.labels]
    arms = {"all": ALL_ARMS, "two": ARMS, "own": ("own noise",)}[a.arms]
    done = {r["person"] for r in rows if all(arm in r for arm in arms)}
    rows = [r for r in rows if r["person"] in done]
    for p in a.persons:
        if p in done or a.report_only:
            continue
        r = run_person(a.cache, a.work, p, a.motion, a.labels, a.joints, arms)
        rows.append(r)
        if a.jsonl is not None:
            with a.jsonl.open("a") as f:
                f.write(json.dumps(r) + "\n")
        print(json.dumps({k: v for k, v in r.items()}), flush=True)
    report([r for r in rows if r["person"] in a.persons], a.joints, arms)


if __name__ == "__main__":
    main()
