"""Camera response: how often ``--response auto`` names the right response class, and how often
the ``response`` self-check fires with the response declared right and wrong, on N studio
pitches per response (linear, sRGB, gamma 1.8, gamma 2.6, a consumer tone curve).

    PYTHONPATH=src python benchmarks/bench_response_rates.py [N] [SIZE]

Runs the pitch pipeline's response stages, not the whole pipeline (for speed): "auto" is
:func:`stillcap.pipelines._response.pitch_auto_estimates` on the capture with a rig that does not
state the response; the self-check is :func:`stillcap.detect.response.response_check` on each
camera's ball images found with the declared response (:func:`ball_centers_stereo`, as the
pipeline's first stage). A capture "fires" when any camera's check fails. Wrong declaration: sRGB
for a linear camera, linear for an encoded one. Accuracy only: no timing.
"""

from __future__ import annotations

import sys
import tempfile
from dataclasses import replace

from stillcap.ball.layout import BASEBALL_RADIUS
from stillcap.detect.response import response_check
from stillcap.io.capture import Capture, stereo_pairs
from stillcap.pipelines._response import _pair_estimates, pitch_auto_estimates
from stillcap.response import Response
from stillcap.studio.pitch import PRESETS, pitch_capture
from stillcap.studio.sensor import Sensor

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from bench_response import TRUE, wrong_for  # noqa: E402


def fired(cap: Capture, declared: Response) -> tuple[bool, list]:
    specs, _ = stereo_pairs(cap)
    values = []
    for sp in specs:
        cams = [cap.rig[c].with_response(declared) for c in sp.cameras]
        imgs = [cap.read_image(im) for im in sp.images]
        for e in _pair_estimates(cams, imgs, BASEBALL_RADIUS):
            values.append(response_check(e, declared))
    return any(not c.passed for c in values), [round(c.value, 2) for c in values]


def main(n: int, size) -> None:
    print(f"N = {n} pitches per response, {size[0]}x{size[1]}")
    print(f"{'true':>10} {'auto class right':>17} {'fires (right)':>13} {'fires (wrong)':>13}  auto gammas")
    for name, true in TRUE.items():
        ok = total = fr = fw = 0
        gammas = []
        for seed in range(n):
            preset = list(PRESETS)[seed % len(PRESETS)]
            r = pitch_capture(preset, rng=1000 + seed, calibrate=False, image_size=size, sensor=Sensor(gamma=true))
            cap, photos = r.to_capture()
            cap = Capture.load(cap.save(tempfile.mkdtemp(prefix="bench-rates-"), photos))
            blind = replace(cap, rig=cap.rig.with_responses(Response.srgb()))
            est = pitch_auto_estimates(blind, BASEBALL_RADIUS)
            for e in est.values():
                total += 1
                ok += e.response_class == true.response_class
                gammas.append(round(e.gamma, 2))
            fr += fired(cap, true)[0]
            fw += fired(cap, wrong_for(true))[0]
        print(f"{name:>10} {ok:>8}/{total:<8} {fr:>6}/{n:<6} {fw:>6}/{n:<6}  {sorted(gammas)[::max(1, len(gammas) // 12)]}",
              flush=True)


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 12
    size = tuple(int(v) for v in sys.argv[2].split("x")) if len(sys.argv) > 2 else (1280, 960)
    main(n, size)
