"""Pose stage of the puppet pipeline (stillcap.body.puppet_pose); its accuracy on rendered
poses is tested with the pipeline (tests/pipelines/test_puppet_pipeline.py)."""

import numpy as np
import pytest

from stillcap.body import MarkerSet, Skeleton
from stillcap.body.puppet_pose import fit_pose, frame_status


def test_rest_markers_give_the_rest_pose():
    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    rest = sk.rest_pose()
    pts = ms.positions(rest)
    fit = fit_pose(sk, ms, pts)
    assert fit.success and fit.n_markers == len(ms)
    assert fit.rms_m < 1e-6
    np.testing.assert_allclose(fit.pose.positions, rest.positions, atol=1e-6)
    assert frame_status(sk, ms)["lower-back"] == "full"
    with pytest.raises(ValueError, match=r"marker_positions must have shape \(16, 3\), got \(15, 3\)"):
        fit_pose(sk, ms, pts[:15])


def test_euler_matrices_are_scipys_elementary_rotations():
    """The fit's closed-form Rx, Ry, Rz are Rotation.from_euler's, and their product the
    intrinsic XYZ rotation the joint limits are written in."""
    from scipy.spatial.transform import Rotation

    from stillcap.body.puppet_pose import _euler_matrices

    a = np.random.default_rng(0).uniform(-180, 180, (25, 3))
    R = _euler_matrices(a)
    for k, ax in enumerate("xyz"):
        np.testing.assert_allclose(R[k], Rotation.from_euler(ax, a[:, k:k + 1], degrees=True).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(R[0] @ R[1] @ R[2], Rotation.from_euler("XYZ", a, degrees=True).as_matrix(), atol=1e-14)


def _blas_threads():
    from threadpoolctl import threadpool_info

    return sorted({d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"})


def test_fit_pose_runs_blas_on_one_thread_and_restores_the_callers_setting(monkeypatch):
    # the dense trust-region solve spins OpenBLAS's threads on a busy machine (15x slower)
    from threadpoolctl import threadpool_limits

    import stillcap.body.puppet_pose as pp

    inside = []
    real = pp.least_squares

    def spy(*args, **kwargs):
        inside.append((_blas_threads(), kwargs["tr_solver"]))
        return real(*args, **kwargs)

    monkeypatch.setattr(pp, "least_squares", spy)
    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    with threadpool_limits(2, user_api="blas"):
        fit = fit_pose(sk, ms, ms.positions(sk.rest_pose()))
        assert _blas_threads() == [2]
    assert fit.success and inside and all(t == ([1], "exact") for t in inside)
