"""benchmarks/_robust_pitch.run resumes a stopped run from its rows (bench_robustness.py --jsonl)."""

import json
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture
def rp(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCH))
    import _robust_pitch

    calls = []

    def fake(condition, index, seed, size, workdir, variants=None, scenes=None):  # no rendering: records the call
        calls.append((condition, index))
        row = {"condition": condition, "index": index, "ok": False, "error": "fake"}
        return row if scenes is None else {**row, "scenes": scenes}

    monkeypatch.setattr(_robust_pitch, "run_capture", fake)
    _robust_pitch.calls = calls
    yield _robust_pitch
    sys.modules.pop("_robust_pitch", None)


def test_run_skips_the_captures_it_holds_and_keeps_their_rows(rp, tmp_path):
    conds = ["clean", "blur 1.5 px"]
    written = tmp_path / "rows.jsonl"

    def on_row(row):
        with open(written, "a") as f:
            f.write(json.dumps(row) + "\n")
    first = rp.run(conds[:1], 2, 0, (64, 48), 1, on_row=on_row)
    assert rp.calls == [("clean", 0), ("clean", 1)]
    assert [(r["condition"], r["index"]) for r in first] == rp.calls
    done = [json.loads(line) for line in written.read_text().splitlines()]
    assert len(done) == 2 and all(r["seed"] == 0 and r["size"] == [64, 48] for r in done)
    rp.calls.clear()
    rows = rp.run(conds, 3, 0, (64, 48), 1, done=done, on_row=on_row)
    # only the captures not held are run; every capture's row comes back, in condition order
    assert rp.calls == [("clean", 2), ("blur 1.5 px", 0), ("blur 1.5 px", 1), ("blur 1.5 px", 2)]
    assert [(r["condition"], r["index"]) for r in rows] == [(c, i) for c in conds for i in range(3)]
    assert len(written.read_text().splitlines()) == 6


def test_rows_of_another_seed_or_photo_size_are_run_again(rp):
    done = [{"condition": "clean", "index": 0, "seed": 1, "size": [64, 48]},
            {"condition": "clean", "index": 1, "seed": 0, "size": [128, 96]},
            {"condition": "clean", "index": 2}]  # an old row without seed and size
    rows = rp.run(["clean"], 3, 0, (64, 48), 1, done=done)
    assert rp.calls == [("clean", 0), ("clean", 1), ("clean", 2)]
    assert all(r.get("error") == "fake" for r in rows)


def test_rows_of_other_scenes_are_run_again(rp):
    """A run drawn from another condition's scenes (``scenes``) is other pitches: its rows and a
    plain run's are not taken for each other."""
    plain = rp.run(["JPEG 70"], 2, 0, (64, 48), 1)
    rp.calls.clear()
    same = rp.run(["JPEG 70"], 2, 0, (64, 48), 1, done=plain, scenes="clean")
    assert rp.calls == [("JPEG 70", 0), ("JPEG 70", 1)] and all(r["scenes"] == "clean" for r in same)
    rp.calls.clear()
    assert rp.run(["JPEG 70"], 2, 0, (64, 48), 1, done=plain + same, scenes="clean") == same
    assert rp.calls == []
