"""What the puppet pipeline finds: :class:`MarkerSolve` (the 3D markers and which views they rest
on) and :class:`PuppetResult` (everything, with :meth:`PuppetResult.to_dict` for the JSON form,
format :data:`~stillcap.io.puppet_result.RESULT_FORMAT`; :func:`~stillcap.io.puppet_result.load_result`
reads it back)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stillcap.body.kinematics import normalised
from stillcap.body.markerset import MarkerSet, MarkerTrajectories
from stillcap.body.puppet_pose import PoseFit, frame_status
from stillcap.body.skeleton import Pose
from stillcap.camera import Rig
from stillcap.geometry.triangulate import Triangulation
from stillcap.io.puppet_result import RESULT_FORMAT
from stillcap.pipelines.puppet.options import DEFAULT, PuppetOptions

__all__ = ["MarkerSolve", "PuppetResult"]


@dataclass(eq=False)
class MarkerSolve:
    """3D markers from the identified 2D markers of every view.

    Attributes
    ----------
    names : tuple of str, length n_markers
    points : ndarray, shape (n_markers, 3)
        Metres, rig world (puppet frame); NaN for markers identified in fewer than two usable views.
    observations : ndarray, shape (n_views, n_markers, 2)
        Identified pixels (NaN = not identified).
    used : ndarray of bool, shape (n_views, n_markers)
        Observations the final point rests on.
    fill : ndarray, shape (n_views, n_markers)
        :func:`~stillcap.detect.beads.bead_fill` of every observation (NaN without images).
    partial : ndarray of bool, shape (n_views, n_markers)
        Observations left out as partly hidden beads.
    outlier : ndarray of bool, shape (n_views, n_markers)
        Observations left out because they disagree with the other views (> ``outlier_px``):
        a wrong identification, or a bead so hidden that its centre is off.
    whole : ndarray of bool, shape (n_views, n_markers)
        Observations whose bead looks whole (the fill test; all identified ones without it) and
        sit on the other views' consensus within the capture's own pixel noise.
    noise_px : float
        The capture's pixel noise the off-centre test judged by (1-sigma per axis, pixels; NaN
        when it did not run).
    reproj_error_px : ndarray, shape (n_markers,)
        RMS reprojection error over the used views, pixels.
    triangulation : Triangulation
        The final triangulation.
    """

    names: tuple
    points: np.ndarray
    observations: np.ndarray
    used: np.ndarray
    fill: np.ndarray
    partial: np.ndarray
    outlier: np.ndarray
    reproj_error_px: np.ndarray
    triangulation: Triangulation
    whole: np.ndarray | None = None
    noise_px: float = float("nan")

    @property
    def n_views(self) -> np.ndarray:
        """Views used per marker, shape (n_markers,)."""
        return self.used.sum(axis=0)

    @property
    def identified_views(self) -> np.ndarray:
        """Views that identified each marker, shape (n_markers,)."""
        return np.isfinite(self.observations[..., 0]).sum(axis=0)

    @property
    def ok(self) -> np.ndarray:
        return np.isfinite(self.points).all(axis=1)

    @property
    def whole_views(self) -> np.ndarray:
        """Used views per marker whose bead looked whole, shape (n_markers,): a marker with
        fewer than 2 rests on partly hidden (or image-border) views and may be off by a few
        tenths of a millimetre to 2 mm."""
        w = self.used if self.whole is None else self.used & self.whole
        return w.sum(axis=0)

    @property
    def partly_hidden(self) -> np.ndarray:
        """Recovered markers that fewer than two views show whole, shape (n_markers,): partly
        hidden beads (or cut by the image border), whose points may be 1-2 mm off; never counted
        as whole beads."""
        return self.ok & (self.whole_views < 2)

    @property
    def missing(self) -> tuple:
        """Markers without a 3D position (identified in fewer than two usable views): the
        thesis's red entries."""
        return tuple(n for n, good in zip(self.names, self.ok) if not good)



def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None



@dataclass(eq=False)
class PuppetResult:
    """Everything the puppet pipeline found (see :meth:`to_dict` for the JSON form).

    Attributes
    ----------
    rig : Rig
        The camera of every view, in view order.
    view_names : list of str
    angles_deg : list of float or None
        Turn angle of every view, degrees (None for rig views).
    markerset : MarkerSet
    markers : MarkerSolve
        2D observations, 3D markers, which views were used.
    fit : PoseFit
        Fitted and thesis poses.
    options : PuppetOptions
    views : list of ViewResult or None
        Detection per view (None when the markers came from a project's stored detections).
    source : dict
        Where the photos came from (``{"type": "capture"|"project", "path": ...}``).
    timings_s : dict
        Seconds per stage.
    comparison : PuppetComparison or None
        Against the truth, for synthetic captures: set by the caller that has the truth
        (:func:`stillcap.studio.compare.puppet.compare_with_capture`); the pipeline leaves it None.
    files : list of str or None
        The photo of every view.
    raw_observations : ndarray, shape (n_views, n_markers, 2), or None
        The colour-only identification, before :func:`~stillcap.detect.beads.reidentify` named the candidates after
        the 3D markers (None when it did not run); ``markers.observations`` is the final one.
    self_checks : list of SelfCheck
        Per bone: does the skeleton match the puppet (:func:`~stillcap.body.puppet_checks.skeleton_checks`);
        per partly hidden bead (:func:`~stillcap.body.puppet_checks.partly_hidden_checks`).
    """

    rig: Rig
    view_names: list
    angles_deg: list
    markerset: MarkerSet
    markers: MarkerSolve
    fit: PoseFit
    options: PuppetOptions = DEFAULT
    views: list | None = None
    source: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    comparison: object | None = None
    files: list | None = None
    raw_observations: np.ndarray | None = None
    self_checks: list = field(default_factory=list)

    @property
    def names(self) -> tuple:
        return self.markers.names

    @property
    def pose(self) -> Pose:
        """The result's pose: the fitted one, or the thesis's with ``options.pose="thesis"``."""
        return self.fit.pose if self.options.pose == "fit" else self.fit.thesis_pose

    @property
    def thesis_pose(self) -> Pose:
        return self.fit.thesis_pose

    @property
    def trajectories(self) -> MarkerTrajectories:
        """The 3D markers as one frame of :class:`MarkerTrajectories` (for :func:`stillcap.io.export.export`)."""
        return MarkerTrajectories.single(self.names, self.markers.points)

    @property
    def missing(self) -> tuple:
        return self.markers.missing

    def to_dict(self) -> dict:
        """JSON-ready dict; keys shared with ``truth.json`` (``markers[].name/position``,
        ``joints[].name/position/local_rotation``, ``root2world``, ``cameras``, ``angles_deg``,
        ``markers_px``) mean the same, in the same units (metres, pixels). See ``docs/puppet.md``."""
        m, pose = self.markers, self.pose
        sk = pose.skeleton

        def pts(a):
            return [None if not np.isfinite(p).all() else [float(v) for v in p] for p in a]

        def joints(p: Pose):
            return [{"name": n, "position": [float(v) for v in x], "local_rotation": R.tolist()}
                    for n, x, R in zip(sk.names, p.positions, p.local_rotations)]

        vecs = normalised(pose.bone_vectors())
        from stillcap._selfcheck import checks_to_json
        from stillcap.body.puppet_checks import bead_pair_directions

        pairs = bead_pair_directions(self.markerset, m.points)
        fitted_pairs = bead_pair_directions(self.markerset, self.markerset.positions(self.fit.pose))
        hidden = m.partly_hidden
        d = {
            "format": RESULT_FORMAT, "version": 1, "kind": "puppet", "frame": self.rig.world,
            "units": {"length": "m", "pixels": "px (x, y), origin top-left pixel centre", "angle": "deg"},
            "source": dict(self.source),
            "settings": self.options.to_dict(),
            "markers": [{"name": n, "position": p, "n_views": int(k), "whole_views": int(wv),
                         "identified_views": int(iv), "reproj_error_px": _num(e), "missing": p is None,
                         "partly_hidden": bool(h), "fit_residual_m": _num(r)}
                        for n, p, k, wv, iv, e, r, h in zip(m.names, pts(m.points), m.n_views, m.whole_views,
                                                            m.identified_views, m.reproj_error_px,
                                                            self.fit.residuals_m, hidden)],
            "missing": list(m.missing),
            "partly_hidden": [n for n, h in zip(m.names, hidden) if h],
            "joints": joints(pose),
            "root2world": pose.root2world.tolist(),
            "bone_directions": {n: pts(vecs[j:j + 1])[0] for j, n in enumerate(sk.names) if sk.parents[j] >= 0
                                and sk.bone_lengths[j] > 0},
            # the thesis's model-free directions, beside the fitted pose: measured bead pairs, and
            # the angle to the same pair of the fitted model's beads
            "bead_pair_directions": {b: {"from": d["from"], "to": d["to"], "direction": pts(d["direction"][None])[0],
                                         "fitted_angle_deg": _num(np.degrees(np.arccos(np.clip(
                                             d["direction"] @ fitted_pairs[b]["direction"], -1.0, 1.0))))
                                         if b in fitted_pairs else None}
                                     for b, d in pairs.items()},
            "cameras": list(self.view_names),
            "angles_deg": [None if a is None else float(a) for a in self.angles_deg],
            "markers_px": [[[_num(c) for c in p] for p in v] for v in m.observations],  # as truth.json: [null, null]
            "markers_px_colour": None if self.raw_observations is None else
            [[[_num(c) for c in p] for p in v] for v in self.raw_observations],
            "used": m.used.astype(bool).tolist(),
            "partial": m.partial.astype(bool).tolist(),
            "outlier": m.outlier.astype(bool).tolist(),
            "fill": [[_num(f) for f in row] for row in m.fill],
            "views": [{"name": n, "file": f, "angle_deg": None if a is None else float(a),
                       "identified": int(np.isfinite(m.observations[v, :, 0]).sum()), "used": int(m.used[v].sum()),
                       **({"candidates": len(self.views[v].circles)} if self.views else {})}
                      for v, (n, f, a) in enumerate(zip(self.view_names, self.files or [None] * len(self.view_names),
                                                        self.angles_deg))],
            "pose_fit": {"method": self.options.pose, "success": self.fit.success, "n_markers": self.fit.n_markers,
                         "rms_m": _num(self.fit.rms_m), "root": self.fit.root,
                         "frames": frame_status(sk, self.markerset)},
            "thesis": {"bone_directions": {b: pts(np.asarray(v)[None])[0] for b, v in self.fit.directions.items()},
                       "joints": joints(self.thesis_pose)},
            "skeleton": sk.to_dict("m"),
            "markerset": self.markerset.name,
            "camera_rig": self.rig.to_dict(),
            "timings_s": {k: float(v) for k, v in self.timings_s.items()},
            "self_checks": checks_to_json(self.self_checks),
        }
        if self.comparison is not None:
            d["comparison"] = self.comparison.to_dict()
        return d

