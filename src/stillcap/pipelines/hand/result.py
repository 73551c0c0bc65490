"""What the hand pipeline finds: :class:`HandResult` (labelled 3D markers, poses, animation, the
ball and its release), with :meth:`HandResult.to_dict` for the JSON form."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap._numeric import RPM_PER_RAD_S
from stillcap._selfcheck import checks_to_json
from stillcap.ball.release import Release
from stillcap.body.hand_label import HandLabels
from stillcap.body.hand_track import HandSequence
from stillcap.body.markerset import MarkerTrajectories
from stillcap.body.skeleton import Animation
from stillcap.files.jsonable import to_jsonable
from stillcap.geometry.marker_points import MarkerPoints
from stillcap.io.capture import Capture
from stillcap.pipelines.hand.ball import HandBalls, HandBallSpin

__all__ = ["HandResult"]


@dataclass
class HandResult:
    """What :func:`analyse_hand` found (rig world frame, SI, times after the first hand flash).

    Attributes
    ----------
    capture : Capture
    strobe_hz : float
    pairs : list of str
    blobs : list of ColorBlobs
        Coloured blobs per camera (rig order).
    points : MarkerPoints
        Unlabelled 3D markers of all flashes.
    labels : HandLabels
    sequence : HandSequence or None
        Poses of the reconstructed flashes (None when no flash could be reconstructed).
    animation : Animation or None
        Keyframe-interpolated motion (None with fewer than two poses).
    balls : HandBalls or None
    release : Release or None
    spin : HandBallSpin or None
    messages : list of str
    timings_s : dict
    self_checks : list of SelfCheck
        What the markers show against what the hand model and the noise allow
        (:func:`~stillcap.body.hand_checks.hand_self_checks`) and ``response``: the ball's shading
        against each camera's response; JSON key ``self_checks``.
    truth : dict or None
        The comparison with the capture's truth file, for synthetic captures: set by the caller
        that has the truth (:func:`stillcap.studio.compare.hand.compare_with_capture`); the
        pipeline leaves it None.
    response : dict or None
        The cameras' responses used and where they came from (rig, option, auto).
    """

    capture: Capture
    strobe_hz: float
    pairs: list
    blobs: list
    points: MarkerPoints
    labels: HandLabels
    sequence: HandSequence | None
    animation: Animation | None
    balls: HandBalls | None
    release: Release | None
    spin: HandBallSpin | None
    messages: list = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)
    self_checks: list = field(default_factory=list)
    truth: dict | None = None
    response: dict | None = None

    @property
    def skeleton(self):
        return self.sequence.skeleton if self.sequence is not None else self.labels.skeleton

    @property
    def markers(self) -> MarkerTrajectories:
        """The labelled markers per flash (for the C3D/CSV exporters)."""
        lab = self.labels
        n_frames = int(lab.order.max()) + 1 if lab.n_flashes else 0
        pts = np.full((n_frames, len(lab.marker_names), 3), np.nan)
        pts[lab.order] = lab.positions  # one frame per strobe period: missed flashes stay NaN
        return MarkerTrajectories(list(lab.marker_names), pts, self.strobe_hz)

    def partly_hidden_markers(self) -> list[dict]:
        """The partly hidden 3D markers (a view saw part of the marker, its centroid shifts by a few
        mm; :attr:`MarkerPoints.partly_hidden`), listed apart from the fully seen ones: per point
        its index in :attr:`points`, its smallest flux ratio, and its label (``flash``: the
        flash number ``labels.order``, ``marker``) and fit residual (mm) when it got one."""
        lab, seq = self.labels, self.sequence
        flux = np.where(np.isfinite(self.points.flux_ratio), self.points.flux_ratio, np.inf).min(axis=0)
        where = {int(p): (k, j) for (k, j), p in np.ndenumerate(lab.point_index) if p >= 0}
        pose_of = {int(k): i for i, k in enumerate(seq.flashes)} if seq is not None else {}
        out = []
        for p in np.flatnonzero(self.points.partly_hidden):
            k, j = where.get(int(p), (None, None))
            r = None
            if k is not None and k in pose_of and np.isfinite(seq.residuals[pose_of[k], j]):
                r = float(seq.residuals[pose_of[k], j] * 1e3)
            out.append({"point": int(p), "flux_ratio": float(flux[p]) if np.isfinite(flux[p]) else None,
                        "flash": None if k is None else int(lab.order[k]),
                        "marker": None if j is None else lab.marker_names[j], "fit_residual_mm": r})
        return out

    def angles_partly_hidden(self) -> np.ndarray | None:
        """Which joint angles rest only on partly hidden markers, per flash: bool, shape
        ``(n_flashes, n_joints, 3)`` like the JSON's ``flashes.angles_deg`` (False where the flash
        has no pose; :func:`~stillcap.body.hand_track.dofs_on_partly_hidden`); None without poses."""
        from stillcap.body.hand_track import dofs_on_partly_hidden

        seq, lab = self.sequence, self.labels
        if seq is None:
            return None
        out = np.zeros((lab.n_flashes, seq.skeleton.n_joints, 3), bool)
        out[seq.flashes] = dofs_on_partly_hidden(seq, lab.point_index, self.points.partly_hidden)
        return out

    def ball_held(self) -> dict:
        """``{flash number (labels.order): True if the ball is in the hand, False if free}`` for
        the flashes that show the ball (empty without a release estimate)."""
        if self.release is None or self.balls is None:
            return {}
        return {int(k): bool(h) for k, h in zip(self.balls.flash_index, self.release.held)}

    def to_dict(self) -> dict:
        """JSON-ready; keys shared with the hand truth (``flashes.times_s``, ``markers``,
        ``angles_deg``, ``root2world``, ``joints``, ``release``)."""
        lab = self.labels
        flashes = {"times_s": lab.times.tolist(), "order": lab.order.tolist(),
                   "reconstructed": lab.reconstructed.tolist(), "skipped": list(lab.skipped),
                   "markers": lab.positions, "fit_rms_mm": lab.rms * 1e3}
        seq = self.sequence
        if seq is not None:
            nf, nj = lab.n_flashes, seq.skeleton.n_joints
            ang, r2w, joints = (np.full((nf, nj, 3), np.nan), np.full((nf, 4, 4), np.nan),
                                np.full((nf, nj, 3), np.nan))
            for k, p, a in zip(seq.flashes, seq.poses, seq.angles_deg):
                ang[k], r2w[k], joints[k] = a, p.root2world, p.positions
            flashes.update(angles_deg=ang, root2world=r2w, joints=joints,
                           angles_partly_hidden=self.angles_partly_hidden())
        d = {"kind": "hand", "frame": self.capture.rig.world,
             "units": {"length": "m", "time": "s (after the first flash with the hand)", "angle": "deg"},
             "strobe_hz": self.strobe_hz, "pairs": self.pairs, "marker_names": list(lab.marker_names),
             "marker_colours": list(lab.marker_colors), "joint_names": list(self.skeleton.names),
             "flashes": flashes, "points": self.points.to_dict(),
             "scales": None if seq is None else seq.scales,
             "ball": None if self.balls is None else self.balls.to_dict(),
             "release": None if self.release is None else self.release.to_dict(),
             "spin": None if self.spin is None else _spin_dict(self.spin),
             "partly_hidden": self.partly_hidden_markers(),
             "self_checks": checks_to_json(self.self_checks),
             "messages": list(self.messages), "timings_s": dict(self.timings_s)}
        d["response"] = self.response
        if self.truth is not None:
            d["truth_comparison"] = self.truth
        return to_jsonable(d)


def _spin_dict(s: HandBallSpin) -> dict:
    rpm = float(np.linalg.norm(s.spin) * RPM_PER_RAD_S) if s.available else None
    return {"available": s.available, "spin": s.spin.tolist(), "spin_rpm": rpm,
            "candidates_rpm": list(s.candidates_rpm), "ambiguous": s.ambiguous, "message": s.message}
