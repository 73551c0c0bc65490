"""Puppet bead detection and identification: the thesis's chain against the better ones.

    python benchmarks/bench_beads.py [--images 50] [--seed 0]

Every image is a drawn 640x480 webcam photo (``random_bead_scene``): 10-16 of the 16 thesis
bead colours (radius 5-7 px, matte spheres lit from the camera, drawn at 8x) on dark grey
limbs criss-crossing a black background, two beads touching another, one partly behind a limb,
brightness x U(0.8, 1.2), red and blue gains 1 +- U(0.05), blur sigma 0.5 px, noise sigma 3,
JPEG quality 80. Harder conditions: grey limbs (grey 0.10-0.25 instead of 0.05-0.14, often
above the IsoData threshold) and strong light changes (x 0.65-1.35, white balance +- 12 %).

Tables: detection (rate over beads less than half hidden, false circles per image, centre error
over the matched beads and over the unoccluded ones, time); identification (right / wrong /
missed as % of the beads drawn, a marker "right" when put within 3 px of its bead); palette
(minimum pairwise distances, and identification with the proposed palette).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.optimize import linear_sum_assignment

from stillcap.body.markerset import MarkerSet
from stillcap.detect.circles import METHODS, find_circles
from stillcap.detect.identify import RECOMMENDED, THESIS, calibrate_palette, identify_markers
from stillcap.detect.palette import Palette, propose_palette
from stillcap.studio.beads import random_bead_scene

CONDITIONS = {
    "dark limbs": dict(),
    "grey limbs": dict(limb_grey=(0.10, 0.25)),
    "strong light change": dict(brightness=(0.65, 1.35), white_balance=0.12),
}


def scenes(colors, n, seed, **kw):
    rng = np.random.default_rng(seed)
    return [random_bead_scene(colors, rng=rng, n_beads=int(rng.integers(10, len(colors) + 1)), **kw) for _ in range(n)]


def match(truth, found, tol=3.0):
    m = np.full(len(truth), -1)
    e = np.full(len(truth), np.nan)
    if len(found) and len(truth):
        D = np.linalg.norm(truth[:, None] - found[None], axis=2)
        r, c = linear_sum_assignment(np.where(D < tol, D, 1e6))
        ok = D[r, c] < tol
        m[r[ok]], e[r[ok]] = c[ok], D[r[ok], c[ok]]
    return m, e


def detection_row(scs, method):
    found = total = fp = 0
    errs, clean, t = [], [], 0.0
    circles = []
    for sc in scs:
        t0 = time.perf_counter()
        c = find_circles(sc.image, method=method)
        t += time.perf_counter() - t0
        circles.append(c)
        m, e = match(sc.centers, c.centers)
        vis = sc.occluded < 0.5
        found += (m[vis] >= 0).sum()
        total += vis.sum()
        fp += len(c) - (m >= 0).sum()
        errs += list(e[m >= 0])
        clean += list(e[(m >= 0) & (sc.occluded == 0)])
    errs, clean = np.array(errs), np.array(clean)
    row = dict(rate=found / total, fp=fp / len(scs), mean=errs.mean(), median=np.median(errs), max=errs.max(),
               clean_mean=clean.mean(), clean_max=clean.max(), ms=1e3 * t / len(scs))
    return row, circles


def identification_row(scs, circles, palette, kw):
    right = wrong = missed = drawn = 0
    t = 0.0
    for sc, c in zip(scs, circles):
        t0 = time.perf_counter()
        ident = identify_markers(sc.image, c, palette, **kw)
        t += time.perf_counter() - t0
        truth = np.full((len(palette), 2), np.nan)
        truth[sc.labels] = sc.centers
        ok = ident.found & (np.linalg.norm(ident.points - truth, axis=1) < 3)
        right += ok.sum()
        wrong += (ident.found & ~ok).sum()
        present = np.zeros(len(palette), bool)
        present[sc.labels] = True
        missed += (present & ~ident.found).sum()
        drawn += len(sc.labels)
    return dict(right=right / drawn, wrong=wrong / drawn, missed=missed / drawn, ms=1e3 * t / len(scs))


def calibrated(palette, sampler, seed):
    """The thesis's colour calibration: 12 'T-pose' photos at nominal light, known positions."""
    shots = [random_bead_scene(palette.rgb, rng=seed + k, brightness=(1, 1), white_balance=0) for k in range(12)]
    pts, rad = [], []
    for sc in shots:
        p = np.full((len(palette), 2), np.nan)
        keep = sc.occluded == 0
        p[sc.labels[keep]] = sc.centers[keep]
        r = np.full(len(palette), 6.0)
        r[sc.labels] = sc.radii
        pts.append(p)
        rad.append(r)
    return calibrate_palette([s.image for s in shots], pts, palette, radii=rad, sampler=sampler).palette


CHAINS = [
    # name, detector, palette kind ("ref" or "cal"), identification keywords
    ("thesis: Hough + greedy HSB (5x5 patch, max 0.15)", "thesis", "ref", THESIS),
    ("thesis Hough, calibrated palette", "thesis", "cal-patch", THESIS),
    ("template + greedy HSB", "template", "ref", THESIS),
    ("template + assignment HSB", "template", "ref", dict(THESIS, method="assignment")),
    ("template + greedy CIEDE2000 (disc, kL=2, adapt)", "template", "ref", dict(RECOMMENDED, method="greedy")),
    ("template + assignment CIEDE2000 (disc, kL=2)", "template", "ref", dict(RECOMMENDED, adapt=False)),
    ("recommended: template + assignment CIEDE2000 + adapt", "template", "ref", RECOMMENDED),
    ("recommended, calibrated palette", "template", "cal-disc", RECOMMENDED),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    con = Console(width=150)
    thesis = Palette.from_markerset(MarkerSet.puppet())
    cal = {"ref": thesis, "cal-patch": calibrated(thesis, "patch", 10_000),
           "cal-disc": calibrated(thesis, "disc", 10_000)}

    for cond, kw in CONDITIONS.items():
        scs = scenes(thesis.rgb, args.images, args.seed, **kw)
        det = Table(title=f"Detection, {cond}, {args.images} images, {sum(len(s.labels) for s in scs)} beads")
        for col in ("method", "found %", "false/img", "err mean px", "median", "max", "unoccl. mean", "unoccl. max",
                    "ms/img"):
            det.add_column(col, justify="right")
        circles = {}
        for method in METHODS:
            row, circles[method] = detection_row(scs, method)
            det.add_row(method, f"{100 * row['rate']:.1f}", f"{row['fp']:.2f}", f"{row['mean']:.3f}",
                        f"{row['median']:.3f}", f"{row['max']:.2f}", f"{row['clean_mean']:.3f}",
                        f"{row['clean_max']:.2f}", f"{row['ms']:.0f}")
        con.print(det)
        idt = Table(title=f"Identification, {cond} (% of beads drawn)")
        for col in ("chain", "right %", "wrong %", "missed %", "ms/img (identify only)"):
            idt.add_column(col, justify="right")
        for name, detector, pal, ikw in CHAINS:
            row = identification_row(scs, circles[detector], cal[pal], ikw)
            idt.add_row(name, f"{100 * row['right']:.1f}", f"{100 * row['wrong']:.1f}", f"{100 * row['missed']:.1f}",
                        f"{row['ms']:.1f}")
        con.print(idt)

    pt = Table(title="Palettes: smallest pairwise distance of 16 colours")
    for col in ("palette", "CIEDE2000", "CIEDE2000 kL=2", "Lab", "HSB", "closest pair (CIEDE2000)", "s"):
        pt.add_column(col, justify="right")
    t0 = time.perf_counter()
    prop = propose_palette(16, rng=args.seed)
    t_prop = time.perf_counter() - t0
    prop_l = propose_palette(16, rng=args.seed, lightness_weight=0.5)
    rows = [("thesis", thesis, None), ("proposed (CIEDE2000)", prop.palette, t_prop),
            ("proposed (CIEDE2000, kL=2)", prop_l.palette, None)]
    for name, pal, t in rows:
        d = [pal.min_distance(m, w)[0] for m, w in (("ciede2000", 1), ("ciede2000", 0.5), ("lab", 1), ("hsb", 1))]
        pt.add_row(name, *(f"{v:.2f}" if m != 3 else f"{v:.3f}" for m, v in enumerate(d)),
                   " / ".join(pal.min_distance()[1]), "" if t is None else f"{t:.1f}")
    con.print(pt)
    con.print("proposed (CIEDE2000): " + " ".join(prop.palette.hex))
    con.print("proposed (kL=2):      " + " ".join(prop_l.palette.hex))

    it = Table(title="Identification by palette, strong light change (template detection)")
    for col in ("palette", "chain", "right %", "wrong %", "missed %"):
        it.add_column(col, justify="right")
    for name, pal in (("thesis", thesis), ("proposed", prop.palette), ("proposed kL=2", prop_l.palette)):
        scs = scenes(pal.rgb, args.images, args.seed + 1, **CONDITIONS["strong light change"])
        circ = [find_circles(s.image) for s in scs]
        for chain, kw in (("greedy HSB (thesis)", THESIS), ("recommended", RECOMMENDED)):
            row = identification_row(scs, circ, pal, kw)
            it.add_row(name, chain, f"{100 * row['right']:.1f}", f"{100 * row['wrong']:.1f}",
                       f"{100 * row['missed']:.1f}")
    con.print(it)


if __name__ == "__main__":
    main()
