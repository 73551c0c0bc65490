"""The pitch pipeline's self-checks (issue 12, part 5): what the photos show against what the
model expects, one :class:`stillcap._selfcheck.SelfCheck` per check and subject.

Each check is a test of a statistic against the quantile (``1 - CHECK_P``) of its distribution
when the model and the stated noise hold, so a clean capture fails a given check about once in a
thousand; a failed check says which and why:

- ``ball_epipolar`` (per pair): the ball centres' triangulation residuals against the expected
  random centre error ``PitchOptions.center_sigma_px``: ``2 sum(e^2) / sigma^2`` (a two-view
  reprojection residual sees half the variance of the epipolar distance) against chi-square(K).
  A camera moved after calibration, a wrong rig or wrong lens distortion fail it.
- ``marker_epipolar`` (per pair): the median epipolar distance of the markers matched across the
  pair against half the matching gate (``marker_epipolar_px``): when the gate cuts the
  distribution the matches are not trustworthy.
- ``marker_matches``: markers triangulated across a pair per ball image, over all pairs (at
  least 0.5; a wrong camera response or colour cast loses them).
- ``flight_chi2``: the final reference fit's residuals against each position's covariance from
  ``center_sigma_px`` through the pair's triangulation geometry (the depth along the lines of
  sight included), chi-square(3N - parameters). Wrong physics, a wrong strobe rate, a wrong
  flash order or positions biased differently along the flight fail it.
- ``pair_agreement`` (per pair but the reference): the mean residual of the pair's positions in
  the joint fit against its standard error (chi-square(3)): two pairs that disagree about where
  the ball was (one pair's calibration or response) fail it.
- ``spin_fit``: the marker spin fit's share of inliers (at least 70 %).
- ``alias_margin``: the second-best spin alias's chi-square minus the best's (at least 9, a
  likelihood ratio of 1 %), and the best consistent with the evidence (value None when there is no
  rival alias: then only the consistency counts).
- ``spin_alias``: fails when the markers themselves cannot reject (at 99.9 %) another rotation per interval
  than the best (``AliasResolution.undecided``, :func:`stillcap.ball.alias.marker_misfit_test`):
  the marker spin is then withheld.
- ``spin_vs_flight``: the marker spin's transverse part against the flight's curvature
  (:func:`stillcap.ball.spin_from_flight.compare_spins`): a reversed axis or a wrong alias.
- ``missed_ball_images`` (per camera): flashes where the fitted flight puts the whole ball disc
  inside the photo, within the span of flashes the pair photographed or next to it, no
  silhouette was found there, and the photo shows no light inside that disc either (a flash that
  did not fire, a hidden ball, a wrong flight). A ball image the photo shows but the silhouette
  detector did not measure (a thin back-lit crescent, a small noisy half moon below its area
  limit: :func:`faint_ball_images`) is named in the message, not counted: on the studio's own
  photos every "missed" ball image was one of these (``docs/pitch.md``, "The missed-ball check").

The uncertainties that go with them: the flight fit's covariance is scaled by its residuals
(``ReferenceFit.residual_scale``) and the spin's by its own (``SpinResult.spin_covariance``);
:func:`disagreement_factor` scales the flight's covariance (and the positions') further by the
pairs' disagreement, ``max(1, chi2 / 3)``.
"""

from __future__ import annotations

import cv2
import numpy as np
# chi2.ppf(q, k) is 2 gammaincinv(k / 2, q) (what scipy.stats computes): importing scipy.stats
# cost 0.4-1 s of every CLI call, for two quantiles
from scipy.special import gammaincinv as _gammaincinv, ndtri as _ndtri

from stillcap._numeric import RPM_PER_RAD_S
from stillcap.ball.alias import UNDECIDED_P
from stillcap._selfcheck import SelfCheck
from stillcap.ball.physics import simulate
from stillcap.ball.uncertainty import center_bias_modes
from stillcap.detect.ball._arcs import faint_mask

__all__ = ["CHECK_P", "pitch_self_checks", "flight_chi2", "pair_disagreement", "expected_ball_images",
           "expected_flight", "faint_ball_images", "disagreement_factor", "ambiguous_alias_candidates",
           "widen_spin_for_aliases", "identity_candidates"]

#: False-alarm probability of each check on a capture where the model holds.
CHECK_P = 1e-3
#: Fewest markers triangulated across a pair per ball image.
MIN_MARKERS_PER_IMAGE = 0.5
#: Smallest share of the spin fit's marker observations that are inliers.
MIN_SPIN_INLIERS = 0.7
#: Smallest chi-square gap between the best spin alias and the runner-up (likelihood ratio 1 %).
MIN_ALIAS_GAP = 9.2
#: Faint light that shows a ball image is in the photo (:func:`faint_ball_images`): pixels of the
#: half-resolution faint mask (``stillcap.detect.ball._arcs.faint_mask``, 4 robust sigmas after
#: averaging) in one connected piece inside the expected disc, as ``thin_arcs``' smallest piece
#: of a crescent (6 pixels there are ~24 px^2 of the photo).
FAINT_MIN_PIXELS = 6
#: How far outside the expected disc (px) its light may reach: the lens blur and the flight's
#: own error at the expected flash (measured 0.0-0.4 px on the studio captures whose ball images
#: were missed; ``docs/pitch.md``).
FAINT_TOLERANCE_PX = 2.0


def _chi2_ppf(q: float, dof) -> float:
    """The chi-square quantile (``scipy.stats.chi2.ppf``) for ``0 < q < 1``."""
    return float(2 * _gammaincinv(np.asarray(dof) / 2, q))


def _limit(dof: int) -> float:
    return _chi2_ppf(1.0 - CHECK_P, max(int(dof), 1))


def _expected_covariances(pair, sigma_px: float) -> np.ndarray:
    """Each position's covariance (m^2) from a random centre error of ``sigma_px`` per image axis."""
    d = center_bias_modes(pair._check_cams, pair.centers_px, sigma_px)  # (4, K, 3), one image at a time
    return np.einsum("mki,mkj->kij", d, d)


def flight_chi2(fit, pairs, pair_index, sigma_px: float) -> tuple[float, int, dict]:
    """Chi-square of the reference fit's residuals with the covariances of ``sigma_px`` centres.

    Returns ``(chi2, dof, per-pair {i: (chi2 of the pair's mean residual, 3)})``."""
    r = np.asarray(fit.residuals, float)
    total, n = 0.0, 0
    per_pair = {}
    for i, p in enumerate(pairs):
        sel = np.flatnonzero(pair_index == i)
        if not len(sel) or getattr(p, "_check_cams", None) is None:
            continue
        C = _expected_covariances(p, sigma_px)
        ri = r[sel]
        ok = np.all(np.isfinite(ri), axis=1) & np.all(np.isfinite(C), axis=(1, 2))
        if not ok.any():
            continue
        Ci = C[ok] + np.eye(3) * 1e-12
        total += float(np.einsum("ki,ki->", ri[ok], np.linalg.solve(Ci, ri[ok][:, :, None])[:, :, 0]))
        n += 3 * int(ok.sum())
        per_pair[i] = pair_disagreement(ri[ok], Ci)
    n_par = int(np.asarray(fit.covariance).shape[0])
    return total, max(n - n_par, 1), per_pair


def pair_disagreement(residuals, covariances) -> tuple[float, int]:
    """Chi-square (3 dof) of a pair's mean residual against its standard error."""
    K = len(residuals)
    if K < 2:
        return float("nan"), 3
    m = residuals.mean(axis=0)
    # the standard error from the scatter of the pair's own residuals and the stated noise,
    # whichever is larger (a pair whose own scatter is large must not look disagreeing)
    S = np.cov(residuals.T) / K
    C = covariances.mean(axis=0) / K
    W = S if np.trace(S) > np.trace(C) else C
    return float(m @ np.linalg.solve(W + np.eye(3) * 1e-14, m)), 3


def expected_flight(fit, model, pair, extend: int = 2, span=None) -> tuple[np.ndarray, np.ndarray]:
    """The flashes of ``pair`` it did not find and where the fitted flight puts the ball then
    (:func:`expected_ball_images`): flash indices (K,) and positions (K, 3), m (both empty when
    there are none). The same for both cameras of the pair: computed once for them (one
    integration of the flight, not one per camera)."""
    k = np.asarray(pair.flash_index, int)
    none = np.zeros(0, int), np.zeros((0, 3))
    if len(k) == 0:
        return none
    ks = np.arange(k.min() - extend, k.max() + extend + 1)
    ks = ks[~np.isin(ks, k)]
    if not len(ks):
        return none
    t = pair.time_offset_s + ks / pair.strobe_hz
    tr = simulate(fit.p0, fit.v0, fit.spin, t, model, t0=fit.t0)
    P = tr.positions
    if span is not None:
        u = np.asarray(fit.v0, float) / np.linalg.norm(fit.v0)
        s_along = (P - fit.p0) @ u
        keep = (s_along >= span[0]) & (s_along <= span[1])
        ks, P = ks[keep], P[keep]
    return ks, P


def expected_ball_images(fit, model, pair, cam, which: int, margin_px: float = 2.0, extend: int = 2,
                         span=None, flight=None, with_radius: bool = False):
    """Flashes of ``pair`` where the fitted flight puts the whole ball disc inside ``cam``'s photo
    but no silhouette was found near it.

    Flash indices from ``min(flash_index) - extend`` to ``max(flash_index) + extend`` (the
    span the pair photographed and ``extend`` flashes either side), kept only where the flight
    surely passed: ``span = (s_min, s_max)``, the stretch along the initial velocity between
    the first and the last ball position any pair found (before it the ball may still be in the
    hand, after it caught). ``flight``: :func:`expected_flight` of the same arguments, computed
    before (the pair's other camera needs the same; None: computed here).

    Returns
    -------
    list of (flash index, (x, y) px)
        With ``with_radius``: (flash index, (x, y) px, the expected image radius px).
    """
    ks, P = expected_flight(fit, model, pair, extend, span) if flight is None else flight
    if not len(ks):
        return []
    pc = cam.world_to_cam(P)
    px = cam.project(P)
    r_m = float(np.nanmedian(pair.radius_px[which])) if np.any(np.isfinite(pair.radius_px[which])) else 20.0
    # the ball's image radius at each flash: the pair's median radius scaled by depth (the ball
    # images nearest the camera are the largest; a median radius made the gate below too tight
    # for them, and a found half moon there counted as missed)
    z_found = cam.world_to_cam(np.asarray(pair.positions, float).reshape(-1, 3))[:, 2]
    z_med = float(np.nanmedian(z_found)) if np.any(np.isfinite(z_found) & (z_found > 0)) else np.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        rad = np.where(np.isfinite(z_med) & (pc[:, 2] > 0), r_m * z_med / pc[:, 2], r_m)
    W, H = cam.image_size
    inside = ((pc[:, 2] > 0) & np.all(np.isfinite(px), axis=1)
              & (px[:, 0] - rad >= margin_px) & (px[:, 0] + rad <= W - 1 - margin_px)
              & (px[:, 1] - rad >= margin_px) & (px[:, 1] + rad <= H - 1 - margin_px))
    det = pair.stereo.detections_a if which == 0 else pair.stereo.detections_b
    found = np.asarray(det.centers, float).reshape(-1, 2) if det is not None else np.zeros((0, 2))
    out = []
    for kk, x, ok, rr in zip(ks, px, inside, rad):
        if not ok:
            continue
        if len(found) and np.min(np.linalg.norm(found - x, axis=1)) < max(rr, 3.0):
            # a silhouette is there (found, maybe not matched or dropped): its centre lies inside
            # the expected disc (a half moon's silhouette centre sits up to ~0.6 r toward the light)
            continue
        out.append((int(kk), (float(x[0]), float(x[1]))) + ((float(rr),) if with_radius else ()))
    return out


def faint_ball_images(image, expected, found_centers=None, found_radii=None,
                      min_pixels: int = FAINT_MIN_PIXELS, tolerance_px: float = FAINT_TOLERANCE_PX) -> np.ndarray:
    """Which expected ball images the photo shows although the silhouette detector found none.

    The silhouette detector keeps only silhouettes above a 6-sigma threshold that survive its
    opening and its area limit (``detect_balls(min_area=50)``): a thin back-lit crescent or a
    small half moon on a noisy photo falls below them, yet the ball was photographed there. Around
    each expected ball image the photo is averaged to half resolution and thresholded at 4
    robust sigmas of that crop (:func:`stillcap.detect.ball._arcs.faint_mask`, what the optional
    faint-crescent search uses); the ball image is seen when one connected piece of at least
    ``min_pixels`` of that mask lies inside its disc (radius + ``tolerance_px``) and outside the
    discs of the silhouettes found (a neighbouring ball image's light is not this one's).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        The photo (BGR ``uint8``).
    expected : sequence of (flash index, (x, y), radius px)
        :func:`expected_ball_images` ``(..., with_radius=True)``.
    found_centers : array_like, shape (N, 2), optional
    found_radii : array_like, shape (N,), optional
        The silhouettes the detector found in this photo (their centres and radii, px).

    Returns
    -------
    ndarray of bool, shape (len(expected),)
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
        raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {img.shape}")
    H, W = img.shape[:2]
    fc = np.asarray(found_centers if found_centers is not None else np.zeros((0, 2)), float).reshape(-1, 2)
    fr = np.asarray(found_radii if found_radii is not None else np.zeros(0), float).reshape(-1)
    fr = np.where(np.isfinite(fr), fr, 0.0)
    seen = np.zeros(len(expected), bool)
    for i, e in enumerate(expected):
        (x, y), r = e[1], float(e[2])
        h = int(np.ceil(3.0 * r + 8.0))  # a crop mostly of background: its median and MAD are the room's
        x0, y0 = max(int(x) - h, 0) & ~1, max(int(y) - h, 0) & ~1  # even: the half-resolution grid
        x1, y1 = min(int(x) + h + 1, W), min(int(y) + h + 1, H)
        if x1 - x0 < 8 or y1 - y0 < 8:
            continue
        crop = img[y0:y1, x0:x1]
        fy, fx = np.mgrid[y0:y1, x0:x1] + 0.5
        ring = np.hypot(fx - x, fy - y) > r + tolerance_px + 1.0  # the room around the expected disc
        for c, rc in zip(fc, fr):
            ring &= np.hypot(fx - c[0], fy - c[1]) > rc + 1.0
        m = faint_mask(_less_room_plane(crop, fx, fy, ring)) > 0
        yy, xx = np.mgrid[0:m.shape[0], 0:m.shape[1]]
        # each half-resolution pixel's centre in the photo
        px, py = x0 + 2.0 * xx + 0.5, y0 + 2.0 * yy + 0.5
        m &= np.hypot(px - x, py - y) <= r + tolerance_px
        for c, rc in zip(fc, fr):
            m &= np.hypot(px - c[0], py - c[1]) > rc + 1.0
        if np.count_nonzero(m) < min_pixels:
            continue
        n, _, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
        seen[i] = n > 1 and int(stats[1:, cv2.CC_STAT_AREA].max()) >= min_pixels
    return seen


def _less_room_plane(crop, fx, fy, ring, iterations: int = 3) -> np.ndarray:
    """``crop`` (h, w[, 3]) as float less a plane in the photo's coordinates (``fx``, ``fy``, each
    pixel's centre) fitted to its channel mean over the ``ring`` pixels (the room around the
    expected ball image): where the flashes light the room its level changes across the crop,
    and a flat level (the crop's median, as :func:`faint_mask` takes it) leaves one side of the
    disc above the threshold or lifts the threshold's robust sigma over a faint ball's light.
    Least squares, refitted without the ring pixels more than 3 robust sigmas from the plane
    (a neighbouring unfound ball image, a seam of light); the crop unchanged with fewer than 12
    ring pixels."""
    a = np.asarray(crop, np.float32)
    g = a.mean(axis=2) if a.ndim == 3 else a
    keep = np.asarray(ring, bool).copy()
    if keep.sum() < 12:
        return a
    A = np.stack([np.ones(g.size, np.float32), (fx - fx.mean()).ravel(), (fy - fy.mean()).ravel()], axis=1)
    gv, kv = g.ravel(), keep.ravel()
    coef = np.zeros(3)
    for _ in range(iterations):
        coef, *_ = np.linalg.lstsq(A[kv], gv[kv], rcond=None)
        res = gv - A @ coef
        sig = 1.4826 * float(np.median(np.abs(res[kv] - np.median(res[kv]))))
        new = ring.ravel() & (np.abs(res) <= 3.0 * max(sig, 1e-3))
        if new.sum() < 12 or np.array_equal(new, kv):
            break
        kv = new
    # the plane's tilt only: the mean level stays, so faint_mask's floor of 0.2 grey levels keeps its meaning
    tilt = (A[:, 1:] @ coef[1:]).reshape(g.shape).astype(np.float32)
    return a - (tilt[..., None] if a.ndim == 3 else tilt)


def pitch_self_checks(pairs, flight, measured, fit, flight_spin, spin_cmp, model, options,
                      photo=None) -> list[SelfCheck]:
    """Every self-check of one analysed pitch (module docstring), in a fixed order.

    ``photo``: camera name -> its photo (or None), read only for a camera where the flight
    expects a ball image no silhouette was found for (:func:`faint_ball_images`); None: every
    such ball image counts as missed."""
    checks: list[SelfCheck] = []
    s_px = float(options.center_sigma_px)
    for p in pairs:
        K = len(p)
        if K == 0:
            continue
        e = np.asarray(p.reproj_error_px, float)
        e = e[np.isfinite(e)]
        if len(e):
            c2 = float(2.0 * np.sum(e ** 2) / s_px ** 2)
            lim = _limit(len(e))
            checks.append(SelfCheck(
                "ball_epipolar", c2 <= lim, c2, lim,
                f"ball centres miss their epipolar lines by {np.sqrt(np.mean(e ** 2)):.2f} px RMS, expected "
                f"{s_px / np.sqrt(2):.2f} px (center_sigma_px {s_px:g})"
                + ("" if c2 <= lim else ": a camera moved after calibration, or the rig or its lens distortion "
                   "is wrong; recalibrate"), p.name, ""))
        if p.observations is not None and p.n_markers_3d + p.n_markers_ray > 0 and np.isfinite(p.marker_reproj_px):
            lim = 0.5 * float(options.marker_epipolar_px)
            checks.append(SelfCheck(
                "marker_epipolar", p.marker_reproj_px <= lim, float(p.marker_reproj_px), lim,
                f"markers matched across the pair miss their epipolar lines by {p.marker_reproj_px:.2f} px "
                f"(median; the matching gate is {options.marker_epipolar_px:g} px)"
                + ("" if p.marker_reproj_px <= lim else ": the gate cuts the distribution, the rig is off"),
                p.name, "px"))


    n_img = sum(len(p) for p in pairs)
    n_3d = sum(p.n_markers_3d for p in pairs)
    if n_img:
        per_image = n_3d / n_img
        checks.append(SelfCheck(
            "marker_matches", per_image >= MIN_MARKERS_PER_IMAGE, per_image, MIN_MARKERS_PER_IMAGE,
            f"{n_3d} markers triangulated across the pairs over {n_img} ball images"
            + ("" if per_image >= MIN_MARKERS_PER_IMAGE else ": too few for a trustworthy spin (check the camera "
               "response, the white balance and the ball's marker colours)"), "", "per image"))

    # the flight
    c2, dof, per_pair = flight_chi2(fit, pairs, flight.pair_index, s_px)
    lim = _limit(dof)
    checks.append(SelfCheck(
        "flight_chi2", c2 <= lim, c2 / dof, lim / dof,
        f"the reference trajectory misses the positions by chi-square {c2:.0f} with {dof} degrees of freedom "
        f"(centres at {s_px:g} px)"
        + ("" if c2 <= lim else ": the flight model, a strobe rate, the flash order or the positions are wrong; "
           "the uncertainties were scaled up by the misfit"), "", "chi2/dof"))
    for i, (c2p, d) in per_pair.items():
        if pairs[i].group == 0 or not np.isfinite(c2p):
            continue
        lim = _limit(d)
        checks.append(SelfCheck(
            "pair_agreement", c2p <= lim, c2p, lim,
            f"pair {pairs[i].name!r} sits {np.linalg.norm(np.nanmean(fit.residuals[flight.pair_index == i], axis=0)) * 1e3:.1f} mm "
            f"off the flight the pairs share (chi-square {c2p:.1f}, 3 dof)"
            + ("" if c2p <= lim else ": the pairs disagree (calibration, camera response or ball size of one pair); "
               "the uncertainties include the disagreement"), pairs[i].name, ""))

    # the spin
    spin = measured.spin
    if spin is not None and spin.n_observations:
        frac = spin.n_inliers / spin.n_observations
        checks.append(SelfCheck(
            "spin_fit", frac >= MIN_SPIN_INLIERS and bool(spin.success), frac, MIN_SPIN_INLIERS,
            f"the spin explains {spin.n_inliers} of {spin.n_observations} marker observations "
            f"({spin.rms_deg:.1f} deg RMS)"
            + ("" if frac >= MIN_SPIN_INLIERS else ": markers misidentified or the ball layout is wrong"), "", ""))
    alias = measured.alias
    if alias is not None and len(alias.candidates) >= 1:
        # no rival alias (one candidate): the margin cannot be measured, so its value is None (as JSON
        # keeps it; an infinity would come back as None), and the check rests on the evidence's consistency
        gap = float(alias.candidates[1].chi2 - alias.best.chi2) if len(alias.candidates) >= 2 else None
        ok = (gap is None or gap >= MIN_ALIAS_GAP) and bool(alias.consistent)
        checks.append(SelfCheck(
            "alias_margin", ok, gap, MIN_ALIAS_GAP,
            f"the chosen spin alias ({alias.best.spin_rpm:.0f} rpm) beats the next "
            + (f"({alias.candidates[1].spin_rpm:.0f} rpm) by chi-square {gap:.1f}" if len(alias.candidates) >= 2
               else "(none)")
            + ("" if alias.consistent else f"; the evidence disagrees with it (chi-square {alias.best.chi2:.1f}, "
               f"{alias.dof} dof)")
            + ("" if ok else ": the spin rate and axis may be a wrong alias; use two strobe rates"),
            "", "chi2"))
    undecided = list(getattr(alias, "undecided", None) or []) if alias is not None else []
    if undecided:
        checks.append(SelfCheck(
            "spin_alias", False, float(undecided[0].p_markers), UNDECIDED_P,
            f"spin alias undecided: {alias.undecided_text()} (F test of their misfits, {alias.marker_dof} degrees "
            f"of freedom, p >= {UNDECIDED_P:g}): the marker spin is withheld; photograph more markers (a second "
            "pair, larger ball images) or two strobe rates", "", "p"))
    if spin_cmp is not None:
        checks.append(SelfCheck(
            "spin_vs_flight", bool(spin_cmp.agree), float(spin_cmp.chi2), _chi2_ppf(1 - spin_cmp.alpha, spin_cmp.dof),
            f"the marker spin's transverse part and the flight's curvature differ by {spin_cmp.difference_rpm:.0f} rpm "
            f"(axes {spin_cmp.axis_angle_deg:.0f} deg apart)"
            + ("" if spin_cmp.agree else ": a wrong alias, a reversed axis or a wrong flight model"), "", "chi2"))

    # ball images the flight says are there (only where the ball surely flew)
    u = np.asarray(fit.v0, float) / np.linalg.norm(fit.v0)
    along = [(p.positions - fit.p0) @ u for p in pairs if len(p)]
    along = np.concatenate(along) if along else np.zeros(0)
    span = (float(along.min()), float(along.max())) if len(along) else None
    for p in pairs:
        if not len(p) or p.stereo is None or getattr(p, "_check_cams", None) is None:
            continue
        expected = expected_flight(fit, model, p, span=span)  # the same for both cameras: once
        for which, cam in enumerate(p._check_cams):
            absent = expected_ball_images(fit, model, p, cam, which, span=span, flight=expected,
                                          with_radius=True)
            faint = []
            img = photo(cam.name) if (absent and photo is not None) else None
            if img is not None:
                det = p.stereo.detections_a if which == 0 else p.stereo.detections_b
                seen = faint_ball_images(img, absent, det.centers, det.radii_px)
                faint = [e for e, s_ in zip(absent, seen) if s_]
                absent = [e for e, s_ in zip(absent, seen) if not s_]
            checks.append(SelfCheck("missed_ball_images", not absent, float(len(absent)), 0.0,
                                    _missed_message(absent, faint), cam.name, ""))
    return checks


def _missed_message(absent: list, faint: list) -> str:
    """The ``missed_ball_images`` message: the ball images with no light there (what fails the
    check) and those the photo shows but the detector did not measure (named, not counted)."""
    def where(items):
        return ", ".join(f"flash {k} at ({x:.0f}, {y:.0f}) px" for k, (x, y), _ in items[:4])

    if absent:
        msg = (f"{len(absent)} ball image(s) the fitted flight puts inside the photo were not found and the "
               f"photo shows no light there: {where(absent)} (a flash that did not fire, a hidden ball, or a "
               "wrong flight)")
    else:
        msg = "every ball image the fitted flight puts inside the photo was found" + (" or seen" if faint else "")
    if faint:
        msg += (f"; {len(faint)} seen in the photo but too faint or small for the silhouette detector (thin "
                f"back-lit crescents, small balls on a noisy photo; not measured): {where(faint)}")
    return msg


def disagreement_factor(checks) -> float:
    """Variance factor (>= 1) for the flight's uncertainties from the pairs' disagreement: the
    largest ``chi2 / 3`` of the failed ``pair_agreement`` checks (a chi-square of 3 dof below
    its 99.9 % quantile is no evidence of a disagreement: clean captures keep their sigmas). The fit's covariance already follows
    its residuals' scatter (``ReferenceFit.residual_scale``), and the spin's its own
    (``SpinResult.spin_covariance``); a pair's mean offset, which the joint fit partly absorbs in
    the clock offsets, is what neither sees."""
    f = 1.0
    for c in checks:
        if c.name == "pair_agreement" and not c.passed and np.isfinite(c.value):
            f = max(f, float(c.value) / 3.0)
    return f


def ambiguous_alias_candidates(checks, alias) -> list:
    """The spin aliases the photos cannot rule out when the ``alias_margin`` check failed: every
    candidate but the best within ``MIN_ALIAS_GAP`` of its chi-square, at least the runner-up
    (the best's evidence is then weak); every candidate when the evidence is inconsistent (a
    wrong strobe measurement or curvature: the ranking itself cannot be trusted). Empty when
    the check passed."""
    failed = any(c.name == "alias_margin" and not c.passed for c in checks)
    if not failed or alias is None or len(alias.candidates) < 2:
        return []
    if not alias.consistent:  # the evidence contradicts itself: it rules no alias out
        return list(alias.candidates[1:])
    best = float(alias.best.chi2)
    out = [c for c in alias.candidates[1:] if float(c.chi2) - best < MIN_ALIAS_GAP]
    return out or [alias.candidates[1]]


def widen_spin_for_aliases(spin, candidates):
    """The spin result with intervals that cover the other aliases the photos allow.

    An ambiguous alias is a mixture: the true spin is the reported one or one of
    ``candidates``. Its vector covariance gains ``d d^T`` per candidate (``d`` = candidate -
    reported: the candidate at one sigma along ``d``), and the rate and axis sigmas are what puts
    every candidate's own interval inside the reported 95 % intervals (rate ``|d rate| / 1.96 +
    sigma``; axis, which a reversed alias turns by up to 180 deg, ``angle / 2.45 + sigma``, 2.45
    the 2-D 95 % radius). Returns
    ``(spin, extra_covariance)`` (rad/s)^2.
    """
    from dataclasses import replace

    w = np.asarray(spin.spin, float)
    extra = np.zeros((3, 3))
    need_rate, need_axis = 0.0, 0.0
    n = float(np.linalg.norm(w))
    # each candidate is itself measured to about the reported spin's sigmas: the intervals
    # reach past it by those
    s_rate0 = float(spin.sigma_rpm) if np.isfinite(spin.sigma_rpm) else 0.0
    s_axis0 = float(spin.sigma_axis_deg) if np.isfinite(spin.sigma_axis_deg) else 0.0
    for c in candidates:
        wc = np.asarray(c.spin, float)
        d = wc - w
        extra += np.outer(d, d)
        need_rate = max(need_rate, abs(float(np.linalg.norm(wc)) - n) * RPM_PER_RAD_S / _ndtri(0.975) + s_rate0)
        if n > 0 and np.linalg.norm(wc) > 0:
            ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(w, wc)), w @ wc))
            need_axis = max(need_axis, float(ang) / np.sqrt(_chi2_ppf(0.95, 2)) + s_axis0)
    cov = np.asarray(spin.spin_covariance, float) + extra
    # the rate and axis sigmas from the candidates themselves (the vector covariance projected
    # on the rate is meaningless for a reversed alias, whose rate is close and vector opposite)
    return replace(spin, spin_covariance=cov, sigma_rpm=max(s_rate0, need_rate),
                   sigma_axis_deg=max(s_axis0, need_axis)), extra


class _Candidate:
    """A spin the photos cannot rule out (:func:`widen_spin_for_aliases` reads ``spin``)."""

    def __init__(self, spin):
        self.spin = np.asarray(spin, float)
        self.spin_rpm = float(np.linalg.norm(self.spin)) * RPM_PER_RAD_S
        n = np.linalg.norm(self.spin)
        self.axis = self.spin / n if n > 0 else np.full(3, np.nan)


def identity_candidates(spin, layout_check, flight_spin, spin_cmp, scale: float = 1.0) -> list:
    """The spin the flight's curvature points to, when the markers' identities failed.

    With misidentified markers (the ``ball_layout`` check failed: the markers lie further from
    every rotation of the ball's layout than markers are found) the spin fit's errors are
    systematic, and its residual-scaled covariance does not cover them (issue 12: JPEG 70
    typed small green and blue markers black, and the spin came out 83 rpm off with a sigma of
    11 rpm while the flight's curvature was 9 rpm off). Where the flight's curvature also
    disagrees with the marker spin (``spin_vs_flight``), the spin the flight shows is a second
    candidate: the marker spin with its transverse part the flight's (with the seed's lift law,
    whose flight sees the total rate, its rate the flight's). Empty when the identities held,
    the flight agrees or there is no flight spin.

    ``scale``: the marker spin's magnitude over ``spin_cmp``'s (which compares the spin at the
    flight's ``t0``).
    """
    if (spin is None or layout_check is None or layout_check.passed or spin_cmp is None or flight_spin is None
            or spin_cmp.agree):
        return []
    w = np.asarray(spin.spin, float)
    if getattr(flight_spin, "lift_from", "") == "total":
        rm = float(spin_cmp.marker_transverse_rpm)
        if not rm > 0:
            return []
        c = w * (float(spin_cmp.flight_rpm) / rm)
    else:
        c = w + (np.asarray(flight_spin.spin, float) - np.asarray(spin_cmp.marker_transverse, float)) / scale
    return [_Candidate(c)] if np.all(np.isfinite(c)) else []
