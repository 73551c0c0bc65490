"""What a hand calibration recovers of the person's hand, part by part, against the studio's true
hand (issue 12, the hand goal): phalanx lengths, the knuckles' places (splay), the thumb's axis
and the markers' places on their bones (heights), for each calibration motion.

    python benchmarks/bench_hand_cal_model.py --cache DIR --work DIR [--persons 7 8 12 14]
        [--motions curl protocol] [--arm own-noise] [--jsonl FILE]

It only reads: ``--cache DIR`` holds ``p{p}/own.json`` and ``p{p}/own.markers.json`` (the
person's true model, ``another_hand(p)``) and ``--work DIR`` the pickled calibrations
``p{p}/cal-{motion}.{arm}.pkl`` that ``bench_hand_cal_weighting.py`` writes (``HandCalibration``
of :func:`stillcap.body.hand_calibrate.calibrate_hand_from_points`). Per person and motion:

- ``proximal``, ``middle``: the fingers' proximal (MCP-PIP) and middle (PIP-DIP) phalanx lengths,
  RMS error (mm) over the four fingers; ``thumb``: the thumb's CMC-MCP and MCP-IP lengths;
- ``splay``: the finger knuckles' sideways place (``y``), RMS (mm); ``knuckle x``: along the hand;
- ``thumb axis``: angle (deg) between each calibrated thumb bone and the true one, RMS;
- ``heights``: each digit marker's offset from its bone's axis (the part across the bone), RMS
  error (mm), and ``along``: its place along the bone (mm);
- ``z``: the RMS and the largest of error / stated 1-sigma over every length, knuckle component
  and thumb axis (about 1 when the calibration's 1-sigma are honest);
- ``not fixed``: what the self-check ``calibration_fixes_the_model`` names.

No time is measured.
"""

from __future__ import annotations

import argparse
import json
import pickle
from pathlib import Path

import numpy as np

FINGERS = ("index", "middle", "ring", "little")


def model_errors(cal, own_sk, own_ms) -> dict:
    """Errors of a calibration's model against the true one, by part (module docstring)."""
    sk, ms = cal.skeleton, cal.markerset
    o, t = sk.offsets, own_sk.offsets
    idx = {n: i for i, n in enumerate(sk.names)}
    length = lambda n: (np.linalg.norm(o[idx[n]]) - np.linalg.norm(t[idx[n]])) * 1e3
    rms = lambda v: float(np.sqrt(np.mean(np.square(v)))) if len(v) else float("nan")
    out = {"proximal": rms([length(f"{f}-pip") for f in FINGERS]),
           "middle": rms([length(f"{f}-dip") for f in FINGERS]),
           "thumb": rms([length("thumb-mcp"), length("thumb-ip")]),
           "splay": rms([(o[idx[f"{f}-mcp"], 1] - t[idx[f"{f}-mcp"], 1]) * 1e3 for f in FINGERS]),
           "knuckle_x": rms([(o[idx[f"{f}-mcp"], 0] - t[idx[f"{f}-mcp"], 0]) * 1e3 for f in FINGERS])}
    ang = []
    for n in ("thumb-mcp", "thumb-ip", "thumb-tip"):
        a, b = o[idx[n]], t[idx[n]]
        ang.append(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))
    out["thumb_axis_deg"] = rms(ang)
    frames = ms.bone_frames(sk)
    hts, along = [], []
    for k, m in enumerate(ms.markers):
        if frames[k] == sk.root:
            continue
        b = sk.index(m.bone)
        u = t[b] / np.linalg.norm(t[b])  # the true bone's direction in its start joint's frame
        d = ms.offsets[k] - own_ms.offsets[own_ms.index(m.name)]
        along.append(d @ u * 1e3)
        v_cal = ms.offsets[k] - (ms.offsets[k] @ u) * u
        v_own = own_ms.offsets[own_ms.index(m.name)] - (own_ms.offsets[own_ms.index(m.name)] @ u) * u
        hts.append((np.linalg.norm(v_cal) - np.linalg.norm(v_own)) * 1e3)
    out["heights"], out["along"] = rms(hts), rms(along)
    # the stated 1-sigma against the true error (length, knuckle component, thumb axis)
    truth = {}
    for i, n in enumerate(own_sk.names):
        if i == own_sk.root or n.endswith("-tip"):
            continue
        if own_sk.parents[i] == own_sk.root:
            for a, ax in enumerate("xyz"):
                truth[f"{n} {ax}"] = t[i, a] * 1e3
        else:
            truth[f"{own_sk.names[own_sk.parents[i]]} to {n}"] = np.linalg.norm(t[i]) * 1e3
    z = []
    for q in cal.parameters:
        if q.kind in ("length", "knuckle") and q.name in truth and q.sigma > 0:
            z.append((q.value - truth[q.name]) / q.sigma)
    z = np.abs(z)
    out["z_rms"], out["z_max"] = (rms(z), float(z.max())) if len(z) else (float("nan"), float("nan"))
    out["unfixed"] = [q.name for q in cal.parameters if q.kind != "height" and q.fixed > 0.7]
    return out


def main() -> None:
    from stillcap.body.markerset import MarkerSet
    from stillcap.body.skeleton import Skeleton

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--persons", type=int, nargs="+", default=[7, 8, 12, 14])
    ap.add_argument("--motions", nargs="+", default=["curl", "protocol"])
    ap.add_argument("--arm", default="own-noise", help="the calibration arm's file name part (own-noise, common)")
    ap.add_argument("--jsonl", type=Path)
    a = ap.parse_args()
    cols = ("proximal", "middle", "thumb", "splay", "knuckle_x", "thumb_axis_deg", "heights", "along", "z_rms", "z_max")
    print(f"{'person':>6} {'motion':>10} " + " ".join(f"{c:>9}" for c in cols) + "  not fixed")
    for p in a.persons:
        own_sk = Skeleton.load(a.cache / f"p{p}" / "own.json")
        own_ms = MarkerSet.load(a.cache / f"p{p}" / "own.markers.json")
        for mo in a.motions:
            f = a.work / f"p{p}" / f"cal-{mo}.{a.arm}.pkl"
            if not f.exists():
                print(f"{p:>6} {mo:>10} (no calibration: {f})")
                continue
            with f.open("rb") as fh:
                cal = pickle.load(fh)
            e = model_errors(cal, own_sk, own_ms)
            print(f"{p:>6} {mo:>10} " + " ".join(f"{e[c]:>9.2f}" for c in cols) + "  " + (", ".join(e["unfixed"]) or "-"))
            if a.jsonl is not None:
                with a.jsonl.open("a") as fh:
                    fh.write(json.dumps({"person": p, "motion": mo, "arm": a.arm, **e}) + "\n")


if __name__ == "__main__":
    main()
