"""Robustness rows for the puppet pipeline (issue 12): puppets unlike the default.

:func:`rows` renders, per condition, puppets of other proportions (+-15 %) with beads in other
places (:func:`stillcap.studio.puppet_variation.another_puppet`, seeded), runs the pipeline with

- the built-in skeleton and marker set (what a user gets without files),
- a skeleton calibrated by the documented protocol (``docs/puppet.md``): a rest-pose capture plus
  two captures in other poses (:func:`stillcap.body.puppet_calibrate.calibrate_skeleton`, as
  ``puppet calibrate-skeleton rest --pose p1 --pose p2``), on the beads the pipeline recovered
  whole,
- the puppet's own skeleton and marker set (the user's files, ``--skeleton/--markers``),

and reports wrong identifications, 3D RMS on beads seen whole, partly hidden beads (count and
their RMS), fitted bone-direction RMS and max on the bones the beads fix (``full`` frames of the
marker set's design) for each skeleton, and beside it the same over the bones the beads this
capture recovered fix (``*_measured``: a bone whose frame's beads were not recovered is the fit's
guess, named by the ``bone_measured`` self-check), the calibration's own predicted direction error on those bones
(:attr:`SkeletonCalibration.direction_sd_deg`, RMS; the calibration weighs each bead by the noise
its capture's photos show, :func:`stillcap.body.puppet_checks.bead_noise`), ``z`` (measured over
predicted error per bone, RMS: about 1 when the prediction is honest), the bones it names as
uncertain (right: measured error over the 1 deg limit; wrong: not over it; missed: over it but not
named), ``z_within_1.96`` (the share of bones whose measured error is within 1.96 predicted
sigmas: 0.95 when honest), ``weakly_posed`` (bones the calibration names as fixed by its
captures' poses much better than in a new pose: :attr:`SkeletonCalibration.weakly_posed`), the
model-free bead-pair direction RMS, and per skeleton the bones the result's self-checks
name as not matching the puppet (``*_checks_failed``; ``*_over1_named_missed``: of the bones over
1 deg, named / not named; ``*_bones_checked``: bones with a per-bone check; ``*_captures_named``:
captures with a bone named). On the default puppet (condition 0) every skeleton matches, so the
bones named are false alarms (each check's rate: ``puppet_checks.FALSE_ALARM_P``); with the
built-in skeleton on other puppets they are detections. ``--no-calibration`` leaves out the
calibrated skeleton (one capture per puppet instead of four). ``calibrations_over_1deg``: puppets
whose calibrated skeleton gave over 1 deg RMS; ``calibration_wrong_ids``: wrong names in the three
calibration captures (built-in body); ``calibrations_converged``: calibrations whose joint fit
converged (:attr:`SkeletonCalibration.joint_converged`). The per-bone checks name a bone at the
default bone tolerance (``puppet_checks.BONE_TOLERANCE_DEG``).
``benchmarks/bench_robustness.py`` imports :func:`rows`;

    python benchmarks/_robust_puppet.py [--quick] [--seeds 11-22] [--conditions 0,1,...] [--no-calibration]

prints one row per puppet (seed) and the table per condition. The conditions vary what real
photos vary and the studio's puppet renderer can vary: proportions and bead placement, the
marker set, lens blur and the camera response (declared in the rig the capture writes, as a
user's rig file would). The light stays the webcam's LEDs at each camera (the puppet renderer
has no other light placement yet).

Timings are not measured here (the machine this was written on was shared by nine agents);
``--quick`` (2 conditions x 2 puppets, 8 captures each) is meant to take under 10 minutes on a
quiet machine; run it there to confirm.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

_MOVED = dict(proportions=0.15)
CONDITIONS = {
    # name: (another_puppet keywords, marker set, Sensor changes from the webcam's)
    "default puppet": (dict(proportions=0.0, bead_shift_m=0.0, bead_turn_deg=0.0, bead_height=0.0), "puppet-16", {}),
    "+-15 % proportions, beads moved": (_MOVED, "puppet-16", {}),
    "+-15 % proportions, beads moved, puppet-20": (_MOVED, "puppet-20", {}),
    "beads moved +-6 mm, turned +-60 deg": (dict(proportions=0.15, bead_shift_m=0.006, bead_turn_deg=60.0),
                                            "puppet-16", {}),
    "lens blur 1.5 px": (_MOVED, "puppet-16", dict(blur_px=1.5)),
    "linear response": (_MOVED, "puppet-16", dict(gamma=1.0)),
    "gamma 2.6 + tone curve": (_MOVED, "puppet-16", dict(gamma=2.6, tone=True)),
}


def _analyse(folder, markerset, skeleton):
    from stillcap.pipelines.puppet import analyse_puppet
    from stillcap.studio.compare.puppet import compare_with_capture

    res, _ = analyse_puppet(folder, markerset=markerset, skeleton=skeleton, workers=1)
    return res, compare_with_capture(res, folder)


def _save(scene, folder: Path) -> Path:
    cap, images = scene.to_capture(".png")
    cap.save(folder, images)
    return folder


def _rms(v) -> float:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")


def one_puppet(seed: int, kw: dict, msname: str, sensor_kw: dict, tmp: Path, calibrate: bool = True) -> dict:
    """Render and measure one puppet (see the module docstring); a dict of its numbers."""
    from dataclasses import replace

    from stillcap.body.markerset import MarkerSet
    from stillcap.body.puppet_calibrate import calibrate_skeleton
    from stillcap.body.puppet_checks import bead_noise
    from stillcap.body.skeleton import Skeleton
    from stillcap.studio.puppet import puppet_scene, webcam_sensor
    from stillcap.studio.puppet_variation import another_puppet

    sk, ms = another_puppet(seed, markerset=msname, **kw)
    sensor = replace(webcam_sensor(), **sensor_kw)

    def shoot(name, spec):
        return _save(puppet_scene(pose=spec, rng=seed, markerset=ms, skeleton=sk, sensor=sensor), tmp / name)

    test = shoot("test", f"random:{seed + 7}")
    cal_wrong = 0
    bodies = [("builtin", (MarkerSet.puppet(msname), Skeleton.puppet()))]
    if calibrate:
        cal_pts, cal_noise = [], []
        for name, spec in (("rest", "tpose"), ("p1", f"random:{seed + 1}"), ("p2", f"random:{seed + 2}")):
            r, c_ = _analyse(shoot(name, spec), MarkerSet.puppet(msname), Skeleton.puppet())
            cal_wrong += c_.wrong  # wrong names in the calibration's own captures (built-in body)
            m = r.markers
            p = m.points.copy()
            p[m.partly_hidden] = np.nan  # as calibrate-skeleton does
            cal_pts.append(p)
            cal_noise.append(bead_noise(r.rig, m.points, m.observations, m.used, exclude=m.partly_hidden).sd_m)
        cal = calibrate_skeleton(cal_pts[0], Skeleton.puppet(), MarkerSet.puppet(msname), cal_pts[1:],
                                 noise_m=cal_noise)
        bodies.append(("calibrated", (cal.markerset, cal.skeleton)))
    bodies.append(("user", (ms, sk)))
    out = {"seed": seed, "cal_wrong": cal_wrong, "cal_converged": bool(calibrate and cal.joint_converged)}
    for label, (m_, s_) in bodies:
        res, cmp = _analyse(test, m_, s_)
        out[f"{label}_rms"], out[f"{label}_max"] = cmp.bone_stats("full")
        # the same over the bones the beads this capture recovered fix (the design's "full"
        # bones less those whose frame's beads were not recovered: the fit's guess)
        out[f"{label}_measured_rms"], out[f"{label}_measured_max"] = cmp.bone_stats("full", measured=True)
        # the per-bone self-checks (does the skeleton match the puppet?) against the measured
        # error: bones named (a failed bone_residual or bead_pair_direction check), and of the
        # bones the beads fix, those over 1 deg that were named / not named
        named = {c.subject for c in res.self_checks
                 if not c.passed and c.name in ("bone_residual", "bead_pair_direction")}
        over = {b for b in cmp.bone_groups.get("full", []) if cmp.bone_errors_deg.get(b, 0.0) > 1.0}
        out[f"{label}_checks_failed"] = len(named)
        out[f"{label}_bones_checked"] = len({c.subject for c in res.self_checks
                                             if c.name in ("bone_residual", "bead_pair_direction")})
        out[f"{label}_over1_named"] = len(over & named)
        out[f"{label}_over1_missed"] = len(over - named)
        if label == "calibrated":
            full = [b for b in cmp.bone_groups.get("full", [])]
            pred = np.array([cal.direction_sd_deg.get(b, np.nan) for b in full])
            err = np.array([cmp.bone_errors_deg.get(b, np.nan) for b in full])
            out["predicted_rms"] = _rms(pred)
            out["z"] = list(err / pred)  # measured over predicted, per bone: RMS about 1 when honest
            out["uncertain"] = sorted(b for b in cal.uncertain if b in full)
            # bones whose error the captures' poses hide (SkeletonCalibration.weakly_posed)
            out["weak"] = sorted(b for b in cal.weakly_posed if b in full)
            # the calibration's uncertain bones against the measured error over its limit (1 deg)
            over = {b for b, e in zip(full, err) if e > 1.0}
            out["uncertain_right"] = len(over & set(out["uncertain"]))
            out["uncertain_wrong"] = len(set(out["uncertain"]) - over)
            out["uncertain_missed"] = len(over - set(out["uncertain"]))
        if label == "user":
            out["partial_user"] = cmp.bone_stats("partial")[0]
            out["wrong"] = cmp.wrong
            e, ph = cmp.marker_errors_m, cmp.partly_hidden
            out["whole_m"] = list(e[~ph & np.isfinite(e)])
            out["ph_m"] = list(e[ph & np.isfinite(e)])
            out["ph_n"] = int(ph.sum())
            out["pairs"] = cmp.bead_pair_stats()[0]
    return out


def rows(quick: bool = False, seeds=None, conditions=None, per_seed: list | None = None, progress=None,
         calibrate: bool = True) -> list[dict]:
    """One dict per condition (see the module docstring). ``quick``: 2 puppets in each of the
    first two conditions; default 4 puppets per condition (seeds ``1000 * condition + k``).
    ``seeds``: these seeds in every condition instead. ``per_seed``: a list that receives each
    puppet's dict (:func:`one_puppet` with ``condition``). ``calibrate=False``: without the
    calibrated skeleton (its keys NaN)."""
    conds = list(CONDITIONS.items())
    if conditions is not None:
        conds = [conds[i] for i in conditions]
    elif quick:
        conds = conds[:2]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for ci, (cname, (kw, msname, sensor_kw)) in enumerate(conds):
            todo = list(seeds) if seeds is not None else [1000 * ci + k for k in range(2 if quick else 4)]
            recs = []
            for seed in todo:
                r = one_puppet(seed, kw, msname, sensor_kw, Path(tmp) / f"c{ci}_{seed}", calibrate)
                if not calibrate:
                    r.update({"calibrated_rms": np.nan, "calibrated_max": np.nan, "calibrated_measured_rms": np.nan,
                              "calibrated_measured_max": np.nan, "predicted_rms": np.nan, "z": [], "uncertain": [],
                              "weak": [], "uncertain_right": 0, "uncertain_wrong": 0, "uncertain_missed": 0,
                              "calibrated_checks_failed": 0, "calibrated_bones_checked": 0,
                              "calibrated_over1_named": 0, "calibrated_over1_missed": 0})
                r["condition"] = cname
                recs.append(r)
                if per_seed is not None:
                    per_seed.append(r)
                if progress is not None:
                    progress(r)
            out.append({"pipeline": "puppet", "condition": cname, "n": len(recs),
                        "wrong_ids": int(sum(r["wrong"] for r in recs)),
                        "whole_rms_mm": _rms([v for r in recs for v in r["whole_m"]]) * 1e3,
                        "partly_hidden": int(sum(r["ph_n"] for r in recs)),
                        "partly_hidden_rms_mm": _rms([v for r in recs for v in r["ph_m"]]) * 1e3,
                        "bone_deg_builtin": _rms([r["builtin_rms"] for r in recs]),
                        "bone_deg_builtin_measured": _rms([r["builtin_measured_rms"] for r in recs]),
                        "bone_deg_calibrated": _rms([r["calibrated_rms"] for r in recs]),
                        "bone_deg_calibrated_measured": _rms([r["calibrated_measured_rms"] for r in recs]),
                        "bone_deg_calibrated_worst": (float(np.nanmax([r["calibrated_rms"] for r in recs]))
                                                      if calibrate else float("nan")),
                        "calibrations_over_1deg": int(sum(r["calibrated_rms"] > 1.0 for r in recs)) if calibrate else 0,
                        "calibration_wrong_ids": int(sum(r["cal_wrong"] for r in recs)),
                        "calibrations_converged": int(sum(r["cal_converged"] for r in recs)),
                        "bone_deg_predicted": _rms([r["predicted_rms"] for r in recs]),
                        "z_rms": _rms([z for r in recs for z in r["z"]]),
                        "z_within_1.96": (float(np.mean(np.abs([z for r in recs for z in r["z"]]) < 1.96))
                                          if calibrate else float("nan")),
                        "weakly_posed": int(sum(len(r["weak"]) for r in recs)),
                        "uncertain_right": int(sum(r["uncertain_right"] for r in recs)),
                        "uncertain_wrong": int(sum(r["uncertain_wrong"] for r in recs)),
                        "uncertain_missed": int(sum(r["uncertain_missed"] for r in recs)),
                        "bone_deg_user": _rms([r["user_rms"] for r in recs]),
                        "bone_deg_user_measured": _rms([r["user_measured_rms"] for r in recs]),
                        "partial_bone_deg_user": _rms([r["partial_user"] for r in recs]),
                        "bead_pair_deg": _rms([r["pairs"] for r in recs]),
                        **{f"{lab}_checks_failed": int(sum(r[f"{lab}_checks_failed"] for r in recs))
                           for lab in ("builtin", "calibrated", "user")},
                        **{f"{lab}_bones_checked": int(sum(r[f"{lab}_bones_checked"] for r in recs))
                           for lab in ("builtin", "calibrated", "user")},
                        **{f"{lab}_captures_named": int(sum(r[f"{lab}_checks_failed"] > 0 for r in recs))
                           for lab in ("builtin", "calibrated", "user")},
                        **{f"{lab}_over1_named_missed": f"{sum(r[f'{lab}_over1_named'] for r in recs)}/"
                                                        f"{sum(r[f'{lab}_over1_missed'] for r in recs)}"
                           for lab in ("builtin", "calibrated", "user")}})
    return out


def _seed_line(r: dict) -> str:
    def bones(lab):  # design grouping RMS max, then the measured grouping's RMS in brackets
        return f"{r[lab + '_rms']:5.2f} {r[lab + '_max']:5.2f} ({r[lab + '_measured_rms']:5.2f})"

    return (f"{r['condition'][:38]:38s} | {r['seed']:5d} | {bones('builtin')} | {bones('calibrated')} | "
            f"{r['predicted_rms']:5.2f} | {bones('user')} | {r['wrong']:3d} | {_rms(r['whole_m']) * 1e3:5.3f} | "
            f"{r['ph_n']:2d} {_rms(r['ph_m']) * 1e3:5.2f} | {_rms(r['z']):4.2f} | {','.join(r['uncertain']) or '-'} | "
            + " ".join(f"{r[lab + '_checks_failed']}/{r[lab + '_bones_checked']}"
                       for lab in ("builtin", "calibrated", "user"))
            + f" | {r['cal_wrong']}")


def _seeds(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b) + 1) if b else [int(a)])
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 puppets in each of the first two conditions")
    ap.add_argument("--seeds", type=_seeds, default=None, help="seeds in every condition, e.g. 11-22")
    ap.add_argument("--conditions", default=None, help="condition indices, e.g. 0,1,4 (default all)")
    ap.add_argument("--no-calibration", action="store_true",
                    help="leave out the calibrated skeleton (built-in and own files only: one capture per puppet)")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    conds = None if args.conditions is None else [int(c) for c in args.conditions.split(",")]
    print("bones the beads fix, direction error deg (RMS max, and in brackets the RMS over the bones whose beads "
          "this capture recovered), per puppet; predicted = the calibration's own estimate; 3D = RMS of beads seen "
          "whole (mm), own files")
    print(f"{'condition':38s} |  seed | built-in            | calibrated          | pred. | own files           | "
          "wrong | 3D mm | partly hidden n, mm | z | calibration names uncertain | bones failing self-checks / "
          "checked: built-in calibrated own | wrong IDs in the calibration captures")
    table = rows(args.quick, seeds=args.seeds, conditions=conds, progress=lambda r: print(_seed_line(r), flush=True),
                 calibrate=not args.no_calibration)
    keys = list(table[0])
    print()
    print(" | ".join(keys))
    for r in table:
        print(" | ".join(f"{r[k]:.3f}" if isinstance(r[k], float) else str(r[k]) for k in keys))


if __name__ == "__main__":
    main()
