"""A dense finite-difference Jacobian that perturbs unknowns with disjoint residual rows together
(:func:`grouped_jacobian`), for SciPy's exact trust-region solver (``tr_solver="exact"``), which
``jac_sparsity`` rules out."""
from __future__ import annotations

import numpy as np

__all__ = ["grouped_jacobian"]


def grouped_jacobian(fun, sparsity, lower: np.ndarray, upper: np.ndarray):
    """A dense forward-difference Jacobian of ``fun`` that perturbs, in one evaluation, every
    unknown of a group whose residual rows (``sparsity``, csc, rows x unknowns) do not overlap
    (greedy column grouping). SciPy does this grouping only with ``jac_sparsity``, which forces
    the inexact LSMR trust-region solver; its ``approx_derivative`` is private, hence by hand.
    Steps as SciPy's ``'2-point'`` (``sqrt(eps) * max(1, |x|)``), turned back inside ``upper``."""
    n_rows, n = sparsity.shape
    rows = [sparsity.indices[sparsity.indptr[j]:sparsity.indptr[j + 1]] for j in range(n)]
    groups, used = [], []
    for j in range(n):
        for g, u in zip(groups, used):
            if not u[rows[j]].any():
                g.append(j)
                u[rows[j]] = True
                break
        else:
            u = np.zeros(n_rows, bool)
            u[rows[j]] = True
            groups.append([j])
            used.append(u)
    groups = [np.array(g) for g in groups]
    row_of = [[rows[j] for j in g] for g in groups]

    def jac(x, f0=None):
        f0 = fun(x) if f0 is None else f0
        J = np.zeros((len(f0), n))
        for g, rs in zip(groups, row_of):
            h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(x[g]))
            h = np.where(x[g] + h > upper[g], -h, h)
            xx = x.copy()
            xx[g] += h
            df = fun(xx) - f0
            for j, hj, r in zip(g, h, rs):
                J[r, j] = df[r] / hj
        return J

    return jac
