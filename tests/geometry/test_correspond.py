import numpy as np
import pytest

from stillcap.geometry.correspond import correspond
from stillcap.geometry.triangulate import triangulate

from support import ring_rig


def test_tracks_recovered_from_shuffled_detections_with_missing_and_spurious():
    rig = ring_rig(4, dist=(-0.1, 0.03, 0, 0, 0))
    rng = np.random.default_rng(0)
    X = rng.uniform(-0.4, 0.4, (25, 3))
    labels_true = np.array(["red", "green", "blue"])[np.arange(25) % 3]
    proj = rig.project(X) + rng.normal(0, 0.2, (4, 25, 2))
    pts, labs, perms = [], [], []
    for k in range(4):
        keep = rng.random(25) > 0.15  # each camera misses some points
        perm = rng.permutation(np.flatnonzero(keep))
        p = np.concatenate([proj[k, perm], rng.uniform(0, 900, (2, 2))])  # plus 2 spurious blobs
        l = np.concatenate([labels_true[perm], ["red", "blue"]])
        pts.append(p), labs.append(l), perms.append(perm)
    x, index, tl = correspond(rig, pts, labs, max_px=2.0)
    tri = triangulate(rig, x)
    # every recovered track is a true point, consistently labelled, with correct members
    seen_by = np.array([[i in perms[k] for k in range(4)] for i in range(25)]).sum(1)
    n_expected = int((seen_by >= 2).sum())
    assert x.shape[1] >= n_expected - 1
    for t in range(x.shape[1]):
        d = np.linalg.norm(X - tri.points[t], axis=1)
        i = d.argmin()
        assert d[i] < 3e-3
        assert tl[t] == labels_true[i]
        for k in range(4):
            if index[k, t] >= 0 and index[k, t] < len(perms[k]):
                assert perms[k][index[k, t]] == i
            else:
                assert index[k, t] == -1


def test_bad_input(rig4):
    with pytest.raises(ValueError, match="one array per camera"):
        correspond(rig4, [np.zeros((1, 2))])
    with pytest.raises(ValueError, match="one label per detection"):
        correspond(rig4, [np.zeros((1, 2))] * 4, [["a"]] * 3 + [[]])
