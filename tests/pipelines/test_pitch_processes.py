"""The pitch pipeline's per-pair work in worker processes (``PitchOptions.processes``): the
same result as the threads, worker errors named like the main process's, the pool reused."""

import shutil

import numpy as np
import pytest
from support import studio_pitch

from stillcap.io.capture import Capture
from stillcap.pipelines.pitch import PitchOptions, analyse_pitch
from stillcap.pipelines.pitch import workers as pitch_workers


@pytest.fixture(scope="module")
def fastball(tmp_path_factory):
    return studio_pitch(tmp_path_factory, "fastball")


CLOCK = {"timings_s", "fit_time_s", "time_s"}  # wall-clock times, not results


def assert_same(a, b, path="result"):
    """Equal, recursively (arrays element by element, NaN equal to NaN), clock times aside."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), path
        for k in set(a) - CLOCK:
            assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, (list, tuple, np.ndarray)) and not isinstance(a, str):
        a_, b_ = np.asarray(a), np.asarray(b)
        if a_.dtype == object or b_.dtype == object:
            assert len(a) == len(b), path
            for i, (x, y) in enumerate(zip(a, b)):
                assert_same(x, y, f"{path}[{i}]")
        else:
            np.testing.assert_array_equal(a_, b_, err_msg=path)
    elif isinstance(a, float) and isinstance(b, float) and np.isnan(a):
        assert np.isnan(b), path
    else:
        assert a == b, path


def test_processes_give_the_threads_result(fastball):
    threads = analyse_pitch(fastball, n_samples=30, processes=0)
    procs = analyse_pitch(fastball, n_samples=30, processes=2)
    assert procs.spin_available and len(procs.pairs) == 2 and procs.messages == threads.messages
    assert_same(threads.to_dict(), procs.to_dict())
    for p, q in zip(threads.pairs, procs.pairs):  # what to_dict leaves out
        np.testing.assert_array_equal(p.observations.directions, q.observations.directions)
        np.testing.assert_array_equal(p.observations.types, q.observations.types)
        assert [len(m) for m in p.markers] == [len(m) for m in q.markers]
        np.testing.assert_array_equal(p.stereo.points_3d, q.stereo.points_3d)
    np.testing.assert_array_equal(threads.fit.covariance, procs.fit.covariance)
    assert procs.timings_s["spin_pairs"] > 0
    # the pool lives on: the same processes serve the next capture, holding no photos between captures
    pools = pitch_workers.worker_pools(2)
    assert pools == pitch_workers.worker_pools(2)
    assert all(ex.submit(pitch_workers.cached_tokens).result() == [] for ex in pools)


def test_worker_errors_name_the_file(fastball, tmp_path):
    cap = shutil.copytree(fastball, tmp_path / "cap")
    (cap / "images" / "front_top.png").write_bytes(b"\x89PNG garbage" + bytes(range(256)) * 4)
    with pytest.raises(ValueError, match="front_top.png is not an image"):
        analyse_pitch(cap, processes=2)
    (cap / "images" / "back_left.png").unlink()
    shutil.copy(fastball / "images" / "front_top.png", cap / "images" / "front_top.png")
    with pytest.raises(ValueError, match="back_left.png does not exist"):
        analyse_pitch(cap, processes=2)
    # the pair whose photos were fine had them cached: dropped when the capture failed
    for ex in pitch_workers.worker_pools(2):
        assert ex.submit(pitch_workers.cached_tokens).result() == []


def test_bad_process_options(fastball):
    with pytest.raises(ValueError, match="processes must be >= 0"):
        PitchOptions(processes=-1)
    cap = Capture.load(fastball)
    cap.root = None  # an in-memory capture: the workers could not read its photos
    with pytest.raises(ValueError, match="processes > 0 needs a capture loaded from or saved to a folder"):
        analyse_pitch(cap, processes=2)
    pitch_workers.shutdown_worker_pools()  # stopped and restarted on demand
    assert analyse_pitch(fastball, n_samples=0, processes=1).spin_available


def test_worker_pools_needs_a_worker():
    with pytest.raises(ValueError, match="need at least 1 worker process, got 0"):
        pitch_workers.worker_pools(0)
