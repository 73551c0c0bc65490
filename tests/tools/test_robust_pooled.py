"""bench_robustness.py's pitch table ends with a pooled row: the figures over every capture of
every condition run (coverage weighted by captures, positions by ball images, wrong aliases summed).
The benchmark runs as its own process on rows it holds already (``--jsonl``: nothing is rendered)."""

import json
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_robustness.py"
SRC = Path(__file__).resolve().parents[2] / "src"


def _row(condition, index, covered, positions, positions_n, rate_rpm=0.5, alias_ok=True):
    return {"condition": condition, "index": index, "seed": 0, "size": [1280, 960], "ok": True,
            "pos_mean_mm": 1.0, "speed_mph": 0.01, "dir_deg": 0.01, "rate_rpm": rate_rpm, "axis_deg": 0.1,
            "coverage": {"positions": positions, "speed": covered, "direction": covered,
                         "spin_rate": covered, "spin_axis": True},
            "positions_n": positions_n, "preset": "seed-4seam", "true_rpm": 2300.0, "spin_available": True, "aliased": True, "alias_ok": alias_ok,
            "checks_failed": []}


def _table_row(out: str, name: str) -> list[str]:
    lines = [ln for ln in out.splitlines() if ln.startswith(f"| {name}")]
    assert len(lines) == 1, out
    return [c.strip() for c in lines[0].strip("|").split("|")]


def test_the_pooled_row_weighs_captures_and_ball_images(tmp_path):
    rows = [_row("clean", 0, True, 1.0, 10), _row("clean", 1, True, 1.0, 30),
            _row("JPEG 70", 0, False, 0.5, 20), _row("JPEG 70", 1, True, 0.0, 40, rate_rpm=400, alias_ok=False)]
    jsonl = tmp_path / "rows.jsonl"
    jsonl.write_text("".join(json.dumps(r) + "\n" for r in rows))
    r = subprocess.run([sys.executable, str(BENCH), "--quick", "--n", "2", "--only", "pitch", "--jobs", "1",
                        "--conditions", "clean,JPEG 70", "--jsonl", str(jsonl), "--markdown"],
                       capture_output=True, text=True, timeout=600, env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    clean, jpeg = _table_row(r.stdout, "clean"), _table_row(r.stdout, "JPEG 70")
    pooled = _table_row(r.stdout, "pooled (2 conditions)")
    assert (clean[1], jpeg[1], pooled[1]) == ("2", "2", "4")
    # positions: (10 + 30 + 0.5 * 20 + 0) / 100 ball images = 50 %; speed: 3 of 4 captures covered
    assert pooled[7] == "50!" and pooled[8] == "75!"
    assert clean[8] == "100!" and jpeg[8] == "50!"
    assert pooled[12] == "1/4!"  # the wrong alias of JPEG 70 #1, over the 4 captures spinning past Nyquist
