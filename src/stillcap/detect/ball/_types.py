"""Results of the ball detector: per-ball quality flags, the silhouettes of a photo
(:class:`BallDetections`) and the refined centres (:class:`RefinedCenters`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

import numpy as np


class BallFlag(enum.IntFlag):
    """Per-ball quality flags (bit set; ``0`` means nothing to report)."""

    NONE = 0
    #: the silhouette touches the image border (a cut ball: centre and size unreliable; with
    #: ``EDGE`` they are a circle fitted to the in-frame limb)
    TOUCHES_BORDER = 1
    #: the ball came from a silhouette of several overlapping ball images
    MERGED = 2
    #: ... and its centre is a circle fitted to its own outer arc (else it is the distance-
    #: transform maximum, flagged PARTIAL too)
    SPLIT = 4
    #: the silhouette is clearly not round (half moon, partly lit): the ellipse centre is biased
    PARTIAL = 8
    #: Hough refinement failed (weak peak, or the peak on the search border): centre = ellipse centre
    REFINE_FAILED = 16
    #: the ellipse size disagrees with the radius projected from the triangulated centre
    SIZE_MISMATCH = 32
    #: a thin crescent (a ball lit from behind) found in the unopened mask: its centre and radius
    #: are a circle fitted to the crescent's outer limb (``partial: crescent``)
    CRESCENT = 64
    #: a ball cut by the photo's border (also ``TOUCHES_BORDER``) whose centre and radius are a
    #: circle fitted to its in-frame limb (``partial: edge``)
    EDGE = 128


def partial_kind(flags: int) -> str:
    """``"crescent"``, ``"edge"``, ``"crescent|edge"`` or ``""`` for a ball's flags."""
    f = int(flags)
    return "|".join(n for n, b in (("crescent", BallFlag.CRESCENT), ("edge", BallFlag.EDGE)) if f & int(b))


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass
class BallDetections:
    """Ball images found in one photo, sorted left to right (by ellipse centre x).

    Attributes
    ----------
    centers : ndarray, shape (N, 2)
        Best centre estimate (raw pixels): the refined centre where refinement ran and
        succeeded, else the arc fit's for ``CRESCENT`` and ``EDGE`` balls, else the ellipse
        centre.
    ellipse_centers : ndarray, shape (N, 2)
        Centre of the ellipse fitted to the convex hull (first estimate, step 2; what stereo
        matching uses). A faint crescent found without a silhouette: its circle's centre.
    radii_px : ndarray, shape (N,)
        Radius in pixels: the known radius used by the refinement, else the ellipse's
        semi-major axis (a split ball: its circle's radius). The silhouette includes the
        blurred rim down to the (low) dark-room threshold, so this is ~1-2 px above the true
        radius; the refinement uses the radius projected from 3D instead.
    ellipses : ndarray, shape (N, 5)
        ``cv2.fitEllipse`` result per ball: centre x, centre y, full width, full height (px),
        angle (degrees).
    areas : ndarray, shape (N,)
        Contour area in px^2 (for split balls: the area of their piece).
    hull_areas : ndarray, shape (N,)
        Convex-hull area in px^2.
    scores : ndarray, shape (N,)
        Refinement support: the share of the outline with a clear inward edge (about 1 for a
        fully lit ball, 0.5 for a half moon); NaN where not refined.
    flags : ndarray of int, shape (N,)
        :class:`BallFlag` bits.
    contour_index : ndarray of int, shape (N,)
        Index of the silhouette each ball came from (balls split from one silhouette share it;
        -1 for a crescent found in the unopened mask).
    arc_radii_px : ndarray, shape (N,), optional
        Radius of the arc fit of ``CRESCENT``, ``EDGE`` and ``SPLIT`` balls (the circle through
        the outer, in-frame or own limb), px; NaN for the others.
    center_sigma_px : ndarray, shape (N,), optional
        Centre uncertainty (1 sigma, px) of balls whose centre is an arc fit (``CRESCENT``,
        ``EDGE``, ``SPLIT``: from the arc's length, residual and blur; larger the shorter the arc); NaN for
        whole silhouettes (their error is the pair's, from its residuals).
    arc_points : list, optional
        Per ball, the limb points its arc fit used (ndarray (M, 2), raw px) for ``EDGE`` balls
        (the stereo step refits them with the ball's projected outline shape) and ``SPLIT`` ones
        (their own arc of a merged silhouette: the stereo step's sigma), else None.
    """

    centers: np.ndarray
    ellipse_centers: np.ndarray
    radii_px: np.ndarray
    ellipses: np.ndarray
    areas: np.ndarray
    hull_areas: np.ndarray
    scores: np.ndarray
    flags: np.ndarray
    contour_index: np.ndarray
    mask: np.ndarray | None = field(default=None, repr=False)
    center_sigma_px: np.ndarray | None = None
    arc_radii_px: np.ndarray | None = None
    arc_points: list | None = field(default=None, repr=False)

    def __post_init__(self):
        if self.center_sigma_px is None:
            self.center_sigma_px = np.full(len(self.centers), np.nan)
        if self.arc_radii_px is None:
            self.arc_radii_px = np.full(len(self.centers), np.nan)
        if self.arc_points is None:
            self.arc_points = [None] * len(self.centers)

    def __len__(self) -> int:
        return len(self.centers)

    @property
    def partial(self) -> list:
        """Per ball, which partial fit gave its centre: ``"crescent"``, ``"edge"``, both
        (``"crescent|edge"``) or ``""``."""
        return [partial_kind(f) for f in self.flags]

    @classmethod
    def empty(cls, mask=None) -> BallDetections:
        z2, z1 = np.zeros((0, 2)), np.zeros(0)
        return cls(z2, z2.copy(), z1, np.zeros((0, 5)), z1.copy(), z1.copy(), z1.copy(),
                   np.zeros(0, int), np.zeros(0, int), mask)

    def has(self, flag: BallFlag) -> np.ndarray:
        """Boolean (N,) array: which balls carry ``flag``."""
        return (self.flags & int(flag)) != 0

    def with_refined(self, refined: RefinedCenters) -> BallDetections:
        """A copy whose centres, radii, scores and flags come from :func:`refine_ball_centers`."""
        if len(refined) != len(self):
            raise ValueError(f"refined has {len(refined)} centres for {len(self)} detections")
        return replace(self, centers=refined.centers.copy(), radii_px=refined.radii_px.copy(),
                       scores=refined.scores.copy(), flags=self.flags | refined.flags)


@dataclass
class RefinedCenters:
    """Result of :func:`refine_ball_centers`.

    Attributes
    ----------
    centers : ndarray, shape (N, 2)
        Refined centres (raw pixels); the input centre where refinement failed.
    radii_px : ndarray, shape (N,)
        The known radius used (mean distance of the outline from its centre).
    scores : ndarray, shape (N,)
        Share of the outline with a clear inward edge at the refined centre (0-1).
    shifts : ndarray, shape (N, 2)
        ``centers - input centres``.
    flags : ndarray of int, shape (N,)
        ``BallFlag.REFINE_FAILED`` where the peak was weak or on the search border.
    shading_px : ndarray, shape (N, 2) or None
        The shading correction subtracted from each centre (px; 0 where none ran).
    shading_phase_rad, shading_phase_sd_rad : ndarray, shape (N,) or None
        The phase angle the shading correction used and its split-half 1-sigma (rad;
        :func:`stillcap.detect.ball._shading._phase_split_sd`), NaN where none ran.
    shading_misfit_px : ndarray, shape (N, 2) or None
        The centre shift a least-squares fit of the correction's model to the photo asks for
        (px; :func:`stillcap.detect.ball._shading._misfit_shift`), NaN where none ran.
    """

    centers: np.ndarray
    radii_px: np.ndarray
    scores: np.ndarray
    shifts: np.ndarray
    flags: np.ndarray
    shading_px: np.ndarray | None = None
    shading_phase_rad: np.ndarray | None = None
    shading_phase_sd_rad: np.ndarray | None = None
    shading_misfit_px: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.centers)

    @property
    def ok(self) -> np.ndarray:
        """Which centres were refined, shape (N,) bool."""
        return (self.flags & int(BallFlag.REFINE_FAILED)) == 0
