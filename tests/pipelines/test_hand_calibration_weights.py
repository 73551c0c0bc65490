"""``stillcap hand-calibrate`` weighs each 3D marker by its own noise, from what the photos show:
a partly hidden marker (its centroid shifts by millimetres) counts less, the less of its light
its worst view got, as the throw's pose fit weighs it."""

import numpy as np

from stillcap.body.hand_calibrate import NOISE_M
from stillcap.geometry.marker_points import MarkerPoints
from stillcap.pipelines.hand.calibration import calibration_weights
from stillcap.pipelines.hand.stages import HIDDEN_SIGMA_M, SEEN_SIGMA_M, marker_sigma


def _points(flux, n_views):
    """Four points; ``flux`` (n_cams, 4) the share of each view's light (NaN: view not used)."""
    flux = np.asarray(flux, float)
    n = flux.shape[1]
    return MarkerPoints(np.zeros((n, 3)), np.array(["red"] * n), np.asarray(n_views), np.zeros(n),
                        np.zeros((flux.shape[0], n, 2)), np.zeros(flux.shape, int), np.array(["left"] * n),
                        np.zeros(n, bool), ["a", "b", "c"], False, flux)


def test_each_marker_gets_the_noise_of_what_its_worst_view_showed():
    pts = _points([[1.0, 0.5, 0.95, 0.001],
                   [1.0, 1.0, 0.2, np.nan],
                   [np.nan, np.nan, np.nan, 1.0]], [2, 2, 3, 2])
    s = marker_sigma(pts)
    # fully seen; half hidden (0.5 of its light); 0.2 in one view; a sliver (clipped at 0.02)
    assert np.allclose(s, [SEEN_SIGMA_M, HIDDEN_SIGMA_M / 0.5, HIDDEN_SIGMA_M / 0.2, HIDDEN_SIGMA_M / 0.02])
    assert np.allclose(marker_sigma(pts, seen_m=NOISE_M)[0], NOISE_M)


def test_the_calibration_weights_follow_the_points_and_flag_two_view_partly_hidden_ones():
    pts = _points([[1.0, 0.5, 0.95, 0.3],
                   [1.0, 1.0, 0.2, 1.0],
                   [np.nan, 1.0, np.nan, 1.0]], [2, 3, 2, 2])
    w = calibration_weights(pts)
    assert set(w) == {"point_sigma_m", "unconfirmed"}
    assert np.allclose(w["point_sigma_m"], [NOISE_M, HIDDEN_SIGMA_M / 0.5, HIDDEN_SIGMA_M / 0.2, HIDDEN_SIGMA_M / 0.3])
    # partly hidden and only two views: no third view checked the match
    assert w["unconfirmed"].tolist() == [False, False, True, True]


def test_hand_calibrate_passes_the_weights_only_when_asked(monkeypatch, tmp_path):
    """``calibrate_hand_capture(marker_noise=...)`` gives the fit the points' own noise ("own") or
    none (every marker at the common noise); another word is refused."""
    import pytest

    from stillcap.pipelines.hand import calibration as mod
    from stillcap.studio.hand import hand_capture

    hc = hand_capture(7, image_size=(320, 240), supersample=1, calibration_pose="flat")
    cap, images = hc.to_capture(".png")
    cap.save(tmp_path / "cal", images)
    got = {}

    def fake(sets, **kw):
        (s,) = sets
        got.update(point_sigma_m=s.point_sigma_m, unconfirmed=s.unconfirmed, n=len(s.points))
        raise ValueError("stop here")

    monkeypatch.setattr(mod, "calibrate_hand_from_point_sets", fake)
    with pytest.raises(ValueError, match="stop here"):
        mod.calibrate_hand_capture(tmp_path / "cal", marker_noise="common")
    assert got["point_sigma_m"] is None and got["unconfirmed"] is None
    got.clear()
    with pytest.raises(ValueError, match="stop here"):
        mod.calibrate_hand_capture(tmp_path / "cal", marker_noise="own")
    assert got["point_sigma_m"].shape == (got["n"],) and np.all(got["point_sigma_m"] >= NOISE_M)
    assert got["unconfirmed"].shape == (got["n"],)
    with pytest.raises(ValueError, match="marker noise 'loud' is not one of own, common"):
        mod.calibrate_hand_capture(tmp_path / "cal", marker_noise="loud")


def test_the_cli_refuses_an_unknown_marker_noise(tmp_path, capsys):
    from support import run_cli

    code, _out, err = run_cli(["hand-calibrate", tmp_path / "nothing", "--out", tmp_path / "h.json",
                              "--marker-noise", "loud"], capsys)
    assert code == 2 and "'loud' is not one of own, common" in err
    assert not (tmp_path / "h.json").exists()
