"""The shading model of a lit ball (``stillcap.detect.ball._shading``): the photo's lens blur read
from the ball images' limbs, and clipped (over-exposed) balls, on photos drawn by the exact
sphere renderer of ``tests/detect/test_ball.py`` (orthographic, lambertian, blur in linear light,
gamma 2.2, noise, JPEG)."""

from __future__ import annotations

import numpy as np
import pytest

from detect.test_ball import SIZE, baseball_markers, draw_balls, flight_balls, nearest
from stillcap.ball.stereo import photo_blur_px
from stillcap.detect.ball import detect_balls, refine_ball_centers
from stillcap.response import Response

#: the drawing's response (a pure power law 2.2, stated as the rig would state it)
GAMMA22 = Response.from_json({"gamma": 2.2}, "response")


def _circles(radii, m: int = 96) -> np.ndarray:
    th = np.linspace(0, 2 * np.pi, m, endpoint=False)
    return np.stack([r * np.stack([np.cos(th), np.sin(th)], axis=1) for r in radii])


@pytest.mark.parametrize("light", [(0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.6, 0.0, 0.8)])
@pytest.mark.parametrize("blur", [0.4, 1.0, 1.6])
def test_photo_blur_is_read_from_the_limbs(light, blur):
    """Full discs, half moons and crescents (lit from behind), 14-24 px, painted markers, noise
    and JPEG: the median of the ball images' limb fits is the lens blur to within 15 %. The
    shading of the limb (a soft edge lit from the front, a thin rim lit from behind) is in the
    model, so it is not taken for blur."""
    balls = flight_balls(3, n=8, size=SIZE, r_range=(14, 24), spacing=(2.4, 3.2))
    mk = [baseball_markers(300 + b) for b in range(len(balls))]
    img, _ = draw_balls(SIZE, balls, light=light, blur=blur, markers=mk, rng=3)
    est = photo_blur_px(img, balls[:, :2], _circles(balls[:, 2]), GAMMA22)
    assert abs(est - blur) < 0.15 * blur + 0.03, est


def test_photo_blur_without_balls_is_nan():
    z = np.zeros((200, 200, 3), np.uint8)
    assert np.isnan(photo_blur_px(z, np.zeros((0, 2)), np.zeros((0, 96, 2))))
    # a ball cut by the photo's edge is not used
    assert np.isnan(photo_blur_px(z, [[2.0, 100.0]], _circles([10.0])))


@pytest.mark.parametrize("exposure, before_min, after_max", [(2.0, 0.15, 0.08), (4.0, 0.8, 0.15)])
def test_clipped_balls_shading_correction(exposure, before_min, after_max):
    """Over-exposed balls lit 25 deg from the camera: the clipped lit side has a hard edge and
    the Hough centre sits toward the light (0.23 px at 2x, 1.0 px at 4x the exposure that just
    clips, 20 px balls, no noise); the clipped model (gain from the clipped area, phase from the
    clipped centroid in the corrected centre's frame) leaves 0.04 and 0.08 px. What it leaves is the model's error the pitch pipeline's
    ``shading_model_error`` sizes (``docs/pitch.md``, "Uncertainties")."""
    light = (0.42, 0.0, -0.91)
    u = np.array([1.0, 0.0])
    along = {False: [], True: []}
    corr = []
    for seed in (3, 4):
        balls = flight_balls(seed, n=8, size=SIZE, r_range=(20, 20), spacing=(2.4, 3.2))
        img, _ = draw_balls(SIZE, balls, light=light, exposure=exposure, rng=seed, jpeg=None, noise=0.0)
        det = detect_balls(img)
        idx, _ = nearest(det.centers, balls[:, :2])
        for sh in (False, True):
            ref = refine_ball_centers(img, det.centers[idx], balls[:, 2], shading=np.full(len(idx), sh),
                                      response=GAMMA22, psf_px=0.6)
            assert np.all(ref.ok)
            along[sh] += list((ref.centers - balls[:, :2]) @ u)
            if sh:
                corr += list(ref.shading_px @ u)
            else:
                assert not np.any(ref.shading_px)
    before, after = np.mean(along[False]), np.mean(along[True])
    assert before > before_min
    assert abs(after) < after_max and abs(after) < 0.35 * before
    # the correction recorded is what moved the centres
    np.testing.assert_allclose(np.mean(corr), before - after, atol=1e-9)


def _row_of_balls(r: float, blur: float, phase_deg: float, seed: int = 1, n: int = 10):
    """``n`` balls of radius ``r`` px in a row lit at ``phase_deg`` from the camera (toward +x),
    drawn with ``blur`` px of lens blur, no background level (the drawing adds its background
    after the gamma, which is no linear offset), little noise and no JPEG; and their outlines."""
    rng = np.random.default_rng(seed)
    balls = np.stack([80 + np.arange(n) * 120 + rng.uniform(0, 1, n), 100 + rng.uniform(0, 1, n), np.full(n, r)], 1)
    a = np.radians(phase_deg)
    img, _ = draw_balls((200, 1400), balls, light=(np.sin(a), 0.0, -np.cos(a)), blur=blur, noise=0.5, jpeg=None,
                        background=0.0, rng=seed, exposure=0.8)
    return img, balls, _circles(balls[:, 2])


@pytest.mark.parametrize("r, blur, phase", [(8, 1.5, 90), (8, 1.5, 130), (8, 1.5, 30), (8, 0.5, 110),
                                            (15, 1.5, 130), (15, 0.3, 90), (8, 1.0, 0)])
def test_shading_correction_of_small_balls_under_heavy_blur(r, blur, phase):
    """Small partly lit balls under heavy blur: the uncorrected Hough centre sits up to a tenth
    of a radius toward the light (8 px half moons, 1.5 px blur: 0.8 px), and the light read in
    that frame, from the sharp sphere's centroid table, had too small a phase (90 deg read as 71,
    130 as 88): the correction left 0.18 and 0.68 px. Read in the corrected centre's frame from
    the blurred model's centroid, what is left is under 0.05 px, and where the correction was
    already right (15 px, 0.3 px blur; a full disc) it stays so."""
    img, balls, outl = _row_of_balls(r, blur, phase)
    start = balls[:, :2] + np.random.default_rng(5).normal(0.0, 0.3, (len(balls), 2))
    along = {}
    for sh in (False, True):
        ref = refine_ball_centers(img, start, balls[:, 2], outlines=outl, shading=np.full(len(balls), sh),
                                  response=GAMMA22, psf_px=blur)
        assert np.all(ref.ok)
        along[sh] = float(np.mean(ref.centers[:, 0] - balls[:, 0]))
    assert abs(along[True]) < 0.05, along
    if abs(along[False]) > 0.1:
        assert abs(along[True]) < 0.2 * abs(along[False]), along


def test_photo_blur_from_uncorrected_centres_of_half_moons():
    """8 px half moons under 1.5 px of blur: read at the refined but uncorrected centres (as
    ``ball_centers_stereo`` has them when it first reads the blur), the limb fits gave 1.24 px;
    read at the true centres, within 0.1 px of the truth (the pipeline reads it again at its
    refinement's corrected centres: ``tests/ball/test_stereo.py``)."""
    img, balls, outl = _row_of_balls(8.0, 1.5, 90.0)
    ref = refine_ball_centers(img, balls[:, :2], balls[:, 2], outlines=outl, response=GAMMA22)
    assert abs(photo_blur_px(img, balls[:, :2], outl, GAMMA22) - 1.5) < 0.1
    assert photo_blur_px(img, ref.centers, outl, GAMMA22) < 1.35  # the centres' bias


def _ball_crops(img, balls, outl):
    """Each drawn ball's linear crop (as :func:`photo_blur_px` cuts it), its centre in the crop
    and its outline."""
    from stillcap.detect.ball._refine import _linear_max, _response_lut
    lut = _response_lut(GAMMA22)
    crops = []
    for (x, y, _), o in zip(balls, outl):
        ext = float(np.abs(o).max()) + 6.0
        x0, y0 = int(np.floor(x - ext)), int(np.floor(y - ext))
        x1, y1 = int(np.ceil(x + ext)) + 1, int(np.ceil(y + ext)) + 1
        crops.append((_linear_max(img[y0:y1, x0:x1], lut), np.array([x - x0, y - y0]), o))
    return crops


@pytest.mark.parametrize("phase", [90, 130])
def test_blurred_phase_search_warm_started_from_a_nearby_frame(phase):
    """The phase search of the next corrected-centre frame, started from the last frame's phase
    and slope, finds the cold search's phase (to its tolerance) with fewer renders."""
    from stillcap.detect.ball._shading import _blurred_phase_light, _lit_frame, _renderer
    img, balls, outl = _row_of_balls(8.0, 1.5, phase)
    psf = 1.5  # the lens blur the balls are drawn with
    n_cold = n_warm = 0
    for lin, c, o in _ball_crops(img, balls, outl)[:4]:
        warm = {}
        for k, shift in enumerate((0.0, 0.15, 0.3)):
            mid, A, q, light = _lit_frame(lin, c + (shift, 0.0), o)
            got = {}
            for how in ("cold", "warm"):
                render = _renderer(lin.shape, mid, A, 8.0, q)
                calls = []

                def counted(lt, render=render, calls=calls):
                    calls.append(1)
                    return render(lt)
                got[how] = _blurred_phase_light(lin, mid, A, q, light, psf, 8.0, render=counted,
                                                warm=warm if how == "warm" else None)
                if k:
                    n_cold += len(calls) if how == "cold" else 0
                    n_warm += len(calls) if how == "warm" else 0
            a_cold, a_warm = (np.degrees(np.arccos(np.clip(got[h][2], -1, 1))) for h in ("cold", "warm"))
            assert abs(a_cold - a_warm) < 0.1, (shift, a_cold, a_warm)
    assert n_warm < n_cold, (n_warm, n_cold)



@pytest.mark.parametrize("r, blur, phase", [(8.0, 1.5, 90), (8.0, 1.5, 130), (12.0, 1.0, 60), (15.0, 0.5, 110)])
def test_cold_phase_search_steps_to_the_blur_scaled_table(r, blur, phase):
    """A cold phase search's first step goes to the sharp table's phase at the photo's centroid
    scaled by the blur's shrink at the start (``m_obs^2 / (m_obs + f)``), not 5 deg: on drawn
    balls its answer is the phase a dense scan of the blurred model finds (to 0.05 deg), from fewer
    renders."""
    import cv2
    from stillcap.detect.ball._shading import _blurred_phase_light, _lit_frame, _radiance_centroid, _renderer
    img, balls, outl = _row_of_balls(r, blur, phase)
    renders = []
    for lin, c, o in _ball_crops(img, balls, outl)[:4]:
        mid, A, q, light = _lit_frame(lin, c, o)
        render = _renderer(lin.shape, mid, A, 4.0 * blur + 4.0, q)
        calls = []

        def counted(lt, render=render, calls=calls):
            calls.append(1)
            return render(lt)
        got = _blurred_phase_light(lin, mid, A, q, light, blur, 4.0 * blur + 4.0, render=counted, warm={})
        renders.append(len(calls))
        m_obs = float(np.hypot(*_radiance_centroid(lin, q)))
        az = np.array(light[:2]) / np.hypot(light[0], light[1])
        scan = np.radians(np.arange(0.0, 175.0, 0.05))
        a0 = float(np.arccos(np.clip(got[2], -1, 1)))
        near = scan[np.abs(scan - a0) < np.radians(3.0)]
        miss = [abs(float(np.hypot(*_radiance_centroid(cv2.GaussianBlur(
            render((np.sin(a) * az[0], np.sin(a) * az[1], np.cos(a))), (0, 0), blur), q))) - m_obs) for a in near]
        assert abs(np.degrees(near[int(np.argmin(miss))] - a0)) <= 0.05 + 1e-9
    # two renders (the 5-deg step: three) where the blur is a tenth of the radius or less; small
    # balls under heavy blur are shrunk unevenly over the phases: 3-4 (the 5-deg step: 3-5)
    assert max(renders) <= (2 if r >= 10 * blur else 4), renders


def test_shading_bias_started_at_its_answer():
    """``_shading_bias``' ``start`` (``photo_blur_px``' next round: the corrected centre at the last
    blur read): started at the corrected centre it returns the same bias to the secant's
    tolerance, with fewer renders of the model (8 px balls at 110 deg under 1.5 px of blur)."""
    import stillcap.detect.ball._shading as shading
    from stillcap.detect.ball._refine import hough_template
    img, balls, outl = _row_of_balls(8.0, 1.5, 110.0)
    blur = float(np.hypot(0.7, 1.5))
    peaks = []
    real = shading._model_peak

    def counted(*args, **kwargs):
        peaks.append(1)
        return real(*args, **kwargs)
    n = {"cold": 0, "warm": 0}
    diffs = []
    for lin, c, o in _ball_crops(img, balls, outl):
        c = c + (0.4, 0.0)  # an uncorrected centre, toward the light
        tpl = hough_template(o)
        try:
            shading._model_peak = counted
            peaks.clear()
            cold = shading._shading_bias(lin, c, o, tpl, 0.0, blur, 0.1, smooth=0.7)
            n["cold"] += len(peaks)
            peaks.clear()
            warm = shading._shading_bias(lin, c, o, tpl, 0.0, blur, 0.1, smooth=0.7, start=c - cold)
            n["warm"] += len(peaks)
        finally:
            shading._model_peak = real
        diffs.append(float(np.hypot(*(warm - cold))))
    # the corrected centre is the root of a function with steps of a few hundredths of a pixel
    # (the model's Hough peak: its grid and moves), found to |h| < 0.005 px: two searches from
    # different starts land that far apart (here 0.001-0.028 px on biases of 1.4-1.9 px)
    assert max(diffs) < 0.05 and np.mean(diffs) < 0.02, diffs
    assert n["warm"] < n["cold"], n


@pytest.mark.parametrize("r, blur, phase", [(15, 1.0, 90), (15, 1.0, 130), (10, 0.5, 60)])
def test_shading_correction_reports_its_phase_and_the_models_misfit(r, blur, phase):
    """The correction reports, per ball image, the phase angle it used, that phase's split-half
    sigma and the centre shift a least-squares fit of its model to the ball's pixels asks for
    (what ``ball.uncertainty`` sizes the correction's remaining share from). On drawn lambertian
    balls with the true blur: the phase within 1 deg, its sigma under 1 deg, the misfit's shift
    along the light under 0.01 px on average (0.05 px per image: the drawing's noise). Told a wrong blur (0.3x, 2x) the correction is off by 0.04-1.8 px and the
    misfit's shift points against that error, a fifth to a half of it; painted markers (the
    seed's baseball) raise the phase's sigma."""
    img, balls, outl = _row_of_balls(r, blur, phase)
    shade = np.ones(len(balls), bool)
    ref = refine_ball_centers(img, balls[:, :2], balls[:, 2], outlines=outl, shading=shade, response=GAMMA22, psf_px=blur)
    assert abs(np.degrees(np.mean(ref.shading_phase_rad)) - phase) < 1.0
    sd_plain = float(np.degrees(np.sqrt(np.mean(ref.shading_phase_sd_rad ** 2))))
    assert sd_plain < 1.0
    assert abs(np.mean(ref.shading_misfit_px[:, 0])) < 0.01 and np.all(np.abs(ref.shading_misfit_px[:, 0]) < 0.05)
    for psf in (0.3 * blur, 2.0 * blur):
        wrong = refine_ball_centers(img, balls[:, :2], balls[:, 2], outlines=outl, shading=shade, response=GAMMA22,
                                    psf_px=psf)
        err = float(np.mean(wrong.centers[:, 0] - balls[:, 0]))
        shift = float(np.mean(wrong.shading_misfit_px[:, 0]))
        assert abs(err) > 0.03
        assert shift * err < 0 and abs(shift) > 0.2 * abs(err), (psf, err, shift)
    a = np.radians(phase)
    mk = [baseball_markers(300 + b) for b in range(len(balls))]
    painted, _ = draw_balls((200, 1400), balls, light=(np.sin(a), 0.0, -np.cos(a)), blur=blur, noise=0.5, jpeg=None,
                            background=0.0, rng=1, exposure=0.8, markers=mk)
    ref = refine_ball_centers(painted, balls[:, :2], balls[:, 2], outlines=outl, shading=shade, response=GAMMA22,
                              psf_px=blur)
    assert np.degrees(np.sqrt(np.mean(ref.shading_phase_sd_rad ** 2))) > 2.0 * sd_plain
    # without the correction nothing is reported
    off = refine_ball_centers(img, balls[:, :2], balls[:, 2], outlines=outl, response=GAMMA22, psf_px=blur)
    assert np.all(np.isnan(off.shading_phase_rad)) and np.all(np.isnan(off.shading_misfit_px))


def test_shading_start_gives_the_same_corrected_centres():
    """``refine_ball_centers(shading_start=...)``: each ball's corrected-centre search starts at a
    corrected centre found before (at a slightly different blur); it finds the same centre as the
    cold search to within the search's own tolerance (0.005 px of the bias's fixed point, a few
    hundredths of a pixel through the model Hough's grid: 0.04 px at most here, the starts
    0.085 px off at most), and a start 1 px off does not move it more (0.03 px)."""
    img, balls, outl = _row_of_balls(8.0, 1.5, 90.0)
    kw = dict(outlines=outl, response=GAMMA22, shading=np.ones(len(balls), bool))
    cold = refine_ball_centers(img, balls[:, :2], balls[:, 2], psf_px=1.5, **kw)
    near = refine_ball_centers(img, balls[:, :2], balls[:, 2], psf_px=1.5,
                               shading_start=refine_ball_centers(img, balls[:, :2], balls[:, 2], psf_px=1.45,
                                                                 **kw).centers, **kw)
    far = refine_ball_centers(img, balls[:, :2], balls[:, 2], psf_px=1.5, shading_start=cold.centers - (1.0, 0.0),
                              **kw)
    for ref in (near, far):
        assert np.all(ref.ok)
        assert np.abs(ref.centers - cold.centers).max() < 0.05
    assert abs(float(np.mean(near.centers[:, 0] - balls[:, 0]))) < 0.05


def test_a_drawn_shadings_log_gradient_is_the_analytic_one():
    """The blur correction's ``grad log S`` from a drawn shading (central differences, bilinear):
    an exponential ramp ``exp(0.05 x - 0.03 y)`` gives (0.05, -0.03) anywhere inside, no correction
    at the crop's edge or under the floor."""
    from stillcap.detect._blur_shift import DrawnShading, _grad_log_shading

    yy, xx = np.mgrid[0:20, 0:30]
    S = np.exp(0.05 * xx - 0.03 * yy).astype(np.float32)
    sh = DrawnShading(S, 100, 200, 0.1)
    g, ok = _grad_log_shading(sh, (100 + 12.3, 200 + 7.8))
    assert ok
    assert np.allclose(g, [0.05, -0.03], atol=1e-4)
    assert not _grad_log_shading(sh, (100.5, 200 + 7.8))[1]
    assert not _grad_log_shading(DrawnShading(S, 100, 200, 10.0), (100 + 12.3, 200 + 7.8))[1]
