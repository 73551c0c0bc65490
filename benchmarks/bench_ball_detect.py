"""Ball detection in strobe photos: centre accuracy (ellipse vs known-radius Hough), detection
rate, markers, stereo 3D error and time per photo.

    python benchmarks/bench_ball_detect.py [--photos 30] [--pairs 6] [--seed 0] [--only-missed]

Photos are drawn by the exact sphere drawing of ``tests/detect/test_ball.py``: 2560x1920 px,
8 ball images of radius 20-32 px along a line (the seed's front pair: a 73.7 mm ball at 3.5 m
with a 2560 px sensor), each with the seed's 12 painted markers in a random orientation, a
0.6 px optical blur, gamma 2.2, noise sigma 2 grey levels, JPEG quality 92 (4:2:0 chroma).
Conditions: lit from the camera (full disc), from the side (half moon), from the side and
front (gibbous), from a little behind (crescent), and overlapping images (spacing 1.3-1.6
radii, one silhouette). The Hough refinement gets the true radius, as the stereo pipeline
provides it from the triangulated centre (its radius error there is ~0.1 px). "toward light":
the mean signed centre error along the light's direction in the image (a lit limb pulls the
Hough centre toward the light); "+ shading": ``refine_ball_centers(shading=True)``, the lit-sphere
shading correction the stereo pipeline applies to partly lit balls.
The stereo rows run the whole pipeline (``ball_centers_stereo``) on the seed's front pair
(0.8 m vertical baseline, 3.5 m away, lens distortion on one camera).
"Ball images the silhouettes miss" (issue 12): faint back-lit crescents (phase angle 150-165 deg,
exposure 0.2, noise sigma 5: a thin rim a few noise sigmas above the room) and flights that run
off the photo (the first and last ball cut by the frame edge, their centre 0.2-1.0 radii inside
it), each without (``crescents=False, edges=False``: the detector before), with the default
crescent and edge fits ("default": crescent silhouettes re-centred on their outer limb, cut balls
fitted to their in-frame limb) and with the faint-crescent search as well (``faint_crescents=True``). "detected": truth images with a detection within 0.35 r (where the refinement's
search, 0.6 r, surely reaches); "within r": with one within a radius; "false": detections farther
than a radius from every truth image; "fit err": the detection's own centre (the outer-limb / in-frame-limb circle for
CRESCENT / EDGE balls; of the detections within 0.35 r); "refined ok", "Hough err": every
detection within a radius refined by ``refine_ball_centers`` with the true radius (and the
shading correction for ``PARTIAL`` balls, as ``ball_centers_stereo`` runs it), how many it did
not flag ``REFINE_FAILED`` and their errors;
"sigma/err": the mean ``center_sigma_px`` of the arc fits over their RMS refined (crescent; the
refined ones only, as the pipelines drop ``REFINE_FAILED``) or fitted (edge) error per axis
(1 = honest); "toward light px" (crescents): their mean refined error along the light's
direction in the photo (refined with ``crescent=``, as ``ball_centers_stereo`` runs it).
Goal: a 2560x1920 photo well under 0.3 s, within 3x of decoding it. Times are CPU times
(``time.process_time``, all threads of the process): on a shared machine wall times swing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from detect.test_ball import (FLIGHT, R_BALL, baseball_markers, draw_balls,  # noqa: E402
                              draw_balls_camera, flight_balls, front_pair)

from stillcap.detect.ball import BallFlag, detect_balls, refine_ball_centers  # noqa: E402
from stillcap.ball.stereo import ball_centers_stereo  # noqa: E402
from stillcap.detect.ball_markers import detect_ball_markers  # noqa: E402

SIZE = (1920, 2560)
CONDITIONS = [
    ("full disc", (0.0, 0.0, -1.0), (2.4, 3.2)),
    ("half moon", (1.0, 0.0, 0.0), (2.4, 3.2)),
    ("gibbous", (0.8, 0.2, -0.55), (2.4, 3.2)),
    ("crescent", (0.9, 0.0, 0.3), (2.4, 3.2)),
    ("overlapping", (0.0, 0.0, -1.0), (1.3, 1.6)),
]


def match(found, truth, max_px=3.0):
    """Greedy one-to-one match of found centres to truth centres within max_px."""
    if len(found) == 0:
        return np.full(len(truth), -1)
    d = np.linalg.norm(found[None] - truth[:, None], axis=2)
    out = np.full(len(truth), -1)
    for flat in np.argsort(d, axis=None):
        i, j = np.unravel_index(flat, d.shape)
        if d[i, j] > max_px:
            break
        if out[i] < 0 and j not in out:
            out[i] = j
    return out


def crescent_photo(seed):
    """A photo of 8 faint back-lit crescents (phase 150-165 deg) along a line."""
    rng = np.random.default_rng(seed)
    balls = flight_balls(seed, n=8, size=SIZE, r_range=(20, 32))
    ph = np.radians(rng.uniform(150, 165))
    az = rng.uniform(0, 2 * np.pi)
    light = (np.sin(ph) * np.cos(az), np.sin(ph) * np.sin(az), -np.cos(ph))  # phase angle ph
    img, _ = draw_balls(SIZE, balls, light=light, exposure=0.2, noise=5.0, rng=seed)
    return img, balls, np.array([np.cos(az), np.sin(az)])  # the light's direction in the photo


def edge_photo(seed):
    """A photo of 8 lit balls along a line that runs off the photo at both ends."""
    rng = np.random.default_rng(seed)
    H, W = SIZE
    r = rng.uniform(20, 32)
    inside = rng.uniform(0.2, 1.0, 2)  # the end balls' centres, radii inside the frame
    x0, x1 = inside[0] * r - 0.5, W - 0.5 - inside[1] * r
    y0 = rng.uniform(200, H - 200)
    k = np.linspace(0, 1, 8)
    balls = np.stack([x0 + (x1 - x0) * k, y0 + rng.uniform(-150, 150) * k, np.full(8, r)], 1)
    mk = [baseball_markers(100 * seed + b) for b in range(8)]
    img, _ = draw_balls(SIZE, balls, markers=mk, rng=seed)
    return img, balls, None


def missed_table(con, photos, seed):
    tab = Table(title=f"Ball images the silhouettes miss, {photos} photos x 8 balls, 2560x1920")
    for col in ("condition", "detector", "detected", "within r", "false", "flagged", "fit err mean px", "fit err max px",
                "refined ok", "Hough err mean px", "Hough err max px", "toward light px", "sigma/err", "detect CPU ms"):
        tab.add_column(col, justify="right")
    for name, make, flag in (("faint crescents", crescent_photo, BallFlag.CRESCENT), ("frame edge", edge_photo, BallFlag.EDGE)):
        for label, kw in (("before", {"crescents": False, "edges": False}), ("default", {}),
                          ("+ faint", {"faint_crescents": True})):
            n_true = n_det = n_near = n_false = n_flag = n_hok = 0
            e_fit, e_h, t_det, sig, e_axis, toward = [], [], [], [], [], []
            for p in range(photos):
                img, balls, light = make(1000 * seed + p)
                t = time.process_time()
                det = detect_balls(img, **kw)
                t_det.append(time.process_time() - t)
                m = match(det.centers, balls[:, :2], max_px=0.35 * balls[:, 2].mean())
                ok = m >= 0
                n_true += len(balls)
                n_det += int(ok.sum())
                near = match(det.centers, balls[:, :2], max_px=balls[:, 2].mean())
                n_near += int((near >= 0).sum())
                n_false += len(det) - int((near >= 0).sum())
                if ok.any():
                    e_fit.append(np.linalg.norm(det.centers[m[ok]] - balls[ok, :2], axis=1))
                nr = near >= 0
                if not nr.any():
                    continue
                # every detection within a radius refined (its search reaches 0.6 r), with the
                # shading correction for partly lit balls, as the stereo pipeline runs it
                j = near[nr]
                ref = refine_ball_centers(img, det.centers[j], balls[nr, 2], shading=det.has(BallFlag.PARTIAL)[j],
                                          crescent=det.has(BallFlag.CRESCENT)[j])
                e_h.append(np.linalg.norm(ref.centers - balls[nr, :2], axis=1))
                n_hok += int(ref.ok.sum())
                fl = det.has(flag)[j]
                n_flag += int(fl.sum())
                if fl.any():
                    # the centre the arc fit stands for: refined for crescents, the fit for edges
                    c = ref.centers if flag == BallFlag.CRESCENT else det.centers[j]
                    # of the refined (not REFINE_FAILED, which the pipelines drop) crescents
                    use = fl & (ref.ok if flag == BallFlag.CRESCENT else True)
                    sig.append(det.center_sigma_px[j][use])
                    e_axis.append((c - balls[nr, :2])[use].ravel())
                    if light is not None:
                        toward.append((c - balls[nr, :2])[use] @ light)
            e_fit = np.concatenate(e_fit) if e_fit else np.full(1, np.nan)
            e_h = np.concatenate(e_h) if e_h else np.full(1, np.nan)
            ratio = (f"{np.mean(np.concatenate(sig)) / np.sqrt(np.mean(np.concatenate(e_axis) ** 2)):.2f}"
                     if sig and len(np.concatenate(sig)) else "-")
            tw = np.concatenate(toward) if toward else np.zeros(0)
            tw = f"{tw.mean():.3f}" if len(tw) else "-"
            tab.add_row(name, label, f"{n_det}/{n_true}", f"{n_near}/{n_true}", str(n_false), f"{n_flag}", f"{e_fit.mean():.3f}",
                        f"{e_fit.max():.3f}", f"{n_hok}/{n_near}", f"{e_h.mean():.3f}", f"{e_h.max():.3f}", tw, ratio,
                        f"{1e3 * np.mean(t_det):.0f}")
    con.print(tab)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photos", type=int, default=30, help="photos per condition")
    ap.add_argument("--pairs", type=int, default=6, help="stereo pairs per lighting")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only-missed", action="store_true",
                    help="only the table of ball images the silhouettes miss (crescents, frame edge)")
    args = ap.parse_args(argv)
    con = Console(width=230)
    missed_table(con, args.photos, args.seed)
    if args.only_missed:
        return

    tab = Table(title=f"Ball centres, {args.photos} photos x 8 balls per condition, 2560x1920, r 20-32 px")
    for col in ("condition", "detected", "flags", "ellipse mean px", "ellipse max px", "Hough mean px",
                "Hough max px", "toward light px", "+ shading mean px", "+ shading toward light px", "markers found", "marker type ok", "marker err px", "detect CPU ms",
                "refine CPU ms", "markers CPU ms"):
        tab.add_column(col, justify="right")
    decode = []
    for name, light, spacing in CONDITIONS:
        n_true = n_det = n_mk = n_mk_found = n_type = 0
        e_ell, e_h, e_mk, t_det, t_ref, t_mk, flags = [], [], [], [], [], [], []
        b_h, e_s, b_s = [], [], []  # signed error toward the light; the shading correction's error and bias
        toward = np.asarray(light[:2], float)
        toward = toward / np.linalg.norm(toward) if np.linalg.norm(toward) > 1e-9 else None
        for p in range(args.photos):
            seed = 1000 * args.seed + p
            balls = flight_balls(seed, n=8, size=SIZE, r_range=(20, 32), spacing=spacing)
            mk = [baseball_markers(100 * seed + b) for b in range(8)]
            img, truth = draw_balls(SIZE, balls, light=light, markers=mk, rng=seed)
            if name == "full disc" and p < 5:
                ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 92])
                t = time.process_time()
                cv2.imdecode(buf, cv2.IMREAD_COLOR)
                decode.append(time.process_time() - t)
            t = time.process_time()
            det = detect_balls(img)
            t_det.append(time.process_time() - t)
            m = match(det.centers, balls[:, :2], max_px=0.6 * balls[:, 2].mean())
            ok = m >= 0
            n_true += len(balls)
            n_det += int(ok.sum())
            flags.extend(det.flags)
            e_ell.append(np.linalg.norm(det.centers[m[ok]] - balls[ok, :2], axis=1))
            t = time.process_time()
            ref = refine_ball_centers(img, det.centers[m[ok]], balls[ok, 2])
            t_ref.append(time.process_time() - t)
            e_h.append(np.linalg.norm(ref.centers - balls[ok, :2], axis=1))
            shaded = refine_ball_centers(img, det.centers[m[ok]], balls[ok, 2], shading=True)
            e_s.append(np.linalg.norm(shaded.centers - balls[ok, :2], axis=1))
            if toward is not None:
                b_h.append((ref.centers - balls[ok, :2]) @ toward)
                b_s.append((shaded.centers - balls[ok, :2]) @ toward)
            t = time.process_time()
            mm = detect_ball_markers(img, ref.centers, balls[ok, 2])
            t_mk.append(time.process_time() - t)
            ball_of = np.flatnonzero(ok)
            lit = np.asarray(light, float)
            for tr in truth:  # markers within 60 deg of the view and lit
                if not (tr["direction"][2] < -0.5 and tr["direction"] @ lit > 0.35) or tr["ball"] not in ball_of:
                    continue
                n_mk += 1
                bi = int(np.flatnonzero(ball_of == tr["ball"])[0])
                cand = np.flatnonzero(mm.ball_index == bi)
                if len(cand) == 0:
                    continue
                d = np.linalg.norm(mm.centers[cand] - tr["xy"], axis=1)
                if d.min() < 3:
                    n_mk_found += 1
                    n_type += mm.types[cand[np.argmin(d)]] == tr["type"]
                    e_mk.append(d.min())
        e_ell, e_h, e_s = np.concatenate(e_ell), np.concatenate(e_h), np.concatenate(e_s)
        bias_h = f"{np.concatenate(b_h).mean():+.3f}" if b_h else "-"
        bias_s = f"{np.concatenate(b_s).mean():+.3f}" if b_s else "-"
        bits = np.bitwise_or.reduce(np.array(flags, int)) if flags else 0
        names = [f for f, b in (("MERGED", 2), ("SPLIT", 4), ("PARTIAL", 8)) if bits & b]
        tab.add_row(name, f"{n_det}/{n_true}", ",".join(names) or "-", f"{e_ell.mean():.2f}", f"{e_ell.max():.2f}",
                    f"{e_h.mean():.3f}", f"{e_h.max():.3f}", bias_h, f"{e_s.mean():.3f}", bias_s,
                    f"{n_mk_found}/{n_mk}", f"{n_type}/{n_mk_found}",
                    f"{np.mean(e_mk):.2f}" if e_mk else "-", f"{1e3 * np.mean(t_det):.0f}",
                    f"{1e3 * np.mean(t_ref):.0f}", f"{1e3 * np.mean(t_mk):.0f}")
        con.print(f"[dim]{name} done[/dim]")
    con.print(tab)
    con.print(f"JPEG decode of a 2560x1920 photo: {1e3 * np.mean(decode):.0f} ms CPU (cv2.imdecode)")

    st = Table(title=f"Stereo pipeline (ball_centers_stereo), seed front pair, {args.pairs} pairs x 8 balls")
    for col in ("lighting", "matched", "ellipse 3D mean mm", "ellipse 3D max mm", "Hough 3D mean mm",
                "Hough 3D max mm", "reproj rms px", "CPU ms per pair"):
        st.add_column(col, justify="right")
    a, b = front_pair()
    for name, lw in (("full disc", None), ("half moon", (1.0, 0.0, 0.0))):
        e0, e1, rp, tt, nm = [], [], [], [], 0
        for p in range(args.pairs):
            rng = np.random.default_rng(1000 * args.seed + p)
            X = FLIGHT + rng.uniform(-0.2, 0.2, 3)
            ia = draw_balls_camera(a, X, R_BALL, light_world=lw, rng=2 * p)
            ib = draw_balls_camera(b, X, R_BALL, light_world=lw, rng=2 * p + 1)
            t = time.process_time()
            res = ball_centers_stereo(a, ia, b, ib, R_BALL)
            tt.append(time.process_time() - t)
            nm += len(res)
            if len(res) == 0:
                continue
            d = np.linalg.norm(res.points_3d[:, None] - X[None], axis=2)
            j = d.argmin(axis=1)
            e1.append(d.min(axis=1))
            e0.append(np.linalg.norm(res.points_3d_initial - X[j], axis=1))
            rp.append(res.reproj_error_px)
        e0, e1, rp = np.concatenate(e0), np.concatenate(e1), np.concatenate(rp)
        st.add_row(name, f"{nm}/{8 * args.pairs}", f"{1e3 * e0.mean():.2f}", f"{1e3 * e0.max():.2f}",
                   f"{1e3 * e1.mean():.2f}", f"{1e3 * e1.max():.2f}", f"{np.sqrt(np.mean(rp ** 2)):.3f}",
                   f"{1e3 * np.mean(tt[1:] if len(tt) > 1 else tt):.0f}")
    con.print(st)


if __name__ == "__main__":
    main()
