"""Robustness rows of the hand (issue 12, part 6): labelling and poses on studio hands unlike the
model the pipeline ships.

    python benchmarks/_robust_hand.py [--quick]

Each condition draws hands (``stillcap.studio.hand_variation.another_hand``: size, per-phalanx
proportions, knuckle splay, thumb axis, marker heights, own motion, light and cameras; seeded),
takes the studio truth of a throw (``hand_capture`` at 320x240: only the truth is used) and
makes the 3D markers the triangulation would give (``hand_points_from_truth``: markers seen by
2+ cameras, Gaussian noise 0.3 mm per axis, 3 spurious points, shuffled). Then the labelling
(``label_hand_markers``) and the per-flash poses (``fit_hand_sequence``), with the built-in
model, with the hand's own model (as ``--hand-model`` / ``--markers`` give it), or with
``adapted`` the model adapted to the hand first (``stillcap.body.hand_adapt.label_and_adapt``).

What this measures: the labelling and the hand model, not the photos (no rendering, no
detection or triangulation; the marker RMS is the noise put in). Metrics per condition:
labels right (% of the labels given), markers seen twice that got a label (%), marker RMS
(labelled point to true marker, mm), joint-angle RMS on the degrees of freedom the seen markers
fix (deg), captures lost (no flash with a pose although one showed its back-of-hand markers
to 2+ cameras), flashes posed (of the throw's flashes). ``quick`` (2 hands per condition, no adaptation rows) runs in about a minute
on a quiet machine; the times were not measured on one.
"""

from __future__ import annotations

import argparse

import numpy as np

from stillcap.body.hand import hand_markerset, hand_skeleton
from stillcap.body.hand_label import hand_points_from_truth, label_hand_markers
from stillcap.body.hand_track import fit_hand_sequence, observed_dofs
from stillcap.studio.hand import hand_capture
from stillcap.studio.hand_variation import another_hand

from bench_hand_labels import flash_of_groups

NOISE_M = 0.0003


def _calibrated(seed: int, person):
    """The hand's model from a studio calibration capture (``--calibration-pose flat``, the
    protocol motion) through ``stillcap.body.hand_calibrate`` on its 3D markers (as ``_one``)."""
    from stillcap.body.hand_calibrate import calibrate_hand_from_points

    tr = hand_capture(seed + 1000, image_size=(320, 240), supersample=1, person=person, calibration_pose="flat").truth
    d = hand_points_from_truth(tr, noise_m=NOISE_M, drop=0.0, n_spurious=3, rng=seed + 1000)
    cal = calibrate_hand_from_points(d["points"], d["colours"], strobe_hz=tr.strobe_hz)
    return cal.skeleton, cal.markerset


def _one(seed: int, person, adapted: bool, own: bool = False, calibrated: bool = False) -> dict:
    truth = hand_capture(seed, image_size=(320, 240), supersample=1, person=person).truth
    d = hand_points_from_truth(truth, noise_m=NOISE_M, drop=0.0, n_spurious=3, rng=seed)
    if calibrated:  # the model from a calibration capture (stillcap hand-calibrate), then --hand-model
        sk, ms = _calibrated(seed, person)
        lab = label_hand_markers(d["points"], d["colours"], strobe_hz=truth.strobe_hz, skeleton=sk, markerset=ms)
    elif adapted:
        from stillcap.body.hand_adapt import label_and_adapt

        lab, _ = label_and_adapt(d["points"], d["colours"], strobe_hz=truth.strobe_hz, skeleton=hand_skeleton(),
                                 markerset=hand_markerset())
    elif own:  # the hand's own model, as given with --hand-model / --markers
        lab = label_hand_markers(d["points"], d["colours"], strobe_hz=truth.strobe_hz, skeleton=person.skeleton,
                                 markerset=person.markerset)
    else:
        lab = label_hand_markers(d["points"], d["colours"], strobe_hz=truth.strobe_hz)
    fmap = flash_of_groups(lab, d["flash"])
    lp = lab.labels()
    given = lp[:, 0] >= 0
    right = np.array([g and fmap[lp[i, 0]] == d["flash"][i] and lp[i, 1] == d["marker"][i]
                      for i, g in enumerate(given)], bool)
    real = d["flash"] >= 0
    err = np.linalg.norm(d["points"][right] - truth.markers[d["flash"][right], d["marker"][right]], axis=1)
    ang, ang_nb = [], []  # flashes posed from their back-of-hand triplet | from their neighbours
    if lab.reconstructed.any():
        seq = fit_hand_sequence(lab)
        for i, k in enumerate(fmap[seq.flashes]):
            e = [seq.angles_deg[i, j, a] - truth.angles_deg[k, j, a] for j, a in observed_dofs(seq, i)]
            if lab.pose_source and lab.pose_source[seq.flashes[i]] == "neighbours":
                ang_nb += e
            else:
                ang += e
    back_seen = (truth.markers_visible.sum(axis=0) >= 2)[:, :3].all(axis=1).any()
    return {"given": int(given.sum()), "right": int(right.sum()), "seen2": int(real.sum()),
            "labelled": int((right & real).sum()), "err": err, "ang": np.asarray(ang), "ang_nb": np.asarray(ang_nb),
            "lost": bool(back_seen and not lab.reconstructed.any()), "posed": int(lab.reconstructed.sum()),
            "posed_nb": sum(1 for x in (lab.pose_source or []) if x == "neighbours"),
            "flashes": int(truth.n)}


CONDITIONS = {
    "default hand": dict(person=lambda s: None),
    "another hand (±15 % size, own proportions)": dict(person=lambda s: another_hand(s)),
    "hand 15 % larger": dict(person=lambda s: another_hand(s, size=1.15)),
    "hand 15 % smaller": dict(person=lambda s: another_hand(s, size=0.85)),
}


def rows(quick: bool = False) -> list[dict]:
    """One dict per condition (keys ``pipeline``, ``condition``, ``n`` and the metrics)."""
    n = 2 if quick else 8
    other = CONDITIONS["another hand (±15 % size, own proportions)"]["person"]
    conds = [(name, c["person"], False, False, False) for name, c in CONDITIONS.items()]
    conds.append(("another hand, its own model file (--hand-model, --markers)", other, False, True, False))
    if not quick:
        conds.append(("another hand, model adapted to it", other, True, False, False))
        conds.append(("another hand, calibrated model (hand-calibrate, protocol)", other, False, False, True))
    out = []
    for name, person, adapted, own, calibrated in conds:
        rs = [_one(100 + s, person(100 + s), adapted, own, calibrated) for s in range(n)]
        given = sum(r["given"] for r in rs)
        err = np.concatenate([r["err"] for r in rs])
        ang = np.concatenate([r["ang"] for r in rs])
        ang_nb = np.concatenate([r["ang_nb"] for r in rs])
        both = np.concatenate([ang, ang_nb])
        rms = lambda v: float(np.sqrt(np.mean(v ** 2))) if len(v) else None  # noqa: E731
        out.append({"pipeline": "hand", "condition": name, "n": n,
                    "label_accuracy_pct": 100.0 * sum(r["right"] for r in rs) / given if given else None,
                    "seen_twice_labelled_pct": 100.0 * sum(r["labelled"] for r in rs) / max(1, sum(r["seen2"] for r in rs)),
                    "marker_rms_mm": float(np.sqrt(np.mean(err ** 2)) * 1e3) if len(err) else None,
                    "joint_angle_rms_deg": rms(both),
                    # apart: flashes posed from their back-of-hand triplet, and those posed from their
                    # neighbours (no back-of-hand triplet: the palm rests on the fingers and the model)
                    "joint_angle_rms_triplet_deg": rms(ang), "joint_angle_rms_neighbours_deg": rms(ang_nb),
                    "captures_lost": int(sum(r["lost"] for r in rs)),
                    "flashes_posed": f"{sum(r['posed'] for r in rs)}/{sum(r['flashes'] for r in rs)}"
                                     f" ({sum(r['posed_nb'] for r in rs)} from neighbours)",
                    "source": "3D markers from the studio truth (0.3 mm noise per axis), not rendered photos"})
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    from rich.console import Console
    from rich.table import Table

    t = Table(title="Hand robustness (goals: labels >= 99.5 %, >= 95 % of markers seen twice labelled, "
                    "marker RMS <= 1 mm, joint angles <= 2 deg, no capture lost)")
    for c in ("condition", "n", "labels right %", "seen twice labelled %", "marker RMS mm", "joint angles RMS deg",
              "triplet-posed flashes", "neighbour-posed flashes", "captures lost", "flashes posed"):
        t.add_column(c, justify="left" if c == "condition" else "right")
    f = lambda v, p: "-" if v is None else f"{v:.{p}f}"  # noqa: E731
    for r in rows(args.quick):
        t.add_row(r["condition"], str(r["n"]), f(r["label_accuracy_pct"], 2), f(r["seen_twice_labelled_pct"], 1),
                  f(r["marker_rms_mm"], 2), f(r["joint_angle_rms_deg"], 2), f(r["joint_angle_rms_triplet_deg"], 2),
                  f(r["joint_angle_rms_neighbours_deg"], 2), str(r["captures_lost"]), r["flashes_posed"])
    Console(width=160).print(t)


if __name__ == "__main__":
    main()
