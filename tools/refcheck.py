"""Reference dump for refactors: render a kept set of studio captures, analyse them through the
CLI, and compare two dumps number by number.

It drives only the ``stillcap`` command, so it survives any internal renaming: a refactor that
keeps behaviour gives the same dump.

    python tools/refcheck.py render KEPT            # once, with the code before the change
    python tools/refcheck.py renders OUT_BEFORE     # fresh renders of the kept set, hashed
    python tools/refcheck.py dump KEPT OUT_BEFORE   # analyses of the kept captures
    ... change the code ...
    python tools/refcheck.py renders OUT_AFTER; python tools/refcheck.py dump KEPT OUT_AFTER
    python tools/refcheck.py compare OUT_BEFORE OUT_AFTER   # exit 1 on any difference

``renders``/``dump`` take an optional name prefix to run a part. ``compare`` checks the records
the second folder has. Numbers compare within 1e-12 (relative to max(1, |a|)); text and file hashes exactly (rendered
JSON files by their numbers). Renders run on one thread (see ONE_THREAD). Keys that
hold wall-clock times are left out.
"""

from __future__ import annotations

import glob
import hashlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

STILLCAP = [sys.executable, "-m", "stillcap"]
TOL = 1e-12
#: Keys whose values are wall-clock measurements or machine paths, not results.
SKIP_KEY = re.compile(r"(timing|time_s|_seconds|elapsed|wall|duration_s|^seconds$|^path$|folder|capture_dir|created|modified)", re.I)

#: (name, studio arguments) of the kept captures.
RENDERS = [
    ("pitch-4seam-0", ["pitch", "--seed", "0", "--preset", "seed-4seam"]),
    ("pitch-curve-1", ["pitch", "--seed", "1", "--preset", "seed-curveball"]),
    ("pitch-mlb-2", ["pitch", "--seed", "2", "--preset", "mlb-4seam", "--model", "nathan"]),
    ("hand-0", ["hand", "--seed", "0"]),
    ("puppet16-0", ["puppet", "--seed", "0"]),
    ("puppet20-1", ["puppet", "--seed", "1", "--markers", "puppet-20"]),
    ("markers-0", ["markers", "--seed", "0"]),
    ("markers-1", ["markers", "--seed", "1", "--jpeg", "90"]),
    ("chessboard-0", ["chessboard", "--seed", "0"]),
]

#: (name, command with {K} for the kept folder and {O} for the output folder, files to keep).
ANALYSES = [
    ("pitch-4seam", "pitch {K}/pitch-4seam-0 --json --csv {O}/pitch-4seam.csv", ["pitch-4seam.csv"]),
    ("pitch-curve", "pitch {K}/pitch-curve-1 --json --spin seed --physics nathan", []),
    ("pitch-mlb", "pitch {K}/pitch-mlb-2 --json --physics nathan --fit powell", []),
    ("pitch-session", "pitch {K}/pitch-4seam-0 {K}/pitch-curve-1 {K}/pitch-mlb-2 --json", []),
    ("hand", "hand {K}/hand-0 --json --export {O}/hand.bvh --export {O}/hand.csv", ["hand.bvh", "hand.csv"]),
    ("puppet16", "puppet run {K}/puppet16-0 --json --out {O}/puppet16", ["puppet16/result.json"]),
    ("puppet16-thesis", "puppet run {K}/puppet16-0 --json --detector thesis --identify thesis", []),
    ("puppet20", "puppet run {K}/puppet20-1 --json", []),
    ("puppet-export", "export {O}/puppet16/result.json --to {O}/pose.bvh --to {O}/pose.csv", ["pose.bvh", "pose.csv"]),
    ("markers-0", "markers {K}/markers-0 --json", []),
    ("markers-1", "markers {K}/markers-1 --json", []),
    ("intrinsics", "calibrate intrinsics {K}/chessboard-0/images/*.png --pattern 9x6 --json", []),
    ("demo-rig", "demo rig --out {O}/demo-rig", []),
]


#: One thread for OpenCV and BLAS: the studio's calibration of a rendered rig is then the same,
#: digit for digit, from run to run (with threads it varies in the last digits).
ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "OPENCV_FOR_THREADS_NUM": "1"}


def _run(args: list[str], log: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, COLUMNS="200", NO_COLOR="1", TERM="dumb", **(env or {}))
    p = subprocess.run(STILLCAP + args, capture_output=True, text=True, env=env)
    log.write_text(f"$ stillcap {' '.join(args)}\nexit {p.returncode}\n--- stderr\n{p.stderr}")
    return p


def render(kept: Path) -> None:
    kept.mkdir(parents=True, exist_ok=True)
    for name, args in RENDERS:
        if (kept / name).exists():
            continue
        p = _run(["studio", *args, "--out", str(kept / name)], kept / f"{name}.log")
        print(f"render {name}: exit {p.returncode}", flush=True)


def _hash_tree(folder: Path) -> dict:
    """Every file's SHA-256, but JSON files' contents (numbers compared within the tolerance)."""
    return {str(f.relative_to(folder)): json.loads(f.read_text()) if f.suffix == ".json"
            else hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(folder.rglob("*")) if f.is_file()}


def renders(out: Path, only: str | None = None) -> None:
    """Render the kept set afresh and record the hash of every file written."""
    out.mkdir(parents=True, exist_ok=True)
    folder = out / "renders"
    for name, args in RENDERS:
        if only and not name.startswith(only):
            continue
        shutil.rmtree(folder / name, ignore_errors=True)
        p = _run(["studio", *args, "--out", str(folder / name)], out / f"render-{name}.log", ONE_THREAD)
        (out / f"render-{name}.json").write_text(json.dumps({"exit": p.returncode, "files": _hash_tree(folder / name)}, indent=1))
        print(f"render {name}: exit {p.returncode}", flush=True)
    shutil.rmtree(folder, ignore_errors=True)


def dump(kept: Path, out: Path, only: str | None = None) -> None:
    """Analyse the kept captures through the CLI; record stdout and the files named."""
    out.mkdir(parents=True, exist_ok=True)
    for name, cmd, files in ANALYSES:
        if only and not name.startswith(only):
            continue
        args = []
        for a in cmd.format(K=kept, O=out).split():
            args += sorted(glob.glob(a)) if "*" in a else [a]
        p = _run(args, out / f"{name}.log")
        record = {"exit": p.returncode, "stdout": _parse(p.stdout.replace(str(out), "{O}"))}
        for f in files:
            path = out / f
            text = path.read_text().replace(str(out), "{O}") if path.exists() else None
            record[f] = json.loads(text) if text and f.endswith(".json") else text
        (out / f"{name}.json").write_text(json.dumps(record, indent=1, default=str))
        print(f"{name}: exit {p.returncode}", flush=True)


def _parse(text: str):
    """JSON output (after any lines the command printed first), else the text."""
    text = "\n".join(line for line in text.splitlines() if not line.startswith("time:"))  # wall-clock lines
    found = re.search(r"^[\[{]", text, re.M)
    start = found.start() if found else -1
    try:
        return {"before_json": text[:start], "json": json.loads(text[start:])} if start >= 0 else text
    except ValueError:
        return text


def _text_numbers(a: str, b: str, where: str, out: list[str]) -> None:
    """Compare two texts token by token: numbers within TOL, everything else exactly."""
    ta, tb = re.split(r"([-+0-9.eE]+)", a), re.split(r"([-+0-9.eE]+)", b)
    if len(ta) != len(tb):
        out.append(f"{where}: texts differ in shape")
        return
    for x, y in zip(ta, tb):
        if x == y:
            continue
        try:
            fx, fy = float(x), float(y)
        except ValueError:
            out.append(f"{where}: {x[:60]!r} != {y[:60]!r}")
            return
        if not _close(fx, fy):
            out.append(f"{where}: {fx!r} != {fy!r}")
            return


def _close(a: float, b: float) -> bool:
    if math.isnan(a) and math.isnan(b):
        return True
    return a == b or abs(a - b) <= TOL * max(1.0, abs(a), abs(b))


def _compare(a, b, where: str, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if SKIP_KEY.search(str(k)):
                continue
            if k not in a or k not in b:
                out.append(f"{where}.{k}: only in {'after' if k not in a else 'before'}")
                continue
            _compare(a[k], b[k], f"{where}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{where}: length {len(a)} != {len(b)}")
            return
        for i, (x, y) in enumerate(zip(a, b)):
            _compare(x, y, f"{where}[{i}]", out)
    elif isinstance(a, bool) or isinstance(b, bool) or a is None or b is None:
        if a != b:
            out.append(f"{where}: {a!r} != {b!r}")
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if not _close(float(a), float(b)):
            out.append(f"{where}: {a!r} != {b!r}")
    elif isinstance(a, str) and isinstance(b, str):
        if a != b:
            _text_numbers(a, b, where, out)
    elif a != b:
        out.append(f"{where}: {type(a).__name__} {a!r:.60} != {type(b).__name__} {b!r:.60}")


def compare(before: Path, after: Path) -> int:
    problems: list[str] = []
    names = sorted(p.name for p in after.glob("*.json") if not p.name.startswith("."))  # not the outputs manifest
    for name in names:
        if not (before / name).exists():
            problems.append(f"{name}: missing before")
            continue
        _compare(json.loads((before / name).read_text()), json.loads((after / name).read_text()), name, problems)
    for p in problems[:200]:
        print(p)
    print(f"{len(names)} records compared, {len(problems)} differences")
    return 1 if problems else 0


if __name__ == "__main__":
    verb = sys.argv[1] if len(sys.argv) > 1 else ""
    if verb == "render" and len(sys.argv) == 3:
        render(Path(sys.argv[2]).resolve())
    elif verb == "renders" and len(sys.argv) in (3, 4):
        renders(Path(sys.argv[2]).resolve(), sys.argv[3] if len(sys.argv) == 4 else None)
    elif verb == "dump" and len(sys.argv) in (4, 5):
        dump(Path(sys.argv[2]).resolve(), Path(sys.argv[3]).resolve(), sys.argv[4] if len(sys.argv) == 5 else None)
    elif verb == "compare" and len(sys.argv) == 4:
        sys.exit(compare(Path(sys.argv[2]), Path(sys.argv[3])))
    else:
        sys.exit(__doc__)
