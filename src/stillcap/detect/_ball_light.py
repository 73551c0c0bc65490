"""The light's direction at one ball from its shading (issue 12): a matte sphere lit by one point
light and ambient light, fitted to the ball image's linearised brightness
(:func:`fit_ball_light`), in the ball's *view frame* (x, y along the image's axes, z along the
line of sight through the ball's centre, away from the camera).

Why not the white model's plane (:func:`stillcap.detect._blur_shift._fit_shading`): that plane,
``a n_x + b n_y + c n_z + d``, is fitted to every pixel whose closing is above a fifth of the
ball's brightest (encoded), which on a side-lit ball takes in the unlit side's ambient-lit
leather, where Lambert's ``max(n.l, 0)`` is flat and the plane is not: on the robustness
benchmark's side-lit captures its light was 10-40 deg off (median per capture). Here the
clipped model is fitted instead, robustly (the markers and seams are the outliers), and a ball away from the optical
axis is seen along its own line of sight (up to 20 deg from the axis on those captures): the
caller turns the view frame into the camera's (:func:`view_to_camera`).
"""

from __future__ import annotations

import cv2
import numpy as np

from stillcap._numeric import median
from stillcap.detect._blur_shift import DrawnShading

__all__ = ["crop_cos_light", "crop_light", "crop_shading", "fit_ball_light", "light_disc", "terminator_weights",
           "view_to_camera"]

#: the centroids weigh paint in reflectance where the light's model of the leather stands this many
#: of its residuals' robust sigmas above zero (elsewhere the ratio is noise over noise; there the
#: detector's darkness, which pulls toward the light, is taken). 2 sigmas: lit at 97.7 % one-sided;
#: at 5 a noisy photo's floor rose into the paint near the terminator (a drawn ball with 1.5-3 of
#: 255 of sensor noise: +1.3 to +3.8 deg toward the light, at 2 -0.7 to +0.6; docs/spin.md)
SHADING_SNR = 2.0
#: ... for markers within this (in n.l) plus two blur sigmas (over the radius) of the terminator
#: (:func:`fit_ball_light`'s band left out across it)
TERMINATOR_BAND = 0.05


def fit_ball_light(lin, nx, ny, init=None, min_pixels: int = 30, band: float = 0.05, rounds: int = 20):
    """The light's direction at a ball from its linear brightness, view frame, and its error.

    Parameters
    ----------
    lin : ndarray, shape (N,)
        Linear brightness of the ball's pixels (markers and seams may be among them: the fit is
        robust), e.g. ``Response.linearize`` of the photo's luma.
    nx, ny : ndarray, shape (N,)
        The pixels' positions relative to the ball image's centre, in radii (within the disc).
    init : array_like, shape (3,), optional
        A starting direction (view frame); default the brightness-weighted mean normal.
    min_pixels : int
        Fewest pixels to fit.
    band : float
        Half-width in ``n.l`` of the band across the terminator left out (the blur smears it).
    rounds : int
        Most rounds of the active set and the robust weights (it stops once the direction moves
        less than 0.01 deg in a round, from the third on).

    Returns
    -------
    (direction (3,), sigma_deg, rho, ambient, noise) or None
        ``sigma_deg``: the direction's expected (RMS) angular error from the fit, deg; ``rho``
        and ``ambient`` the model's two brightnesses and ``noise`` its residuals' robust sigma
        (linear, as ``lin``; :func:`crop_shading` draws the model). None with too few pixels or
        lit pixels.

    The model is a Lambertian sphere clipped at the terminator with ambient light,
    ``S = rho max(n.l, 0) + a``, the normal ``n = (nx, ny, -nz)`` (``nz = sqrt(1 - nx^2 - ny^2)``,
    toward the camera). Solved by an active set, each round linear least squares: the pixels
    with ``n.l > band`` under the current direction follow ``rho n.l + a`` (the light's
    direction is that plane's normalised gradient), those below ``-band`` the ambient ``a``
    alone; Huber weights at 1.5 robust sigmas (1.4826 MAD) of the residuals. (scipy's
    ``least_squares`` on the clipped model cost ten times more and fell into other minima from
    the default start.)
    """
    lin, nx, ny = (np.asarray(v, float).ravel() for v in (lin, nx, ny))
    if not (len(lin) == len(nx) == len(ny)):
        raise ValueError(f"lin, nx and ny must have one length, got {len(lin)}, {len(nx)}, {len(ny)}")
    ok = np.isfinite(lin) & np.isfinite(nx) & np.isfinite(ny) & (nx * nx + ny * ny < 1.0)
    if np.count_nonzero(ok) < min_pixels:
        return None
    lin, nx, ny = lin[ok], nx[ok], ny[ok]
    N = np.stack([nx, ny, -np.sqrt(1.0 - nx * nx - ny * ny)], axis=1)
    if init is None:
        w0 = np.clip(lin - np.percentile(lin, 10), 0, None)
        init = (w0 @ N) if w0.sum() > 0 else np.array([0.0, 0.0, -1.0])
    l = np.asarray(init, float)
    if not (np.all(np.isfinite(l)) and np.linalg.norm(l) > 0):
        return None
    l = l / np.linalg.norm(l)
    w = np.ones(len(lin))
    A = np.empty((len(lin), 4))
    A[:, 3] = 1.0
    # the round's arrays written into buffers made once (the same operations on the same numbers:
    # the same bits; per round the NumPy calls' overhead, not their arithmetic, was the cost on a
    # ball's 10^3 pixels; speed only, issue 16)
    Aw, wu, ares = np.empty_like(A), np.empty(len(lin)), np.empty(len(lin))
    stop = np.cos(np.radians(0.01))
    for it in range(rounds):
        s = N @ l
        lit, use = s > band, np.abs(s) > band
        if np.count_nonzero(lit) < 8:
            return None
        np.multiply(N, lit[:, None], out=A[:, :3])
        np.multiply(w, use, out=wu)
        # the 4x4 normal equations (a lstsq of the whole design each round cost twice the detector);
        # the normal matrix built once per round and kept: the last round's is the covariance's below
        np.multiply(A, wu[:, None], out=Aw)
        AtA = Aw.T @ A
        try:
            coef = np.linalg.solve(AtA, Aw.T @ lin)
        except np.linalg.LinAlgError:
            return None
        g = coef[:3]
        gn = np.linalg.norm(g)
        if not (np.all(np.isfinite(g)) and gn > 0):
            return None
        l_prev, l = l, g / gn
        np.subtract(A @ coef, lin, out=ares)
        np.abs(ares, out=ares)  # the residuals' size, once for the scale and the weights
        scale = 1.4826 * median(ares[use]) + 1e-12  # np.median's bits, without its overhead
        np.maximum(ares, 1e-12, out=ares)
        np.divide(1.5 * scale, ares, out=ares)
        np.minimum(ares, 1.0, out=w)  # the Huber weights min(1, 1.5 scale / |res|)
        if it >= 2 and l @ l_prev > stop:
            break
    # the direction's error: the weighted fit's covariance of the gradient, across the direction
    cov = np.linalg.pinv(AtA)[:3, :3] * scale ** 2
    Pt = np.eye(3) - np.outer(l, l)
    sig = float(np.degrees(np.sqrt(max(np.trace(Pt @ cov @ Pt), 0.0)) / gn))
    return l, sig, float(np.dot(g, l)), float(coef[3]), scale


def light_disc(geo, dist, r):
    """The pixels :func:`crop_light` fits, by the ball's geometry alone: its disc ``geo`` (h, w;
    the circle, less what lies nearer another ball) within 0.85 r of the ball image's centre
    (``dist``, px, (h, w); the cap the fit had before: the limb's mix in the background).

    Not the searched hull of the pixels over the detector's ``min_value``: with no room light
    that hull ends short of the terminator, no pixel of the unlit side enters the fit and its
    ambient term is free. On tests/detect/test_ball_light.py's drawn ball with ambient 0 (rho
    0.63, blur 0.3-1.5 px, light 60-110 deg beside the camera) the hull's fit
    gave ambient up to 0.012 on the optical axis and 0.032 14 deg off it, this disc's up to 0.0016
    and 0.0048; the light on the axis 0.46 deg off on average (up to 1.25), this disc's 0.19 (up
    to 0.78). 14 deg off the axis neither is better (mean 0.65 / 0.79 deg, up to 1.4 / 1.5): there
    the fit's normals, the pixels' offsets over ``r``, are not the view frame's. (A rim shrunk by
    the blur read instead of 0.85 r: ``r - (0.5 + 2 blur)`` 0.17 deg on the axis, ``r - max(blur,
    1)`` 0.39.)
    """
    return geo & (dist <= 0.85 * r)


def crop_light(luma, X, Y, cx, cy, r, sel, response, plane_model=None):
    """:func:`fit_ball_light` on a ball image's crop: its luma (0-1, encoded, (h, w)), pixel
    coordinates ``X`` (1, w) and ``Y`` (h, 1), the ball image's centre and radius (px), the pixels
    ``sel`` (h, w) to fit (:func:`light_disc`: the ball's disc by geometry, short of the limb's mix in
    the background), linearised
    through ``response``; started from the white model's plane
    (:func:`stillcap.detect._blur_shift._fit_shading`'s ``(a, b, c, ...)``: light ``(a, b, -c)``)
    when given."""
    rows, cols = sel.nonzero()
    init = None if plane_model is None else np.array([plane_model[0], plane_model[1], -plane_model[2]])
    return fit_ball_light(response.linearize(np.clip(luma[sel] * 255.0, 0, 255)), (X[0, cols] - cx) / r,
                          (Y[rows, 0] - cy) / r, init)


def crop_cos_light(X, Y, cx, cy, r, direction_view) -> np.ndarray:
    """``n.l`` (h, w) on a crop's pixels ``X`` (1, w), ``Y`` (h, 1) of the ball image centred at
    ``(cx, cy)``, radius ``r`` px, for the light ``direction_view`` (view frame, as
    :func:`fit_ball_light`'s); beyond the limb the limb's normals continue."""
    l = direction_view
    nx, ny = np.broadcast_arrays((X - cx) / r, (Y - cy) / r)
    rr = np.hypot(nx, ny)
    out = rr > 1.0
    nx, ny = np.where(out, nx / np.maximum(rr, 1e-12), nx), np.where(out, ny / np.maximum(rr, 1e-12), ny)
    nz = -np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 0.0, 1.0))
    return nx * l[0] + ny * l[1] + nz * l[2]


def crop_shading(cos_light, fit, blur_px: float | None = None) -> np.ndarray:
    """:func:`fit_ball_light`'s model ``rho max(n.l, 0) + ambient`` (linear brightness) drawn on a
    crop from its ``n.l`` (:func:`crop_cos_light`), (h, w); blurred like the photo (a Gaussian of
    ``blur_px`` px, when given and positive), since the photo's terminator is."""
    _, _, rho, amb = fit[:4]
    S = (rho * np.maximum(cos_light, 0.0) + amb).astype(np.float32)
    if blur_px is not None and np.isfinite(blur_px) and blur_px > 0:
        S = cv2.GaussianBlur(S, (0, 0), float(blur_px), borderType=cv2.BORDER_REPLICATE)
    return S


def terminator_weights(luma, X, Y, cx, cy, r, x0, y0, disc, dark_luma, fit, response, blur_px=None, geo=None):
    """The centroid weights of markers near the terminator: the paint's darkness in reflectance.

    The detector's white is the white model's plane (:func:`stillcap.detect._blur_shift._fit_shading`),
    exact where lit but crossing zero at its own terminator: there it drops the part of a marker
    beyond and pulls the centroid toward the light (2-9 deg, tests/detect/test_ball_light.py).
    Here the crop's luma is divided by the light's clipped model (:func:`crop_shading`, blurred
    like the photo, encoded as the luma is: the same measure as ``dark_luma``; the linear ratio
    did worse on the benchmark's side-lit captures, "light to the side" axis 0.49 deg against
    0.43) where that model stands ``SHADING_SNR`` noise sigmas above zero (``dark_luma``
    elsewhere). ``geo`` (h, w), the ball's disc by its geometry alone: where the searched ``disc``
    (the hull of the pixels over the detector's ``min_value``) ends short of the terminator (no
    room light: at n.l 0.04-0.08 on tests/detect/test_ball_light.py's drawn ball), the weights and
    the band below reach on into ``geo`` as far as the model stands over that floor (a marker the
    hull cuts is weighed one pixel across it: ``_marker_measure._measure``). Returns the weights
    (h, w), the pixels within ``TERMINATOR_BAND`` + 2 blur sigmas of the terminator (the markers
    reaching them take these weights) and the drawn shading
    (:class:`~stillcap.detect._blur_shift.DrawnShading`, crop at ``(x0, y0)``) whose
    ``grad log S`` the blur correction then takes."""
    cos_light = crop_cos_light(X, Y, cx, cy, r, fit[0])  # once: the model and the band below
    S = crop_shading(cos_light, fit, blur_px)
    refl = 1.0 - luma / np.maximum(response.encode(S) / 255.0, 1e-6)  # as dark_luma, on the encoded scale
    floor = SHADING_SNR * fit[4]
    ball = disc if geo is None else disc | (geo & (S > floor))
    cen_w = np.where(ball & (S > floor), np.clip(refl, 0, 1), dark_luma).astype(np.float32)
    near_t = ball & (cos_light < 2.0 * (blur_px or 0.0) / r + TERMINATOR_BAND)
    return cen_w, near_t, DrawnShading(S, x0, y0, floor)


def view_to_camera(direction_view, ray_cam):
    """A direction in a ball's view frame (z along ``ray_cam``, the ray through the ball image's
    centre in the camera frame; x, y the image's axes turned with it) in the camera frame: the
    smallest rotation taking the optical axis to ``ray_cam``, (3,) or (N, 3)."""
    d = np.asarray(direction_view, float)
    r = np.asarray(ray_cam, float)
    r = r / np.linalg.norm(r, axis=-1, keepdims=True)
    z = np.array([0.0, 0.0, 1.0])
    ax = np.cross(z, r)
    c = r @ z
    # Rodrigues for the rotation z -> r: I + [ax]_x + [ax]_x^2 / (1 + c). By hand because it is one
    # closed form over every ball's ray at once; body.kinematics.rotation_between (scipy's
    # align_vectors) takes one pair at a time, and detection sits below body and ball in the stack
    Kx = np.zeros(ax.shape[:-1] + (3, 3))
    Kx[..., 0, 1], Kx[..., 0, 2], Kx[..., 1, 2] = -ax[..., 2], ax[..., 1], -ax[..., 0]
    Kx[..., 1, 0], Kx[..., 2, 0], Kx[..., 2, 1] = ax[..., 2], -ax[..., 1], ax[..., 0]
    Rv = np.eye(3) + Kx + Kx @ Kx / (1.0 + np.asarray(c))[..., None, None]
    return np.einsum("...ij,...j->...i", Rv, d)
