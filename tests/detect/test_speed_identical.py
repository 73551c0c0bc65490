"""Speed-ups of session 32 (issue 16) give the same bits as the straightforward code they replaced
(kept here as the references): ``detect._ball_light.fit_ball_light`` (each round's weighted normal
matrix built once and kept for the covariance, ``_numeric.median`` for ``np.median``, the
residuals' size taken once) on random lit spheres with markers (outliers), noise and a few NaNs;
``detect.ball._shading._centroid_table`` (its phases' radiance written into buffers)."""

import numpy as np
import pytest

from stillcap.detect._ball_light import fit_ball_light
from stillcap.detect.ball import _shading


def _reference(lin, nx, ny, init=None, min_pixels=30, band=0.05, rounds=20):
    """fit_ball_light as it was on 1ccb874 (the straightforward version)."""
    lin, nx, ny = (np.asarray(v, float).ravel() for v in (lin, nx, ny))
    ok = np.isfinite(lin) & np.isfinite(nx) & np.isfinite(ny) & (nx * nx + ny * ny < 1.0)
    if np.count_nonzero(ok) < min_pixels:
        return None
    lin, nx, ny = lin[ok], nx[ok], ny[ok]
    N = np.stack([nx, ny, -np.sqrt(1.0 - nx * nx - ny * ny)], axis=1)
    if init is None:
        w0 = np.clip(lin - np.percentile(lin, 10), 0, None)
        init = (w0 @ N) if w0.sum() > 0 else np.array([0.0, 0.0, -1.0])
    l = np.asarray(init, float)
    if not (np.all(np.isfinite(l)) and np.linalg.norm(l) > 0):
        return None
    l = l / np.linalg.norm(l)
    w = np.ones(len(lin))
    A = np.empty((len(lin), 4))
    A[:, 3] = 1.0
    for it in range(rounds):
        s = N @ l
        lit, use = s > band, np.abs(s) > band
        if np.count_nonzero(lit) < 8:
            return None
        A[:, :3] = N * lit[:, None]
        wu = w * use
        try:
            coef = np.linalg.solve((A * wu[:, None]).T @ A, (A * wu[:, None]).T @ lin)
        except np.linalg.LinAlgError:
            return None
        g = coef[:3]
        if not (np.all(np.isfinite(g)) and np.linalg.norm(g) > 0):
            return None
        l_prev, l = l, g / np.linalg.norm(g)
        res = A @ coef - lin
        scale = 1.4826 * float(np.median(np.abs(res[use]))) + 1e-12
        w = np.minimum(1.0, 1.5 * scale / np.maximum(np.abs(res), 1e-12))
        if it >= 2 and l @ l_prev > np.cos(np.radians(0.01)):
            break
    cov = np.linalg.pinv((A * wu[:, None]).T @ A)[:3, :3] * scale ** 2
    Pt = np.eye(3) - np.outer(l, l)
    sig = float(np.degrees(np.sqrt(max(np.trace(Pt @ cov @ Pt), 0.0)) / np.linalg.norm(g)))
    return l, sig, float(np.dot(g, l)), float(coef[3]), scale


def _ball(rng, n):
    """``n`` pixels of a lit sphere (random light, rho, ambient), a tenth of them paint (darker),
    noise, an odd or even count of pixels (the median's two paths), a few NaN."""
    r = np.sqrt(rng.uniform(0, 0.85 ** 2, n))
    t = rng.uniform(0, 2 * np.pi, n)
    nx, ny = r * np.cos(t), r * np.sin(t)
    nrm = np.stack([nx, ny, -np.sqrt(1 - nx * nx - ny * ny)], 1)
    light = rng.normal(size=3)
    light[2] = -abs(light[2]) - 0.3
    light /= np.linalg.norm(light)
    lin = rng.uniform(0.3, 1.0) * np.maximum(nrm @ light, 0) + rng.uniform(0, 0.1)
    paint = rng.random(n) < 0.1
    lin = np.where(paint, 0.2 * lin, lin) + rng.normal(0, rng.uniform(0.002, 0.03), n)
    lin[rng.integers(0, n, 2)] = np.nan
    return lin, nx, ny


@pytest.mark.parametrize("seed", range(40))
def test_fit_ball_light_gives_the_straightforward_versions_bits(seed):
    rng = np.random.default_rng(seed)
    lin, nx, ny = _ball(rng, int(rng.integers(200, 3000)))
    init = None if seed % 2 else rng.normal(size=3)
    got, ref = fit_ball_light(lin, nx, ny, init), _reference(lin, nx, ny, init)
    assert (got is None) == (ref is None)
    if ref is not None:
        assert np.array_equal(got[0], ref[0])
        assert got[1:] == ref[1:]


def _reference_centroid_table():
    """_centroid_table as it was on 1ccb874."""
    q = (np.arange(200) + 0.5) / 100.0 - 1.0
    qx, qy = np.meshgrid(q, q)
    r2 = qx * qx + qy * qy
    inside = r2 < 1.0
    qz = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    alpha = np.radians(np.arange(0.0, 176.0, 1.0))
    m = np.empty_like(alpha)
    for k, a in enumerate(alpha):
        rad = np.where(inside, np.maximum(qx * np.sin(a) + qz * np.cos(a), 0.0), 0.0)
        m[k] = np.sum(rad * qx) / np.sum(rad)
    return alpha, np.maximum.accumulate(m)


def test_centroid_table_gives_the_straightforward_versions_bits():
    alpha, table = _shading._centroid_table.__wrapped__()  # built afresh, not the cached one
    ref_alpha, ref_table = _reference_centroid_table()
    assert np.array_equal(alpha, ref_alpha)
    assert np.array_equal(table, ref_table)
