"""The pitch part of ``bench_robustness.py``: accuracy and 95 % interval coverage per condition.

Each condition varies one thing the photos of a real lab vary (``CONDITIONS``), "everything
varied" everything at once (each capture draws its own conditions). Two vary the ball painted:
"ball painted at random" (each capture draws its own ball from what users plausibly paint,
:func:`stillcap.studio.ball_variation.painted_ball`: 6-16 markers placed by the layout designer
or by hand, 2-5 types of any shape, colour and size the ball format allows, radius 34-42 mm) and
"built-in and repainted balls" (``FIXED_BALLS`` in turn); the ball is declared as a user
declares theirs, by its ball file in capture.json (``ball``), which also gives the radius.

Every capture is a studio pitch (``seed-4seam``, ``seed-curveball`` and ``mlb-high-spin`` in turn, release scatter on) rendered
through the true cameras (no calibration error: what is measured is the photos' effect), written
as a capture folder (PNG, or JPEG at the condition's quality) and analysed by
``analyse_pitch`` with its defaults, **with the truth declared where a user can declare it**:
the ball radius (``PitchOptions.ball_radius_m``) and each camera's response (``rig.json``
``response``, which the detectors read; ``benchmarks/bench_response_rates.py`` measures wrong
declarations and ``auto``).

Per capture the errors and coverage flags are those of ``bench_pitch.evaluate`` (positions:
``e^T C^-1 e <= chi2_3(95 %)`` per ball image; speed ``|d| <= 1.96 sigma``; direction 2-D
Mahalanobis ``<= 5.99``; spin rate ``|d| <= 1.96 sigma``; axis ``angle <= 2.45 sigma``), plus
whether a self-check failed. ``rows(quick)`` returns one dict per condition.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

#: The issue's goals per condition.
GOALS = {"pos_mean_mm": 2.0, "speed_mph": 0.1, "dir_deg": 0.2, "rate_rpm": 3.0, "axis_deg": 0.5,
         "coverage": (0.90, 0.98)}
PRESETS = ("seed-4seam", "seed-curveball", "mlb-high-spin")
COVERAGE_KEYS = ("positions", "speed", "direction", "spin_rate", "spin_axis")

#: name -> (pitch_capture keywords, Sensor keywords, JPEG quality or None)
CONDITIONS = {
    "clean": ({}, {}, None),
    "light near cameras": ({"lights": "near"}, {}, None),
    "light to the side": ({"lights": "side"}, {}, None),
    "light behind cameras": ({"lights": "behind"}, {}, None),
    "room lit by flashes": ({"room_flash": 0.0004}, {}, None),
    "blur 0.3 px": ({}, {"blur_px": 0.3}, None),
    "blur 1.5 px": ({}, {"blur_px": 1.5}, None),
    "sensor noise x3": ({}, {"full_well": 1200.0, "read_noise": 0.006}, None),
    "white balance cast": ({}, {"white_balance": (1.25, 1.0, 0.8)}, None),
    "JPEG 70": ({}, {}, 70),
    "JPEG 98": ({}, {}, 98),
    "response linear": ({}, {"gamma": 1.0}, None),
    "response gamma 1.8": ({}, {"gamma": 1.8}, None),
    "response gamma 2.6": ({}, {"gamma": 2.6}, None),
    "response tone curve": ({}, {"tone": True}, None),
    "ball radius 34 mm": ({"ball_radius_m": 0.034}, {}, None),
    "ball radius 42 mm": ({"ball_radius_m": 0.042}, {}, None),
    "everything varied": (None, None, None),
    "ball painted at random": ({"ball": "painted"}, {}, None),
    "built-in and repainted balls": ({"ball": "builtin"}, {}, None),
}
#: the balls of "built-in and repainted balls", in turn (as ``bench_ball_layouts.py``'s)
FIXED_BALLS = ("baseball", "tests/data/repainted-baseball.json", "softball", "cricket", "tennis")


def _mixed(rng: np.random.Generator) -> tuple[dict, dict, int | None]:
    """One capture's conditions drawn from every range at once (``render_capture`` paints half of
    the balls at random, :func:`stillcap.studio.ball_variation.painted_ball`)."""
    cap = {"lights": str(rng.choice(["default", "near", "side", "behind"])),
           "room_flash": float(rng.choice([0.0, 0.0004])),
           "ball_radius_m": float(rng.uniform(0.034, 0.042))}
    resp = rng.integers(4)
    sensor = {"blur_px": float(rng.uniform(0.3, 1.5)),
              "full_well": float(rng.uniform(1200.0, 10000.0)), "read_noise": float(rng.uniform(0.002, 0.006)),
              "white_balance": tuple(float(v) for v in rng.uniform(0.8, 1.25, 3)),
              "gamma": ["srgb", 1.0, float(rng.uniform(1.8, 2.6)), "srgb"][resp], "tone": bool(resp == 3)}
    q = int(rng.integers(70, 99)) if rng.random() < 0.7 else None
    return cap, sensor, q


#: the sigmas a variant of the analysis records (``run_capture(variants=...)``)
SIGMA_KEYS = ("speed_sigma_mph", "dir_sigma_hv_deg", "rate_sigma_rpm", "axis_sigma_deg")
#: and its errors and coverage flags (the final fit weighs the positions by their covariances)
VARIANT_KEYS = ("coverage", "speed_mph", "dir_deg", "dir_err_hv_deg", "rate_rpm", "axis_deg")


def _draw_ball(kind: str, index: int, rng: np.random.Generator):
    """The ball of capture ``index``: painted at random (:func:`stillcap.studio.ball_variation.painted_ball`)
    or the fixed balls in turn (``FIXED_BALLS``)."""
    from stillcap.ball.ballfile import load_ball
    from stillcap.studio.ball_variation import painted_ball

    if kind == "painted":
        return painted_ball(rng)
    spec = FIXED_BALLS[index % len(FIXED_BALLS)]
    return load_ball(Path(__file__).resolve().parent.parent / spec if spec.endswith(".json") else spec)


def render_capture(condition: str, index: int, seed: int, size: tuple, workdir: str, scenes: str | None = None):
    """Render capture ``index`` of ``condition`` into a new folder under ``workdir``, each camera's
    true response declared in its rig file (what a user can declare); returns the studio capture,
    the folder and ``(preset, capture keywords, sensor keywords, JPEG quality or None)``.

    ``scenes``: draw the capture from the random stream of that condition's capture ``index``
    instead of its own (the streams are seeded by the condition's name): conditions that change
    only the photos (JPEG quality, response, sensor) then photograph the same pitch as it, so that
    the condition's effect is measured on the same scenes (``bench_robustness.py --scenes``)."""
    from stillcap.files.atomic import write_text
    from stillcap.studio.pitch import pitch_capture
    from stillcap.studio.sensor import Sensor

    rng = np.random.default_rng([seed, index, sum(map(ord, scenes or condition))])
    cap_kw, sensor_kw, quality = CONDITIONS[condition]
    if cap_kw is None:
        cap_kw, sensor_kw, quality = _mixed(rng)
        # half of the captures a ball painted at random (its own stream: the other draws as before)
        if np.random.default_rng([seed, index, 8]).random() < 0.5:
            cap_kw = {k: v for k, v in cap_kw.items() if k != "ball_radius_m"} | {"ball": "painted"}
    preset = PRESETS[index % len(PRESETS)]
    if cap_kw.get("ball") is not None:  # the ball, declared in capture.json as a user gives their ball file
        cap_kw = {**cap_kw, "ball": _draw_ball(cap_kw["ball"], index, np.random.default_rng([seed, index, 7]))}
    pc = pitch_capture(preset, rng=rng, calibrate=False, image_size=size, sensor=Sensor(**sensor_kw), **cap_kw)
    cap, files = pc.to_capture(".jpg" if quality else ".png")
    folder = Path(tempfile.mkdtemp(dir=workdir))
    cap.save(folder, files, jpeg_quality=quality or 95)
    rig_path = folder / "rig.json"
    rig = json.loads(rig_path.read_text())
    responses = pc.truth.studio["camera_response"]
    for c in rig["cameras"]:
        c["response"] = responses[c["name"]]
    write_text(rig_path, json.dumps(rig))
    return pc, folder, (preset, cap_kw, sensor_kw, quality)


def run_capture(condition: str, index: int, seed: int, size: tuple, workdir: str, variants: dict | None = None,
                scenes: str | None = None) -> dict:
    """Render, analyse and evaluate one capture of ``condition`` (a process-pool task; ``scenes``:
    :func:`render_capture`'s, recorded in the row when given).

    ``variants``: name -> ``analyse_pitch`` keywords; the same photos are analysed again with
    each, and ``row["variants"][name]`` keeps their sigmas (``SIGMA_KEYS``), e.g. to split the
    variance of each quantity into its terms (``bench_spin_conditions.py --decompose``)."""
    from bench_pitch import evaluate

    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import analyse_pitch
    from stillcap.studio.compare.pitch import add_truth_comparison

    t = time.perf_counter()
    pc, folder, (preset, cap_kw, sensor_kw, quality) = render_capture(condition, index, seed, size, workdir, scenes)
    ball = cap_kw.get("ball")
    if ball is not None:
        cap_kw = {**cap_kw, "ball": {"name": ball.name, "description": ball.description,
                                     "radius_mm": 1e3 * ball.radius, "markers": len(ball.layout),
                                     "types": len(ball.layout.type_names)}}
    row = {"condition": condition, "index": index, "preset": preset, "capture_kw": cap_kw,
           "sensor_kw": {k: v for k, v in sensor_kw.items()}, "jpeg_quality": quality}
    if scenes is not None:
        row["scenes"] = scenes
    try:
        loaded = Capture.load(folder)
        # the radius declared: the ball file's (capture.json "ball") when the capture has one
        radius = None if ball is not None else pc.truth.studio["ball_radius_m"]
        res = analyse_pitch(loaded, ball_radius_m=radius, workers=1)
        add_truth_comparison(res, loaded.truth)
        row.update(evaluate(res, loaded.truth))
        if res.spin is not None:  # the marker-centroid noise the spin fit's residuals show (px)
            nz = float(getattr(res.spin, "noise_px", float("nan")))
            row["marker_noise_px"] = nz if np.isfinite(nz) else None
        if res.alias is not None:  # the alias chosen (what the per-capture alias lines print)
            row["alias_chosen_rpm"] = float(res.alias.best.spin_rpm)
            row["alias_left_out"] = list(getattr(res.alias, "left_out", []))
        checks = getattr(res, "self_checks", None) or []
        row["checks_failed"] = [c.name for c in checks if not c.passed]
        row["ok"] = True
        row["variants"] = {}
        for name, kw in (variants or {}).items():
            rv = analyse_pitch(loaded, ball_radius_m=radius, workers=1, **kw)
            add_truth_comparison(rv, loaded.truth)
            ev = evaluate(rv, loaded.truth)
            row["variants"][name] = {k: ev.get(k) for k in SIGMA_KEYS + VARIANT_KEYS}
    except ValueError as e:  # a capture the pipeline rejects counts as a failure of the condition
        row["ok"] = False
        row["error"] = str(e)
    finally:
        for f in folder.rglob("*"):
            if f.is_file():
                f.unlink()
    row["t_s"] = time.perf_counter() - t
    return row


def _mean_abs(rs, key):
    x = [abs(r[key]) for r in rs if r.get(key) is not None and np.isfinite(r[key])]
    return float(np.mean(x)) if x else float("nan")


def summarise(condition: str, rs: list) -> dict:
    """One condition's row: mean absolute errors, coverage fractions (+- binomial 1-sigma)."""
    ok = [r for r in rs if r.get("ok")]
    out = {"pipeline": "pitch", "condition": condition, "n": len(rs), "n_failed": len(rs) - len(ok)}
    for k in ("pos_mean_mm", "speed_mph", "dir_deg", "rate_rpm", "axis_deg"):
        out[k] = _mean_abs(ok, k)
    for k in COVERAGE_KEYS:
        xs = [float(r["coverage"][k]) for r in ok if k in r.get("coverage", {})]
        if k == "positions":  # a fraction per capture; weigh by ball images
            num = sum(float(r["coverage"][k]) * r.get("positions_n", 0) for r in ok if k in r.get("coverage", {}))
            n = sum(r.get("positions_n", 0) for r in ok if k in r.get("coverage", {}))
            out["cov_positions"], out["cov_positions_n"] = (num / n if n else float("nan")), n
        else:
            out[f"cov_{k}"] = float(np.mean(xs)) if xs else float("nan")
            out[f"cov_{k}_n"] = len(xs)
    # z = error / sigma (mean and spread over the captures): a mean off 0 is a shared bias the
    # intervals miss, a spread above 1 sigmas too small, below 1 too large
    # (spin: captures whose alias is right only; a wrong alias's z says nothing of the width)
    for key, err, sig, i in (("speed", "speed_mph", "speed_sigma_mph", None),
                             ("dir_h", "dir_err_hv_deg", "dir_sigma_hv_deg", 0),
                             ("dir_v", "dir_err_hv_deg", "dir_sigma_hv_deg", 1),
                             ("rate", "rate_rpm", "rate_sigma_rpm", None),
                             ("axis", "axis_deg", "axis_sigma_deg", None)):
        z = []
        for r in ok:
            if key in ("rate", "axis") and not alias_right(r):
                continue
            e, s = r.get(err), r.get(sig)
            if i is not None:
                e, s = (e[i], s[i]) if e is not None and s is not None else (None, None)
            if e is not None and s is not None and np.isfinite(e) and np.isfinite(s) and s > 0:
                # the axis: an angle over its per-component sigma, angle^2 / sigma^2 ~ chi2(2),
                # so z per component is the angle / (sqrt(2) sigma) (its RMS is 1 when calibrated)
                z.append(e / s / (np.sqrt(2.0) if key == "axis" else 1.0))
        out[f"z_{key}_mean"] = float(np.mean(z)) if z else float("nan")
        out[f"z_{key}_sd"] = float(np.std(z)) if z else float("nan")
        out[f"z_{key}_rms"] = float(np.sqrt(np.mean(np.square(z)))) if z else float("nan")
        out[f"z_{key}_n"] = len(z)
    # the spin alias: captures whose true rate is above a strobe's Nyquist limit, and how many of
    # them got a wrong alias (rate off by 100+ rpm or axis by 10+ deg: any wrong alias is)
    spun = [r for r in ok if r.get("spin_available") and r.get("rate_rpm") is not None]
    out["alias_n"] = sum(bool(r.get("aliased")) for r in spun)
    out["alias_wrong"] = sum(not r.get("alias_ok", True) for r in spun)
    out["checks_fired"] = float(np.mean([bool(r.get("checks_failed")) for r in ok])) if ok else float("nan")
    names = sorted({c for r in ok for c in r.get("checks_failed", [])})
    out["checks"] = {c: sum(c in r.get("checks_failed", []) for r in ok) for c in names}
    return out


def z_table(rows: list) -> tuple[list, list]:
    """Per condition, z = error / sigma of speed, of the direction (horizontal / vertical across
    the flight) and of the spin rate, mean +- spread over the captures, and of the spin axis
    (per component, RMS): the coverage with n = 6 moves by +-9 % per capture, these say more (a
    mean off 0: a shared bias the intervals miss; a spread or RMS above 1: sigmas too small,
    below 1: too large). Spin columns count captures whose alias is right only; the last row
    pools every condition (z RMS per quantity)."""
    def cell(r, key):
        m, s = r.get(f"z_{key}_mean"), r.get(f"z_{key}_sd")
        if m is None or s is None or not (np.isfinite(m) and np.isfinite(s)):
            return "-"
        return f"{m:+.2f} +- {s:.2f}"

    def rms(r, key):
        v = r.get(f"z_{key}_rms")
        return "-" if v is None or not np.isfinite(v) else f"{v:.2f}"
    head = ["condition", "n", "z speed", "z dir h", "z dir v", "z rate", "z axis rms"]
    body = [[r["condition"], str(r["n"]), cell(r, "speed"), cell(r, "dir_h"), cell(r, "dir_v"), cell(r, "rate"),
             rms(r, "axis")] for r in rows]
    pooled = ["pooled z RMS", str(sum(r["n"] for r in rows))]
    for key in ("speed", "dir_h", "dir_v", "rate", "axis"):
        num = sum(r.get(f"z_{key}_rms", np.nan) ** 2 * r.get(f"z_{key}_n", 0) for r in rows
                  if np.isfinite(r.get(f"z_{key}_rms", np.nan)))
        n = sum(r.get(f"z_{key}_n", 0) for r in rows if np.isfinite(r.get(f"z_{key}_rms", np.nan)))
        pooled.append(f"{np.sqrt(num / n):.2f}" if n else "-")
    return head, body + [pooled]


def alias_right(row: dict, max_rpm: float = 50.0) -> bool:
    """Whether a capture's spin rate is within ``max_rpm`` of the truth (its alias right; the
    wrong aliases of the benchmark are 180-800 rpm off)."""
    r = row.get("rate_rpm")
    return r is None or abs(r) < max_rpm


def run(conditions, n: int, seed: int, size, jobs: int, progress=None, variants: dict | None = None,
        done: list | None = None, on_row=None, scenes: str | None = None) -> list[dict]:
    """Every capture of every condition on ``jobs`` processes; rows per capture (``variants``,
    ``scenes``: :func:`run_capture`'s).

    ``done``: rows of an earlier run (e.g. read back from ``bench_robustness.py --jsonl``); the
    captures they hold (same condition, index, seed and photo size) are not run again and their
    rows are returned with the new ones. ``on_row(row)`` is called with each new row as it
    finishes (to append it to a file, so that a stopped run resumes)."""
    size = tuple(size)
    old = {(r["condition"], r["index"]): r for r in (done or [])
           if r.get("seed") == seed and tuple(r.get("size") or ()) == size and r["condition"] in conditions
           and r["index"] < n and r.get("scenes") == scenes}
    tasks = [(c, i) for c in conditions for i in range(n) if (c, i) not in old]
    rows = list(old.values())
    total = len(rows) + len(tasks)

    def add(row):
        row["seed"], row["size"] = seed, list(size)
        rows.append(row)
        if on_row is not None:
            on_row(row)
        if progress:
            progress(len(rows), total)
    with tempfile.TemporaryDirectory() as work:
        if jobs <= 1:
            for c, i in tasks:
                add(run_capture(c, i, seed, size, work, variants, scenes))
        else:
            with ProcessPoolExecutor(jobs) as ex:
                futs = [ex.submit(run_capture, c, i, seed, size, work, variants, scenes) for c, i in tasks]
                for f in futs:
                    add(f.result())
    order = {(c, i): k for k, (c, i) in enumerate((c, i) for c in conditions for i in range(n))}
    return sorted(rows, key=lambda r: order[(r["condition"], r["index"])])


def rows(quick: bool = False, n: int | None = None, seed: int = 0, jobs: int | None = None,
         progress=None, captures: list | None = None, conditions=None, done: list | None = None,
         on_row=None, scenes: str | None = None) -> list[dict]:
    """One dict per condition (``pipeline``, ``condition``, ``n``, the metric keys).

    quick: 1280x960 photos and 6 captures per condition (about 3 min on 2 cores); else
    2560x1920 and 40 per condition (about 30 min on 2 quiet cores). ``captures``, a list, gets
    the per-capture rows as well; ``conditions`` (names of ``CONDITIONS``) runs only those;
    ``done`` and ``on_row`` as :func:`run`'s (resuming a stopped run); ``scenes`` (a name of
    ``CONDITIONS``): every condition's captures drawn from that condition's scenes
    (:func:`render_capture`).
    Each row also has the z-scores' mean and spread (``z_speed_mean``, ``z_speed_sd``,
    ``z_dir_h_*``, ``z_dir_v_*``).
    """
    size = (1280, 960) if quick else (2560, 1920)
    n = n or (6 if quick else 40)
    jobs = jobs or min(2, os.cpu_count() or 1)
    conds = list(CONDITIONS) if conditions is None else list(conditions)
    unknown = [c for c in conds if c not in CONDITIONS]
    if scenes is not None and scenes not in CONDITIONS:
        unknown.append(scenes)
    if unknown:
        raise ValueError(f"unknown pitch conditions {unknown}; known: {list(CONDITIONS)}")
    per = run(conds, n, seed, size, jobs, progress, done=done, on_row=on_row, scenes=scenes)
    if captures is not None:
        captures.extend(per)
    return [summarise(c, [r for r in per if r["condition"] == c]) for c in conds]


def wrong_alias_lines(captures: list) -> list[str]:
    """One line per capture whose spin has a wrong alias: condition, index, preset, the chosen and
    the true rate, the axis error, and whether a self-check flagged it."""
    out = []
    for r in captures:
        if not r.get("ok") or r.get("rate_rpm") is None or r.get("alias_ok", True):
            continue
        true = r.get("true_rpm") or float("nan")
        chosen = r.get("alias_chosen_rpm", true + r["rate_rpm"])
        flagged = [c for c in r.get("checks_failed", []) if c in ("alias_margin", "spin_vs_flight")]
        out.append(f"{r['condition']} #{r['index']} ({r['preset']}): alias {chosen:.0f} rpm chosen, true {true:.0f} rpm, "
                   f"final rate off {r['rate_rpm']:+.0f} rpm, axis off {r['axis_deg']:.1f} deg; "
                   + (f"flagged ({', '.join(flagged)})" if flagged else "NOT flagged")
                   + (f"; left out {', '.join(r['alias_left_out'])}" if r.get("alias_left_out") else ""))
    return out
