"""Robustness: accuracy and 95 % interval coverage per photographic condition, per pipeline.

    python benchmarks/bench_robustness.py [--quick] [--n N] [--seed S] [--jobs J] [--markdown]
                                          [--jsonl FILE] [--conditions "clean,blur 1.5 px"] [--scenes NAME]

Each condition varies one thing the photos of a real lab vary (light placement, lens blur,
sensor noise, white balance, JPEG quality, camera response, ball radius, a room lit by the
flashes), "everything varied" all of them at once (half of its captures with a ball painted at
random, from a stream of its own); two more vary the ball: "ball painted at
random" (each capture its own ball, ``stillcap.studio.ball_variation.painted_ball``) and
"built-in and repainted balls" (the five balls of ``bench_ball_layouts.py`` in turn), each
declared by its ball file in capture.json. The pitch part is ``_robust_pitch.py``; the puppet
and hand parts are ``_robust_puppet.py`` and ``_robust_hand.py`` when present (same
``rows(quick)`` signature), otherwise "not available" is printed.

The pitch table's "wrong alias" column counts, per condition, the captures whose spin has a
wrong alias (rate off by 100+ rpm or axis by 10+ deg) over those spinning faster than a strobe's
Nyquist limit; each such capture is then listed with the alias chosen, the true rate and whether
a self-check flagged it.

``--jsonl FILE`` appends each pitch capture's row to FILE as it finishes, and a run started
again with the same file (and the same ``--seed``, ``--quick`` or not) runs only the captures it
does not hold yet: a long run can be stopped and resumed. ``--conditions`` runs only the named
pitch conditions. ``--scenes NAME`` draws every condition's captures from condition NAME's
scenes (pitch, release, ball; the photos keep each condition's own settings): ``--conditions
"clean,JPEG 70,JPEG 98" --scenes clean`` compares PNG and JPEG on the same pitches, where the
conditions' own draws differ by scene as well (``docs/pitch.md``, "JPEG photos' position
intervals"). Rows of such a run record ``scenes`` and resume only with the same ``--scenes``.

Coverage is a binomial proportion: with ``n`` captures and a true coverage of 95 % its 1-sigma is
``sqrt(0.95 x 0.05 / n)`` (3.4 % at n = 40, 8.9 % at n = 6); the table prints it beside each
figure. Positions are counted per ball image (about 20-25 per capture), so their figure is
tighter but correlated within a capture. With more than one condition, the pitch table ends with
a "pooled" row: the same figures over every capture run (coverage weighted by captures, positions
by ball images; wrong aliases summed), whose coverage moves far less than a condition's.

Timing: the full run (2560x1920, 40 captures per condition, 18 conditions) takes about 30 min on
2 quiet cores; ``--quick`` (1280x960, 6 per condition) about 3 min. Timings measured while the
machine is shared are longer; run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

GOAL_TEXT = {"pos_mean_mm": "<= 2 mm", "speed_mph": "<= 0.1 mph", "dir_deg": "<= 0.2 deg",
             "rate_rpm": "<= 3 rpm", "axis_deg": "<= 0.5 deg", "coverage": "90-98 %"}
PITCH_COLUMNS = [("pos_mean_mm", "pos mm", 2.0), ("speed_mph", "speed mph", 0.1), ("dir_deg", "dir deg", 0.2),
                 ("rate_rpm", "rate rpm", 3.0), ("axis_deg", "axis deg", 0.5)]
COV_COLUMNS = [("cov_positions", "cov pos"), ("cov_speed", "cov speed"), ("cov_direction", "cov dir"),
               ("cov_spin_rate", "cov rate"), ("cov_spin_axis", "cov axis")]


def _fmt(v, digits=2):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}"


def _cov(row, key):
    v = row.get(key)
    n = row.get(f"{key}_n", row.get("n", 0))
    if v is None or not math.isfinite(v):
        return "-"
    mark = "" if 0.90 <= v <= 0.98 else "!"
    return f"{100 * v:.0f}{mark}"


def pitch_table(rows: list, pooled: dict | None = None) -> tuple[list, list]:
    """The pitch table: a row per condition, then ``pooled`` (the same figures over every capture
    of every condition run, ``_robust_pitch.summarise``) if given, then the goals."""
    head = (["condition", "n"] + [h for _, h, _ in PITCH_COLUMNS] + [h for _, h in COV_COLUMNS]
            + ["wrong alias", "checks fired"])
    body = []
    for r in rows + ([pooled] if pooled is not None else []):
        cells = [r["condition"], f"{r['n']}" + (f" ({r['n_failed']} failed)" if r.get("n_failed") else "")]
        for k, _, goal in PITCH_COLUMNS:
            v = r.get(k)
            cells.append(_fmt(v, 3 if k in ("speed_mph", "dir_deg") else 2)
                         + ("!" if v is not None and math.isfinite(v) and v > goal else ""))
        cells += [_cov(r, k) for k, _ in COV_COLUMNS]
        # captures with a wrong spin alias / captures spinning above a strobe's Nyquist limit
        cells.append(f"{r['alias_wrong']}/{r['alias_n']}" + ("!" if r["alias_wrong"] else "")
                     if r.get("alias_n") is not None else "-")
        fired = r.get("checks_fired")
        cells.append("-" if fired is None or not math.isfinite(fired) else f"{100 * fired:.0f} %")
        body.append(cells)
    body.append(["goal", ""] + [GOAL_TEXT[k] for k, _, _ in PITCH_COLUMNS] + ["90-98"] * len(COV_COLUMNS) + ["0", ""])
    return head, body


def generic_table(rows: list) -> tuple[list, list]:
    keys = []
    for r in rows:
        for k in r:
            if k not in keys and k not in ("pipeline",):
                keys.append(k)
    body = [[_fmt(r.get(k)) if isinstance(r.get(k), float) else str(r.get(k, "-")) for k in keys] for r in rows]
    return keys, body


def print_text(title, head, body):
    widths = [max(len(str(x)) for x in col) for col in zip(head, *body)]
    print(f"\n{title}")
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)))
    for b in body:
        print("  ".join(str(x).ljust(w) for x, w in zip(b, widths)))


def print_markdown(title, head, body):
    print(f"\n### {title}\n")
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---" for _ in head) + "|")
    for b in body:
        print("| " + " | ".join(str(x) for x in b) + " |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1280x960 photos, 6 captures per condition (~3 min)")
    ap.add_argument("--n", type=int, default=None, help="captures per condition (default 40, quick 6)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default 2)")
    ap.add_argument("--markdown", action="store_true", help="print markdown tables as well")
    ap.add_argument("--jsonl", type=Path, default=None,
                    help="append every pitch capture's row to this file; a run with the same file resumes")
    ap.add_argument("--conditions", default=None, help="pitch conditions to run (comma-separated names)")
    ap.add_argument("--only", default="pitch,puppet,hand", help="pipelines to run (comma-separated)")
    ap.add_argument("--scenes", default=None,
                    help="pitch: draw every condition's captures from this condition's scenes (e.g. clean)")
    args = ap.parse_args(argv)
    wanted = [w.strip() for w in args.only.split(",") if w.strip()]
    tables = []
    for name in ("pitch", "puppet", "hand"):
        if name not in wanted:
            continue
        try:
            mod = importlib.import_module(f"_robust_{name}")
        except ImportError:
            print(f"\n{name}: not available (benchmarks/_robust_{name}.py is missing)")
            continue
        if name == "pitch":
            captures: list = []

            def prog(done, total):
                print(f"\r  pitch: {done}/{total} captures", end="", file=sys.stderr, flush=True)
            done, on_row = None, None
            if args.jsonl is not None:
                if args.jsonl.exists():
                    done = [json.loads(line) for line in args.jsonl.read_text().splitlines() if line.strip()]

                def on_row(row, path=args.jsonl):
                    with open(path, "a") as f:
                        f.write(json.dumps(row, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)) + "\n")
            conds = None if args.conditions is None else [c.strip() for c in args.conditions.split(",") if c.strip()]
            try:
                rs = mod.rows(args.quick, n=args.n, seed=args.seed, jobs=args.jobs, progress=prog, captures=captures,
                              conditions=conds, done=done, on_row=on_row, scenes=args.scenes)
            except ValueError as e:
                ap.error(str(e))
            print(file=sys.stderr)
            # the coverage over every capture run: a condition's n = 12 moves it by +-6 % a capture,
            # the pooled figure (weighted by captures; positions by ball images) by far less
            pooled = mod.summarise(f"pooled ({len(rs)} conditions)", captures) if len(rs) > 1 else None
            head, body = pitch_table(rs, pooled)
            n = rs[0]["n"] if rs else 0
            title = (f"pitch: mean absolute errors and 95 % interval coverage (%), n = {n} captures per condition "
                     f"(coverage 1-sigma at 95 %: +-{100 * math.sqrt(0.95 * 0.05 / max(n, 1)):.1f} %); "
                     "! = outside the goal")
            checks = {r["condition"]: r.get("checks") for r in rs if r.get("checks")}
        else:
            rs = mod.rows(args.quick)
            head, body = generic_table(rs)
            title, checks = f"{name}", {}
        print_text(title, head, body)
        if name == "pitch" and hasattr(mod, "z_table"):  # the intervals' calibration beside the coverage
            print_text("pitch: z = error / sigma, mean +- spread over the captures (axis: RMS per component; "
                       "spin: right aliases only; last row: every condition pooled)", *mod.z_table(rs))
        if name == "pitch" and hasattr(mod, "wrong_alias_lines"):  # per capture: the alias chosen
            lines = mod.wrong_alias_lines(captures)
            print("pitch: captures with a wrong spin alias: " + ("none" if not lines else ""))
            for line in lines:
                print(f"  {line}")
        if checks:
            print("self-checks that failed (captures per condition): "
                  + "; ".join(f"{c}: {', '.join(f'{k} {v}' for k, v in d.items())}" for c, d in checks.items()))
        tables.append((title, head, body))
    if args.markdown:
        for t in tables:
            print_markdown(*t)


if __name__ == "__main__":
    main()
