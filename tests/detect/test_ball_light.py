"""The light at a ball from its shading (issue 12): a drawn, side-lit ball (Lambert, ambient,
blur, sRGB) away from the optical axis; the detector's ``light_view`` turned into the camera frame
is the true light's direction, and a marker the terminator cuts joins the cut markers' noise class
in ``pair_marker_observations`` while a marker clear of it stays whole."""

import cv2
import numpy as np
import pytest

from stillcap.ball.layout import BallLayout
from stillcap.ball.markers import marker_types, pair_marker_observations
from stillcap.camera import Camera, look_at
from stillcap.detect._ball_light import fit_ball_light, view_to_camera
from stillcap.detect.ball_markers import detect_ball_markers

LAYOUT = BallLayout.seed()
RADIUS = 0.0366
CENTER = np.array([0.0, 10.0, 1.5])
SIZE = float(LAYOUT.sizes_of_types[LAYOUT.type_index(["red"])][0])  # the red squares' angular size, rad


def _light(phase_deg):
    """The light ``phase_deg`` from the cameras' direction (-y), to their right (+x)."""
    p = np.radians(phase_deg)
    return np.array([np.sin(p), -np.cos(p), 0.0])


def _cameras(aim_offset=(0.0, 0.0, 0.0)):
    """Two cameras 4 m from the ball, aimed ``aim_offset`` (m) beside it (a ball off the axis)."""
    dirs = [np.array([0.0, -1.0, 0.0]), np.array([0.15, -0.98, 0.1]) / np.linalg.norm([0.15, -0.98, 0.1])]
    return [Camera.from_intrinsics(n, 1800.0, 1800.0, 640.0, 480.0, (1280, 960),
                                   world2cam=look_at(CENTER + 4.0 * d, CENTER + np.asarray(aim_offset)))
            for n, d in zip("ab", dirs)]


def _photo(cam, light, marker_u=None, blur_px=1.0, k=4, ambient=0.03):
    """The ball lit from ``light`` (Lambert, ``ambient`` light), one red marker within ``SIZE`` of
    ``marker_u`` (what lies beyond the terminator is unlit), photographed by ``cam``: ray-traced at
    ``k x k`` samples a pixel, blurred, sRGB."""
    W, H = cam.image_size
    x0, y0 = (cam.project(CENTER[None])[0] - 40).astype(int)
    sub = (np.arange(80 * k) + 0.5) / k - 0.5
    xx, yy = np.meshgrid(x0 + sub, y0 + sub)
    o, d = cam.rays(np.stack([xx.ravel(), yy.ravel()], axis=1))
    oc = o - CENTER
    b = np.einsum("ij,ij->i", d, oc)
    disc = b * b - (np.einsum("ij,ij->i", oc, oc) - RADIUS ** 2)
    hit = disc > 0
    n = (oc + (-b - np.sqrt(np.where(hit, disc, 0.0)))[:, None] * d) / RADIUS
    paint = np.zeros(len(n), bool) if marker_u is None else n @ marker_u > np.cos(SIZE)
    albedo = np.where(paint[:, None], np.asarray(LAYOUT.palette["red"], float)[::-1], 0.75)
    lin = np.where(hit[:, None], (0.85 * np.clip(n @ light, 0.0, None) + ambient)[:, None] * albedo, 0.02)
    img = np.full((H, W, 3), 0.02, np.float32)
    img[y0:y0 + 80, x0:x0 + 80] = cv2.resize(lin.reshape(80 * k, 80 * k, 3).astype(np.float32), (80, 80),
                                             interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), blur_px)
    enc = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.clip(img, 0, None) ** (1 / 2.4) - 0.055)
    return (np.clip(enc, 0, 1) * 255.0).astype(np.uint8)


@pytest.mark.parametrize("phase", [40.0, 75.0, 100.0, 120.0])
def test_the_light_from_a_balls_shading_off_the_optical_axis(phase):
    """A ball 14 deg off the optical axis, lit from 40-120 deg beside the camera: the light's
    direction within 3 deg (the white model's plane read in the camera frame, last session's
    try, was 10 / 16 / 26 deg off at 40 / 75 / 100 deg and gave none at 120: it takes in the unlit
    side and ignores the line of sight; main has no light)."""
    cam = _cameras(aim_offset=(1.0, 0.0, 0.0))[0]
    light = _light(phase)
    # a marker clear of the terminator, on the lit side toward the camera
    u = (light + np.array([0.0, -1.0, 0.0])) / np.linalg.norm(light + np.array([0.0, -1.0, 0.0]))
    img = _photo(cam, light, u)
    ctr = cam.project(CENTER[None])
    r = cam.K[0, 0] * RADIUS / np.linalg.norm(CENTER - cam.center)
    m = detect_ball_markers(img, ctr, r, marker_types(LAYOUT), blur_px=1.0)
    assert len(m)
    ray = cam.rays(ctr)[1] @ cam.R.T
    got = view_to_camera(m.light_view[0], ray[0])
    err = np.degrees(np.arccos(np.clip(got @ (cam.R @ light), -1, 1)))
    assert err < 3.0
    assert 0 < m.light_sigma_deg[0] < 3.0


def _observe(above_rad, blur_px=1.0, phase=60.0, noise_dn=0.0, seed=0, ambient=0.03):
    """The marker ``above_rad`` above the terminator, at its point nearest the cameras; with
    ``noise_dn`` > 0 each photo gets Gaussian sensor noise of that sigma (of 255, seeded)."""
    cams = _cameras()
    light = _light(phase)
    v = np.array([0.0, -1.0, 0.0])
    t = v - (v @ light) * light
    t /= np.linalg.norm(t)
    u = np.cos(above_rad) * t + np.sin(above_rad) * light
    imgs = [_photo(cam, light, u, blur_px, ambient=ambient) for cam in cams]
    if noise_dn > 0:
        rng = np.random.default_rng(seed)
        imgs = [np.clip(im + rng.normal(0.0, noise_dn, im.shape), 0, 255).astype(np.uint8) for im in imgs]
    ctr = [cam.project(CENTER[None]) for cam in cams]
    rad = [cam.K[0, 0] * RADIUS / np.linalg.norm(CENTER - cam.center) for cam in cams]
    obs, found, _ = pair_marker_observations(cams[0], imgs[0], cams[1], imgs[1], ctr[0], ctr[1], rad[0], rad[1],
                                             CENTER[None], layout=LAYOUT, radius_m=RADIUS, blur_px=blur_px)
    assert len(obs) == 1
    return obs, u, light


@pytest.mark.parametrize("above", [0.0, 0.3, 0.6])
def test_a_marker_the_terminator_cuts_joins_the_cut_markers_noise_class(above):
    """Cut at 0-0.6 of its size above the terminator, the marker joins the cut markers' noise
    class though its region does not touch the ball's edge (main put it with the whole markers,
    class 0): its centroid is corrected to first order only (below)."""
    obs, _, _ = _observe(above * SIZE)
    assert obs.noise_class[0] == 1


@pytest.mark.parametrize("blur_px", [1.0, 1.5])
@pytest.mark.parametrize("above", [-0.3, 0.0, 0.3, 0.6])
def test_a_terminator_cut_markers_direction_is_not_pulled_toward_the_light(above, blur_px):
    """Cut at -0.3 to 0.6 of its size above the terminator, the marker's direction is within 2 deg
    of its centre along the light: its centroid weighs the paint in reflectance over the light's
    clipped, blurred model. Weighed against the white model's plane, which crosses zero at its
    own terminator, it lay 2-9 deg toward the light (2.2-8.3 at 1 px of blur, 3.7-9.5 at 1.5)."""
    obs, u, light = _observe(above * SIZE, blur_px=blur_px)
    w = light - (light @ u) * u
    w /= np.linalg.norm(w)
    assert abs(np.degrees((obs.directions[0] - u) @ w)) < 2.0


@pytest.mark.parametrize("noise_dn", [1.5, 3.0])
@pytest.mark.parametrize("above", [-0.3, 0.0, 0.3])
def test_a_terminator_cut_markers_direction_under_sensor_noise(above, noise_dn):
    """With sensor noise (1.5 and 3 of 255, 1.25 px of blur; mean of three noise draws) the
    terminator-cut marker's direction stays within 1.2 deg of its centre along the light. The
    reflectance weights are used where the light's model of the leather stands ``SHADING_SNR``
    noise sigmas above zero, the detector's darkness (whose white crosses zero at its own
    terminator) below: at 5 sigmas the noise moved that floor up into the paint near the
    terminator and the centroid lay +1.3 to +3.8 deg toward the light (at 2: -0.7 to +0.6)."""
    errs = []
    for seed in range(3):
        obs, u, light = _observe(above * SIZE, blur_px=1.25, noise_dn=noise_dn, seed=seed)
        w = light - (light @ u) * u
        errs.append(np.degrees((obs.directions[0] - u) @ (w / np.linalg.norm(w))))
    assert abs(np.mean(errs)) < 1.2


@pytest.mark.parametrize("above", [0.6, 1.0])
def test_a_terminator_cut_marker_reaches_across_the_searched_discs_edge(above):
    """With no ambient light the searched disc (the hull of the pixels over ``min_value``) ends at
    n.l 0.04-0.08, short of the terminator; a marker it cuts there is weighed one pixel on across
    that edge, where the light's model still stands over its floor. With 0.3 px of blur its
    direction is then within 1 deg of its centre along the light at 0.6 and 1 of its size above
    the terminator (+0.62 / -0.53 deg; ending at the disc's edge +3.00 / +1.00)."""
    obs, u, light = _observe(above * SIZE, blur_px=0.3, ambient=0.0)
    w = light - (light @ u) * u
    assert abs(np.degrees((obs.directions[0] - u) @ (w / np.linalg.norm(w)))) < 1.0


@pytest.mark.xfail(strict=True, reason=(
    "not reached yet (issue 12, docs/spin.md 'The spin axis on the hardest captures'): with no "
    "ambient light the marker's region ends where its paint gets too dim for the detector's "
    "thresholds (about n.l 0.1), so its centroid lies +6.3 / +5.4 / +3.6 deg toward the light at "
    "0 / 0.3 / 0.6 of its size above the terminator (1.25 px of blur; +7.1 / +5.7 / +3.7 with the light "
    "fitted on the searched hull, not the disc; +7.6 / +7.1 / +5.2 before the "
    "region went one pixel across the searched disc's edge; +0.9 / +1.2 / +0.6 with 3 % ambient); a "
    "footprint of the marker's size seen where the detector sees would be needed (a cap of the "
    "type's mean squared angle, tried: docs/spin.md)"))
@pytest.mark.parametrize("above", [0.0, 0.3, 0.6])
def test_a_terminator_cut_marker_without_ambient_light(above):
    """The studio's side-lit captures without room light (EV #1, "light to the side"): markers
    within 0.2 of the terminator in ``n.l`` lie 0.5-2 px toward the light after the reflectance
    weights."""
    obs, u, light = _observe(above * SIZE, blur_px=1.25, ambient=0.0)
    w = light - (light @ u) * u
    assert abs(np.degrees((obs.directions[0] - u) @ (w / np.linalg.norm(w)))) < 2.0


@pytest.mark.parametrize("above", [0.0, 0.3, 0.6])
def test_a_terminator_cut_marker_without_ambient_light_under_more_blur(above):
    """Without ambient light and with 1.5 px of blur, the marker cut at 0 / 0.3 / 0.6 of its size
    above the terminator lies within 5 deg of its centre along the light (+3.9 / +4.1 / +2.6 deg):
    the light's model, which weighs the paint near the terminator, is fitted on the ball's disc by
    geometry, whose unlit side pins the ambient at 0 (+0.0014). Fitted on the searched hull
    (1ccb874; ambient -0.013 / -0.017 in the two photos, the drawn shading below zero before the
    terminator) the centroid lay +10.0 / +7.4 / +5.2 deg toward the light. (Not
    the 2 deg of the 1.25 px case above: the paint beyond the terminator stays unseen.)"""
    obs, u, light = _observe(above * SIZE, blur_px=1.5, ambient=0.0)
    w = light - (light @ u) * u
    assert abs(np.degrees((obs.directions[0] - u) @ (w / np.linalg.norm(w)))) < 5.0


def test_a_marker_clear_of_the_terminator_stays_whole():
    obs, u, _ = _observe(5.0 * SIZE)
    assert np.degrees(np.linalg.norm(obs.directions[0] - u)) < 0.5
    assert obs.noise_class[0] == 0


def test_fit_ball_light_names_mismatched_inputs():
    with pytest.raises(ValueError, match="one length, got 40, 40, 39"):
        fit_ball_light(np.ones(40), np.zeros(40), np.zeros(39))


def test_the_light_fit_takes_the_balls_disc_by_geometry_without_room_light(monkeypatch):
    """With no ambient light the searched hull (the pixels over the detector's ``min_value``)
    ends short of the terminator and a light fit on it has its ambient term free; fitted on the
    ball's disc by geometry (:func:`stillcap.detect._ball_light.light_disc`) the unlit side pins
    it. A drawn ball on the optical axis, ambient 0, 0.3-1.5 px of blur, light 60-110 deg beside
    the camera: the fitted ambient within 1 % of the fitted ``rho`` (the hull's: up to 2.0 %,
    -0.0124 of 0.632 at 1.5 px / 60 deg) and the light's direction 0.3 deg off on average (the
    hull's: 0.46 deg, the disc's 0.19; 1ccb874 fails both)."""
    import stillcap.detect._ball_light as bl
    fits = []
    real = bl.fit_ball_light

    def spy(*a, **k):
        fits.append(real(*a, **k))
        return fits[-1]

    monkeypatch.setattr(bl, "fit_ball_light", spy)
    cam = _cameras()[0]
    ctr = cam.project(CENTER[None])
    r = cam.K[0, 0] * RADIUS / np.linalg.norm(CENTER - cam.center)
    ray = cam.rays(ctr)[1] @ cam.R.T
    errs, amb_share = [], []
    for blur_px in (0.3, 1.0, 1.5):
        for phase in (60.0, 90.0, 110.0):
            light = _light(phase)
            fits.clear()
            detect_ball_markers(_photo(cam, light, None, blur_px, ambient=0.0), ctr, r, marker_types(LAYOUT),
                                blur_px=blur_px)
            assert len(fits) == 1 and fits[0] is not None
            got = view_to_camera(fits[0][0], ray[0])
            errs.append(np.degrees(np.arccos(np.clip(got @ (cam.R @ light), -1, 1))))
            amb_share.append(abs(fits[0][3]) / fits[0][2])
    assert max(amb_share) < 0.01
    assert np.mean(errs) < 0.3
