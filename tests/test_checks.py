"""Input checks shared by the package (stillcap._checks)."""
import math

import numpy as np
import pytest

from stillcap._checks import as_array, as_points, as_positive


def test_as_positive_accepts_numbers_and_numeric_strings():
    assert as_positive(2, "fps") == 2.0
    assert as_positive("0.5", "slowdown") == 0.5
    assert as_positive(np.float32(3.0), "dpi") == 3.0


@pytest.mark.parametrize("bad", [0, -1.0, math.inf, math.nan, "fast", None, [1.0]])
def test_as_positive_names_the_argument_and_the_value(bad):
    with pytest.raises(ValueError, match="tolerance_mm"):
        as_positive(bad, "tolerance_mm")


def test_shape_errors_name_the_shape_that_came():
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\), got \(2, 2\)"):
        as_array(np.zeros((2, 2)), (None, 3), "points")
    with pytest.raises(ValueError, match=r"p0 must have shape \(3,\) or \(N, 3\), got \(4,\)"):
        as_points(np.zeros(4), 3, "p0")
    one, single = as_points([1.0, 2.0, 3.0], 3, "p0")
    assert one.shape == (1, 3) and single


def test_is_rotation_answers_as_allclose_and_det():
    from scipy.spatial.transform import Rotation

    from stillcap._checks import is_rotation

    rng = np.random.default_rng(3)
    for k in range(3000):
        R = Rotation.random(random_state=k).as_matrix()
        kind = k % 6
        if kind == 1:  # off by 1e-8 .. 1e-4: both sides of the tolerance
            R = R + rng.normal(0.0, 10 ** rng.uniform(-8, -4), (3, 3))
        elif kind == 2:
            R = -R  # a reflection
        elif kind == 3:
            R[rng.integers(3), rng.integers(3)] = np.nan
        elif kind == 4:  # scaled near the diagonal's tolerance (1.1e-5)
            R = R * (1 + rng.normal(0.0, 6e-6))
        elif kind == 5:
            R = np.diag([1.0, 1.0, -1.0]) @ R + rng.normal(0.0, 1e-6, (3, 3))
        want = bool(np.allclose(R @ R.T, np.eye(3), atol=1e-6) and not np.linalg.det(R) < 0)
        assert is_rotation(R, 1e-6) == want, (k, R)
