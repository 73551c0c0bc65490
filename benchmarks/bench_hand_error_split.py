"""Where the joint-angle error of another person's hand comes from (issue 12, the hand goal):
the model (built-in, calibrated, the hand's own) against the markers (exact, triangulated), per
joint.

    python benchmarks/bench_hand_error_split.py [--persons 5 6 7 8 9] [--motion protocol|curl]
        [--size 1280x960] [--jsonl runs/hand_error_split.jsonl]

Per person ``p`` (``stillcap.studio.hand_variation.another_hand(p)``):

1. the throw ``hand_capture(100 + p, person=...)`` written as JPEG 92 and analysed with the
   person's own true model (``analyse_hand(--hand-model/--markers own)``): its labelled,
   triangulated markers per flash (the labelling is then the best it can be, so the split
   below is about the fit, not the labels; a wrong label still shows as a large error);
2. the calibration capture ``hand_capture(200 + p, calibration_pose="flat",
   calibration_motion=MOTION)`` calibrated as ``stillcap hand-calibrate`` does ("calibrated"),
   and calibrated again from the capture's exact markers (the truth, 0.3 mm noise, every marker
   seen by two cameras, no spurious points: "calibrated from exact"), which tells apart what the
   calibration's motion cannot fix from what its photos' noise costs;
3. every matched flash fitted with :func:`stillcap.body.hand.fit_hand` (the pipeline's fit of a
   flash) by each model on (a) the exact markers (the truth's, for the markers the pipeline
   labelled) and (b) the triangulated markers, all started from the own model's pose of the
   pipeline; the joint-angle error on the degrees of freedom the seen markers fix
   (:func:`stillcap.body.hand_track.dofs_fixed_by`, the rule of ``observed_dofs``), RMS per joint and overall.

Prints one table per person and the RMS over persons per arm and joint (``--report-only``: of
the rows already in ``--jsonl``). Person 5 at 1280x960 took about 3 CPU-minutes (a loaded
machine: 18 minutes of wall time; no quiet time was measured).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from stillcap.body.hand import fit_hand, hand_markerset, hand_skeleton
from stillcap.body.hand_calibrate import calibrate_hand_from_points
from stillcap.body.hand_label import hand_points_from_truth
from stillcap.body.hand_track import dofs_fixed_by
from stillcap.body.skeleton import Pose
from stillcap.io.capture import Capture
from stillcap.pipelines.hand import analyse_hand
from stillcap.pipelines.hand.calibration import calibrate_hand_capture
from stillcap.studio.compare.hand import compare_with_capture
from stillcap.studio.hand import hand_capture
from stillcap.studio.hand_variation import another_hand

from bench_hand_calibration import resumed_rows  # (run from benchmarks/, as the other scripts import theirs)


def _write(hc, root: Path) -> Capture:
    cap, images = hc.to_capture(".jpg")
    cap.save(root, images, jpeg_quality=92)
    return Capture.load(root)


def split(models: dict, flashes) -> dict:
    """``{arm: {"dof name": [errors deg]}}`` for every model and marker kind.

    ``flashes``: list of ``(exact (M, 3), triangulated (M, 3), start Pose, true angles (J, 3),
    wrong (M,) bool)``; ``wrong`` marks a triangulated marker more than 5 mm from its true place (a
    wrong label): a degree of freedom that rests on one is kept apart (its key ends in
    " (wrong label)"), in both arms, so that the labelling's errors and the fit's are told apart."""
    out = {}
    for mname, (sk, ms) in models.items():
        for kind in ("exact", "triangulated"):
            errs: dict = {}
            for exact, tri, start, truth, wrong in flashes:
                pts = exact if kind == "exact" else tri
                seen = np.isfinite(pts).all(axis=1)
                init = Pose(sk, start.root2world, start.local_rotations)
                try:
                    f = fit_hand(sk, ms, pts, initial=init)
                except ValueError:
                    continue
                ang = sk.limit_angles_deg(f.pose.local_rotations)
                for j, a, need in dofs_fixed_by(sk, ms, seen):
                    key = f"{sk.names[j]} {'xyz'[a]}" + (" (wrong label)" if wrong[need].any() else "")
                    errs.setdefault(key, []).append(float(ang[j, a] - truth[j, a]))
            out[f"{mname}/{kind}"] = errs
    return out


def run_person(p: int, size, motion: str) -> dict:
    who = another_hand(p)
    row = {"person": p, "size": list(size), "motion": motion, "hand_size": who.size}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        throw_hc = hand_capture(100 + p, image_size=size, person=who)
        throw = _write(throw_hc, tmp / "throw")
        who.skeleton.save(tmp / "own.json")
        who.markerset.save(tmp / "own.markers.json")
        res = analyse_hand(throw, hand_model=str(tmp / "own.json"), hand_markers=str(tmp / "own.markers.json"))
        cmp_ = compare_with_capture(res) or {}
        row["own_pipeline_joint_rms_deg"] = cmp_.get("joint_angle_rms_deg")
        cal_hc = hand_capture(200 + p, image_size=size, person=who, calibration_pose="flat",
                              calibration_motion=motion)
        cal_cap = _write(cal_hc, tmp / "cal")
        models = {"built-in": (hand_skeleton(), hand_markerset()), "own": (who.skeleton, who.markerset)}
        try:
            cal = calibrate_hand_capture(cal_cap)
            models["calibrated"] = (cal.skeleton, cal.markerset)
            row["calibrated_parameters"] = [q.to_dict() for q in cal.parameters]
        except ValueError as e:
            row["calibrated_refused"] = str(e)
    try:
        d = hand_points_from_truth(cal_hc.truth, noise_m=0.0003, drop=0.0, n_spurious=0, rng=p)
        cx = calibrate_hand_from_points(d["points"], d["colours"], strobe_hz=cal_hc.truth.strobe_hz)
        models["cal-exact"] = (cx.skeleton, cx.markerset)
        row["cal_exact_parameters"] = [q.to_dict() for q in cx.parameters]
    except ValueError as e:
        row["cal_exact_refused"] = str(e)
    tr = throw_hc.truth
    seq, lab = res.sequence, res.labels
    match = cmp_.get("flash_match", [])
    flashes = []
    if seq is not None:
        vis2 = np.asarray(tr.markers_visible).sum(axis=0) >= 2
        for i, k in enumerate(seq.flashes):
            j = match[k] if k < len(match) else -1
            if j < 0:
                continue
            tri = lab.positions[k]
            exact = np.where((np.isfinite(tri).all(axis=1) & vis2[j])[:, None], tr.markers[j], np.nan)
            wrong = np.nan_to_num(np.linalg.norm(tri - tr.markers[j], axis=1), nan=0.0) > 0.005
            flashes.append((exact, tri, seq.poses[i], tr.angles_deg[j], wrong))
    row["n_flashes"] = len(flashes)
    row["split"] = split(models, flashes)
    return row


def _rms(v) -> float:
    v = np.asarray(v, float)
    return float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")


def report(rows) -> None:
    arms = [f"{m}/{k}" for m in ("built-in", "calibrated", "cal-exact", "own") for k in ("exact", "triangulated")]
    for r in rows:
        s = r["split"]
        extra = " ".join(f"{k}: {r[k][:120]}" for k in ("calibrated_refused", "cal_exact_refused") if k in r)
        print(f"person {r['person']} (size {r['hand_size']:.3f}, {r['n_flashes']} flashes, {r['motion']}; pipeline "
              f"with own model {r['own_pipeline_joint_rms_deg']}) {extra}")
        print("  " + "  ".join(f"{a}: {_rms(sum(s[a].values(), [])):.2f}" for a in arms if a in s))
    print("\nRMS over persons per joint (deg); columns: " + ", ".join(arms))
    keys = sorted({k for r in rows for a in r["split"].values() for k in a})
    for key in keys:
        vals = []
        for a in arms:
            v = sum((r["split"].get(a, {}).get(key, []) for r in rows), [])
            vals.append(f"{_rms(v):6.2f}" if v else "     -")
        print(f"{key:>30} " + " ".join(vals))
    tot = []
    for a in arms:
        v = sum((sum(r["split"].get(a, {}).values(), []) for r in rows), [])
        tot.append(f"{_rms(v):6.2f}" if v else "     -")
    print(f"{'all':>30} " + " ".join(tot))
    tot = []
    for a in arms:
        v = sum((sum((e for k, e in r["split"].get(a, {}).items() if not k.endswith("(wrong label)")), [])
                 for r in rows), [])
        tot.append(f"{_rms(v):6.2f}" if v else "     -")
    print(f"{'right labels':>30} " + " ".join(tot))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--persons", type=int, nargs="+", default=[5, 6, 7, 8, 9])
    ap.add_argument("--motion", default="protocol")
    ap.add_argument("--size", default="1280x960")
    ap.add_argument("--jsonl", type=Path)
    ap.add_argument("--report-only", action="store_true", help="print the table of the rows in --jsonl")
    a = ap.parse_args()
    size = tuple(int(v) for v in a.size.split("x"))
    rows = resumed_rows(a.jsonl, a.motion, size, [] if a.report_only else a.persons, run_person,
                        lambda r: print(f"person {r['person']} done", flush=True))
    report([r for r in rows if r["person"] in a.persons])


if __name__ == "__main__":
    main()
