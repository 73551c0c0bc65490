"""Pose stage of the puppet pipeline (stillcap.body.puppet_pose); its accuracy on rendered
poses is tested with the pipeline (tests/pipelines/test_puppet_pipeline.py)."""

import numpy as np
import pytest

from stillcap.body import MarkerSet, Skeleton
from stillcap.body.puppet_pose import fit_pose, frame_status


def test_the_pipeline_still_exports_the_moved_stages():
    import stillcap.body.puppet_pose as pose
    import stillcap.detect.beads as beads
    import stillcap.pipelines.puppet as pipe

    for mod, names in ((pose, ("fit_pose", "frame_status", "PoseFit")),
                       (beads, ("bead_fill", "bright_region", "reidentify", "ViewResult", "DETECTORS", "IDENTIFIERS"))):
        for n in names:
            assert getattr(pipe, n) is getattr(mod, n)
            assert n in pipe.__all__


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
