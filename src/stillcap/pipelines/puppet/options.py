"""How the puppet pipeline runs: :class:`PuppetOptions`, its presets :data:`DEFAULT` (the
measured best) and :data:`THESIS_CHAIN` (the thesis's chain), and :func:`with_options`."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from stillcap.body.markerset import MarkerSet
from stillcap.body.puppet_checks import BONE_TOLERANCE_DEG
from stillcap.detect.beads import DETECTORS, IDENTIFIERS
from stillcap.response import check_response_option

__all__ = ["PuppetOptions", "DEFAULT", "THESIS_CHAIN", "with_options"]

# DETECTORS and IDENTIFIERS (the choices PuppetOptions offers) live in stillcap.detect.beads.


@dataclass(frozen=True)
class PuppetOptions:
    """How the pipeline runs. :data:`DEFAULT` is the measured best, :data:`THESIS_CHAIN` the
    thesis's own chain (see ``docs/puppet.md``).

    Attributes
    ----------
    detector : str
        :func:`~stillcap.detect.circles.find_circles` method (:data:`DETECTORS`).
    identify : str
        ``"recommended"`` (assignment, CIEDE2000, white-balance adaptation) or ``"thesis"``
        (greedy HSB).
    radius_range : (float, float)
        Bead radius in the photos, pixels (thesis: 5-7 px at 640x480).
    n_circles : int
        Candidates per photo (thesis: N = 16).
    triangulation : str
        ``"dlt"`` (with reprojection refinement) or ``"midpoint"`` (the thesis's least-squares
        point nearest to the back-projection lines, no refinement).
    outlier_px : float or None
        Views that disagree with a marker's point by more than this are not used (None: keep all).
    use_fill : bool
        Leave out views where a bead looks partly hidden (:func:`~stillcap.detect.beads.bead_fill`) while 2+ whole
        views remain.
    min_fill, fill_ratio : float
        A view is whole when its fill is at least ``min_fill``, or at least ``fill_ratio`` x the
        marker's best fill when that best view is whole.
    arc_fit : bool
        For a bead that fewer than two views show whole: refit its centre in each partly hidden
        view to the visible arc of its rim (:func:`~stillcap.detect.bead_arc.arc_centers`), and
        leave out the views where the arc fixes none (while two remain). Off by default: on the
        studio's captures it changed no partly hidden bead's error yet (the rim test takes the
        ring's median grey as the background, but a bead borders its own limb on one side).
    pose : str
        The result's pose: ``"fit"`` (:func:`~stillcap.body.puppet_pose.fit_pose`) or ``"thesis"`` (bone directions).
    marker_sigma_m : float
        Expected 3D marker error, metres: weight of the markers against the prior in :func:`~stillcap.body.puppet_pose.fit_pose`.
    roi : bool
        Detect only inside the box around the bright pixels (:func:`~stillcap.detect.beads.bright_region`): faster, the
        same beads.
    reidentify : bool
        After the first triangulation, name the candidates after the 3D markers
        (:func:`~stillcap.detect.beads.reidentify`) and triangulate again from that identification.
    reid_gate : float
        :func:`~stillcap.detect.beads.reidentify`'s pixel gate, share of the projected bead radius.
    reid_colour : float
        :func:`~stillcap.detect.beads.reidentify`'s colour gate, multiple of the identification's acceptance distance.
    coarse : bool
        Template detector: find the contrast peaks at half resolution and climb each to its
        full-resolution maximum (faster); False: the full-resolution contrast map.
    root : str
        The root's (pelvis's) frame in the pose fit: ``"auto"`` (default: position and rotation
        fitted when the marker set's beads fix them, :func:`~stillcap.body.puppet_pose.root_freedom`),
        ``"pinned"`` (the skeleton's rest frame: the thesis's pelvis on the turntable axis),
        ``"translate"`` or ``"free"`` (:func:`~stillcap.body.puppet_pose.fit_pose`).
    response : None, Response or str
        The cameras' response (``docs/camera-response.md``): None each view's camera's own from
        the rig; a Response (or ``"srgb"``, ``"linear"``, ``"gamma:2.2"``) for every view. The
        photos are re-encoded to sRGB through it before the beads' colours (sRGB references) are
        compared. ``"auto"`` is not available for the puppet yet (its beads are too small).
    bone_tolerance_deg : float
        The bone-direction error accepted, degrees: the per-bone self-checks name a bone only when
        its misfit is significant and larger than a bone turned by this angle would leave
        (:func:`~stillcap.body.puppet_checks.skeleton_checks`; default
        :data:`~stillcap.body.puppet_checks.BONE_TOLERANCE_DEG`; 0: every significant misfit).
    """

    detector: str = "template"
    identify: str = "recommended"
    radius_range: tuple = (5.0, 7.0)
    n_circles: int = 16
    triangulation: str = "dlt"
    outlier_px: float | None = 1.0
    use_fill: bool = True
    min_fill: float = 0.65
    fill_ratio: float = 0.85
    arc_fit: bool = False
    pose: str = "fit"
    marker_sigma_m: float = 0.2e-3
    roi: bool = True
    reidentify: bool = True
    reid_gate: float = 0.6
    reid_color: float = 2.0
    coarse: bool = True
    root: str = "auto"
    response: object = None
    bone_tolerance_deg: float = BONE_TOLERANCE_DEG

    def __post_init__(self):
        object.__setattr__(self, "response", check_response_option(self.response))
        if self.response == "auto":
            raise ValueError("response 'auto' is not available for puppet captures (the beads are too small to "
                             "fit their shading); give srgb, linear or gamma:G")
        if self.detector not in DETECTORS:
            raise ValueError(f"unknown detector {self.detector!r}; choose one of {', '.join(DETECTORS)}")
        if self.identify not in IDENTIFIERS:
            raise ValueError(f"unknown identification {self.identify!r}; choose one of {', '.join(IDENTIFIERS)}")
        if self.triangulation not in ("dlt", "midpoint"):
            raise ValueError(f"unknown triangulation {self.triangulation!r}; choose dlt or midpoint")
        if self.pose not in ("fit", "thesis"):
            raise ValueError(f"unknown pose method {self.pose!r}; choose fit or thesis")
        if self.root not in ("auto", "pinned", "translate", "free"):
            raise ValueError(f"unknown root {self.root!r}; choose auto, pinned, translate or free")
        lo, hi = (float(v) for v in self.radius_range)
        if not 0 < lo <= hi:
            raise ValueError(f"radius_range must be 0 < min <= max pixels, got {self.radius_range}")
        if not (math.isfinite(self.bone_tolerance_deg) and 0 <= self.bone_tolerance_deg < 90):
            raise ValueError(f"bone_tolerance_deg must be an angle in [0, 90) degrees, got {self.bone_tolerance_deg}")
        if self.outlier_px is not None and not self.outlier_px > 0:
            raise ValueError(f"outlier_px must be > 0 pixels or None, got {self.outlier_px}")

    def to_dict(self) -> dict:
        return {"detector": self.detector, "identify": self.identify, "radius_range_px": list(self.radius_range),
                "n_circles": self.n_circles, "triangulation": self.triangulation, "outlier_px": self.outlier_px,
                "use_fill": self.use_fill, "min_fill": self.min_fill, "fill_ratio": self.fill_ratio,
                "arc_fit": self.arc_fit,
                "pose": self.pose, "marker_sigma_m": self.marker_sigma_m, "roi": self.roi,
                "reidentify": self.reidentify, "reid_gate": self.reid_gate, "reid_colour": self.reid_color,
                "coarse": self.coarse, "root": self.root, "bone_tolerance_deg": self.bone_tolerance_deg}


#: The measured best chain (``benchmarks/bench_puppet.py``).
DEFAULT = PuppetOptions()
#: The thesis's chain: IsoData + outline + Hough, greedy HSB, midpoint triangulation of every
#: identified view, bone directions.
THESIS_CHAIN = PuppetOptions(detector="thesis", identify="thesis", triangulation="midpoint", outlier_px=None, roi=False,
                              use_fill=False, pose="thesis", reidentify=False)



def with_options(options: PuppetOptions = DEFAULT, **changes) -> PuppetOptions:
    """A copy of ``options`` with some fields changed (validated)."""
    return replace(options, **changes)


def _options_for(options: PuppetOptions, markerset: MarkerSet) -> PuppetOptions:
    """``options`` with at least one candidate circle per bead of ``markerset``: the thesis's
    "N best circles" has N = its 16 beads, and puppet-20 with 16 candidates lost its four dimmest
    beads in 10-20 % of the photos."""
    if options.n_circles < len(markerset):
        return replace(options, n_circles=len(markerset))
    return options
