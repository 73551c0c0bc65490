"""Robustness rows for the puppet pipeline (issue 12): puppets unlike the default.

:func:`rows` renders, per condition, puppets of other proportions (+-15 %) with beads in other
places (:func:`stillcap.studio.puppet_variation.another_puppet`, seeded), runs the pipeline with

- the built-in skeleton and marker set (what a user gets without files),
- a skeleton calibrated from a rest-pose capture plus two captures in other poses
  (:func:`stillcap.body.puppet_calibrate.calibrate_skeleton`, as ``puppet calibrate-skeleton``),
- the puppet's own skeleton and marker set (the user's files, ``--skeleton/--markers``),

and reports wrong identifications, 3D RMS on beads seen whole, partly hidden beads (count and
their RMS), fitted bone-direction RMS on the bones the beads fix (``full`` frames) for each
skeleton, and the model-free bead-pair direction RMS. ``benchmarks/bench_robustness.py`` imports
:func:`rows`; ``python benchmarks/_robust_puppet.py [--quick]`` prints the table alone.

Timings are not measured here (the machine this was written on was shared).
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

CONDITIONS = {
    # name: (another_puppet keywords, marker set)
    "default puppet": (dict(proportions=0.0, bead_shift_m=0.0, bead_turn_deg=0.0, bead_height=0.0), "puppet-16"),
    "+-15 % proportions, beads moved": (dict(proportions=0.15), "puppet-16"),
    "+-15 % proportions, beads moved, puppet-20": (dict(proportions=0.15), "puppet-20"),
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


def rows(quick: bool = False) -> list[dict]:
    """One dict per condition (see the module docstring). ``quick``: one puppet per condition
    and the first two conditions only (about 1-2 minutes on a quiet machine)."""
    from stillcap.body.markerset import MarkerSet
    from stillcap.body.puppet_calibrate import calibrate_skeleton
    from stillcap.body.skeleton import Skeleton
    from stillcap.studio.puppet import puppet_scene
    from stillcap.studio.puppet_variation import another_puppet

    n_puppets = 1 if quick else 4
    conds = list(CONDITIONS.items())[:2] if quick else list(CONDITIONS.items())
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for ci, (cname, (kw, msname)) in enumerate(conds):
            acc = {k: [] for k in ("wrong", "whole", "ph", "ph_n", "builtin", "calibrated", "user", "pairs",
                                   "partial_user")}
            for k in range(n_puppets):
                seed = 1000 * ci + k
                sk, ms = another_puppet(seed, markerset=msname, **kw)
                base = Path(tmp) / f"c{ci}_{k}"

                def shoot(name, spec):
                    return _save(puppet_scene(pose=spec, rng=seed, markerset=ms, skeleton=sk), base / name)

                test = shoot("test", f"random:{seed + 7}")
                # calibration captures: the rest pose and two others
                cal_pts = []
                for name, spec in (("rest", "tpose"), ("p1", f"random:{seed + 1}"), ("p2", f"random:{seed + 2}")):
                    r, _ = _analyse(shoot(name, spec), MarkerSet.puppet(msname), Skeleton.puppet())
                    p = r.markers.points.copy()
                    p[r.markers.partly_hidden] = np.nan
                    cal_pts.append(p)
                cal = calibrate_skeleton(cal_pts[0], Skeleton.puppet(), MarkerSet.puppet(msname), cal_pts[1:])
                for label, (m_, s_) in (("builtin", (MarkerSet.puppet(msname), Skeleton.puppet())),
                                        ("calibrated", (cal.markerset, cal.skeleton)), ("user", (ms, sk))):
                    res, cmp = _analyse(test, m_, s_)
                    acc[label].append(cmp.bone_stats("full")[0])
                    if label == "user":
                        acc["partial_user"].append(cmp.bone_stats("partial")[0])
                        acc["wrong"].append(cmp.wrong)
                        e = cmp.marker_errors_m
                        ph = cmp.partly_hidden
                        acc["whole"].extend(e[~ph & np.isfinite(e)])
                        acc["ph"].extend(e[ph & np.isfinite(e)])
                        acc["ph_n"].append(int(ph.sum()))
                        acc["pairs"].append(cmp.bead_pair_stats()[0])

            def rms(v):
                v = np.asarray(v, float)
                v = v[np.isfinite(v)]
                return float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")

            out.append({"pipeline": "puppet", "condition": cname, "n": n_puppets,
                        "wrong_ids": int(sum(acc["wrong"])),
                        "whole_rms_mm": rms(acc["whole"]) * 1e3,
                        "partly_hidden": int(sum(acc["ph_n"])),
                        "partly_hidden_rms_mm": rms(acc["ph"]) * 1e3,
                        "bone_deg_builtin": rms(acc["builtin"]),
                        "bone_deg_calibrated": rms(acc["calibrated"]),
                        "bone_deg_user": rms(acc["user"]),
                        "partial_bone_deg_user": rms(acc["partial_user"]),
                        "bead_pair_deg": rms(acc["pairs"])})
    return out


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    table = rows(quick="--quick" in argv)
    keys = list(table[0])
    print(" | ".join(keys))
    for r in table:
        print(" | ".join(f"{r[k]:.3f}" if isinstance(r[k], float) else str(r[k]) for k in keys))


if __name__ == "__main__":
    main()
