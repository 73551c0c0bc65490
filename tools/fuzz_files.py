"""A longer campaign of the property tests of tests/test_*_validation.py and tests/test_cli_bad_files.py:
arbitrary JSON and mutations of a valid file of every format (skeleton, marker set, puppet result,
label overrides, palette, marker-ball palette, project.json, JumpingJack XML), read by the library
and by the commands that read them. Prints the count per format and outcome:

- ``ok``: the file loaded (the command exited 0);
- ``refused``: ``ValueError`` in one line naming the file (the command exited 2 with one line);
- ``FAILED``: anything else (another exception, a message over several lines or naming no file);
  the first few are printed, and the exit status is 1.

Usage::

    PYTHONPATH=src python tools/fuzz_files.py --examples 2000 [--cli] [--formats skeleton,result]

capture.json and rig.json (and a project's turntable camera) are another part's formats.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from hypothesis import HealthCheck, given, settings  # noqa: E402

import fuzzing  # noqa: E402

counts: collections.Counter = collections.Counter()
failures: list[str] = []


def record(fmt: str, fn) -> None:
    try:
        counts[fmt, fn()] += 1
    except Exception as e:  # the campaign records every failure instead of stopping at the first
        counts[fmt, "FAILED"] += 1
        if len(failures) < 20:
            failures.append(f"{fmt}: {type(e).__name__}: {str(e)[:300]}")


def campaign(name: str, strategy, body, n: int) -> None:
    @settings(max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(strategy)
    def run(x):
        record(name, lambda: body(x))

    t = time.perf_counter()
    run()
    print(f"  {name}: {sum(v for (f, _), v in counts.items() if f == name)} cases in {time.perf_counter() - t:.0f} s",
          file=sys.stderr)


def cli(args) -> str:
    """Run a command in-process; ``"ok"`` for exit 0, ``"refused"`` for exit 2 with one line."""
    from stillcap.cli import main

    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):  # rich writes to sys.stderr as it is
        try:
            main([str(a) for a in args])
        except SystemExit as e:
            code = e.code
    text = err.getvalue().strip()
    if code == 0:
        return "ok"
    if code == 2 and len(text.splitlines()) == 1:
        return "refused"
    raise AssertionError(f"exit {code}: {text[:300]!r}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--examples", type=int, default=1000, help="Cases per format (and per command with --cli).")
    ap.add_argument("--cli", action="store_true", help="Also run the commands that read the files.")
    ap.add_argument("--formats", default="", help="Comma-separated formats (default: all).")
    a = ap.parse_args()
    n = a.examples
    only = set(filter(None, a.formats.split(",")))
    tmp = Path(tempfile.mkdtemp(prefix="fuzz-files-"))
    try:
        for name, fmt in fuzzing.FORMATS.items():
            if only and name not in only:
                continue
            path = tmp / fmt.file_name

            def body(doc, fmt=fmt, path=path):
                path.write_text(fuzzing.dumps(doc))
                return fuzzing.outcome(fmt.read, path)

            campaign(name, fuzzing.json_files(fmt.seed(), fmt.frozen), body, n)
        project = fuzzing.make_project(tmp / "seed-project").root
        seed = json.loads((project / "project.json").read_text())
        if not only or "project" in only:
            def body(doc):
                root = tmp / "p"
                if not root.exists():
                    shutil.copytree(project, root)
                (root / "project.json").write_text(fuzzing.dumps(doc))
                return fuzzing.outcome(lambda p: fuzzing.read_project(p.parent), root / "project.json")

            campaign("project", fuzzing.json_files(seed, fuzzing.PROJECT_FROZEN), body, n)
        from stillcap.io.jumpingjack import export_jumpingjack, import_jumpingjack, read_jumpingjack

        from stillcap.io.project import Project

        juja = export_jumpingjack(Project.load(project), tmp / "jj" / "seed.juja")
        runs = iter(range(10 ** 9))
        if not only or "jumpingjack" in only:
            def body(xml):
                (tmp / "jj" / "t.juja").write_text(xml)

                def read(p):
                    read_jumpingjack(p)
                    target = tmp / "imported" / str(next(runs))
                    import_jumpingjack(p, target)
                    shutil.rmtree(target, ignore_errors=True)
                return fuzzing.outcome(read, tmp / "jj" / "t.juja")

            campaign("jumpingjack", fuzzing.xml_mutations(juja.read_text()), body, n)
        if a.cli:
            def export_body(doc):
                (tmp / "r.json").write_text(fuzzing.dumps(doc))
                return cli(["export", tmp / "r.json", "--to", tmp / "o.c3d", "--to", tmp / "o.bvh",
                            "--to", tmp / "o.json"])

            campaign("cli export", fuzzing.json_files(fuzzing.seed_result()), export_body, n)

            def show_body(doc):
                root = tmp / "cli-p"
                shutil.rmtree(root, ignore_errors=True)
                shutil.copytree(project, root)
                (root / "project.json").write_text(fuzzing.dumps(doc))
                return cli(["puppet", "show", root])

            campaign("cli puppet show", fuzzing.json_files(seed, fuzzing.PROJECT_FROZEN), show_body, n)

            def import_body(xml):
                (tmp / "jj" / "c.juja").write_text(xml)
                target = tmp / "cli-imported" / str(next(runs))
                try:
                    return cli(["puppet", "import-jj", tmp / "jj" / "c.juja", target])
                finally:
                    shutil.rmtree(target, ignore_errors=True)

            campaign("cli puppet import-jj", fuzzing.xml_mutations(juja.read_text()), import_body, n)

            def keep_body(doc):
                (tmp / "keep.json").write_text(fuzzing.dumps(doc))
                return cli(["palette", "2", "--keep", tmp / "keep.json", "--restarts", "1"])

            campaign("cli palette --keep", fuzzing.json_files(fuzzing.seed_palette()), keep_body, max(1, n // 10))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    names = sorted({f for f, _ in counts})
    print(f"{'format':24} {'ok':>7} {'refused':>8} {'FAILED':>7}")
    for f in names:
        print(f"{f:24} {counts[f, 'ok']:7d} {counts[f, 'refused']:8d} {counts[f, 'FAILED']:7d}")
    total = {k: sum(v for (_, o), v in counts.items() if o == k) for k in ("ok", "refused", "FAILED")}
    print(f"{'total':24} {total['ok']:7d} {total['refused']:8d} {total['FAILED']:7d}")
    for line in failures:
        print("FAILED", line)
    return 1 if total["FAILED"] else 0


if __name__ == "__main__":
    sys.exit(main())
