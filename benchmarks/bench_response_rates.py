"""Camera response: how often ``--response auto`` names the right response class, and how often
the ``response`` self-check fires with the response declared right and wrong, on N studio
pitches per response (linear, sRGB, gamma 1.8, gamma 2.6, a consumer tone curve).

    PYTHONPATH=src python benchmarks/bench_response_rates.py [N] [SIZE] [--cache DIR]

With ``--cache DIR`` the rendered captures are kept in DIR (``<response>-<seed>-<size>``) and
read from there on later runs (rendering is most of the time: compare two versions of the
estimate on the same photos).

Runs the pitch pipeline's response stages, not the whole pipeline (for speed): "auto" is
:func:`stillcap.pipelines._response.pitch_auto_estimates` on the capture with a rig that does not
state the response; the self-check is :func:`stillcap.detect.response.response_check` on each
camera's ball images found with the declared response (:func:`ball_centers_stereo`, as the
pipeline's first stage). A capture "fires" when any camera's check fails. Wrong declaration: sRGB
for a linear camera, linear for an encoded one. Accuracy only: no timing.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
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


def capture(name: str, true: Response, seed: int, size, cache: Path | None) -> Capture:
    """The studio pitch of ``seed`` photographed with the response ``true`` (rendered, or read from ``cache``)."""
    folder = None if cache is None else cache / f"{name.replace(':', '')}-{seed}-{size[0]}x{size[1]}"
    if folder is not None and (folder / "capture.json").is_file():
        return Capture.load(folder)
    preset = list(PRESETS)[seed % len(PRESETS)]
    r = pitch_capture(preset, rng=1000 + seed, calibrate=False, image_size=size, sensor=Sensor(gamma=true))
    cap, photos = r.to_capture()
    return Capture.load(cap.save(folder or tempfile.mkdtemp(prefix="bench-rates-"), photos))


def main(n: int, size, cache: Path | None = None) -> None:
    print(f"N = {n} pitches per response, {size[0]}x{size[1]}")
    print(f"{'true':>10} {'auto class right':>17} {'fires (right)':>13} {'fires (wrong)':>13}  auto gammas")
    for name, true in TRUE.items():
        ok = total = fr = fw = 0
        gammas = []
        for seed in range(n):
            cap = capture(name, true, seed, size, cache)
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
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("n", nargs="?", type=int, default=12, help="pitches per response (default 12)")
    ap.add_argument("size", nargs="?", default="1280x960", help="image size WxH (default 1280x960)")
    ap.add_argument("--cache", type=Path, help="keep the rendered captures here and reuse them")
    a = ap.parse_args()
    cache = a.cache
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
    main(a.n, tuple(int(v) for v in a.size.split("x")), cache)
