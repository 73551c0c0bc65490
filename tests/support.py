"""Test helpers shared by all test folders (importable as ``support``; tests/ is on pythonpath)."""

from pathlib import Path

import numpy as np
import pytest

from stillcap.camera import Camera, Rig, look_at

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def ring_rig(n=4, radius=3.0, height=1.0, dist=(0.0, 0.0, 0.0, 0.0, 0.0), size=(1280, 960), f=1100.0):
    """``n`` cameras on a circle around the origin, looking at it."""
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = (radius * np.cos(a), radius * np.sin(a), height)
        cams.append(Camera.from_intrinsics(f"cam_{i}", f, f * 1.002, size[0] / 2 + 3, size[1] / 2 - 2,
                                           size, dist=dist, world2cam=look_at(eye, (0, 0, 0))))
    return Rig(cams)


def shared_data(sub: str) -> Path:
    """Path to a folder of ../shared/data, or skip the test with a message saying why."""
    p = SHARED_DATA / sub
    if not p.exists():
        pytest.skip(f"real data folder {p} is absent (see shared/data/README.md)")
    return p


def run_cli(args, capsys):
    """Run ``stillcap ARGS`` in-process: ``(exit code, stdout, stderr)``."""
    from stillcap.cli import main

    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


PITCH_SIZE = (1280, 960)  # half the seed's resolution keeps the field of view; 4x cheaper to render and detect


def studio_pitch(factory, name, **kw):
    """Render a studio pitch (true rig) into the session's temp folder once; its folder."""
    from stillcap.studio.pitch import pitch_capture

    root = factory.getbasetemp() / f"pitch-{name}"
    if not (root / "capture.json").is_file():
        pc = pitch_capture(kw.pop("preset", "seed-4seam"), kw.pop("seed", 1), calibrate=False,
                           image_size=PITCH_SIZE, **kw)
        cap, images = pc.to_capture()
        cap.save(root, images)
    return root


def assert_same_reconstruction(one, two):
    """Two puppet results with the same circles, identifications, 2D and 3D markers and pose."""
    import numpy as np

    for a, b in zip(one.views, two.views):
        np.testing.assert_array_equal(a.circles.centers, b.circles.centers)
        np.testing.assert_array_equal(a.identification.cost, b.identification.cost)
    np.testing.assert_array_equal(one.markers.observations, two.markers.observations)
    np.testing.assert_array_equal(one.markers.points, two.markers.points)
    np.testing.assert_array_equal(one.pose.positions, two.pose.positions)


def untimed(x):
    """A result's JSON without its timings (they differ from run to run)."""
    if isinstance(x, dict):
        return {k: untimed(v) for k, v in x.items() if k not in ("timings_s", "fit_time_s")}
    if isinstance(x, list):
        return [untimed(v) for v in x]
    return x


def bead_levels_one_by_one(image, centers, radii_px):
    """The beads' levels by their definition, bead by bead (the reference the vectorised
    :mod:`stillcap.detect.beads` functions are tested against): per bead ``(background, peak,
    disc)`` = median of the ring r + 1.5 .. r + 3.5, 90th percentile within r / 2 and the disc's
    pixels (grey: the channels' mean), or None where the bead is invalid, outside or a set is empty."""
    import math

    import numpy as np

    img = np.asarray(image, float)
    img = img.mean(axis=2) if img.ndim == 3 else img
    h, w = img.shape
    out = []
    for (x, y), r in zip(centers, radii_px):
        out.append(None)
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(r) and r > 0):
            continue
        R = int(math.ceil(r + 4))
        xi, yi = int(round(x)), int(round(y))
        y0, y1, x0, x1 = max(0, yi - R), min(h, yi + R + 1), max(0, xi - R), min(w, xi + R + 1)
        if y1 <= y0 or x1 <= x0:
            continue
        ys, xs = np.mgrid[y0:y1, x0:x1]
        rr = np.hypot(xs - x, ys - y)
        p = img[y0:y1, x0:x1]
        ring, core, disc = p[(rr > r + 1.5) & (rr < r + 3.5)], p[rr < 0.5 * r], p[rr <= r]
        if ring.size and core.size and disc.size:
            out[-1] = (float(np.median(ring)), float(np.percentile(core, 90)), disc)
    return out


class SimulatedPair:
    """What the pitch spin stage reads of a stereo pair: its flashes on the reference clock and its
    markers, simulated from ``ball2world`` at t = 0 and a constant ``spin`` (rad/s) seen from
    ``views`` (``simulate_observations``, ``noise_deg`` per component), and its own spin fit."""

    def __init__(self, name, hz, per_flash, t_start, group, views, seed, ball2world, spin, noise_deg=0.7):
        from stillcap.ball.orientation import simulate_observations
        from stillcap.pipelines.pitch.spin import _fit_pair_spin

        self.name, self.strobe_hz, self.group = name, hz, group
        self.times = t_start + np.arange(len(per_flash)) / hz
        self.local_times = self.times - self.times[0]
        self.time_offset_sigma_s = 0.0
        self.observations = simulate_observations(self.times, ball2world, spin, views, t0=0.0, noise_deg=noise_deg,
                                                  max_per_flash=per_flash, rng=seed)
        self.spin = _fit_pair_spin(self, "global", None)

    def __len__(self):
        return len(self.times)
