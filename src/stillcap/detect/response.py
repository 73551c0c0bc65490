"""The camera's response estimated from the photos themselves: the shading of lit spheres.

A matte (lambertian) sphere lit by a distant light has, at the surface point whose normal is
``n``, the radiance ``a max(0, n . s) + b`` (``s``: the light direction, ``a``: albedo times
irradiance, ``b``: ambient). Seen from afar, the pixel at ``(x, y)`` from the centre of a ball
image of radius ``r`` shows the point with normal ``((x / r), (y / r), -sqrt(1 - rho^2))``, so
the radiance across the disc is known up to ``a``, ``b`` and ``s``. The pixel values are that
radiance through the camera's response; fitted with a power law ``v = 255 (radiance) ^ (1 / g)``
the exponent ``g`` is the response's *effective gamma*: about 1 for a linear camera, 1.8-2.6 for
sRGB, power laws and tone curves (:class:`stillcap.response.Response`). The level sets of the
shading are fixed by the geometry, the spacing of the values between them by the response:
``a`` only scales, ``s`` moves the level sets, so the three are separable.

:func:`ball_shading_gamma` fits one ball image (pixels within ``inner`` of the radius, where
the lens blur and the limb's mix with the background do not reach; markers and saturated pixels
fall out of a robust fit); :func:`estimate_response` combines the balls of a photo (or of a
capture) into a :class:`ResponseEstimate` with its class, gamma, spread and evidence, and
:func:`response_check` compares it with a declared response (the ``response`` self-check).

Works on pitch balls (white leather with painted markers), the hand capture's ball, and on lit
beads (a bead is a small matte sphere too; its colour does not matter, the brightest channel is
fitted). The estimate needs spheres of at least ~5 px radius; fewer than :data:`MIN_SPHERES`
usable ones give an estimate that says it cannot tell.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

from stillcap._checks import as_array
from stillcap._selfcheck import SelfCheck
from stillcap.response import LINEAR_LIMIT, Response

__all__ = ["ResponseEstimate", "ball_shading_gamma", "estimate_response", "response_check", "MIN_SPHERES"]

#: Fewest fitted spheres for an estimate (below: "cannot tell").
MIN_SPHERES = 3
_MIN_PIXELS = 25
_G_BOUNDS = (0.4, 5.0)


@dataclass
class ResponseEstimate:
    """What the photos say about the camera's response.

    Attributes
    ----------
    response_class : str or None
        ``"linear"`` or ``"gamma"`` (:data:`stillcap.response.CLASSES`); None when the photos
        cannot tell (too few usable spheres).
    gamma : float
        Effective gamma (weighted median over the spheres), NaN when it cannot tell.
    spread : float
        Robust spread (1.4826 MAD) of the spheres' log-gammas: how well they agree.
    n_spheres : int
        Spheres fitted.
    gammas : ndarray
        Each sphere's effective gamma.
    evidence : str
        One line: what was fitted and what it gave.
    """

    response_class: str | None
    gamma: float
    spread: float
    n_spheres: int
    gammas: np.ndarray = field(repr=False)
    evidence: str = ""

    @property
    def ok(self) -> bool:
        return self.response_class is not None

    def response(self) -> Response | None:
        """The response to use: linear for the linear class, else the power law of the estimated
        gamma (kept within 1.4-3.2, the encodings cameras use); None when it cannot tell."""
        if not self.ok:
            return None
        if self.response_class == "linear":
            return Response.linear()
        return Response.power(round(float(np.clip(self.gamma, 1.4, 3.2)), 2))

    def to_json(self) -> dict:
        r = self.response()
        return {"class": self.response_class, "gamma": None if not np.isfinite(self.gamma) else round(self.gamma, 3),
                "spread": None if not np.isfinite(self.spread) else round(self.spread, 3),
                "n_spheres": int(self.n_spheres), "response": None if r is None else r.to_json(),
                "evidence": self.evidence}


def _brightest(img: np.ndarray) -> np.ndarray:
    if img.ndim == 3:
        return np.maximum(np.maximum(img[..., 0], img[..., 1]), img[..., 2])
    return img


def ball_shading_gamma(image, center, radius_px: float, inner: float = 0.8, f_scale: float = 4.0,
                       terminator_px: float = 2.0) -> dict | None:
    """Fit one lit sphere's shading (module docstring) with a power law.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        The photo (8-bit scale; the brightest channel is fitted).
    center : array_like, shape (2,)
        The sphere image's centre, raw pixels.
    radius_px : float
        Its radius, px.
    inner : float
        Pixels within this share of the radius are fitted.
    f_scale : float
        Robust (soft L1) scale, code values: markers and specular spots fall out.
    terminator_px : float
        The final fit leaves out the pixels within about this distance of the shadow line
        (``|n . s| < terminator_px / radius``), where the lens blur mixes lit and unlit.

    Returns
    -------
    dict or None
        ``gamma``, ``rms`` (code values), ``n`` (pixels), ``light`` (unit ``s``, camera-like
        frame x right, y down, z away from the camera), ``lit`` (share of fitted pixels with
        ``n . s > 0``); None when the sphere is too small, cut by the border or flat.
    """
    img = np.asarray(image)
    c = as_array(center, (2,), "center")
    r = float(radius_px)
    if not (np.all(np.isfinite(c)) and np.isfinite(r) and r >= 3):
        return None
    H, W = img.shape[:2]
    x0, y0 = int(np.floor(c[0] - r)), int(np.floor(c[1] - r))
    x1, y1 = int(np.ceil(c[0] + r)) + 1, int(np.ceil(c[1] + r)) + 1
    if x0 < 0 or y0 < 0 or x1 > W or y1 > H:
        return None
    v = _brightest(img[y0:y1, x0:x1]).astype(float)
    X, Y = np.meshgrid(np.arange(x0, x1) - c[0], np.arange(y0, y1) - c[1])
    rho2 = (X * X + Y * Y) / (r * r)
    sel = (rho2 <= inner * inner) & (v < 254.5) & (v > 0.5)
    if sel.sum() < _MIN_PIXELS:
        return None
    xs, ys, vv = X[sel], Y[sel], v[sel] / 255.0
    if np.ptp(vv) < 12 / 255:  # flat: nothing to fit (a sphere lit by ambient light only)
        return None

    # The centre and radius stay fixed: fitted with the shading they trade off with the gamma
    # (a larger radius flattens the profile like a larger gamma), so they must come from the
    # geometry (the refined centre and the radius projected from the triangulated ball).
    N = np.stack([xs / r, ys / r, -np.sqrt(np.maximum(1.0 - (xs * xs + ys * ys) / (r * r), 0.0))], 1)
    # start: the light toward the bright side, from the value-weighted centroid of the disc
    w = vv - vv.min()
    m = (N * w[:, None]).sum(0) / max(w.sum(), 1e-12)
    s0 = m / max(np.linalg.norm(m), 1e-12)

    def model(p):
        th, ph, la, b, lg = p
        s = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), -np.cos(th)])
        rad = np.exp(la) * np.maximum(N @ s, 0.0) + b
        return np.clip(rad, 1e-9, 1.0) ** np.exp(-lg), s

    keep = np.ones(len(vv), bool)
    Nk, vk = N, vv  # the kept pixels' normals and values (set again with ``keep`` below)

    def resid(p):
        th, ph, la, b, lg = p
        s = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), -np.cos(th)])
        rad = np.exp(la) * np.maximum(Nk @ s, 0.0) + b
        return 255.0 * (np.clip(rad, 1e-9, 1.0) ** np.exp(-lg) - vk)

    def jac(p):
        # analytic: the numerical one cost 5 more evaluations per step, ~2/3 of the fit's time
        th, ph, la, b, lg = p
        st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
        s = np.array([st * cp, st * sp, -ct])
        ns = Nk @ s
        lit = ns > 0.0
        a = np.exp(la)
        rad = a * np.where(lit, ns, 0.0) + b
        inside = (rad > 1e-9) & (rad < 1.0)
        rc = np.clip(rad, 1e-9, 1.0)
        k = np.exp(-lg)
        pred = rc ** k
        dpdr = np.where(inside, k * pred / rc, 0.0)  # d pred / d rad
        al = a * lit
        J = np.empty((len(ns), 5))
        J[:, 0] = dpdr * al * (Nk @ np.array([ct * cp, ct * sp, st]))
        J[:, 1] = dpdr * al * (Nk @ np.array([-st * sp, st * cp, 0.0]))
        J[:, 2] = dpdr * a * np.where(lit, ns, 0.0)
        J[:, 3] = dpdr
        J[:, 4] = -k * pred * np.log(rc)
        return 255.0 * J

    th0 = float(np.arccos(np.clip(-s0[2], -1, 1)))
    ph0 = float(np.arctan2(s0[1], s0[0]))
    best = None
    lo = [0.0, -np.inf, np.log(1e-3), 0.0, np.log(_G_BOUNDS[0])]
    hi = [np.pi, np.inf, np.log(4.0), 0.3, np.log(_G_BOUNDS[1])]
    for g0 in (1.0, 2.2):  # two starts: the linear and the encoded basin
        a0 = float(np.quantile(vv, 0.95)) ** g0
        p0 = [min(max(th0, 1e-3), np.pi - 1e-3), ph0, np.log(max(a0, 2e-3)), 0.0, np.log(g0)]
        try:
            f = least_squares(resid, p0, jac, bounds=(lo, hi), loss="soft_l1", f_scale=f_scale, max_nfev=200)
        except ValueError:
            continue
        if best is None or f.cost < best.cost:
            best = f
    if best is None:
        return None
    # Again without the terminator's band: the lens blur spreads the lit side's light over the
    # shadow line, which a sharp lambertian model reads as a flatter curve (a side- or back-lit
    # ball's gamma came out ~15 % low with 0.6 px of blur).
    # ... and without the dark markers: pixels well below the first fit, grown by a pixel (a
    # marker's blurred rim), are paint, not shading (dark paint near the limb steepened the
    # profile: linear balls came out 0.5-1.0 with the robust loss alone)
    pred0, s0 = model(best.x)
    res = 255.0 * (vv - pred0)
    sigma = 1.4826 * float(np.median(np.abs(res)))
    dark = np.zeros(sel.shape, np.uint8)
    dark[sel] = res < -max(4.0 * sigma, 5.0)
    dark = cv2.dilate(dark, np.ones((3, 3), np.uint8))[sel].astype(bool)
    band = terminator_px / r
    keep = (np.abs(N @ s0) >= band) & ~dark
    if keep.sum() >= _MIN_PIXELS:
        Nk, vk = N[keep], vv[keep]
        try:
            best = least_squares(resid, best.x, jac, bounds=(lo, hi), loss="soft_l1", f_scale=f_scale,
                                 max_nfev=200)
        except ValueError:
            pass
    pred, s = model(best.x)
    res = 255.0 * (pred - vv)
    lit = float(np.mean(N @ s > 0))
    return {"gamma": float(np.exp(best.x[4])), "rms": float(np.sqrt(np.median(res ** 2))), "n": int(sel.sum()),
            "light": s, "lit": lit}


def estimate_response(images, centers, radii_px, max_spheres: int = 40, what: str = "ball") -> ResponseEstimate:
    """The response class and effective gamma from lit spheres in photos of one camera.

    Parameters
    ----------
    images : ndarray or list of ndarray
        One photo, or several (then ``centers`` and ``radii_px`` are lists of the same length).
    centers : array_like, shape (N, 2), or list of them
        Sphere image centres (e.g. the ball detector's), raw pixels.
    radii_px : array_like, shape (N,), or list of them
    max_spheres : int
        At most this many (the largest) spheres are fitted.
    what : str
        What the spheres are, for the evidence line ("ball", "bead").

    Returns
    -------
    ResponseEstimate
    """
    if isinstance(images, np.ndarray):
        images, centers, radii_px = [images], [centers], [radii_px]
    cand = []
    for k, (img, cs, rs) in enumerate(zip(images, centers, radii_px)):
        cs = np.asarray(cs, float).reshape(-1, 2)
        rs = np.broadcast_to(np.asarray(rs, float), (len(cs),))
        cand += [(float(r), k, c) for c, r in zip(cs, rs) if np.isfinite(r) and np.all(np.isfinite(c))]
    cand.sort(key=lambda t: -t[0])
    fits = []
    for r, k, c in cand[:int(max_spheres)]:
        f = ball_shading_gamma(images[k], c, r)
        if f is not None:
            fits.append(f)
    return _combine(fits, what)


def _combine(fits: list, what: str) -> ResponseEstimate:
    n = len(fits)
    if n == 0:
        return ResponseEstimate(None, float("nan"), float("nan"), 0, np.zeros(0),
                                f"no {what} image large and lit enough to fit its shading: cannot tell")
    g = np.array([f["gamma"] for f in fits])
    w = np.array([f["n"] for f in fits], float)
    lg = np.log(g)
    order = np.argsort(lg)
    cw = np.cumsum(w[order])
    med = float(lg[order][np.searchsorted(cw, 0.5 * cw[-1])])
    spread = float(1.4826 * np.median(np.abs(lg - med))) if n > 1 else float("nan")
    gamma = float(np.exp(med))
    if n < MIN_SPHERES:
        return ResponseEstimate(None, gamma, spread, n, g,
                                f"only {n} {what} image(s) to fit (need {MIN_SPHERES}): cannot tell "
                                f"(effective gamma {gamma:.2f})")
    cls = "linear" if gamma < LINEAR_LIMIT else "gamma"
    q1, q3 = np.percentile(g, [25, 75])
    ev = (f"shading of {n} lit {what} images fitted with a lambertian sphere: effective gamma {gamma:.2f} "
          f"(quartiles {q1:.2f}-{q3:.2f}) -> {cls}")
    return ResponseEstimate(cls, gamma, spread, n, g, ev)


def response_check(estimate: ResponseEstimate, declared: Response, subject: str = "",
                   limit: float = 0.3) -> SelfCheck:
    """The ``response`` self-check: the shading's effective gamma against the declared response's.

    ``value`` = ``|ln(gamma_photos / gamma_declared)|``; it passes up to ``limit`` (default 0.3:
    a factor 1.35, the gap between a linear camera and the flattest encoding is 0.59, between
    sRGB and linear 0.79). When the photos cannot tell, the check passes and says so.
    """
    decl = Response.from_json(declared, "declared response")
    gd = decl.effective_gamma
    if not estimate.ok:
        return SelfCheck("response", True, None, limit,
                         f"declared response {decl}; the photos cannot tell ({estimate.evidence})", subject, "")
    value = float(abs(np.log(estimate.gamma / gd)))
    passed = value <= limit
    if passed:
        msg = (f"declared response {decl} (effective gamma {gd:.2f}) agrees with the ball shading "
               f"(effective gamma {estimate.gamma:.2f}, {estimate.n_spheres} images)")
    else:
        msg = (f"declared response {decl} (effective gamma {gd:.2f}) disagrees with the ball shading "
               f"(effective gamma {estimate.gamma:.2f} over {estimate.n_spheres} images, {estimate.response_class} "
               f"class): ball centres are biased by a wrong response; state the camera's response "
               f"(rig 'response', --response) or use --response auto")
    return SelfCheck("response", bool(passed), value, float(limit), msg, subject, "")
