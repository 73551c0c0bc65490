"""Hand labelling and per-flash pose from 3D marker points, against the studio's truth.

    python benchmarks/bench_hand_labels.py [--seeds 20] [--noise 0.3 0.6 1.0] [--personalise none best]

Each seed renders the studio hand truth (``stillcap.studio.hand.hand_capture``, 320x240, only
the truth is used) and makes unlabelled points from it (``hand_points_from_truth``: markers seen
by 2+ cameras, 5 % dropped, Gaussian noise of the given sigma **per axis** (3D RMS = sqrt(3)
sigma), 3 spurious points of random colours near the hands, shuffled). Then
``label_hand_markers`` and ``fit_hand_sequence``.

Columns:
- labels right: points of flashes whose three back markers are among the points, labelled
  with the right flash and marker (%); wrong: labels given that are wrong (% of labels given);
- flashes: of the flashes with all three back markers among the points (after the dropouts),
  those with a pose, "of" how many, then "(+N posed from neighbours)": flashes without their
  three back markers that :mod:`stillcap.body.hand_label_fill` posed from their other markers
  (counted apart, so the column never shows more flashes posed than there are), then the
  flashes whose three back markers 2+ cameras see (truth); order: seeds whose found flashes are
  in the true time order;
- joint angles: error of the degrees of freedom the seen markers fix (every marker from the
  digit's base to the joint seen), RMS and max; DIP: the distal joints alone (short levers);
- fit RMS: marker residual of the per-flash fits (mm); time: labelling + sequence fit per seed.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from stillcap.body.hand_label import hand_points_from_truth, label_hand_markers
from stillcap.body.hand_track import fit_hand_sequence, observed_dofs
from stillcap.studio.hand import hand_capture

console = Console(width=160)


def flash_of_groups(lab, flash) -> np.ndarray:
    """The true flash of each flash group the labelling found (the majority of its points' true
    flashes; -1 for a group of spurious points only)."""
    fmap = []
    for mem in lab.members:
        f = flash[mem]
        f = f[f >= 0]
        fmap.append(int(np.bincount(f).argmax()) if len(f) else -1)
    return np.array(fmap, int)


def run(truth, seed, noise_m, personalise):
    d = hand_points_from_truth(truth, noise_m=noise_m, drop=0.05, n_spurious=3, rng=seed)
    t = time.perf_counter()
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=truth.strobe_hz)
    seq = fit_hand_sequence(lab, personalise=personalise) if lab.reconstructed.any() else None
    dt = time.perf_counter() - t
    n_truth = truth.n
    has_back = np.array([all(((d["flash"] == k) & (d["marker"] == b)).any() for b in range(3)) for k in range(n_truth)])
    vis_back = (truth.markers_visible.sum(axis=0) >= 2)[:, :3].all(axis=1)
    fmap = flash_of_groups(lab, d["flash"])
    lab_pt = lab.labels()
    ok = np.array([lab_pt[i, 0] >= 0 and fmap[lab_pt[i, 0]] == d["flash"][i] and lab_pt[i, 1] == d["marker"][i]
                   for i in range(len(lab_pt))], bool)
    sel = (d["flash"] >= 0) & has_back[np.maximum(d["flash"], 0)]
    given = lab_pt[:, 0] >= 0
    err, dip, other = [], [], []
    if seq is not None:
        for i, k in enumerate(fmap[seq.flashes]):
            for j, a in observed_dofs(seq, i):
                e = seq.angles_deg[i, j, a] - truth.angles_deg[k, j, a]
                err.append(e)
                if seq.skeleton.names[j].endswith("-dip") or seq.skeleton.names[j] == "thumb-ip":
                    dip.append(e)
                else:
                    other.append(e)
    # flashes with a pose: those whose three back markers are among the points, and the others
    # (posed from their neighbours) apart
    rec_back = sum(1 for k, f in enumerate(fmap) if lab.reconstructed[k] and f >= 0 and has_back[f])
    return {"right": int((ok & sel).sum()), "total": int(sel.sum()), "wrong": int((given & ~ok).sum()),
            "given": int(given.sum()), "recon": int(rec_back), "recon_extra": int(lab.reconstructed.sum()) - rec_back, "vis_back": int(vis_back.sum()),
            "has_back": int(has_back.sum()), "order": bool(np.all(np.diff(fmap) > 0)), "err": err, "dip": dip, "other": other,
            "rms": [] if seq is None else list(seq.rms), "time": dt,
            "scales": None if seq is None else np.array(list(seq.scales.values()))}


def _flashes(rs) -> str:
    """The flashes column: "67 of 67 (+3 posed from neighbours) / 77"."""
    extra = sum(r["recon_extra"] for r in rs)
    return (f"{sum(r['recon'] for r in rs)} of {sum(r['has_back'] for r in rs)}"
            + (f" (+{extra} posed from neighbours)" if extra else "") + f" / {sum(r['vis_back'] for r in rs)}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.3, 0.6, 1.0], help="sigma per axis, mm")
    ap.add_argument("--personalise", nargs="+", default=["none"], choices=["none", "best", "joint"])
    args = ap.parse_args()
    t = time.perf_counter()
    truths = [hand_capture(s, image_size=(320, 240), supersample=1).truth for s in range(args.seeds)]
    console.print(f"{args.seeds} studio truths in {time.perf_counter() - t:.1f} s")
    tab = Table(title=f"hand labelling and pose, {args.seeds} seeds (5 % dropped, 3 spurious points per capture)")
    for c in ("noise/axis mm", "personalise", "labels right %", "wrong %", "flashes posed of 3 back in pts (+neighbours) / 3 back vis",
              "order ok", "angle RMS deg", "angle max deg", "DIP/IP RMS deg", "other RMS deg", "fit RMS mm",
              "max |scale-1|", "time s/seed"):
        tab.add_column(c, justify="right")
    for noise in args.noise:
        for pers in args.personalise:
            rs = [run(tr, s, noise / 1000, None if pers == "none" else pers) for s, tr in enumerate(truths)]
            err = np.concatenate([r["err"] for r in rs])
            dip = np.concatenate([r["dip"] for r in rs])
            other = np.concatenate([r["other"] for r in rs])
            rms = np.concatenate([r["rms"] for r in rs])
            sc = [np.abs(r["scales"] - 1).max() for r in rs if r["scales"] is not None]
            tab.add_row(f"{noise:g}", pers, f"{100 * sum(r['right'] for r in rs) / sum(r['total'] for r in rs):.2f}",
                        f"{100 * sum(r['wrong'] for r in rs) / max(1, sum(r['given'] for r in rs)):.2f}",
                        _flashes(rs),
                        f"{sum(r['order'] for r in rs)}/{len(rs)}",
                        f"{np.sqrt(np.mean(err ** 2)):.2f}", f"{np.abs(err).max():.1f}",
                        f"{np.sqrt(np.mean(dip ** 2)):.2f}", f"{np.sqrt(np.mean(other ** 2)):.2f}",
                        f"{1000 * np.sqrt(np.mean(rms ** 2)):.2f}", f"{max(sc):.3f}",
                        f"{np.mean([r['time'] for r in rs]):.2f}")
    console.print(tab)


if __name__ == "__main__":
    main()
