"""How much of each shading correction the studio's photos leave, and how it changes along the
flight: the truth behind ``PitchOptions.shading_model_error`` and ``ball.uncertainty.remaining_bias_modes``.

    python benchmarks/bench_shading_share.py [--conditions "clean,light to the side"] [--n 6]
                                             [--seed 0] [--jobs 2] [--jsonl FILE]

The same captures as ``bench_robustness.py --only pitch`` (``_robust_pitch``: same seeds and
conditions; the true cameras, the truth declared as there). Per camera of each pair, the refined
ball centres' error along their lit direction ``u`` against the true centre projected,
``a_k = (x_k - proj(P_k)) . u_k`` (px), is regressed on the correction made ``m_k``
(``StereoBalls.shading_px``) in the linear profiles ``a_k = (alpha + beta t_k) m_k`` (``t`` from
-1 at the pair's first ball image to +1 at its last): ``alpha`` is the share of the correction
left wrong, ``beta`` its change along the pair's stretch of flight (in the same units), each
with its standard error from the regression's scatter (the random centre error, which the
model sizes apart). Printed per condition and pooled: the precision-weighted mean squares of
``alpha`` and ``beta`` less those of their standard errors (what the noise adds), i.e. the
variance of the true share's constant and change; their ratio gives the correlation of the
share at the pair's first and last images, ``(A - B) / (A + B)``. The model
(``ball.uncertainty.lit_bias_modes``: a constant and a linear trend mode per camera, each at
``shading_model_error``, 0.5) has ``A = B = 0.25`` in these terms: the end images uncorrelated,
the share's 1-sigma 0.5 in the middle of a pair's images and 0.71 at its ends.

Also per camera: the speed shift (mph) that the fitted pattern, a unit constant share and a unit
linear trend give through the final flight fit's linear response (``ReferenceFit.position_gain``);
per condition the RMS over the captures of the fitted patterns' speed shift (summed over the
cameras; the regression's noise included, so an upper bound) over the stated share's speed sigma
(``shading_model_error`` times the root sum of squares of the unit shifts).

**The blur estimate behind the share** (issue 12, "a share each capture measures"): per camera
also the lens blur the correction used (``StereoBalls.psf_px``, the median of the ball images'
limb estimates), the photos' true blur (the condition's ``Sensor.blur_px``), the spread of the
per-image limb estimates (their standard deviation; what the capture itself shows of the
estimate's uncertainty) and ``alpha_blur``: the share the blur's error alone explains through
the correction's model, ``sum_k (o_k(true) - o_k(used)) m_k / sum_k m_k^2`` with ``o_k`` the
model's offset (``shading_model_offset_px`` at the image's phase and radius). The summary adds
per condition the mean blur error, the median per-image spread and the RMS of ``alpha_blur``,
and the error of the phase angle the uncertainty reads (``lit_geometry``: since issue 12's ninth
shift the one the correction used, ``phase_error_deg``; the silhouette's area's beside it,
``phase_area_error_deg``) against the true light-ball-camera angle (mean per camera, its spread
over the camera's images). ``alpha_blur`` uses that phase.

**What each capture states of its own share** (issue 12, ninth shift): per camera
``share_misfit`` (``ball.uncertainty.misfit_share``, from the shift a least-squares fit of the
correction's model to each ball's pixels asks for) and ``share_phase`` (``phase_error_px``, the
phase's split-half sigma through the model, regressed on the correction made like ``alpha``);
the summary prints their RMS beside the true share, the per-camera ratio and correlation of
the true ``sqrt((alpha^2 + beta^2) / 2)`` to ``share_misfit``, and the fitted patterns' speed
shift over the speed sigma the stated shares give (the floor ``shading_model_error`` and
``share_misfit`` in quadrature). And the share a model carried from the
blur estimate's own uncertainty would state: the model's offset at the blur used +- sigma (half
the change), regressed on the correction made like ``alpha`` (``share_blur_se``: sigma the
median's standard error ``1.2533 sd / sqrt(n)``; ``share_blur_sd``: one image's spread ``sd``).
The per-image estimates are recorded by wrapping ``stillcap.ball.stereo.limb_blur_px`` in the
benchmark's own process (the analysis runs with ``workers=1``); the library reports only the
median.
Timings on a loaded machine are not the benchmark's.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _robust_pitch as rp  # noqa: E402
import numpy as np  # noqa: E402

MPH = 0.44704


def _camera_rows(res, rig, truth) -> list:
    """Per camera of each pair: alpha, beta, their standard errors and the speed shifts."""
    from stillcap.ball.uncertainty import (
        _retriangulated_shifts,
        correction_made,
        lit_geometry,
    )
    from stillcap.files.jsonable import from_jsonable

    tpairs = {p["name"]: p for p in truth["pairs"]}
    fit = res.fit
    G = fit.position_gain  # (P, N, 3), the positions in pair order
    ev = fit.v0 / np.linalg.norm(fit.v0)
    out, off = [], 0
    for p in res.pairs:
        K = len(p)
        if K == 0:
            continue
        P = from_jsonable(tpairs[p.name]["positions"]).reshape(-1, 3)
        Pt = P[np.nanargmin(np.linalg.norm(P[None] - p.positions[:, None], axis=2), axis=1)]
        cams = [rig[c] for c in p.cameras]
        u, phase, _ = lit_geometry(p.stereo, p.centers_px, p.flags, p.radius_px)
        made = correction_made(p.stereo, p.centers_px)
        t = np.linspace(-1.0, 1.0, K) if K > 1 else np.zeros(K)
        for c in range(2):
            m = made[c] if made is not None else np.zeros(K)
            a = np.einsum("kj,kj->k", p.centers_px[c] - cams[c].project(Pt), u[c])
            A = np.stack([m, m * t], 1)
            row = {"pair": p.name, "camera": p.cameras[c], "K": K,
                   "phase_deg": [float(np.degrees(phase[c].min())), float(np.degrees(phase[c].max()))]}
            if K >= 4 and np.all(np.isfinite(A)) and np.linalg.matrix_rank(A) == 2:
                coef, *_ = np.linalg.lstsq(A, a, rcond=None)
                s2 = float(np.sum((a - A @ coef) ** 2) / (K - 2))
                se = np.sqrt(np.diag(np.linalg.inv(A.T @ A)) * s2)
                shifts = []
                for prof in (coef[0] + coef[1] * t, np.ones(K), t):
                    xs = p.centers_px.copy()
                    xs[c] = xs[c] + (prof * m)[:, None] * u[c]
                    shifts.append(xs)
                dsp = []
                for dp in _retriangulated_shifts(cams, p.centers_px, shifts):
                    full = np.zeros(G.shape[1:])
                    full[off:off + K] = dp
                    dsp.append(float(ev @ np.einsum("pnk,nk->p", G, full)[3:6]) / MPH)
                row.update(alpha=float(coef[0]), beta=float(coef[1]), se_alpha=float(se[0]), se_beta=float(se[1]),
                           dspeed_fitted_mph=dsp[0], dspeed_unit_constant_mph=dsp[1], dspeed_unit_trend_mph=dsp[2])
            out.append(row)
        off += K
    return out


class _BlurRecorder:
    """Records each photo's per-image limb blur estimates while the analysis runs (wraps
    ``stillcap.ball.stereo``'s ``photo_blur_px`` and ``limb_blur_px`` in this process)."""

    def __enter__(self):
        import stillcap.ball.stereo as st

        self.st, self.photos = st, []
        self.orig = st.photo_blur_px, st.limb_blur_px

        def limb(*a, **k):
            v = self.orig[1](*a, **k)
            if self.photos:
                self.photos[-1][1].append(v)
            return v

        def photo(*a, **k):
            self.photos.append([float("nan"), []])
            v = self.orig[0](*a, **k)
            self.photos[-1][0] = v
            return v
        st.photo_blur_px, st.limb_blur_px = photo, limb
        return self

    def __exit__(self, *exc):
        self.st.photo_blur_px, self.st.limb_blur_px = self.orig

    def estimates(self, psf_px: float) -> np.ndarray:
        """The per-image estimates of the photo whose median was ``psf_px``."""
        est = [e for med, lst in self.photos if np.isfinite(med) and abs(med - psf_px) < 1e-12 for e in lst]
        est = np.asarray(est, float)
        return est[np.isfinite(est)]


def _blur_rows(res, rows: list, recorder: _BlurRecorder, true_blur_px: float, rig, truth, lights: dict) -> None:
    """Adds to each camera's row the blur used, the true blur, the per-image spread and ``alpha_blur``,
    and the error of the phase angle read from the silhouette's area against the true one
    (``lights``: pair name -> its strobe's position)."""
    from stillcap.ball.uncertainty import (
        correction_made,
        lit_geometry,
        lit_phase_from_area,
        misfit_share,
        phase_error_px,
        shading_model_offset_px,
    )
    from stillcap.files.jsonable import from_jsonable

    tpairs = {p["name"]: p for p in truth["pairs"]}
    i = 0
    for p in res.pairs:
        if len(p) == 0:
            continue
        u, phase, _ = lit_geometry(p.stereo, p.centers_px, p.flags, p.radius_px)
        made = correction_made(p.stereo, p.centers_px)
        perr = phase_error_px(p.stereo, p.centers_px, phase, p.radius_px)
        mshare = misfit_share(p.stereo, p.centers_px, u, made)
        # the silhouette's phase (what lit_geometry read before it took the correction's)
        row_a = np.argmin(np.linalg.norm(np.asarray(p.stereo.centers_a)[None] - p.centers_px[0][:, None], axis=2), axis=1)
        area = [lit_phase_from_area(det.areas[p.stereo.pairs[row_a, c]], p.radius_px[c])
                for c, det in enumerate((p.stereo.detections_a, p.stereo.detections_b))]
        P = from_jsonable(tpairs[p.name]["positions"]).reshape(-1, 3)
        Pt = P[np.nanargmin(np.linalg.norm(P[None] - p.positions[:, None], axis=2), axis=1)]
        for c in range(2):
            row = rows[i]
            i += 1
            psf = float(p.stereo.psf_px[c])
            est = recorder.estimates(psf)
            row.update(psf_px=psf, psf_true_px=true_blur_px, psf_images=len(est),
                       psf_image_sd_px=float(np.std(est, ddof=1)) if len(est) > 1 else None)
            if p.name in lights:  # the true phase: the angle light-ball-camera
                to_l, to_c = lights[p.name] - Pt, rig[p.cameras[c]].center - Pt
                cos = np.sum(to_l * to_c, 1) / (np.linalg.norm(to_l, axis=1) * np.linalg.norm(to_c, axis=1))
                d = np.degrees(phase[c] - np.arccos(np.clip(cos, -1.0, 1.0)))
                row.update(phase_error_deg=float(np.mean(d)), phase_error_sd_deg=float(np.std(d)))
                da = np.degrees(area[c] - np.arccos(np.clip(cos, -1.0, 1.0)))
                row.update(phase_area_error_deg=float(np.mean(da)))
            if made is None or not np.any(made[c] > 0):
                continue
            m = made[c]
            # the share the correction's measured phase sigma states (phase_error_px, what
            # remaining_bias_modes adds), regressed on the correction made like alpha
            row["share_phase"] = float(np.sum(perr[c] * m) / np.sum(m * m))
            row["share_misfit"] = float(mshare[c])
            o_used = np.array([shading_model_offset_px(a, r, psf) for a, r in zip(phase[c], p.radius_px[c])])
            o_true = np.array([shading_model_offset_px(a, r, true_blur_px) for a, r in zip(phase[c], p.radius_px[c])])
            row["alpha_blur"] = float(np.sum((o_true - o_used) * m) / np.sum(m * m))
            # the share the blur estimate's own uncertainty would state through the model: the
            # offset's half-change as the blur moves by +-sigma, regressed on the correction made,
            # sigma the median's standard error (1.2533 sd / sqrt(n)) or one image's spread (sd)
            sd = row["psf_image_sd_px"]
            if sd is not None:
                for key, sig in (("share_blur_se", 1.2533 * sd / np.sqrt(len(est))), ("share_blur_sd", sd)):
                    d = np.array([0.5 * (shading_model_offset_px(a, r, psf + sig)
                                         - shading_model_offset_px(a, r, max(psf - sig, 0.0)))
                                  for a, r in zip(phase[c], p.radius_px[c])])
                    row[key] = float(abs(np.sum(d * m)) / np.sum(m * m))


def run_capture(condition: str, index: int, seed: int, size: tuple, workdir: str) -> dict:
    """Render and analyse one capture as ``_robust_pitch.run_capture`` does; its cameras' rows."""
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import analyse_pitch
    from stillcap.studio.compare.pitch import compare_with_truth

    pc, folder, (preset, _, sensor_kw, _) = rp.render_capture(condition, index, seed, size, workdir)
    row = {"condition": condition, "index": index, "preset": preset}
    try:
        loaded = Capture.load(folder)
        with _BlurRecorder() as rec:
            res = analyse_pitch(loaded, ball_radius_m=pc.truth.studio["ball_radius_m"], workers=1)
        row["cameras"] = _camera_rows(res, loaded.rig, loaded.truth)
        from stillcap.studio.sensor import Sensor

        _blur_rows(res, row["cameras"], rec, float(sensor_kw.get("blur_px", Sensor().blur_px)), loaded.rig,
                   loaded.truth, {pr.name: np.asarray(pr.light.position, float) for pr in pc.rig.pairs})
        row["speed_mph"] = compare_with_truth(res, loaded.truth).get("speed_diff_mph_fitted")
        row["ok"] = True
    except ValueError as e:
        row.update(ok=False, error=str(e))
    finally:
        for f in folder.rglob("*"):
            if f.is_file():
                f.unlink()
    return row


def summary(name: str, rows: list) -> str:
    cams = [c for r in rows if r.get("ok") for c in r["cameras"] if "alpha" in c]
    if not cams:
        return f"{name:22s} no camera with 4+ ball images"
    a, b = np.array([c["alpha"] for c in cams]), np.array([c["beta"] for c in cams])
    sa, sb = np.array([c["se_alpha"] for c in cams]), np.array([c["se_beta"] for c in cams])
    # precision weights (the noise floor 0.1 keeps one precise camera from deciding alone)
    wa, wb = 1.0 / (sa ** 2 + 0.01), 1.0 / (sb ** 2 + 0.01)
    A = float(np.sum(wa * (a ** 2 - sa ** 2)) / wa.sum())
    B = float(np.sum(wb * (b ** 2 - sb ** 2)) / wb.sum())
    rho = (A - B) / (A + B) if A + B > 0 else float("nan")
    text = (f"{name:22s} {len(cams):4d} cameras  constant share rms {np.sqrt(max(A, 0)):.2f}  change rms "
            f"{np.sqrt(max(B, 0)):.2f}  end-to-end correlation {rho:+.2f}  (raw rms {np.sqrt(np.mean(a ** 2)):.2f} / "
            f"{np.sqrt(np.mean(b ** 2)):.2f}, median se {np.median(sa):.2f} / {np.median(sb):.2f})")
    blur = [c for c in cams if c.get("psf_px") is not None and c.get("psf_true_px") is not None]
    if blur:  # the blur estimate: its error, the spread its images show, the share its error explains
        err = np.array([c["psf_px"] - c["psf_true_px"] for c in blur])
        sd = [c["psf_image_sd_px"] for c in blur if c.get("psf_image_sd_px") is not None]
        ab = np.array([c["alpha_blur"] for c in blur if c.get("alpha_blur") is not None])
        text += (f"\n{'':22s} blur estimate error {np.mean(err):+.3f} px mean, {np.sqrt(np.mean(err ** 2)):.3f} rms, "
                 f"worst {err[np.argmax(np.abs(err))]:+.3f}; per-image spread {np.median(sd) if sd else float('nan'):.3f} px "
                 f"median; share the blur error explains rms {np.sqrt(np.mean(ab ** 2)) if len(ab) else float('nan'):.2f}")
    sh = [c for c in cams if c.get("share_blur_se") is not None]
    if sh:  # what a share carried from the blur estimate's own sigma would state
        text += (f"\n{'':22s} share stated by the blur estimate's sigma through the model: rms "
                 f"{np.sqrt(np.mean([c['share_blur_se'] ** 2 for c in sh])):.3f} (its standard error), "
                 f"{np.sqrt(np.mean([c['share_blur_sd'] ** 2 for c in sh])):.3f} (one image's spread)")
    z = []  # per capture: the fitted patterns' speed shift over the stated share's speed sigma
    from stillcap.pipelines.pitch import PitchOptions

    k = PitchOptions().shading_model_error
    for r in rows:
        cs = [c for c in r.get("cameras", []) if "dspeed_fitted_mph" in c] if r.get("ok") else []
        # the share each camera states: the floor and what its misfit measures, in quadrature
        sig = np.sqrt(sum((k ** 2 + c.get("share_misfit", 0.0) ** 2)
                          * (c["dspeed_unit_constant_mph"] ** 2 + c["dspeed_unit_trend_mph"] ** 2) for c in cs))
        if cs and sig > 0:
            z.append(sum(c["dspeed_fitted_mph"] for c in cs) / sig)
    if z:
        text += (f"\n{'':22s} speed shift of the fitted shares over the stated shares' speed sigma: rms "
                 f"{np.sqrt(np.mean(np.square(z))):.2f} over {len(z)} captures")
    ph = [c for c in cams if c.get("phase_error_deg") is not None]
    if ph:  # the phase angle the uncertainty reads (the correction's), against the truth
        e = np.array([c["phase_error_deg"] for c in ph])
        text += (f"\n{'':22s} correction's phase error per camera {np.mean(e):+.1f} deg mean ({e.min():+.1f} to "
                 f"{e.max():+.1f}), spread over a camera's images {np.median([c['phase_error_sd_deg'] for c in ph]):.1f} "
                 "deg median")
        ea = np.array([c["phase_area_error_deg"] for c in ph if c.get("phase_area_error_deg") is not None])
        if len(ea):
            text += f"; the silhouette's area {np.mean(ea):+.1f} deg mean ({ea.min():+.1f} to {ea.max():+.1f})"
    sp = np.array([c["share_phase"] for c in cams if c.get("share_phase") is not None])
    if len(sp):  # what the measured phase sigma states, against the true share above
        text += f"\n{'':22s} share the measured phase sigma states, rms {np.sqrt(np.mean(sp ** 2)):.3f}"
    sm = [c for c in cams if c.get("share_misfit") is not None]
    if sm:  # what the model's misfit states, against the true share: rms, and per camera
        k, tr = np.array([c["share_misfit"] for c in sm]), np.hypot([c["alpha"] for c in sm], [c["beta"] for c in sm])
        text += (f"\n{'':22s} share the model's misfit states, rms {np.sqrt(np.mean(k ** 2)):.3f}; true "
                 f"sqrt((alpha^2 + beta^2) / 2) over it per camera: median {np.median(tr / np.sqrt(2) / np.maximum(k, 1e-9)):.2f}, "
                 f"correlation {np.corrcoef(k, tr)[0, 1]:+.2f}")
    return text


def main(argv=None):
    from concurrent.futures import ProcessPoolExecutor

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--conditions", default=",".join(rp.CONDITIONS))
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--full", action="store_true", help="2560x1920 photos instead of 1280x960")
    ap.add_argument("--jsonl", type=Path, default=None, help="append each capture's row (resumes from it)")
    args = ap.parse_args(argv)
    conditions = [c.strip() for c in args.conditions.split(",") if c.strip()]
    unknown = [c for c in conditions if c not in rp.CONDITIONS]
    if unknown:
        ap.error(f"unknown condition(s) {unknown}; known: {list(rp.CONDITIONS)}")
    size = (2560, 1920) if args.full else (1280, 960)
    rows = []
    if args.jsonl is not None and args.jsonl.exists():
        rows = [json.loads(line) for line in args.jsonl.read_text().splitlines() if line.strip()]
    done = {(r["condition"], r["index"]) for r in rows}
    tasks = [(c, i) for c in conditions for i in range(args.n) if (c, i) not in done]
    with tempfile.TemporaryDirectory() as work, ProcessPoolExecutor(args.jobs) as ex:
        futs = [ex.submit(run_capture, c, i, args.seed, size, work) for c, i in tasks]
        for f in futs:
            r = f.result()
            rows.append(r)
            if args.jsonl is not None:
                with open(args.jsonl, "a") as fh:
                    fh.write(json.dumps(r) + "\n")
            print(f"  {r['condition']} #{r['index']}", file=sys.stderr, flush=True)
    rows = [r for r in rows if r["condition"] in conditions and r["index"] < args.n]
    for c in conditions:
        print(summary(c, [r for r in rows if r["condition"] == c]))
    print(summary("pooled", rows))


if __name__ == "__main__":
    main()
