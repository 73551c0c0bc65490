"""A puppet result against the studio's truth (``truth.json`` of ``stillcap studio puppet``).

:func:`compare_with_truth` scores identification, 3D markers, bone directions and joint positions
(:class:`PuppetComparison`); :func:`capture_truth` reads the truth a capture folder holds and
:func:`compare_with_capture` compares a result with it when the capture has one. The pipeline
(:mod:`stillcap.pipelines.puppet`) never sees a truth: the CLI, the demo and the benchmarks call
these.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stillcap.body.kinematics import normalised
from stillcap.body.markerset import MarkerSet
from stillcap.body.puppet_pose import frame_status
from stillcap.body.skeleton import Skeleton
from stillcap.detect.beads import expected_radius_px
from stillcap.io.capture import Capture
from stillcap.pipelines.puppet import PuppetResult
from stillcap.studio.puppet import PuppetTruth

__all__ = ["PuppetComparison", "compare_with_truth", "capture_truth", "compare_with_capture"]


@dataclass
class PuppetComparison:
    """A result against the studio's truth (``truth.json``).

    Identification counts are over (view, marker) pairs: ``right`` = the marker was put within
    one bead radius of its own bead's true pixel (the bead at least partly visible), ``wrong`` =
    anywhere else; ``visible`` = beads whose centre the truth marks visible, ``right_visible``
    = those identified right. ``wrong_used`` =
    wrong identifications the triangulation still used. These are for the final identification
    (after :func:`~stillcap.detect.beads.reidentify`); ``raw_*`` count the colour-only identification the same way
    (equal to the final counts when no re-identification ran). 3D errors are over the recovered
    markers; ``seen_twice`` = markers the truth shows in 2+ views. Bone directions and joint
    positions are grouped by what the markers measure (:func:`frame_status`): ``full`` bones
    start at a fully measured joint frame, ``partial`` at one with a single bead (forearms,
    shins), ``none`` at one without (hands, feet); joints likewise by the least measured frame
    on their way from the root. ``bone_groups`` / ``joint_groups`` group by the marker set's
    design; ``measured_bone_groups`` / ``measured_joint_groups`` the same way but counting only
    the markers this result recovered (a forearm of ``puppet-20`` whose second bead was seen in
    fewer than two views is "partial" there).
    """

    visible: int
    identified: int
    right: int
    right_visible: int
    wrong: int
    wrong_used: int
    seen_twice: int
    recovered: int
    recovered_seen_twice: int
    missing_seen_twice: tuple
    marker_errors_m: np.ndarray
    bone_errors_deg: dict
    thesis_bone_errors_deg: dict
    joint_errors_m: np.ndarray
    thesis_joint_errors_m: np.ndarray
    bone_groups: dict
    joint_groups: dict
    raw_identified: int = 0
    raw_right_visible: int = 0
    raw_wrong: int = 0
    measured_bone_groups: dict = field(default_factory=dict)
    measured_joint_groups: dict = field(default_factory=dict)
    partly_hidden: np.ndarray | None = None
    truth_partly_hidden: np.ndarray | None = None
    bead_pair_errors_deg: dict = field(default_factory=dict)

    @property
    def raw_wrong_pct(self) -> float:
        """Wrong colour-only identifications (before :func:`~stillcap.detect.beads.reidentify`), % of them."""
        return 100.0 * self.raw_wrong / max(self.raw_identified, 1)

    @property
    def raw_right_pct(self) -> float:
        """Visible beads the colour-only identification named right, % of the visible beads."""
        return 100.0 * self.raw_right_visible / max(self.visible, 1)

    @property
    def right_pct(self) -> float:
        """Visible beads identified right, % of the visible beads."""
        return 100.0 * self.right_visible / max(self.visible, 1)

    @property
    def wrong_pct(self) -> float:
        """Wrong identifications, % of all identifications."""
        return 100.0 * self.wrong / max(self.identified, 1)

    def marker_rms_mm(self, which: str = "all") -> float:
        """RMS 3D error of the recovered markers, mm: ``"all"``, ``"whole"`` (the markers the
        result counts as whole beads) or ``"partly_hidden"`` (those it flags as partly hidden)."""
        e = self.marker_errors_m
        if which != "all":
            ph = np.zeros(len(e), bool) if self.partly_hidden is None else self.partly_hidden
            e = e[ph] if which == "partly_hidden" else e[~ph]
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e ** 2)) * 1e3) if len(e) else float("nan")

    def bead_pair_stats(self) -> tuple[float, float]:
        """(RMS, max) error of the bead-pair bone directions (the thesis's, model-free) against
        the true direction between the same two beads, degrees."""
        e = np.array([v for v in self.bead_pair_errors_deg.values() if np.isfinite(v)])
        return (float(np.sqrt(np.mean(e ** 2))), float(e.max())) if len(e) else (float("nan"), float("nan"))

    def marker_max_mm(self) -> float:
        e = self.marker_errors_m[np.isfinite(self.marker_errors_m)]
        return float(e.max() * 1e3) if len(e) else float("nan")

    def bone_stats(self, group: str = "full", thesis: bool = False, measured: bool = False) -> tuple[float, float]:
        """(RMS, max) bone direction error in degrees over a group of bones (of
        ``measured_bone_groups`` with ``measured``)."""
        errs = self.thesis_bone_errors_deg if thesis else self.bone_errors_deg
        groups = self.measured_bone_groups if measured else self.bone_groups
        e = np.array([errs[b] for b in groups.get(group, []) if np.isfinite(errs.get(b, np.nan))])
        return (float(np.sqrt(np.mean(e ** 2))), float(e.max())) if len(e) else (float("nan"), float("nan"))

    def joint_stats(self, group: str | None = None, thesis: bool = False) -> tuple[float, float]:
        """(RMS, max) joint position error in mm, over all joints or a group."""
        errs = self.thesis_joint_errors_m if thesis else self.joint_errors_m
        idx = self.joint_groups.get(group, []) if group else list(range(len(errs)))
        e = errs[idx]
        e = e[np.isfinite(e)]
        return (float(np.sqrt(np.mean(e ** 2)) * 1e3), float(e.max() * 1e3)) if len(e) else (float("nan"), float("nan"))

    def to_dict(self) -> dict:
        def stats(pair):
            return {"rms": _num(pair[0]), "max": _num(pair[1])}

        return {
            "identification": {"visible": self.visible, "identified": self.identified, "right": self.right,
                               "right_visible": self.right_visible, "wrong": self.wrong, "wrong_used": self.wrong_used,
                               "right_pct_of_visible": _num(self.right_pct), "wrong_pct_of_identified": _num(self.wrong_pct),
                               "colour_only": {"identified": self.raw_identified, "right_visible": self.raw_right_visible,
                                               "wrong": self.raw_wrong, "right_pct_of_visible": _num(self.raw_right_pct),
                                               "wrong_pct_of_identified": _num(self.raw_wrong_pct)}},
            "markers": {"seen_twice": self.seen_twice, "recovered": self.recovered,
                        "recovered_seen_twice": self.recovered_seen_twice,
                        "missing_seen_twice": list(self.missing_seen_twice),
                        "error_mm": {"rms": _num(self.marker_rms_mm()), "max": _num(self.marker_max_mm())},
                        "whole_error_mm": {"rms": _num(self.marker_rms_mm("whole"))},
                        "partly_hidden": {"flagged": [] if self.partly_hidden is None else
                                          [int(k) for k in np.flatnonzero(self.partly_hidden)],
                                          "truly_partly_hidden": [] if self.truth_partly_hidden is None else
                                          [int(k) for k in np.flatnonzero(self.truth_partly_hidden)],
                                          "error_mm": {"rms": _num(self.marker_rms_mm("partly_hidden"))}},
                        "errors_mm": [_num(e * 1e3) for e in self.marker_errors_m]},
            "bone_direction_error_deg": {
                "fit": {g: stats(self.bone_stats(g)) for g in self.bone_groups},
                "thesis": {g: stats(self.bone_stats(g, True)) for g in self.bone_groups},
                "per_bone_fit": {b: _num(v) for b, v in self.bone_errors_deg.items()},
                "per_bone_thesis": {b: _num(v) for b, v in self.thesis_bone_errors_deg.items()},
                "groups": {g: list(v) for g, v in self.bone_groups.items()},
                "fit_measured": {g: stats(self.bone_stats(g, measured=True)) for g in self.measured_bone_groups},
                "groups_measured": {g: list(v) for g, v in self.measured_bone_groups.items()},
                "bead_pairs": stats(self.bead_pair_stats()),
                "per_bone_bead_pairs": {b: _num(v) for b, v in self.bead_pair_errors_deg.items()}},
            "joint_position_error_mm": {
                "fit": {"all": stats(self.joint_stats())} | {g: stats(self.joint_stats(g)) for g in self.joint_groups},
                "thesis": {"all": stats(self.joint_stats(thesis=True))}
                | {g: stats(self.joint_stats(g, True)) for g in self.joint_groups}},
        }


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


_ORDER = {"locked": 0, "full": 1, "partial": 2, "none": 3}


def _groups(skeleton: Skeleton, markerset: MarkerSet, recovered=None) -> tuple[dict, dict]:
    """Bones and joints grouped by what the markers measure (see :class:`PuppetComparison`);
    with ``recovered`` (bool, shape (n_markers,)) by what those markers alone measure."""
    status = frame_status(skeleton, markerset, recovered)
    bones: dict[str, list] = {"full": [], "partial": [], "none": []}
    for j, name in enumerate(skeleton.names):
        p = skeleton.parents[j]
        if p < 0 or skeleton.bone_lengths[j] <= 0:
            continue
        s = status[skeleton.names[p]]
        if s != "locked":  # bones of a locked joint (the pelvis) never move
            bones[s].append(name)
    joints: dict[str, list] = {"full": [], "partial": [], "none": []}
    for j in range(skeleton.n_joints):
        worst, k = "full", skeleton.parents[j]
        while k >= 0:
            s = status[skeleton.names[k]]
            if _ORDER[s] > _ORDER[worst]:
                worst = s
            k = skeleton.parents[k]
        joints[worst].append(j)
    return {k: v for k, v in bones.items() if v}, {k: v for k, v in joints.items() if v}


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    a, b = normalised(a), normalised(b)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return float("nan")
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def compare_with_truth(result: PuppetResult, truth) -> PuppetComparison:
    """Compare a result with the truth of a synthetic capture.

    Parameters
    ----------
    result : PuppetResult
    truth : stillcap.studio.puppet.PuppetTruth
        Same views in the same order, same marker names.
    """
    if list(truth.marker_names) != list(result.names):
        raise ValueError("truth and result list different markers")
    obs = result.markers.observations
    nv = obs.shape[0]
    if truth.markers_px.shape[0] != nv:
        raise ValueError(f"truth has {truth.markers_px.shape[0]} views, the result {nv}")
    true_px = np.stack([cam.project(truth.marker_positions) for cam in result.rig])
    r_true = expected_radius_px(result.rig, truth.marker_positions, 0.5 * float(np.mean(truth.marker_diameter)))

    def score(o):
        found = np.isfinite(o[..., 0])
        d = np.linalg.norm(o - true_px, axis=2)
        with np.errstate(invalid="ignore"):
            right = found & (d <= np.maximum(r_true, 2.0)) & (truth.coverage > 0)
        return found, right, found & ~right

    found, right, wrong = score(obs)
    raw = result.raw_observations
    r_found, r_right, r_wrong = (found, right, wrong) if raw is None else score(np.asarray(raw, float))
    seen2 = truth.visible.sum(axis=0) >= 2
    ok = result.markers.ok
    err = np.linalg.norm(result.markers.points - truth.marker_positions, axis=1)
    sk = result.pose.skeleton
    # the truth's own joints (another puppet's skeleton may differ from the result's)
    tjp = np.asarray(truth.joint_positions, float)
    if list(truth.joint_names) != list(sk.names):
        raise ValueError("truth and result skeletons name different joints")
    tb = np.where((sk.parents >= 0)[:, None], tjp - tjp[np.maximum(sk.parents, 0)], 0.0)
    fb, thb = result.pose.bone_vectors(), result.thesis_pose.bone_vectors()
    bone_groups, joint_groups = _groups(sk, result.markerset)
    measured_bones, measured_joints = _groups(sk, result.markerset, ok)
    names = [b for g in bone_groups.values() for b in g]
    fit_e = {b: _angle_deg(fb[sk.index(b)], tb[sk.index(b)]) for b in names}
    th_e = {b: _angle_deg(thb[sk.index(b)], tb[sk.index(b)]) for b in names}
    je = np.linalg.norm(result.pose.positions - tjp, axis=1)
    tje = np.linalg.norm(result.thesis_pose.positions - tjp, axis=1)
    from stillcap.body.puppet_checks import bead_pair_directions

    true_pairs = bead_pair_directions(result.markerset, truth.marker_positions)
    pair_e = {b: _angle_deg(d["direction"], true_pairs[b]["direction"])
              for b, d in bead_pair_directions(result.markerset, result.markers.points).items() if b in true_pairs}
    # truly partly hidden: fewer than two views show at least 90 % of the bead's silhouette
    truth_ph = (truth.coverage >= 0.9).sum(axis=0) < 2
    return PuppetComparison(int(truth.visible.sum()), int(found.sum()), int(right.sum()),
                            int((right & truth.visible).sum()), int(wrong.sum()),
                            int((wrong & result.markers.used).sum()), int(seen2.sum()), int(ok.sum()),
                            int((ok & seen2).sum()), tuple(n for n, s, o in zip(result.names, seen2, ok) if s and not o),
                            np.where(ok, err, np.nan), fit_e, th_e, je, tje, bone_groups, joint_groups,
                            int(r_found.sum()), int((r_right & truth.visible).sum()), int(r_wrong.sum()),
                            measured_bones, measured_joints, result.markers.partly_hidden.copy(), truth_ph, pair_e)




def capture_truth(capture: Capture | str | Path) -> PuppetTruth | None:
    """The puppet truth a capture folder (or loaded :class:`Capture`) holds; None without one."""
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    if cap.truth and cap.truth.get("kind") == "puppet":
        return PuppetTruth.from_dict(cap.truth)
    return None


def compare_with_capture(result: PuppetResult, capture: Capture | str | Path) -> PuppetComparison | None:
    """:func:`compare_with_truth` against the truth of the capture ``result`` was made from; None
    when the capture has no puppet truth or its views or markers differ from the result's."""
    truth = capture_truth(capture)
    if truth is None:
        return None
    if list(truth.cameras) != list(result.view_names) or list(truth.marker_names) != list(result.names):
        return None  # views or markers differ from the truth's: no comparison
    return compare_with_truth(result, truth)
