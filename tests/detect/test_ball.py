"""Ball detection (silhouettes, ellipses, known-radius Hough) on photos drawn here.

The drawing is a small exact sphere renderer: every sub-pixel sample (``ss`` x ``ss`` per pixel)
gets the normal of the sphere it sees (orthographic for balls given in pixels, ray-cast through a
stillcap Camera for balls given in metres), Lambert shading with a light direction plus
ambient, painted markers defined on the sphere (so they foreshorten as on a real ball), then
additive multi-exposure, a slight optical blur, gamma, sensor noise and JPEG. Ground truth is
known to a few thousandths of a pixel.
"""

from __future__ import annotations


import cv2
import numpy as np
import pytest

from stillcap.camera import Camera, look_at
from stillcap.detect.ball import BallFlag, detect_balls, foreground_mask, refine_ball_centers, sphere_outline_px

# --------------------------------------------------------------------------------------------
# drawing (also used by test_ball_markers.py, tests/ball/test_stereo.py and benchmarks/bench_ball_detect.py)
# --------------------------------------------------------------------------------------------
#: linear RGB albedos of the marker types (the studio's baseball palette) and their shapes
MARKER_ALBEDO_RGB = {"red": (0.80, 0.04, 0.03), "blue": (0.03, 0.10, 0.80),
                     "green": (0.05, 0.60, 0.06), "black": (0.02, 0.02, 0.02)}
MARKER_SHAPE = {"red": "square", "blue": "ring", "green": "triangle", "black": "disc"}
BALL_ALBEDO = 0.85
GAMMA = 2.2


def _tangent(m):
    ref = np.array([0.0, 0.0, 1.0]) if abs(m[2]) <= 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, m)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(m, e1)


def _marker_inside(n, m, shape, size, angle=0.0):
    """Which unit normals n (S, 3) fall inside a marker centred on direction m (angular size)."""
    e1, e2 = _tangent(m)
    cosd = np.clip(n @ m, -1, 1)
    dist = np.arccos(cosd)  # azimuthal-equidistant coordinates, as the studio's markers
    u0, v0 = n @ e1, n @ e2
    norm = np.hypot(u0, v0) + 1e-15
    u, v = dist * u0 / norm, dist * v0 / norm
    ca, sa = np.cos(angle), np.sin(angle)
    u, v = ca * u + sa * v, -sa * u + ca * v
    front = cosd > 0
    if shape == "disc":
        inside = u * u + v * v <= size * size
    elif shape == "ring":
        rr = u * u + v * v
        inside = (rr <= size * size) & (rr >= (0.55 * size) ** 2)
    elif shape == "square":
        inside = (np.abs(u) <= size) & (np.abs(v) <= size)
    elif shape == "triangle":  # circumradius = size, pointing towards e2
        inside = np.ones_like(u, bool)
        for k in range(3):
            a = np.pi / 2 + np.pi + 2 * np.pi * k / 3  # outward normals of the edges
            inside &= u * np.cos(a) + v * np.sin(a) <= 0.5 * size
    else:
        raise ValueError(shape)
    return inside & front


def _shade(n, light, ambient, markers, palette=None):
    """Linear BGR radiance (S, 3) of sphere normals n (S, 3) in the camera frame; marker ids (S,).

    palette : dict kind -> (albedo linear RGB, shape), adding to / replacing the baseball's.
    """
    pal = {k: (MARKER_ALBEDO_RGB[k], MARKER_SHAPE[k]) for k in MARKER_SHAPE}
    pal.update(palette or {})
    lam = np.clip(n @ np.asarray(light, float), 0, None) + ambient
    albedo = np.full((len(n), 3), BALL_ALBEDO)
    ids = np.full(len(n), -1)
    for k, (m, kind, size, angle) in enumerate(markers):
        inside = _marker_inside(n, m, pal[kind][1], size, angle)
        albedo[inside] = pal[kind][0][::-1]
        ids[inside] = k
    return albedo * lam[:, None], ids


def _grid(x0, y0, w, h, ss):
    xs = x0 - 0.5 + (np.arange(w * ss) + 0.5) / ss
    ys = y0 - 0.5 + (np.arange(h * ss) + 0.5) / ss
    return np.meshgrid(xs, ys)


def _splat(rad, ids, X, Y, hit, x0, y0, w, h, ss, out, boxes, truth, markers, ball):
    block = np.zeros((h * ss, w * ss, 3))
    block[hit] = rad
    out[y0:y0 + h, x0:x0 + w] += block.reshape(h, ss, w, ss, 3).mean(axis=(1, 3))
    boxes.append((x0, y0, x0 + w, y0 + h))
    idmap = np.full((h * ss, w * ss), -1)
    idmap[hit] = ids
    for k, (m, kind, size, angle) in enumerate(markers):
        sel = idmap == k
        if sel.sum() >= ss * ss:  # at least one pixel's worth of marker visible
            truth.append({"ball": ball, "type": kind, "xy": np.array([X[sel].mean(), Y[sel].mean()]),
                          "area": sel.sum() / ss ** 2, "direction": m})


def _finish(radiance, boxes, rng, exposure, blur, noise, jpeg, background, chroma_444):
    """Optical blur (linear light), gamma, background level, noise, 8 bits, JPEG.

    Blur and gamma run only over the union of the balls' boxes (the photo is mostly black) and
    noise and rounding in OpenCV, which keeps a 2560x1920 photo at ~0.2 s.
    """
    H, W = radiance.shape[:2]
    img = np.full((H, W, 3), float(background), np.float32)
    if boxes:
        b = np.array(boxes)
        m = int(np.ceil(4 * blur)) + 1
        x0, y0 = max(b[:, 0].min() - m, 0), max(b[:, 1].min() - m, 0)
        x1, y1 = min(b[:, 2].max() + m, W), min(b[:, 3].max() + m, H)
        rad = radiance[y0:y1, x0:x1]
        if blur:
            rad = cv2.GaussianBlur(rad, (0, 0), blur)
        img[y0:y1, x0:x1] += 255.0 * np.clip(rad * exposure, 0, 1) ** np.float32(1 / GAMMA)
    if noise:
        cv2.setRNGSeed(int(rng.integers(1 << 30)))
        n = np.empty_like(img)
        cv2.randn(n, (0.0, 0.0, 0.0), (float(noise),) * 3)
        img = cv2.add(img, n)
    img = cv2.convertScaleAbs(cv2.max(img, 0.0))  # rounds and saturates to uint8
    if jpeg:
        params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg)]
        if chroma_444:
            params += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
        ok, buf = cv2.imencode(".jpg", img, params)
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return img


def draw_balls(size, balls, light=(0.0, 0.0, -1.0), ambient=0.0, markers=None, ss=4, exposure=1.0,
               blur=0.6, noise=2.0, jpeg=92, background=6.0, rng=0, chroma_444=False, palette=None):
    """A multi-exposure photo of spheres given in pixels (orthographic), and marker truth.

    size : (H, W); balls : (N, 3) centre x, y and radius in pixels; light : direction to the
    light in the camera frame (x right, y down, z forward; (0, 0, -1) lights the ball from the
    camera, (1, 0, 0) from the right: a half moon); markers : per ball a list of
    (direction (3,) camera frame, type, angular size rad, angle rad); palette : extra marker
    types, kind -> (albedo linear RGB, shape).
    Returns the BGR uint8 image and a list of dicts (ball, type, xy, area) per visible marker.
    """
    rng = np.random.default_rng(rng)
    H, W = size
    out = np.zeros((H, W, 3), np.float32)
    truth, boxes = [], []
    for b, (cx, cy, r) in enumerate(np.asarray(balls, float)):
        mk = [] if markers is None else markers[b]
        x0, y0 = max(int(np.floor(cx - r - 2)), 0), max(int(np.floor(cy - r - 2)), 0)
        x1, y1 = min(int(np.ceil(cx + r + 3)), W), min(int(np.ceil(cy + r + 3)), H)
        if x1 <= x0 or y1 <= y0:
            continue
        X, Y = _grid(x0, y0, x1 - x0, y1 - y0, ss)
        u, v = (X - cx) / r, (Y - cy) / r
        hit = u * u + v * v < 1.0
        n = np.stack([u[hit], v[hit], -np.sqrt(1.0 - u[hit] ** 2 - v[hit] ** 2)], axis=1)
        rad, ids = _shade(n, light, ambient, mk, palette)
        _splat(rad, ids, X, Y, hit, x0, y0, x1 - x0, y1 - y0, ss, out, boxes, truth, mk, b)
    return _finish(out, boxes, rng, exposure, blur, noise, jpeg, background, chroma_444), truth


def draw_balls_camera(camera: Camera, centers_world, radius_m, light_world=None, ambient=0.0, ss=4,
                      exposure=1.0, blur=0.6, noise=2.0, jpeg=92, background=6.0, rng=0):
    """A multi-exposure photo of spheres in metres, ray-cast through ``camera`` (with distortion).

    light_world : direction to the light (world frame); default: from the camera (a full disc).
    """
    rng = np.random.default_rng(rng)
    W, H = camera.image_size
    out = np.zeros((H, W, 3), np.float32)
    boxes = []
    R, t = camera.R, camera.t
    _, outl, _ = sphere_outline_px(camera, centers_world, radius_m, 128)
    for b, C in enumerate(np.asarray(centers_world, float)):
        Cc = R @ C + t
        light = -Cc / np.linalg.norm(Cc) if light_world is None else R @ np.asarray(light_world, float)
        o = outl[b]
        if not np.all(np.isfinite(o)):
            continue
        x0, y0 = max(int(np.floor(o[:, 0].min())) - 2, 0), max(int(np.floor(o[:, 1].min())) - 2, 0)
        x1, y1 = min(int(np.ceil(o[:, 0].max())) + 3, W), min(int(np.ceil(o[:, 1].max())) + 3, H)
        if x1 <= x0 or y1 <= y0:
            continue
        X, Y = _grid(x0, y0, x1 - x0, y1 - y0, ss)
        xn = camera.pixels_to_normalized(np.stack([X.ravel(), Y.ravel()], 1))
        d = np.concatenate([xn, np.ones((len(xn), 1))], 1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        bb = d @ Cc
        disc = bb * bb - (Cc @ Cc - radius_m ** 2)
        hit = disc > 0
        tt = bb[hit] - np.sqrt(disc[hit])
        n = (tt[:, None] * d[hit] - Cc) / radius_m
        rad, ids = _shade(n, light, ambient, [])
        _splat(rad, ids, X, Y, hit.reshape(X.shape), x0, y0, x1 - x0, y1 - y0, ss, out, boxes, [], [], b)
    return _finish(out, boxes, rng, exposure, blur, noise, jpeg, background, False)


#: the seed's 12-marker layout (azimuth deg, polar deg, type), as stillcap.studio.markers
LAYOUT = [(0, 90, "red"), (30, 90, "blue"), (90, 90, "green"), (120, 90, "red"),
          (180, 90, "black"), (210, 90, "green"), (270, 90, "red"), (300, 90, "green"),
          (60, 30, "black"), (60, 150, "blue"), (240, 30, "blue"), (240, 150, "black")]


def baseball_markers(rng, size=0.16):
    """The 12 markers of the seed's ball in a random orientation (camera frame)."""
    from scipy.spatial.transform import Rotation

    R = Rotation.random(random_state=np.random.default_rng(rng).integers(1 << 31)).as_matrix()
    out = []
    for az, pol, kind in LAYOUT:
        a, p = np.radians(az), np.radians(pol)
        d = np.array([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)])
        out.append((R @ d, kind, size, 0.0))
    return out


def flight_balls(rng, n=8, size=(1920, 2560), r_range=(20, 32), spacing=(2.4, 3.2)):
    """(n, 3) ball images (x, y, r px) along a line, as one pitch leaves them in a strobe photo.

    ``spacing`` is the distance between consecutive images in radii (below 2 they overlap).
    """
    rng = np.random.default_rng(rng)
    H, W = size
    r = rng.uniform(*r_range)
    step = r * rng.uniform(*spacing)
    ang = rng.uniform(-0.25, 0.25)
    length = step * (n - 1)
    x0 = rng.uniform(r + 10, W - length * np.cos(ang) - r - 10)
    y0 = rng.uniform(r + 10 + max(0, -length * np.sin(ang)), H - r - 10 - max(0, length * np.sin(ang)))
    k = np.arange(n)
    xs = x0 + step * k * np.cos(ang) + rng.uniform(-0.5, 0.5, n)
    ys = y0 + step * k * np.sin(ang) + rng.uniform(-0.5, 0.5, n)
    rs = r * (1 + 0.01 * k * rng.uniform(-1, 1))
    return np.stack([xs, ys, rs], 1)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
SIZE = (640, 1500)  # small photos keep the tests fast; the benchmark uses 2560x1920
R_BALL = 0.0737 / 2


def nearest(found, truth):
    """Index of the nearest found point for each truth point, and the distances."""
    d = np.linalg.norm(np.asarray(found)[None, :, :] - np.asarray(truth)[:, None, :], axis=2)
    return d.argmin(axis=1), d.min(axis=1)


def photo(seed, light=(0.0, 0.0, -1.0), markers=True, **kw):
    balls = flight_balls(seed, n=8, size=SIZE, r_range=kw.pop("r_range", (20, 32)),
                         spacing=kw.pop("spacing", (2.4, 3.2)))
    mk = [baseball_markers(100 * seed + b) for b in range(len(balls))] if markers else None
    img, _ = draw_balls(SIZE, balls, light=light, markers=mk, rng=seed, **kw)
    return img, balls


def front_pair(dist_b=(-0.05, 0.01, 0.0, 0.0, 0.0)):
    """The seed's front stereo pair: 3.5 m from the flight, 0.8 m vertical baseline, 2560x1920."""
    a = Camera.from_intrinsics("front_low", 2400, 2400, 1279.5, 959.5, (2560, 1920),
                               world2cam=look_at((0, -3.5, 1.1), (0, 0, 1.5)))
    b = Camera.from_intrinsics("front_high", 2380, 2385, 1290, 950, (2560, 1920), dist=dist_b,
                               world2cam=look_at((0, -3.5, 1.9), (0, 0, 1.5)))
    return a, b


#: 8 ball centres 1/80 s apart at ~34 m/s, falling a little (metres, world frame: z up)
FLIGHT = np.array([[-1.5 + 0.42 * k, 0.05 * k, 1.6 - 0.01 * k * k] for k in range(8)])


# --------------------------------------------------------------------------------------------
# steps 1-2: silhouettes and ellipses
# --------------------------------------------------------------------------------------------
def test_full_balls_with_markers_ellipse_and_hough_centers():
    """Lit from the camera (the front pair): 8 ball images, both centre estimates sub-pixel."""
    errs_e, errs_h = [], []
    for seed in range(2):
        img, balls = photo(seed)
        det = detect_balls(img)
        assert len(det) == 8 and np.all(det.flags == 0)
        assert np.all(np.diff(det.centers[:, 0]) > 0)  # sorted left to right
        idx, d = nearest(det.centers, balls[:, :2])
        assert sorted(idx) == list(range(8))
        assert np.all(np.abs(det.radii_px[idx] - balls[:, 2] - 1.0) < 1.0)  # the blurred rim adds ~1.6 px
        ref = refine_ball_centers(img, det.centers[idx], balls[:, 2])
        assert np.all(ref.ok) and np.all(ref.scores > 0.9)
        errs_e.append(d)
        errs_h.append(np.linalg.norm(ref.centers - balls[:, :2], axis=1))
    errs_e, errs_h = np.concatenate(errs_e), np.concatenate(errs_h)
    assert errs_e.max() < 0.3
    # painted markers on the limb perturb the known-radius fit a little (0.03 px without them)
    assert errs_h.mean() < 0.2 and errs_h.max() < 0.4


@pytest.mark.parametrize("light, hough_mean, hough_max", [
    ((1.0, 0.0, 0.0), 0.3, 0.6),      # half moon: lit exactly from the side
    ((0.9, 0.0, 0.3), 0.45, 0.8),     # crescent: lit from a little behind
    ((0.8, 0.2, -0.55), 0.25, 0.5),   # gibbous: lit from the side and front
])
def test_partly_lit_balls_hough_beats_ellipse(light, hough_mean, hough_max):
    img, balls = photo(3, light=light)
    det = detect_balls(img)
    assert len(det) == 8
    assert np.all(det.has(BallFlag.PARTIAL))
    idx, d_ell = nearest(det.centers, balls[:, :2])
    if light[2] > 0:
        # a crescent (phase above ~100 deg, issue 12): the circle through its outer limb
        assert np.all(det.has(BallFlag.CRESCENT)) and d_ell.max() < 1.0
    else:
        # the ellipse centre is pulled several px towards the light
        assert not np.any(det.has(BallFlag.CRESCENT))
        assert d_ell.mean() > 3.0
        toward = (det.centers[idx] - balls[:, :2]) @ np.array(light[:2]) / np.linalg.norm(light[:2])
        assert np.all(toward > 1.0)
    ref = refine_ball_centers(img, det.centers[idx], balls[:, 2])
    d_h = np.linalg.norm(ref.centers - balls[:, :2], axis=1)
    assert np.all(ref.ok)
    assert d_h.mean() < hough_mean and d_h.max() < hough_max
    assert np.all(ref.scores < 0.9)  # only part of the outline has an edge


@pytest.mark.parametrize("light", [(1.0, 0.0, 0.0), (0.9, 0.0, 0.3), (0.8, 0.2, -0.55)])
def test_shading_correction_removes_the_half_moon_bias_toward_the_light(light):
    """The Hough centre of a partly lit ball sits toward the light when lit from the side or
    behind (its thin bright rim's blurred edge peaks outside the limb) and away from it when lit
    from the front; the lit-sphere shading model takes the signed bias (16 balls of 20-32 px,
    lens blur 0.6 px, markers, noise and JPEG) to a few hundredths of a pixel."""
    u = np.array(light[:2]) / np.linalg.norm(light[:2])
    along = {False: [], True: []}
    for seed in (3, 4):
        img, balls = photo(seed, light=light)
        det = detect_balls(img)
        idx, _ = nearest(det.centers, balls[:, :2])
        for shading in (False, True):
            ref = refine_ball_centers(img, det.centers[idx], balls[:, 2], shading=shading)
            assert np.all(ref.ok)
            along[shading] += list((ref.centers - balls[:, :2]) @ u)
    before, after = np.mean(along[False]), np.mean(along[True])
    if light[2] >= 0:  # side / behind: toward the light, ~0.1-0.25 px
        assert before > 0.08 and abs(after) < 0.06 and abs(after) < 0.4 * before
    else:  # gibbous: a small bias away from the light
        assert before < -0.02 and abs(after) < 0.03


def test_shading_correction_leaves_full_discs_alone():
    """Fully lit balls (every part of the outline has an edge) are not corrected."""
    img, balls = photo(3)
    det = detect_balls(img)
    idx, _ = nearest(det.centers, balls[:, :2])
    on = refine_ball_centers(img, det.centers[idx], balls[:, 2], shading=True)
    off = refine_ball_centers(img, det.centers[idx], balls[:, 2], shading=False)
    assert np.all(on.scores > 0.7)
    np.testing.assert_array_equal(on.centers, off.centers)


def test_overlapping_ball_images_are_split():
    """A slow pitch and a fast strobe: consecutive images overlap into one silhouette."""
    img, balls = photo(5, spacing=(1.3, 1.6), markers=False)
    det = detect_balls(img, keep_mask=True)
    n_sil, _ = cv2.connectedComponents(det.mask)
    assert n_sil - 1 == 1  # one silhouette ...
    assert len(det) == 8   # ... eight balls
    assert np.all(det.has(BallFlag.MERGED) & det.has(BallFlag.SPLIT))
    assert len(set(det.contour_index)) == 1
    idx, d = nearest(det.centers, balls[:, :2])
    assert sorted(idx) == list(range(8)) and d.max() < 0.6
    ref = refine_ball_centers(img, det.centers[idx], balls[:, 2])
    assert np.linalg.norm(ref.centers - balls[:, :2], axis=1).max() < 0.6


def test_overlapping_half_moons_are_split_at_their_distance_maxima():
    """Half moons one above the other, two of them overlapping. No circle fits their pieces, so
    the pair is split only because its silhouette is clearly larger than the photo's typical
    one; each comes at its distance-transform maximum (half a radius towards the light),
    flagged; the known-radius Hough fixes it."""
    ys = np.array([40.0, 110.0, 145.0, 215.0, 285.0])  # the 2nd and 3rd overlap (1.4 r apart)
    balls = np.stack([300.0 + 0.1 * ys, ys + 20, np.full(5, 25.0)], axis=1)
    img, _ = draw_balls((360, 600), balls, light=(1.0, 0.0, 0.0), rng=1)
    det = detect_balls(img)
    assert len(det) == 5
    idx, d = nearest(det.centers, balls[:, :2])
    assert sorted(idx) == list(range(5))
    merged = det.has(BallFlag.MERGED)[np.argsort(idx)]
    assert list(merged) == [False, True, True, False, False]
    assert np.all(det.has(BallFlag.PARTIAL)) and not np.any(det.has(BallFlag.SPLIT))
    assert np.all(d > 4)
    ref = refine_ball_centers(img, det.centers[idx], 25.0)
    assert np.all(ref.ok) and np.linalg.norm(ref.centers - balls[:, :2], axis=1).max() < 0.4
    # alone (fewer than 3 silhouettes to compare with) the pair is one partly lit ball
    alone = detect_balls(img[95:205])
    assert len(alone) == 1 and alone.flags[0] == BallFlag.PARTIAL


def test_thin_crescent_is_one_ball():
    """Lit from behind: a thin lit rim, one silhouette per ball (not split at a marker notch)."""
    img, balls = photo(2, light=(0.6, 0.0, 0.8))
    det = detect_balls(img)
    # a crescent (issue 12): its centre is the circle through the outer limb, not the ellipse's
    assert len(det) == 8 and np.all(det.flags == BallFlag.PARTIAL | BallFlag.CRESCENT)
    assert np.linalg.norm(det.centers - balls[:, :2], axis=1).max() < 0.2 * balls[:, 2].min()
    ref = refine_ball_centers(img, det.centers, balls[:, 2])
    assert np.all(ref.ok) and np.linalg.norm(ref.centers - balls[:, :2], axis=1).max() < 1.0


def test_two_merged_then_separate():
    balls = np.array([[200.0, 200.0, 25.0], [240.0, 205.0, 25.0], [400.0, 210.0, 25.0]])
    img, _ = draw_balls((400, 600), balls, rng=1)
    det = detect_balls(img)
    assert len(det) == 3
    assert list(det.has(BallFlag.MERGED)) == [True, True, False]
    _, d = nearest(det.centers, balls[:, :2])
    assert d.max() < 0.6


def test_background_photo_and_clutter():
    """A lit, textured background: the dark-room model fails, a background photo does not."""
    rng = np.random.default_rng(7)
    bg = cv2.GaussianBlur(rng.uniform(40, 140, (320, 640, 3)).astype(np.float32), (0, 0), 6)
    bg = np.clip(bg + np.linspace(0, 60, 640)[None, :, None], 0, 255).astype(np.uint8)
    balls = np.array([[150.0, 160.0, 24.0], [330.0, 150.0, 26.0], [500.0, 170.0, 25.0]])
    fg, _ = draw_balls((320, 640), balls, noise=0, jpeg=0, background=0)
    noisy = lambda a: np.clip(a.astype(float) + rng.normal(0, 2, a.shape), 0, 255).astype(np.uint8)
    img = noisy(np.maximum(bg, fg))
    det = detect_balls(img, background=noisy(bg))
    assert len(det) == 3
    _, d = nearest(det.centers, balls[:, :2])
    assert d.max() < 0.5
    ref = refine_ball_centers(img, det.centers, det.radii_px, background=noisy(bg))
    assert np.linalg.norm(ref.centers - balls[:, :2], axis=1).max() < 0.5
    assert len(detect_balls(img)) != 3  # without it, the lit background is foreground


def test_specks_small_blobs_and_border():
    balls = np.array([[100.0, 100.0, 25.0], [300.0, 120.0, 25.0], [588.0, 150.0, 25.0]])  # last one cut
    img, _ = draw_balls((300, 600), balls, rng=2)
    img[50, 400] = 255  # hot pixel
    img[250:253, 200:203] = 200  # 9 px blob
    cv2.circle(img, (450, 250), 3, (255, 255, 255), -1)  # ~30 px blob: below min_area
    det = detect_balls(img, min_area=50)
    assert len(det) == 3
    assert list(det.has(BallFlag.TOUCHES_BORDER)) == [False, False, True]
    assert len(detect_balls(img, min_area=50, max_area=500)) == 0
    mask = foreground_mask(img)
    assert mask.dtype == np.uint8 and mask.shape == img.shape[:2]
    assert mask[50, 400] == 0 and mask[100, 100] == 255  # the opening removed the hot pixel


def test_grey_and_float_images_give_the_same_balls():
    img, balls = photo(9, markers=False)
    a = detect_balls(img)
    b = detect_balls(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    c = detect_balls(img.astype(np.float32))
    assert len(a) == len(b) == len(c) == 8
    assert np.abs(a.centers - c.centers).max() < 1e-6
    assert np.abs(a.centers - b.centers).max() < 0.2
    r1 = refine_ball_centers(img, a.centers, balls[:, 2])
    r2 = refine_ball_centers(img.astype(np.float64), a.centers, balls[:, 2])
    assert np.abs(r1.centers - r2.centers).max() < 1e-3


def _contour_set(contours):
    return sorted((cv2.boundingRect(c), c.reshape(-1, 2).tolist()) for c in contours)


@pytest.mark.parametrize("open_px", [1, 0])
def test_silhouettes_thresholded_around_candidates_are_the_full_frame_ones(open_px):
    """The mask is thresholded at full resolution only around silhouettes found at half
    resolution: the contours must be those of the whole-frame mask, also for balls cut by the
    border, balls whose boxes overlap, a thin spur the half-resolution image misses (its box
    must grow) and with a background photo."""
    from stillcap.detect.ball._foreground import _raw_mask
    from stillcap.detect.ball._silhouettes import _clean_contours, _foreground_contours

    balls = np.array([[30.0, 40.0, 24.0], [200.0, 150.0, 25.0], [256.0, 160.0, 22.0], [590.0, 280.0, 26.0],
                      [420.0, 60.0, 20.0]])
    img, _ = draw_balls((300, 600), balls, rng=3)
    img[151, 150:180] = 255  # a 1 px spur on an odd row: invisible at half resolution
    img[59:62, 440:470] = 200  # a 3 px wide bar sticking out of a ball
    img[3, 300] = 250  # a hot pixel
    for bg in (None, np.full_like(img, 6)):
        full = _clean_contours(_raw_mask(img, bg, None, 6.0, 20.0), open_px, 25.0)
        roi = _foreground_contours(img, bg, None, 6.0, 20.0, open_px, 25.0)
        assert len(full) == 5  # the hot pixel is below the area limit
        assert _contour_set(roi) == _contour_set(full)
        if open_px == 0:  # the spur is part of its ball's silhouette: the box grew to hold it
            assert any(cv2.boundingRect(c)[0] == 150 for c in roi)


@pytest.mark.parametrize("size", [(300, 600), (301, 600), (302, 599), (297, 601)])
def test_half_resolution_search_image_on_even_and_odd_sizes(size):
    """The half-resolution search image samples every 2nd row as a view where the height is
    even, else resizes the whole photo: the silhouettes are the whole-frame ones either way,
    also for balls cut by the bottom and right edges."""
    from stillcap.detect.ball._foreground import _raw_mask
    from stillcap.detect.ball._silhouettes import _clean_contours, _foreground_contours

    H, W = size
    balls = np.array([[60.0, 50.0, 22.0], [300.0, 150.0, 25.0], [W - 5.0, 120.0, 20.0], [450.0, H - 4.0, 21.0]])
    img, _ = draw_balls(size, balls, rng=5)
    full = _clean_contours(_raw_mask(img, None, None, 6.0, 20.0), 1, 25.0)
    roi = _foreground_contours(img, None, None, 6.0, 20.0, 1, 25.0)
    assert len(full) == 4
    assert _contour_set(roi) == _contour_set(full)


def test_robust_level_is_the_subsample_histogram_median_and_mad():
    """Median and MAD of a uint8 channel from its strided subsample's histogram (cv2.calcHist)
    are the lower middle values of the sorted subsample and of its absolute deviations."""
    from stillcap.detect.ball._foreground import _robust_level

    rng = np.random.default_rng(1)
    for shape, lo, hi in (((1000, 1300), 0, 12), ((480, 640), 3, 40), ((7, 9), 0, 256), ((2000, 2000), 100, 104)):
        ch = rng.integers(lo, hi, shape).astype(np.uint8)
        step = max(1, int(np.sqrt(ch.size / 2.5e5)))
        s = np.sort(ch[::step, ::step].ravel().astype(int))
        k = int(np.ceil(0.5 * len(s))) - 1  # the first value whose cumulative count reaches half
        med = s[k]
        mad = np.sort(np.abs(s - med))[k]
        assert _robust_level(ch) == (float(med), 1.4826 * max(float(mad), 0.5))
        # a view of a BGR photo's channel (strided), as the detection passes it
        bgr = np.stack([ch, ch // 2, ch], axis=2)
        assert _robust_level(bgr[:, :, 0]) == _robust_level(ch)


@pytest.mark.parametrize("size", [(1024, 1280), (1024, 1282), (1500, 1500), (300, 400)])
def test_robust_levels_of_a_photo_are_those_of_its_channels(size):
    """All channels' levels at once (a resized subsample where the step, a power of 2, divides
    the size; else channel by channel) are each channel's own."""
    from stillcap.detect.ball._foreground import _robust_level, _robust_levels

    rng = np.random.default_rng(4)
    img = rng.integers(0, 30, (*size, 3)).astype(np.uint8)
    img[::7, ::5, 1] = 200  # a different pattern on every 2nd/4th row and column would show
    img[1::2, 1::2, 2] = 90
    assert _robust_levels(img) == [_robust_level(img[:, :, k]) for k in range(3)]
    assert _robust_levels(img[:, :, 0]) == [_robust_level(img[:, :, 0])]


@pytest.mark.parametrize("size", [(1024, 1280), (1920, 2560), (1500, 1500)])
def test_robust_levels_from_the_half_resolution_image_are_the_photos(size):
    """The levels taken from the silhouette search's half-resolution image (the same pixels)
    equal those of the photo; a small image of another size is not used."""
    from stillcap.detect.ball._foreground import _mask_limits, _robust_levels, _subsample

    rng = np.random.default_rng(5)
    img = rng.integers(0, 30, (*size, 3)).astype(np.uint8)
    img[::4, ::4, 0] = 17  # exactly the pixels of a step-4 subsample: a wrong pick would show
    img[1::4, 2::4, 2] = 120
    small = _subsample(img, 2)
    assert np.array_equal(small, img[::2, ::2])
    assert _robust_levels(img, small, 2) == _robust_levels(img)
    assert _robust_levels(img, small[:-2], 2) == _robust_levels(img)
    src, hi, sm = _mask_limits(img, None, None, 6.0, 20.0, scale=2)
    assert src is img and np.array_equal(sm, small)
    assert _mask_limits(img, None, None, 6.0, 20.0)[1] == hi


@pytest.mark.parametrize("start", [(40.3, 41.7), (np.float64(39.95), np.float64(42.05))])
def test_grid_peak_scores_every_candidate_of_its_grid(start):
    """_grid_peak builds the outline maps from the grid's distinct rows and columns; its scores
    are _score's of the full list of candidates (x + DX, y + DY) in row-major order."""
    from stillcap.detect.ball._hough import _gradient, _grid_offsets, _grid_peak, _score, _template

    yy, xx = np.mgrid[0:80, 0:84]
    img = (np.hypot(xx - 41.2, (yy - 40.6) * 1.1) < 15).astype(np.float32)
    g = _gradient(cv2.GaussianBlur(img, (0, 0), 1.0))
    th = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    off = np.stack([15 * np.cos(th), 13.6 * np.sin(th)], axis=1)
    nrm, wt = _template(off)
    tpl = (off[:, 0].astype(np.float32), off[:, 1].astype(np.float32),
           nrm[:, 0].astype(np.float32), nrm[:, 1].astype(np.float32), (wt / wt.sum()).astype(np.float32))
    x, y = start
    for step, k in ((0.5, 3), (0.1, 3), (2.0, 5)):
        bx, by, sc, (i, j) = _grid_peak(g, x, y, tpl, 0.0, step, k, moves=0)
        d, DX, DY = _grid_offsets(step, k)
        ref, _ = _score(g, x + DX, y + DY, *tpl, 0.0)
        assert np.array_equal(sc.ravel(), ref)
        assert (bx, by) == (x + float(d[j]), y + float(d[i]))
    # the peak is found (re-centred from a start 2 px off)
    bx, by, _, _ = _grid_peak(g, x + 2.0, y - 2.0, tpl, 0.0, 0.5, 3, moves=3)
    assert abs(bx - 41.2) <= 0.5 and abs(by - 40.6) <= 0.5


def test_percentile_is_numpys():
    from stillcap.detect.ball._hough import _percentile

    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 10, 37, 184, 1000):
        for dtype in (np.float32, np.float64):
            a = rng.random(n).astype(dtype)
            for q in (0.0, 10.0, 50.0, 90.0, 99.0, 100.0):
                assert _percentile(a, q) == float(np.percentile(a, q))


# --------------------------------------------------------------------------------------------
# step 3: projected outline (stereo: tests/ball/test_stereo.py)
# --------------------------------------------------------------------------------------------
def test_sphere_outline_is_the_apparent_circle_on_axis_and_an_ellipse_off_axis():
    cam = Camera.from_intrinsics("c", 1000, 1000, 999.5, 749.5, (2000, 1500))
    d, R = 2.0, 0.1
    cen, outl, rad = sphere_outline_px(cam, [[0, 0, d], [1.2, 0, d], [0, 0, -1.0]], R)
    assert np.allclose(cen[0], (999.5, 749.5))
    assert rad[0] == pytest.approx(1000 * R / np.sqrt(d * d - R * R), rel=1e-9)
    assert np.allclose(np.linalg.norm(outl[0] - cen[0], axis=1), rad[0])
    # off axis: elongated along the radial (x) direction, its middle outside the projected centre
    ext = outl[1].max(axis=0) - outl[1].min(axis=0)
    assert ext[0] > 1.05 * ext[1]
    assert 0.5 * (outl[1][:, 0].max() + outl[1][:, 0].min()) > cen[1, 0] + 1.0
    assert np.all(np.isnan(cen[2])) and np.all(np.isnan(outl[2]))  # behind the camera
    with pytest.raises(ValueError, match="radius_m must be positive"):
        sphere_outline_px(cam, [[0, 0, 1]], 0.0)


def test_exact_outline_template_finds_the_projected_center():
    """A big, near, off-axis ball in a wide lens: its image is an ellipse whose middle is ~3 px
    from the image of the sphere centre. The exact projected outline as Hough template finds the
    latter; a circle finds neither."""
    cam = Camera.from_intrinsics("wide", 1000, 1000, 799.5, 599.5, (1600, 1200),
                                 dist=(-0.08, 0.01, 0, 0, 0))
    C = np.array([[0.75, 0.35, 1.5]])
    img = draw_balls_camera(cam, C, 0.1, rng=3)
    det = detect_balls(img)
    assert len(det) == 1
    cen, outl, rad = sphere_outline_px(cam, C, 0.1)
    exact = refine_ball_centers(img, det.centers, rad, outlines=outl - cen[:, None])
    circle = refine_ball_centers(img, det.centers, rad)
    e_exact = np.linalg.norm(exact.centers - cen, axis=1)[0]
    e_circle = np.linalg.norm(circle.centers - cen, axis=1)[0]
    assert e_exact < 0.3 and e_circle > 2.0


@pytest.mark.parametrize("light", [(0.0, 0.0, -1.0), (1.0, 0.0, 0.0)])
def test_refined_start_skips_the_coarse_grid_and_finds_the_same_center(light):
    """From a refined centre (a later round of ball_centers_stereo) the 0.5 px grid alone finds
    the centre the full coarse-to-fine search finds, also for half moons."""
    balls = np.array([[80.0, 90.0, 28.0], [220.3, 95.6, 29.0], [360.7, 88.2, 27.5]])
    img, _ = draw_balls((180, 440), balls, light=light, rng=5)
    first = refine_ball_centers(img, balls[:, :2] + [[1.5, -1.0]], balls[:, 2])
    assert first.ok.all()
    start = first.centers + [[0.4, -0.3]]
    full = refine_ball_centers(img, start, balls[:, 2], search_px=3.0)
    quick = refine_ball_centers(img, start, balls[:, 2], search_px=3.0, start_refined=True)
    assert quick.ok.all()
    assert np.abs(quick.centers - full.centers).max() < 1e-9
    assert np.linalg.norm(quick.centers - balls[:, :2], axis=1).max() < 0.3


# --------------------------------------------------------------------------------------------
# empty and bad input
# --------------------------------------------------------------------------------------------
def test_empty_images_and_no_centers():
    black = np.zeros((120, 160, 3), np.uint8)
    det = detect_balls(black)
    assert len(det) == 0 and det.centers.shape == (0, 2) and det.ellipses.shape == (0, 5)
    assert len(detect_balls(np.full((50, 60), 255, np.uint8))) == 0  # all white: all background
    ref = refine_ball_centers(black, np.zeros((0, 2)), np.zeros(0))
    assert len(ref) == 0 and ref.centers.shape == (0, 2)


def test_refinement_failure_is_flagged_not_guessed():
    img, balls = photo(4, markers=False)
    start = np.array([[balls[0, 0], balls[0, 1] - 3 * balls[0, 2]], [700.0, 600.0],  # dark, empty
                      [np.nan, np.nan], balls[1, :2]])
    ref = refine_ball_centers(img, start, [25.0, 25.0, 25.0, np.nan], search_px=5.0)
    assert np.all(~ref.ok)
    assert np.all(ref.flags & BallFlag.REFINE_FAILED)
    assert np.allclose(ref.centers, start, equal_nan=True)  # the start comes back, flagged


def test_with_refined_and_has():
    img, balls = photo(6, markers=False)
    det = detect_balls(img)
    ref = refine_ball_centers(img, det.centers, det.radii_px)
    both = det.with_refined(ref)
    assert np.allclose(both.centers, ref.centers) and np.allclose(both.ellipse_centers, det.ellipse_centers)
    assert np.all(np.isfinite(both.scores)) and np.all(np.isnan(det.scores))
    with pytest.raises(ValueError, match="refined has 0 centres for 8 detections"):
        det.with_refined(refine_ball_centers(img, np.zeros((0, 2)), np.zeros(0)))


def test_bad_input_names_the_shape():
    img = np.zeros((50, 60, 3), np.uint8)
    with pytest.raises(ValueError, match=r"image must have shape \(H, W\) or \(H, W, 3\), got \(50, 60, 4\)"):
        detect_balls(np.zeros((50, 60, 4), np.uint8))
    with pytest.raises(ValueError, match=r"background must have the image's shape \(50, 60, 3\), got \(50, 61, 3\)"):
        detect_balls(img, background=np.zeros((50, 61, 3), np.uint8))
    with pytest.raises(ValueError, match=r"centers must have shape \(N, 2\), got \(3, 3\)"):
        refine_ball_centers(img, np.zeros((3, 3)), 10.0)
    with pytest.raises(ValueError, match=r"radius_px must have shape \(2,\), got \(3,\)"):
        refine_ball_centers(img, np.zeros((2, 2)), np.ones(3))
    with pytest.raises(ValueError, match=r"outlines must have shape \(2, M, 2\) with M >= 8, got \(2, 5, 2\)"):
        refine_ball_centers(img, np.zeros((2, 2)), 10.0, outlines=np.zeros((2, 5, 2)))
    with pytest.raises(ValueError, match="must hold numbers"):
        detect_balls(np.zeros((5, 5), object))


@pytest.mark.parametrize("phase_deg", [40.0, 100.0])
def test_lit_sphere_supersampled_near_the_limb_only_keeps_the_limb(phase_deg):
    """The shading model rendered with supersampling only in a band at the limb (what
    _shading_bias uses, for speed) equals the fully supersampled one in the band and outside the
    ball, and its blurred limb gradient is the same: it cannot move the Hough peak."""
    from stillcap.detect.ball._hough import _gradient
    from stillcap.detect.ball._shading import _lit_sphere_image

    a = np.radians(phase_deg)
    light = (np.sin(a) * 0.8, np.sin(a) * 0.6, np.cos(a))
    A = np.array([[14.0, 1.5], [1.5, 12.5]])  # an off-axis (elliptical) outline
    center = np.array([30.3, 28.7])
    full = _lit_sphere_image((60, 62), center, A, light)
    band = 4.0 * 0.86 + 4.0
    part = _lit_sphere_image((60, 62), center, A, light, band_px=band)
    yy, xx = np.mgrid[0:60, 0:62]
    q = np.linalg.solve(A, np.stack([xx.ravel() - center[0], yy.ravel() - center[1]]))
    rho = np.hypot(*q).reshape(60, 62)
    near = rho > 1.0 - band / np.linalg.svd(A, compute_uv=False)[0]
    assert np.array_equal(full[near], part[near])
    inside = ~near
    assert inside.sum() > 100
    # deep inside, one sample per pixel: close but not equal (a real difference, not a no-op)
    assert 0 < np.abs(full[inside] - part[inside]).max() < 1e-2
    gf = _gradient(cv2.GaussianBlur(full, (0, 0), 0.86))
    gp = _gradient(cv2.GaussianBlur(part, (0, 0), 0.86))
    limb = np.abs(rho - 1.0) * 12.5 < 2.5  # within 2.5 px of the limb
    for f, p in zip(gf, gp):
        assert np.abs(f[limb] - p[limb]).max() < 1e-6 * np.abs(f[limb]).max()
