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


def _frame_status_joint_by_joint(skeleton, markerset, recovered=None):
    """frame_status's definition, one SVD per joint (its code before issue 16's batched SVD)."""
    frames = markerset.bone_frames(skeleton)
    if recovered is not None:
        frames = np.where(recovered, frames, -1)
    lim = skeleton.limits_deg
    out = {}
    for j, name in enumerate(skeleton.names):
        if np.all(lim[j, :, 0] == lim[j, :, 1]):
            out[name] = "locked"
            continue
        pts = markerset.offsets[frames == j]
        if len(pts) == 0:
            out[name] = "none"
            continue
        cloud = np.vstack([pts, np.zeros((1, 3))])
        s = np.linalg.svd(cloud - cloud.mean(axis=0), compute_uv=False)
        out[name] = "full" if s[1] > 1e-3 * max(s[0], 1e-12) and len(cloud) >= 3 else "partial"
    return out


@pytest.mark.parametrize("name", ["puppet-16", "puppet-20"])
def test_frame_status_is_the_joint_by_joint_definition(name):
    """One batched SVD of every frame's zero-padded cloud: the same status as a loop of one SVD
    per joint, for the built-in marker sets, random subsets of their beads, and frames whose
    beads lie in one line with their joint (partial) or beside it (full)."""
    from dataclasses import replace

    sk, ms = Skeleton.puppet(), MarkerSet.puppet(name)
    rng = np.random.default_rng(5)
    for recovered in [None, np.zeros(len(ms), bool)] + [rng.random(len(ms)) < p for p in (0.3, 0.6, 0.9)
                                                          for _ in range(20)]:
        assert frame_status(sk, ms, recovered) == _frame_status_joint_by_joint(sk, ms, recovered)
    frames = ms.bone_frames(sk)
    j = next(j for j in range(sk.n_joints) if (frames == j).sum() >= 2 and frame_status(sk, ms)[sk.names[j]] == "full")
    k = np.flatnonzero(frames == j)
    line = [replace(m, offset=(i + 1) * 0.01 * np.array([0.6, 0.0, 0.8])) if i in k else m
            for i, m in enumerate(ms.markers)]
    for markers, want in ((line, "partial"), (ms.markers, "full")):
        m2 = replace(ms, markers=tuple(markers))
        assert frame_status(sk, m2)[sk.names[j]] == want == _frame_status_joint_by_joint(sk, m2)[sk.names[j]]
