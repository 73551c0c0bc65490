"""Bones whose beads a capture did not recover are named (``bone_measured``), not passed off as
measured: their direction is the pose fit's guess (issue 12, part 5)."""

import numpy as np
import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.body.puppet_checks import unmeasured_bone_checks
from stillcap.body.puppet_pose import frame_status
from stillcap.body.skeleton import Skeleton


def _setup():
    sk, ms = Skeleton.puppet(), MarkerSet.puppet("puppet-16")
    return sk, ms, ms.bone_frames(sk), frame_status(sk, ms)


def test_every_bead_recovered_names_no_bone():
    sk, ms, _, _ = _setup()
    assert unmeasured_bone_checks(sk, ms, np.ones(len(ms), bool)) == []


def test_a_frame_without_its_beads_names_its_bones():
    sk, ms, frames, design = _setup()
    full = [j for j in range(sk.n_joints) if design[sk.names[j]] == "full" and np.any(frames == j)]
    assert full
    j = full[-1]
    recovered = frames != j  # every bead of joint j's frame lost
    assert frame_status(sk, ms, recovered)[sk.names[j]] == "none"
    checks = unmeasured_bone_checks(sk, ms, recovered)
    children = {sk.names[c] for c in range(sk.n_joints) if sk.parents[c] == j and sk.bone_lengths[c] > 0}
    assert children and {c.subject for c in checks} == children
    assert all(not c.passed and c.name == "bone_measured" and "guess" in c.message for c in checks)


def test_recovered_of_the_wrong_shape_is_named():
    sk, ms, _, _ = _setup()
    with pytest.raises(ValueError, match="recovered must have shape"):
        frame_status(sk, ms, np.ones(len(ms) + 1, bool))
