"""``kinematics.align_matrix`` (the puppet's start and thesis pose) gives SciPy's
``Rotation.align_vectors`` matrices, and hands the cases it does not solve itself to SciPy."""
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.body.kinematics import align_matrix


def _scipy(a, b, w=None):
    return Rotation.align_vectors(a, b, weights=w)[0].as_matrix()


def test_kabsch_and_minimal_rotation_equal_scipys():
    rng = np.random.default_rng(5)
    for _ in range(300):
        n = int(rng.integers(2, 6))
        a, b, w = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.uniform(0.1, 3.0, n)
        np.testing.assert_allclose(align_matrix(a, b, w), _scipy(a, b, w), atol=1e-12)
        np.testing.assert_allclose(align_matrix(a, b), _scipy(a, b), atol=1e-12)
        # noise-free pairs: the rotation itself
        R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        np.testing.assert_allclose(align_matrix(b @ R.T, b), R, atol=1e-12)
        a1, b1 = rng.normal(size=(1, 3)), rng.normal(size=(1, 3))
        if float(a1[0] @ b1[0]) / np.linalg.norm(a1) / np.linalg.norm(b1) > -0.9:
            M = align_matrix(a1, b1)
            np.testing.assert_allclose(M, _scipy(a1, b1), atol=1e-12)
            np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("case", ["opposed", "in one line", "infinite weight", "zero weights"])
def test_the_other_cases_are_scipys_own(case):
    rng = np.random.default_rng(6)
    a, b, w = rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), np.ones(3)
    if case == "opposed":
        a, b, w = np.array([[0.0, 0.0, 1.0]]), np.array([[0.01, 0.0, -1.0]]), None
    elif case == "in one line":
        b = np.outer([1.0, 2.0, -1.5], [0.3, -0.4, 0.5])
        a = b @ Rotation.from_rotvec([0.2, 0.1, -0.3]).as_matrix().T
    elif case == "infinite weight":
        w = np.array([np.inf, 1.0, 1.0])
    else:
        w = np.zeros(3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # SciPy's own "poorly defined" warning
        np.testing.assert_array_equal(align_matrix(a, b, w), _scipy(a, b, w))
