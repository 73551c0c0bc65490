"""Camera response: pitch accuracy with the right, the estimated ("auto") and a wrong declared
response, on studio pitches rendered with linear, sRGB, gamma 1.8, gamma 2.6 and a consumer tone
curve; the auto classification rate and the response self-check's firing rate.

    PYTHONPATH=src python benchmarks/bench_response.py [N] [SIZE]

N pitches per response (default 6; presets cycled, seeds 0..N-1), SIZE the image size (default
1280x960). Prints one line per analysis (JSON) and a summary table. Accuracy only: no timing.
"""

from __future__ import annotations

import json
import sys
import tempfile
from dataclasses import replace

import numpy as np

from stillcap.io.capture import Capture
from stillcap.pipelines.pitch import PitchOptions, analyse_pitch
from stillcap.response import Response
from stillcap.studio.compare.pitch import compare_with_truth
from stillcap.studio.pitch import PRESETS, pitch_capture
from stillcap.studio.sensor import Sensor, consumer_tone_curve

TRUE = {"linear": Response.linear(), "srgb": Response.srgb(), "gamma:1.8": Response.power(1.8),
        "gamma:2.6": Response.power(2.6), "tone-curve": consumer_tone_curve()}


def wrong_for(r: Response) -> Response:
    """The wrong declaration: sRGB for a linear camera, linear for an encoded one."""
    return Response.srgb() if r.response_class == "linear" else Response.linear()


def one(name: str, true: Response, seed: int, size) -> list:
    preset = list(PRESETS)[seed % len(PRESETS)]
    rendered = pitch_capture(preset, rng=seed, calibrate=False, image_size=size, sensor=Sensor(gamma=true))
    cap, photos = rendered.to_capture()
    folder = cap.save(tempfile.mkdtemp(prefix="bench-response-"), photos)
    rows = []
    for mode, opt in (("right", None), ("auto", "auto"), ("wrong", wrong_for(true))):
        loaded = Capture.load(folder)  # its rig states the true response (the studio writes it)
        if mode == "auto":  # auto starts from a rig that does not say (read as sRGB), not from the truth
            loaded = replace(loaded, rig=loaded.rig.with_responses(Response.srgb()))
        try:
            res = analyse_pitch(loaded, PitchOptions(n_samples=0, response=opt))
        except ValueError as e:
            rows.append({"true": name, "mode": mode, "seed": seed, "preset": preset, "error": str(e)})
            continue
        c = compare_with_truth(res, loaded.truth)["table1"]
        checks = [ch for ch in res.self_checks if ch.name == "response"]
        est = res.response.get("estimates", {}) if mode == "auto" else {}
        rows.append({
            "true": name, "mode": mode, "seed": seed, "preset": preset,
            "pos_mm": c["mean_err_mm"], "markers_3d": [p.n_markers_3d for p in res.pairs],
            "speed_mph": c["speed_diff_mph"], "dir_deg": c["velocity_angle_deg"],
            "rpm": c["spin_rate_diff_rpm"], "axis_deg": c["spin_axis_angle_deg"],
            "check_fired": any(not ch.passed for ch in checks), "n_checks_failed": sum(not ch.passed for ch in checks),
            "auto_class": {k: v["class"] for k, v in est.items()},
            "auto_gamma": {k: v["gamma"] for k, v in est.items()},
        })
    return rows


def _mean(v):
    v = [abs(x) for x in v if x is not None]
    return float(np.mean(v)) if v else float("nan")


def main(n: int = 6, size=(1280, 960)) -> None:
    rows = []
    for name, true in TRUE.items():
        for seed in range(n):
            for r in one(name, true, seed, size):
                print(json.dumps(r), flush=True)
                rows.append(r)
    print(f"\nN = {n} pitches per response, {size[0]}x{size[1]}; means of |error|")
    print(f"{'true':>10} {'declared':>8} {'pos mm':>7} {'markers/pair':>12} {'speed mph':>9} {'dir deg':>8} "
          f"{'rpm':>6} {'axis deg':>8} {'check fired':>11} {'auto class ok':>13}")
    for name, true in TRUE.items():
        for mode in ("right", "auto", "wrong"):
            rs = [r for r in rows if r["true"] == name and r["mode"] == mode and "error" not in r]
            nerr = sum(1 for r in rows if r["true"] == name and r["mode"] == mode and "error" in r)
            if not rs:
                print(f"{name:>10} {mode:>8}  all {nerr} failed")
                continue
            mk = np.mean([np.mean(r["markers_3d"]) for r in rs])
            fired = sum(r["check_fired"] for r in rs)
            if mode == "auto":
                cls = [c == true.response_class for r in rs for c in r["auto_class"].values()]
                auto = f"{sum(cls)}/{len(cls)} cams"
            else:
                auto = "-"
            print(f"{name:>10} {mode:>8} {_mean([r['pos_mm'] for r in rs]):7.2f} {mk:12.1f} "
                  f"{_mean([r['speed_mph'] for r in rs]):9.3f} {_mean([r['dir_deg'] for r in rs]):8.3f} "
                  f"{_mean([r['rpm'] for r in rs]):6.2f} {_mean([r['axis_deg'] for r in rs]):8.2f} "
                  f"{fired:>5}/{len(rs):<5} {auto:>13}" + (f"  ({nerr} failed)" if nerr else ""))


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 6
    size = tuple(int(v) for v in sys.argv[2].split("x")) if len(sys.argv) > 2 else (1280, 960)
    main(n, size)
