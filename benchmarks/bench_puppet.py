"""Puppet capture end to end: rendered turntable photos -> identified markers -> 3D -> pose.

    python benchmarks/bench_puppet.py [--random 40] [--bvh 12] [--seed 0] [--cache DIR] [--workers 2]
                                      [--markers puppet-16|puppet-20|FILE]

Every pose is rendered by the studio (``stillcap.studio.puppet``: the thesis's 12 turntable
views of the 210 mm puppet, 640x480 webcam with noise and JPEG at quality 85) and written as a
capture folder into ``--cache`` (kept, so a second run only analyses). Poses: ``random:SEED``
(every joint uniformly within its limits, no self-intersection) and frames of the BVH files in
``../shared/data/bvh`` retargeted onto the puppet (``bvh:FILE:FRAME``).

Chains (``stillcap.pipelines.puppet``):

- thesis: IsoData + outline + Hough (``find_circles(method="thesis")``), greedy HSB
  identification, midpoint triangulation of every identified view, bone directions;
- thesis + template: the same with the template detector (what the detector alone buys);
- default: template detector on the bright region of the photo, assignment in CIEDE2000 with
  white-balance adaptation, DLT with refinement, partly hidden beads left out (fill test), 1 px
  outlier rejection, re-identification from the 3D markers (``reidentify``) and a second
  triangulation of the markers it renamed, pose fit; "default (whole photo)" detects on the whole photo,
  "default (full-resolution map)" finds the contrast peaks on the full-resolution map instead of
  at half resolution (``PuppetOptions(coarse=False)``).

``--markers`` picks the marker set the studio renders (``MarkerSet.resolve``: the thesis's 16
beads by default, ``puppet-20`` with a second bead on each forearm and shin, or a file); the
captures store it and the pipeline reads it from them. Each marker set has its own cache folder
(default ``/tmp/stillcap-bench-puppet`` for puppet-16, ``/tmp/stillcap-bench-puppet-NAME``
otherwise); a cached capture of another marker set is an error.

Results and their discussion: docs/puppet.md.

Measures, against each capture's truth.json: identifications right (% of visible beads) and
wrong (% of identifications; "colour only" = before the re-identification from 3D; "wrong used" = wrong ones the triangulation still used); markers
the truth shows in 2+ views that were recovered; 3D marker error; bone direction error
(grouped by what the markers measure: "full" bones start at a joint frame whose orientation
the beads fix, "partial" at a frame with one bead (forearms, shins), "none" at one without
(hands, feet)), by design of the marker set and by what the recovered markers of each pose
measure ("measured": a frame whose second bead was seen in fewer than two views counts as
partial there), and by body part; joint position error; time for the 12 views (decode +
pipeline, ``analyse_puppet``: the comparison with the truth (``studio.compare.puppet``) is this
benchmark's evaluation, done after the clock stops) as a ratio to decoding the 12 JPEGs, both measured in
this run, per pose. The pipeline decodes and detects
the views on ``--workers`` threads (default 2); the reference decode is always serial.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from stillcap.body.markerset import MarkerSet
from stillcap.io.capture import Capture
from stillcap.pipelines.puppet import DEFAULT, THESIS_CHAIN, PuppetOptions, analyse_puppet
from stillcap.studio.compare.puppet import compare_with_truth
from stillcap.studio.puppet import PuppetTruth

REPO = Path(__file__).resolve().parents[1]
BVH_DIR = REPO.parent / "shared" / "data" / "bvh"
console = Console(width=150)

CHAINS = {
    "thesis": THESIS_CHAIN,
    "thesis + template": PuppetOptions(detector="template", identify="thesis", triangulation="midpoint",
                                        outlier_px=None, use_fill=False, pose="thesis", reidentify=False),
    "default (whole photo)": PuppetOptions(roi=False),
    "default (full-resolution map)": PuppetOptions(coarse=False),
    "default": DEFAULT,
}


def pose_specs(n_random: int, n_bvh: int, seed: int) -> list[str]:
    specs = [f"random:{seed * 1000 + i}" for i in range(n_random)]
    files = sorted(BVH_DIR.glob("*.bvh")) if BVH_DIR.is_dir() else []
    if n_bvh and not files:
        console.print(f"[yellow]{BVH_DIR} is absent: no BVH poses")
    if files and n_bvh:
        from stillcap.io.bvh_read import read_bvh

        per = [n_bvh // len(files) + (1 if i < n_bvh % len(files) else 0) for i in range(len(files))]
        for f, k in zip(files, per):
            n_frames = read_bvh(f).n_frames
            for fr in np.linspace(0, n_frames - 1, k, dtype=int) if k else []:
                specs.append(f"bvh:{f}:{int(fr)}")
    return specs


def folder_of(cache: Path, spec: str) -> Path:
    if spec.startswith("bvh:"):
        f, fr = spec.split(":", 1)[1].rsplit(":", 1)
        return cache / f"bvh_{Path(f).stem}_{int(fr):04d}"
    return cache / spec.replace(":", "_")


#: Bones by body part (the puppet skeleton names a bone after the joint at its end).
PARTS = {"forearms, shins": ("l-hand", "r-hand", "l-foot", "r-foot"),
         "hands, feet": ("l-finger", "r-finger", "l-toes", "r-toes")}
TRUNK = "torso, head, shoulders, upper arms, thighs"


def render(cache: Path, specs: list[str], seed: int, markerset: MarkerSet | None = None) -> list[Path]:
    import json

    from stillcap.studio.puppet import puppet_scene, webcam_sensor

    markerset = markerset or MarkerSet.puppet()
    folders = [folder_of(cache, s) for s in specs]
    for f in folders:
        if (f / "capture.json").is_file():
            have = MarkerSet.resolve(json.loads((f / "capture.json").read_text()).get("markerset", "puppet-16"))
            if have.to_dict() != markerset.to_dict():
                raise SystemExit(f"{f} holds a capture with another marker set ({have.name}); use another --cache")
    todo = [(s, f) for s, f in zip(specs, folders) if not (f / "capture.json").is_file()]
    if todo:
        with Progress(TextColumn("[bold]rendering poses"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=console, transient=True) as bar:
            task = bar.add_task("render", total=len(todo))
            for i, (s, f) in enumerate(todo):
                rng = np.random.default_rng([seed, i, len(s)])
                sc = puppet_scene(pose=s, rng=rng, sensor=webcam_sensor(jpeg_quality=None), markerset=markerset)
                cap, images = sc.to_capture(".jpg")
                cap.save(f, images, jpeg_quality=85)
                bar.update(task, completed=i + 1)
    return folders


def decode_time(folder: Path) -> float:
    files = sorted((folder / "images").glob("*.jpg"))
    t0 = time.perf_counter()
    for f in files:
        cv2.imread(str(f))
    return time.perf_counter() - t0


def fmt(v, d=2):
    return "-" if v is None or not np.isfinite(v) else f"{v:.{d}f}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--random", type=int, default=40, help="random poses")
    ap.add_argument("--bvh", type=int, default=12, help="BVH poses (split over the files in ../shared/data/bvh)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=None,
                    help="capture folders (default /tmp/stillcap-bench-puppet[-MARKERS])")
    ap.add_argument("--markers", default="puppet-16", help="marker set: puppet-16, puppet-20 or a marker-set file")
    ap.add_argument("--chains", default=",".join(CHAINS), help="comma-separated chains to run")
    ap.add_argument("--workers", type=int, default=2,
                    help="threads that decode and detect the views (analyse_puppet's workers; 1 = serially)")
    args = ap.parse_args(argv)
    specs = pose_specs(args.random, args.bvh, args.seed)
    markerset = MarkerSet.resolve(args.markers)
    cache = args.cache
    if cache is None:
        cache = Path("/tmp/stillcap-bench-puppet" + ("" if markerset.builtin_name() == "puppet-16"
                                                      else f"-{markerset.name}"))
    console.print(f"marker set {markerset.name} ({len(markerset)} beads), captures in {cache}")
    folders = render(cache, specs, args.seed, markerset)
    chains = [c.strip() for c in args.chains.split(",") if c.strip()]
    rows = {c: [] for c in chains}
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task("analysing", total=len(folders) * len(chains))
        truths = {f: PuppetTruth.from_dict(Capture.load(f).truth) for f in folders}
        for spec, folder in zip(specs, folders):
            for c in chains:
                bar.update(task, description=f"{c}: {folder.name}")
                dec = min(decode_time(folder), decode_time(folder))  # warm file cache, best of two
                t0 = time.perf_counter()
                res, _ = analyse_puppet(folder, CHAINS[c], workers=args.workers)
                total = time.perf_counter() - t0
                # the comparison with the truth is the benchmark's evaluation, not the capture's work
                res.comparison = compare_with_truth(res, truths[folder])
                rows[c].append(dict(spec=spec, cmp=res.comparison, total=total, decode=dec, t=res.timings_s))
                bar.advance(task)
    report(rows, specs)


def _agg(rows, kind=None):
    return [r for r in rows if kind is None or r["spec"].startswith(kind)]


def report(rows: dict, specs: list[str]) -> None:
    n_rand = sum(s.startswith("random") for s in specs)
    n_bvh = len(specs) - n_rand
    console.print(f"\n{len(specs)} poses ({n_rand} random, {n_bvh} BVH-retargeted), 12 turntable views each\n")
    t = Table(title="Identification and 3D markers (all poses)")
    for col in ("chain", "colour only: right % / wrong %", "right % of visible", "wrong % of ident.", "wrong used",
                "seen 2+ views", "recovered",
                "3D RMS mm", "3D max mm", "poses with a wrong 3D marker (> 2 mm)"):
        t.add_column(col, justify="right")
    for c, rs in rows.items():
        cm = [r["cmp"] for r in rs]
        vis, ide = sum(x.visible for x in cm), sum(x.identified for x in cm)
        right_vis = sum(x.right_visible for x in cm)
        wrong = sum(x.wrong for x in cm)
        e = np.concatenate([x.marker_errors_m for x in cm])
        e = e[np.isfinite(e)] * 1e3
        bad = sum(bool(np.nanmax(np.append(x.marker_errors_m, 0)) > 2e-3) for x in cm)
        raw = (f"{fmt(100 * sum(x.raw_right_visible for x in cm) / max(vis, 1), 1)} / "
               f"{fmt(100 * sum(x.raw_wrong for x in cm) / max(sum(x.raw_identified for x in cm), 1), 2)}")
        t.add_row(c, raw, fmt(100 * right_vis / max(vis, 1), 1), fmt(100 * wrong / max(ide, 1), 2),
                  str(sum(x.wrong_used for x in cm)), str(sum(x.seen_twice for x in cm)),
                  str(sum(x.recovered_seen_twice for x in cm)),
                  fmt(np.sqrt(np.mean(e ** 2)) if len(e) else np.nan, 3), fmt(e.max() if len(e) else np.nan, 3),
                  str(bad))
    console.print(t)

    groups = ("full", "partial", "none")
    for kind, label in ((None, "all poses"), ("random", "random poses"), ("bvh", "BVH poses")):
        b = Table(title=f"Bone direction error, degrees, RMS / max ({label})")
        b.add_column("chain", justify="left")
        for g in groups:
            b.add_column(g, justify="right")
        for c, rs in rows.items():
            rs = _agg(rs, kind)
            if not rs:
                continue
            # the result's pose: fitted for the default chains, bone directions for the thesis chains;
            # for the default chain also the thesis's bone directions from the same 3D markers
            for thesis in (False, True) if c == "default" else (False,):
                cells = []
                for g in groups:
                    vals = np.array([(r["cmp"].thesis_bone_errors_deg if thesis else r["cmp"].bone_errors_deg)[bn]
                                     for r in rs for bn in r["cmp"].bone_groups.get(g, [])])
                    vals = vals[np.isfinite(vals)]
                    cells.append(f"{fmt(np.sqrt(np.mean(vals ** 2)))} / {fmt(vals.max())}" if len(vals) else "-")
                b.add_row(c + (" (thesis bone directions)" if thesis else f" ({CHAINS[c].pose})"), *cells)
        console.print(b)

    # the same, grouped by what each pose's recovered markers measure, and by body part
    def cell(rs, thesis, pick):
        vals = np.array([(r["cmp"].thesis_bone_errors_deg if thesis else r["cmp"].bone_errors_deg)[bn]
                         for r in rs for bn in pick(r["cmp"])])
        vals = vals[np.isfinite(vals)]
        return f"{fmt(np.sqrt(np.mean(vals ** 2)))} / {fmt(vals.max())} ({len(vals)})" if len(vals) else "-"

    def part(cm, name):
        if name == TRUNK:
            return [b for b in cm.bone_errors_deg if not any(b in v for v in PARTS.values())]
        return [b for b in cm.bone_errors_deg if b in PARTS[name]]

    def measured(cm, status):
        return cm.measured_bone_groups.get(status, [])

    cols = [(f"measured {g}", lambda cm, g=g: measured(cm, g)) for g in groups]
    cols += [(p, lambda cm, p=p: part(cm, p)) for p in (TRUNK, *PARTS)]
    cols += [("forearms, shins: measured full",
              lambda cm: [b for b in part(cm, "forearms, shins") if b in measured(cm, "full")]),
             ("forearms, shins: not",
              lambda cm: [b for b in part(cm, "forearms, shins") if b not in measured(cm, "full")])]
    for kind, label in ((None, "all poses"), ("random", "random poses"), ("bvh", "BVH poses")):
        if not any(_agg(rs, kind) for rs in rows.values()):
            continue
        b = Table(title=f"Bone direction error, degrees, RMS / max (bones), by what the recovered markers measure "
                        f"and by body part ({label})")
        b.add_column("chain", justify="left")
        for name, _ in cols:
            b.add_column(name, justify="right")
        for c, rs in rows.items():
            rs = _agg(rs, kind)
            if rs:
                b.add_row(c + f" ({CHAINS[c].pose})", *[cell(rs, False, pick) for _, pick in cols])
        console.print(b)

    j = Table(title="Joint position error, mm, RMS / max (all poses)")
    j.add_column("chain")
    for g in ("all", "full", "partial", "none"):
        j.add_column(g, justify="right")
    for c, rs in rows.items():
        for thesis in (False, True) if c == "default" else (False,):
            cells = []
            for g in ("all", "full", "partial", "none"):
                vals = []
                for r in rs:
                    cm = r["cmp"]
                    errs = cm.thesis_joint_errors_m if thesis else cm.joint_errors_m
                    idx = range(len(errs)) if g == "all" else cm.joint_groups.get(g, [])
                    vals += [errs[i] * 1e3 for i in idx]
                vals = np.array(vals)
                vals = vals[np.isfinite(vals)]
                cells.append(f"{fmt(np.sqrt(np.mean(vals ** 2)))} / {fmt(vals.max())}" if len(vals) else "-")
            j.add_row(c + (" (thesis bone directions)" if thesis else f" ({CHAINS[c].pose})"), *cells)
    console.print(j)

    s = Table(title="Time for the 12 views (median over poses)")
    for col in ("chain", "decode 12 JPEGs ms", "detect + identify ms", "triangulate ms", "pose ms",
                "end to end ms", "end to end / decode"):
        s.add_column(col, justify="right")
    for c, rs in rows.items():
        med = lambda k: float(np.median([r["t"].get(k, 0.0) for r in rs])) * 1e3  # noqa: E731
        s.add_row(c, fmt(np.median([r["decode"] for r in rs]) * 1e3, 1), fmt(med("detect_identify"), 0),
                  fmt(med("triangulate"), 0), fmt(med("pose"), 0), fmt(np.median([r["total"] for r in rs]) * 1e3, 0),
                  fmt(np.median([r["total"] / r["decode"] for r in rs]), 1))
    console.print(s)


if __name__ == "__main__":
    main()
