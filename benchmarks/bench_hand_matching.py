"""Hand marker matching end to end (issue 12, the hand goal): how many markers seen by two or more
cameras get a label, and how many of the labels are right, from rendered photos.

    python benchmarks/bench_hand_matching.py [--persons 1 2 3 5 6 7 8] [--models built-in own]
        [--size 1280x960] [--captures DIR] [--jsonl FILE] [--causes]

Per person ``p``: the studio throw ``hand_capture(p, person=another_hand(p))`` (as
``stillcap studio hand --person p --seed p``; the capture of ``tests/test_cli_hand_files.py`` is
person 6), written as JPEG (quality 92) with the true rig, then ``analyse_hand`` with the
built-in hand model (``built-in``) and with the hand's own model and marker set (``own``, as
``--hand-model`` / ``--markers`` give it). ``--captures DIR`` keeps the rendered captures there
and reuses them (so two versions of the code can be compared on the same photos).

Columns (against the studio's truth, ``stillcap.studio.compare.hand``):
- ``seen2``: (flash, marker) pairs whose marker the truth shows in 2+ cameras (``markers_visible``:
  the centre unhidden), over the matched flashes;
- ``labelled %``: of those, the share with a right label (hidden or not); this is the goal's
  figure (>= 95 %);
- ``whole %`` and ``hidden %``: ``compare_with_truth``'s ``markers_recovered_pct`` and
  ``markers_recovered_partly_hidden_pct``: right labels on fully seen / partly hidden points over
  ``seen2`` (``bench_hand_calibration.py``'s "seen2 lab %" column is ``whole %`` alone, which is
  why it reads lower than the end-to-end figure);
- ``labels``, ``right %``: labels given and the share right (goal >= 99.5 %);
- ``RMS mm``: fully seen right-labelled markers to the truth (goal <= 1 mm); ``hidden RMS``: the
  partly hidden ones (their centroids shift; scored apart);
- ``joints``: joint-angle RMS on the degrees of freedom the whole seen markers fix (deg);
  ``hidden joints``: on those that only a partly hidden marker fixes (scored apart);
- ``posed``: flashes with a pose.

The times were not measured: the machine was loaded when this was written.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from stillcap.pipelines.hand import HandOptions, analyse_hand
from stillcap.studio.compare.hand import (
    LABEL_TOLERANCE_M,
    compare_with_capture,
    truth_arrays,
)
from stillcap.studio.hand import hand_capture
from stillcap.studio.hand_variation import another_hand

from _hand_causes import causes, print_table  # (run from benchmarks/, as the other scripts import theirs)


def capture_of(p: int, size, root: Path) -> Path:
    """The rendered throw of person ``p`` in ``root`` (rendered once)."""
    folder = root / f"person{p}-{size[0]}x{size[1]}"
    if not (folder / "truth.json").exists():
        v = another_hand(p)
        cap, images = hand_capture(p, image_size=size, person=v).to_capture(".jpg")
        cap.save(folder, images, jpeg_quality=92)
        v.skeleton.save(folder / "my_hand.json", length_unit="mm")
        v.markerset.save(folder / "my_markers.json", length_unit="mm")
    return folder


def seen_twice_labelled(result, truth: dict, match) -> tuple[int, int]:
    """``(seen2, labelled)``: (flash, marker) pairs the truth shows in 2+ cameras, and of those the
    ones with a right label (the nearest true marker of that flash, within the tolerance)."""
    tr = truth_arrays(truth)
    lab = result.labels
    seen2 = tr["visible"].sum(axis=0) >= 2  # (n_true_flashes, n_markers)
    n_seen = n_lab = 0
    for k, j in enumerate(match):
        if j < 0:
            continue
        n_seen += int(seen2[j].sum())
        for m in np.flatnonzero(seen2[j]):
            if lab.point_index[k, m] < 0:
                continue
            d = np.linalg.norm(tr["markers"][j] - lab.positions[k, m], axis=1)
            n_lab += int(int(np.nanargmin(d)) == m and d[m] <= LABEL_TOLERANCE_M)
    return n_seen, n_lab


def run(p: int, model: str, size, root: Path, with_causes: bool = False) -> dict:
    folder = capture_of(p, size, root)
    opts = (HandOptions(hand_model=folder / "my_hand.json", hand_markers=folder / "my_markers.json")
            if model == "own" else HandOptions())
    r = analyse_hand(folder, opts)
    c = compare_with_capture(r)
    truth = json.loads((folder / "truth.json").read_text())
    n_seen, n_lab = seen_twice_labelled(r, truth, c["flash_match"])
    extra = {"causes": dict(causes(r, truth, c["flash_match"]))} if with_causes else {}
    return {**extra, "person": p, "model": model, "seen2": n_seen, "labelled_pct": 100.0 * n_lab / n_seen if n_seen else None,
            "whole_pct": c["markers_recovered_pct"], "hidden_pct": c["markers_recovered_partly_hidden_pct"],
            "labels": c["labels"], "right_pct": c["labels_right_pct"], "rms_mm": c["marker_rms_mm"],
            "hidden_rms_mm": c["partly_hidden_rms_mm"],
            "joints_deg": c["joint_angle_rms_deg"],
            "hidden_joints_deg": c["joint_angle_rms_partly_hidden_deg"], "posed": int(r.labels.reconstructed.sum())}


def _f(v, nd=1):
    return "-" if v is None else f"{v:.{nd}f}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--persons", type=int, nargs="+", default=[1, 2, 3, 5, 6, 7, 8])
    ap.add_argument("--models", nargs="+", default=["built-in", "own"], choices=["built-in", "own"])
    ap.add_argument("--size", default="1280x960")
    ap.add_argument("--captures", type=Path, default=None, help="keep and reuse the rendered captures here")
    ap.add_argument("--jsonl", type=Path, default=None, help="append one row per run")
    ap.add_argument("--causes", action="store_true",
                    help="also count why markers seen twice got no right label, per cause (_hand_causes.py)")
    a = ap.parse_args(argv)
    size = tuple(int(v) for v in a.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        root = a.captures or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        rows = []
        print(f"{'person':>6} {'model':>8} {'seen2':>5} {'labelled %':>10} {'whole %':>7} {'hidden %':>8} "
              f"{'labels':>6} {'right %':>7} {'RMS mm':>6} {'hidden RMS':>10} {'joints':>6} {'hidden joints':>13} {'posed':>5}")
        for model in a.models:
            for p in a.persons:
                row = run(p, model, size, root, a.causes)
                rows.append(row)
                print(f"{p:>6} {model:>8} {row['seen2']:>5} {_f(row['labelled_pct']):>10} {_f(row['whole_pct']):>7} "
                      f"{_f(row['hidden_pct']):>8} {row['labels']:>6} {_f(row['right_pct'], 2):>7} "
                      f"{_f(row['rms_mm'], 3):>6} {_f(row['hidden_rms_mm'], 2):>10} {_f(row['joints_deg'], 2):>6} {_f(row['hidden_joints_deg'], 2):>13} {row['posed']:>5}", flush=True)
                if a.jsonl:
                    with open(a.jsonl, "a") as fh:
                        fh.write(json.dumps(row) + "\n")
        for model in a.models:
            sel = [r for r in rows if r["model"] == model]
            seen = sum(r["seen2"] for r in sel)
            lab = sum(r["labelled_pct"] * r["seen2"] / 100 for r in sel if r["labelled_pct"] is not None)
            given = sum(r["labels"] for r in sel)
            right = sum(r["right_pct"] * r["labels"] / 100 for r in sel if r["right_pct"] is not None)
            print(f"{'all':>6} {model:>8} {seen:>5} {_f(100 * lab / seen if seen else None):>10} {'':>7} {'':>8} "
                  f"{given:>6} {_f(100 * right / given if given else None, 2):>7}")
        if a.causes:
            for model in a.models:
                print(f"\nwhy markers seen twice have no right label ({model} model; every truth flash):")
                print_table({str(r["person"]): Counter(r["causes"]) for r in rows if r["model"] == model})


if __name__ == "__main__":
    main()
