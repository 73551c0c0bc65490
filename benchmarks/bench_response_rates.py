"""Camera response: how often ``--response auto`` names the right response class, and how often
the ``response`` self-check fires with the response declared right and wrong, on N studio
pitches per response (linear, sRGB, gamma 1.8, gamma 2.6, a consumer tone curve).

    PYTHONPATH=src python benchmarks/bench_response_rates.py [N] [SIZE] [--cache DIR] [--condition NAME]

``--condition`` photographs the pitches under a condition of ``bench_robustness.py`` (the light
to the side, lens blur, JPEG, a ball radius; "everything varied" draws all of them per pitch)
with each response under test: the goals hold per condition, not only in the plain studio.

With ``--cache DIR`` the rendered captures are kept in DIR (``<response>-<seed>-<size>``) and
read from there on later runs (rendering is most of the time: compare two versions of the
estimate on the same photos).

Runs the pitch pipeline's response stages, not the whole pipeline (for speed): "auto" is
:func:`stillcap.pipelines._response.pitch_auto_estimates` on the capture with a rig that does not
state the response; the self-check is :func:`stillcap.detect.response.response_check` on each
camera's ball images found with the declared response (:func:`ball_centers_stereo`, as the
pipeline's first stage). A capture "fires" when any camera's check fails. Wrong declaration: sRGB
for a linear camera, linear for an encoded one. The margins: over the captures, the largest
worst-camera ``value / limit`` with the right response (below 1: no false alarm) and the
smallest with the wrong one (above 1: every capture fires). Accuracy only: no timing.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from dataclasses import replace

import numpy as np

from stillcap.ball.layout import BASEBALL_RADIUS
from stillcap.detect.response import response_check
from stillcap.io.capture import Capture, stereo_pairs
from stillcap.pipelines._response import _pair_estimates, pitch_auto_estimates
from stillcap.response import Response
from stillcap.studio.pitch import PRESETS, pitch_capture
from stillcap.studio.sensor import Sensor

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from bench_response import TRUE, wrong_for  # noqa: E402


def fired(cap: Capture, declared: Response, radius_m: float = BASEBALL_RADIUS) -> tuple[bool, list, float]:
    """Whether any camera's check fails, the values, and the worst camera's value over its limit
    (the capture's margin: above 1 it fires; NaN when no camera could tell)."""
    specs, _ = stereo_pairs(cap)
    values = []
    for sp in specs:
        cams = [cap.rig[c].with_response(declared) for c in sp.cameras]
        imgs = [cap.read_image(im) for im in sp.images]
        for e in _pair_estimates(cams, imgs, radius_m):
            values.append(response_check(e, declared))
    ratios = [c.value / c.limit for c in values if c.value is not None]
    return (any(not c.passed for c in values), [None if c.value is None else round(c.value, 2) for c in values],
            max(ratios) if ratios else float("nan"))


def conditions_of(condition: str | None, seed: int) -> tuple[dict, dict, int | None]:
    """The studio's capture and sensor keywords and JPEG quality of a condition of
    ``bench_robustness.py`` (``_robust_pitch.CONDITIONS``; "everything varied" draws its own per
    seed), without the response, which is the one under test. None: the default studio."""
    if condition is None:
        return {}, {}, None
    import numpy as np
    from _robust_pitch import CONDITIONS, _mixed

    if condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; known: {list(CONDITIONS)}")
    cap_kw, sensor_kw, quality = CONDITIONS[condition]
    if cap_kw is None:
        cap_kw, sensor_kw, quality = _mixed(np.random.default_rng([seed, sum(map(ord, condition))]))
    return dict(cap_kw), {k: v for k, v in sensor_kw.items() if k not in ("gamma", "tone")}, quality


def capture(name: str, true: Response, seed: int, size, cache: Path | None,
            condition: str | None = None) -> tuple[Capture, float]:
    """The studio pitch of ``seed`` photographed with the response ``true`` under ``condition``
    (rendered, or read from ``cache``), and its ball radius (m)."""
    tag = "" if condition is None else "-" + condition.replace(" ", "_")
    folder = None if cache is None else cache / f"{name.replace(':', '')}-{seed}-{size[0]}x{size[1]}{tag}"
    cap_kw, sensor_kw, quality = conditions_of(condition, seed)
    radius = float(cap_kw.get("ball_radius_m", BASEBALL_RADIUS))
    if folder is not None and (folder / "capture.json").is_file():
        return Capture.load(folder), radius
    preset = list(PRESETS)[seed % len(PRESETS)]
    r = pitch_capture(preset, rng=1000 + seed, calibrate=False, image_size=size,
                      sensor=Sensor(gamma=true, **sensor_kw), **cap_kw)
    cap, photos = r.to_capture(".jpg" if quality else ".png")
    return Capture.load(cap.save(folder or tempfile.mkdtemp(prefix="bench-rates-"), photos,
                                 jpeg_quality=quality or 95)), radius


def main(n: int, size, cache: Path | None = None, condition: str | None = None) -> None:
    print(f"N = {n} pitches per response, {size[0]}x{size[1]}" + (f", condition {condition!r}" if condition else ""))
    print(f"{'true':>10} {'auto class right':>17} {'fires (right)':>13} {'fires (wrong)':>13} "
          f"{'margin right':>12} {'margin wrong':>12}  auto gammas")
    for name, true in TRUE.items():
        ok = total = fr = fw = 0
        gammas, mr, mw = [], [], []
        for seed in range(n):
            cap, radius = capture(name, true, seed, size, cache, condition)
            blind = replace(cap, rig=cap.rig.with_responses(Response.srgb()))
            est = pitch_auto_estimates(blind, radius)
            for e in est.values():
                total += 1
                ok += e.response_class == true.response_class
                gammas.append(round(e.gamma, 2))
            right, wrong = fired(cap, true, radius), fired(cap, wrong_for(true), radius)
            fr, fw = fr + right[0], fw + wrong[0]
            mr.append(right[2])
            mw.append(wrong[2])
        # margins: the largest worst-camera value/limit with the right response (below 1: no
        # false alarm) and the smallest with the wrong one (above 1: every capture fires)
        print(f"{name:>10} {ok:>8}/{total:<8} {fr:>6}/{n:<6} {fw:>6}/{n:<6} {np.nanmax(mr):>12.2f} {np.nanmin(mw):>12.2f}  "
              f"{sorted(gammas)[::max(1, len(gammas) // 12)]}", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("n", nargs="?", type=int, default=12, help="pitches per response (default 12)")
    ap.add_argument("size", nargs="?", default="1280x960", help="image size WxH (default 1280x960)")
    ap.add_argument("--cache", type=Path, help="keep the rendered captures here and reuse them")
    ap.add_argument("--condition", default=None,
                    help="a condition of bench_robustness.py (light, blur, noise, JPEG, ball radius; "
                         "'everything varied' draws them per pitch); default: the plain studio")
    a = ap.parse_args()
    cache = a.cache
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
    main(a.n, tuple(int(v) for v in a.size.split("x")), cache, a.condition)
