"""``stillcap hand-calibrate`` with several calibration captures of one hand: their flashes are fitted
together (one shape, a pose per flash), so a second photo's bends fix what the first one's did not."""

import numpy as np
import pytest

from stillcap.body.hand import hand_markerset
from stillcap.body.hand_calibrate import UNFIXED_SIGMA_RATIO, CalibrationPoints, calibrate_hand_from_point_sets
from stillcap.body.hand_label import hand_points_from_truth
from stillcap.studio.hand import hand_capture
from stillcap.studio.hand_variation import another_hand


@pytest.fixture(scope="module")
def protocol_points():
    """Exact markers (0.3 mm noise) of the studio's protocol capture of another_hand(5), split by
    flash into the flat flashes and the bending ones, as two captures of the same hand."""
    truth = hand_capture(205, image_size=(320, 240), supersample=1, person=another_hand(5), calibration_pose="flat",
                         calibration_motion="protocol").truth
    d = hand_points_from_truth(truth, noise_m=0.0003, drop=0.0, n_spurious=0, rng=5)
    # the protocol's steps in time order: flat, flat, spread, table top, hook, fist, opposition,
    # half curl, flat, flat (the studio's window holds 9-10 of them)
    flat = np.isin(d["flash"], [0, 1])
    bends = np.isin(d["flash"], np.arange(2, 8))
    assert flat.any() and bends.any()
    sets = [CalibrationPoints(d["points"][s], d["colours"][s], truth.strobe_hz) for s in (flat, bends)]
    return sets


def _middle_phalanges(cal):
    return [p for p in cal.parameters if p.kind == "length" and "-pip to " in p.name and not p.name.startswith("thumb")]


def test_a_second_capture_of_bends_fixes_what_the_flat_one_did_not(protocol_points):
    flat, bends = protocol_points
    alone = calibrate_hand_from_point_sets([flat])
    print("flat alone", [(p.name, round(p.fixed, 2)) for p in _middle_phalanges(alone)], alone.messages[-1])
    # flat flashes alone bend no joint: the middle phalanges' lengths stay at their prior
    assert all(p.fixed > UNFIXED_SIGMA_RATIO for p in _middle_phalanges(alone))
    both = calibrate_hand_from_point_sets([flat, bends])
    print("both", [(p.name, round(p.fixed, 2)) for p in _middle_phalanges(both)], both.messages[-1])
    assert both.n_free >= 4  # the second capture's flashes were used (6 bends)
    assert "capture 1" in both.messages[-1]  # the flat flash is the first capture's
    mid = _middle_phalanges(both)
    assert len(mid) == 4 and all(p.fixed < UNFIXED_SIGMA_RATIO for p in mid)


def test_no_capture_and_no_hand_are_refused(protocol_points):
    flat, _ = protocol_points
    with pytest.raises(ValueError, match="no calibration capture given"):
        calibrate_hand_from_point_sets([])
    far = CalibrationPoints(flat.points[:2], flat.colors[:2], flat.strobe_hz)
    with pytest.raises(ValueError, match="no flash of the calibration captures has a hand pose"):
        calibrate_hand_from_point_sets([far, far])


def test_the_cli_passes_every_capture_given(monkeypatch, tmp_path, capsys):
    """``stillcap hand-calibrate A B --out ...`` calibrates from both captures; one capture stays one."""
    from support import run_cli

    from stillcap.pipelines.hand import calibration as mod

    got = []

    def fake(capture, pose, **kw):
        got.append(capture)
        raise ValueError("stop here")

    monkeypatch.setattr(mod, "calibrate_hand_capture", fake)
    code, _out, err = run_cli(["hand-calibrate", tmp_path / "a", tmp_path / "b", "--out", tmp_path / "h.json"], capsys)
    assert code == 2 and "stop here" in err
    code, _out, err = run_cli(["hand-calibrate", tmp_path / "a", "--out", tmp_path / "h.json"], capsys)
    assert code == 2
    assert got == [[tmp_path / "a", tmp_path / "b"], tmp_path / "a"]
    assert not (tmp_path / "h.json").exists()


def test_a_refused_posed_flash_gives_way_to_the_next_nearest(protocol_points, monkeypatch):
    """When the flash nearest the pose is refused (its markers do not fit it: a wrong label, a
    hand not yet flat), the next nearest flash, of any capture, is tried before the capture is
    refused; the messages name the flash refused."""
    from stillcap.body import hand_calibrate as mod

    real, calls = mod.calibrate_hand, []

    def refuse_first(posed, free=None, **kw):
        calls.append((np.asarray(posed).copy(), free is None))
        if len(calls) == 1:  # the nearest flash of the first pass: refused as not flat
            raise ValueError("the calibration flash is not in the 'flat' pose: simulated")
        return real(posed, free, **kw)

    monkeypatch.setattr(mod, "calibrate_hand", refuse_first)
    monkeypatch.setattr(mod, "_pose_costs", lambda c, **kw: np.zeros(len(c)))  # the template's order
    monkeypatch.setattr(mod, "_also_posed", lambda b, pairs, **kw: [False] * len(pairs))  # one flash held
    cal = calibrate_hand_from_point_sets(protocol_points)
    assert len(calls) == 3  # refused, the next nearest (first pass), the final fit
    assert not np.array_equal(calls[0][0], calls[1][0], equal_nan=True)
    assert any("was not taken as the flat flash: the calibration flash is not in the 'flat' pose: simulated" in m
               for m in cal.messages)
    assert cal.n_free >= 4


def test_every_posed_flash_refused_refuses_the_capture_naming_them(protocol_points, monkeypatch):
    from stillcap.body import hand_calibrate as mod

    calls = []

    def refuse(posed, free=None, **kw):
        calls.append(posed)
        raise ValueError(f"refusal {len(calls)}")

    monkeypatch.setattr(mod, "calibrate_hand", refuse)
    monkeypatch.setattr(mod, "_pose_costs", lambda c, **kw: np.zeros(len(c)))  # the template's order
    monkeypatch.setattr(mod, "_also_posed", lambda b, pairs, **kw: [False] * len(pairs))  # one flash held
    with pytest.raises(ValueError, match=r"^refusal 1; flash \d+ of capture \d was refused too: refusal 2; "):
        calibrate_hand_from_point_sets(protocol_points, max_posed_tries=3)
    assert len(calls) == 3
    calls.clear()
    with pytest.raises(ValueError, match=r"^refusal 1$"):
        calibrate_hand_from_point_sets(protocol_points, max_posed_tries=1)
    assert len(calls) == 1



def _protocol_flashes(person, scales, rng=0):
    """Exact markers (0.3 mm noise, all seen) of ``person`` in the studio protocol's steps, each
    step's angles times ``scales[name]`` (1 when not named), 12 cm sideways per flash."""
    from stillcap.body.hand import hand_pose
    from stillcap.studio.hand_calibration import PROTOCOL_STEPS, _step_angles

    rng = np.random.default_rng(rng)
    out = []
    for i, (name, *_rest) in enumerate(PROTOCOL_STEPS):
        T = np.eye(4)
        T[:3, 3] = (0.12 * i, 0.0, 0.0)
        a = _step_angles(person.skeleton, next(s for s in PROTOCOL_STEPS if s[0] == name)) * scales.get(name, 1.0)
        p = person.markerset.positions(hand_pose(person.skeleton, T, a))
        out.append(p + rng.normal(0, 0.0003, p.shape))
    return [s[0] for s in PROTOCOL_STEPS], np.array(out)


def test_the_fit_tells_the_flat_flash_from_one_a_few_degrees_off():
    """The posed flash's shortlist is ranked by the fit of every flash with each candidate held in
    the pose (``_pose_costs``), not by the template's angles alone: on another person's hand the
    template reads every flash a few degrees bent, and another_hand(5)'s rendered protocol had its
    spread step (3 deg RMS from flat, thumb out) read flatter than its flat flashes, taken as flat,
    and the thumb's MCP calibrated 20 mm off (6.46 deg on its throw; 1.36 with the ranking).
    Here the spread step at half its angles (3 deg RMS): held flat, the shared model must absorb
    it and the other flashes' bends miss that model (fails on main e560c72: no such ranking)."""
    from stillcap.body import hand_calibrate as mod

    person = another_hand(5)
    names, pts = _protocol_flashes(person, {"spread": 0.5})
    flat, near = names.index("flat"), names.index("spread")
    cands = [(pts[k], None, (np.delete(pts, k, axis=0), None)) for k in (flat, near)]
    cost = mod._pose_costs(cands, pose="flat")
    print("cost flat, spread x0.5:", np.round(cost, 1))
    assert np.all(np.isfinite(cost)) and cost[0] < 0.8 * cost[1]


def test_the_posed_flash_is_the_one_the_fit_ranks_first_in_both_passes(protocol_points, monkeypatch):
    """The first pass takes the shortlisted flash whose fit costs least, whatever the template's
    angles say, and the second pass keeps it (the first model reads its own posed flash as flat
    whether it is or not): with the template's second nearest costing least (the two flat flashes
    of the first capture lead the shortlist), it is the posed flash of both."""
    from stillcap.body import hand_calibrate as mod

    real_calibrate, taken, short = mod.calibrate_hand, [], []

    def second_first(candidates, **kw):
        short.append([np.asarray(p, float).reshape(-1, 18, 3)[0].copy() for p, _s, _f in candidates])
        return np.array([1.0, 0.0] + [2.0] * (len(candidates) - 2))

    def spy(posed, free=None, **kw):
        taken.append(np.asarray(posed, float).reshape(-1, 18, 3)[0].copy())
        return real_calibrate(posed, free, **kw)

    monkeypatch.setattr(mod, "_pose_costs", second_first)
    monkeypatch.setattr(mod, "calibrate_hand", spy)
    mod.calibrate_hand_from_point_sets(protocol_points, drop_misfits=False)
    assert len(short) == 1 and len(short[0]) == 3  # a shortlist of MAX_POSED_TRIES, the first pass's
    back = [hand_markerset().index(n) for n in ("back.1", "back.2", "back.3")]
    assert np.allclose(taken[0], short[0][1], equal_nan=True)  # the first pass: the cheapest, the template's second
    assert np.allclose(taken[-1][back], short[0][1][back])  # the second pass: the same flash


def test_every_flash_the_fit_finds_in_the_pose_is_held_a_bent_one_is_not():
    """A protocol has two flat flashes (its first and its last step): held together, one label a
    few mm off in one of them is outvoted (the studio's hands 12 and 7 moved about a degree with
    which of the two was held). ``_also_posed`` tests the rise of the fit's cost when a second
    flash is held too against a chi-square with one degree per angle: the other flat flash
    passes, the spread step at half its angles (3 deg RMS from flat) does not (fails on main
    3f94540: one flash held, no such test)."""
    from stillcap.body import hand_calibrate as mod

    person = another_hand(5)
    names, pts = _protocol_flashes(person, {"spread": 0.5})
    flat = [k for k, n in enumerate(names) if n == "flat"]
    near = names.index("spread")
    assert len(flat) >= 2
    best = flat[0]

    def held_with_best(k):
        rest = np.delete(pts, [best, k], axis=0)
        cand = (pts[[best, k]], None, (rest, None))
        return cand

    alone = (pts[best], None, (np.delete(pts, best, axis=0), None))
    other_flat, spread = mod._also_posed(alone, [held_with_best(flat[1]), held_with_best(near)], pose="flat")
    print("also posed: other flat", other_flat, "spread x0.5", spread)
    assert other_flat and not spread



def test_partly_hidden_labels_stated_noisier_than_they_are_are_weighed_by_the_residuals():
    """A partly hidden marker's stated noise (3 mm over the share of its light) can be ten times
    its error (the studio's eight calibrations: 0.8-1.4 mm median against 4-7 mm stated). When the
    little finger's DIP marker is partly hidden in every flat flash, its place then comes from the
    priors (the studio's hand 11: 2.8 mm off, its throw's DIP 10 deg). Here another_hand(5)'s
    protocol with that marker stated at 5 mm in the flat and spread flashes but 0.6 mm off per
    axis: the fit scales its noise to what the residuals show (``_hidden_noise``) and the
    marker's place comes closer to the hand's (1.60 mm off; fails on main 7132964: 2.39 mm, no scaling)."""
    from stillcap.body import hand_calibrate as mod

    person = another_hand(5)
    truth = hand_capture(205, image_size=(320, 240), supersample=1, person=person, calibration_pose="flat",
                         calibration_motion="protocol").truth
    d = hand_points_from_truth(truth, noise_m=0.0003, drop=0.0, n_spurious=0, rng=5)
    ms = hand_markerset()
    m = ms.index("little.dip")
    # the protocol's flat and spread steps: the first three flashes and the last ones (flat)
    rest = np.isin(d["flash"], [0, 1, 2, 8, 9])
    hidden = (d["marker"] == m) & rest
    pts = d["points"].copy()
    pts[hidden] += np.random.default_rng(1).normal(0.0, 0.0006, (int(hidden.sum()), 3))
    sigma = np.where(hidden, 0.005, mod.NOISE_M)
    cal = calibrate_hand_from_point_sets([CalibrationPoints(pts, d["colours"], truth.strobe_hz, None, sigma)])
    err = np.linalg.norm(cal.markerset.offsets[m] - person.markerset.offsets[m]) * 1e3
    print("little.dip place off by", round(float(err), 2), "mm;", cal.messages)
    assert any("partly hidden markers' noise scaled by" in s for s in cal.messages)
    assert err < 2.0
