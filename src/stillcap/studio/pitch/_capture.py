"""A rendered pitch: the release, the truth, the photos of both strobed pairs and the rig
file (calibrated from rendered photos or the true rig), assembled into a capture
(:func:`pitch_capture`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from stillcap._progress import report_progress
from stillcap._checks import as_rng
from stillcap.ball.metrics import pitch_metrics_from_flight
from stillcap.ball.physics import cross_plane, flight_model
from stillcap.camera import Rig
from stillcap.io.capture import Capture, CaptureImage
from stillcap.studio.pitch._calibration import (FRONT_BOARD_SPOTS, PitchCalibration, _corridor_points,
                                                calibrate_pitch_rig, rig_reprojection_error)
from stillcap.studio.pitch._release import DEFAULT_PRESET, DEFAULT_VARIATION, END_Y, PRESETS, PitchPreset, \
    ReleaseVariation, release_state
from stillcap.studio.pitch._rig import PitchRig, _check_size, pitch_rig, place_lights
from stillcap.studio.pitch._truth import PitchTruth, _pair_truth, ball_sphere
from stillcap.studio.renderer import render
from stillcap.studio.scene import Backdrop, Exposure, Flash, Scene
from stillcap.response import Response
from stillcap.studio.sensor import Sensor


# --------------------------------------------------------------------------------------------
# The capture
# --------------------------------------------------------------------------------------------
#: Smallest image width (px) at which :func:`pitch_capture` calibrates from rendered photos.
MIN_CALIBRATION_WIDTH = 960
#: Radiance of the black room behind the balls (before the sensor), and its texture.
ROOM = Backdrop(level=0.004, contrast=0.3, scale_px=80.0)
#: Ambient light on the ball over the whole shutter (a dark room: almost none).
AMBIENT = 0.002


@dataclass
class PitchCapture:
    """A rendered pitch: the rig, the photos, the truth and what goes into the capture folder.

    Attributes
    ----------
    rig : PitchRig
        The true rig (cameras, strobes, timing).
    images : list of ndarray
        One uint8 BGR photo per camera, in rig order.
    truth : PitchTruth
    capture_rig : Rig
        The rig written to ``rig.json``: calibrated from rendered photos (``calibration``), or
        the true one when ``calibration`` is None.
    calibration : PitchCalibration or None
    scenes : dict[str, Scene]
        The rendered scene of each pair (to re-render, e.g. noise-free radiance in tests).
    known_flash_times : bool
        Whether ``capture.json`` gives each image's ``first_flash_s`` and ``n_flashes``.
    """

    rig: PitchRig
    images: list
    truth: PitchTruth
    capture_rig: Rig
    calibration: PitchCalibration | None = None
    scenes: dict = field(default_factory=dict)
    known_flash_times: bool = False
    #: The ball file's content when a ball was given (written into ``capture.json``'s ``ball``).
    ball: dict | None = None

    @property
    def capture(self) -> Capture:
        """The :class:`~stillcap.io.capture.Capture` (PNG file names; images not attached)."""
        return self.to_capture()[0]

    def to_capture(self, ext: str = ".png") -> tuple[Capture, dict]:
        """The capture folder content: ``(Capture, {file: image})``.

        Per image: ``strobe_hz`` and ``shutter_s`` of its pair; ``first_flash_s`` and
        ``n_flashes`` only with ``known_flash_times`` (free-running strobes: normally unknown);
        ``meta.pair``. Capture meta: ``rig_calibrated``, ``rig_source``, ``calibration`` (the
        procedure and residuals), ``preset``, ``pairs``, ``flash_times``.
        """
        files = [f"images/{c.name}{ext}" for c in self.rig.rig]
        imgs = []
        for f, cam in zip(files, self.rig.rig):
            p = self.rig.pair_of(cam.name)
            pt = self.truth.pair(p.name)
            timing = (pt.first_flash_s, pt.n_flashes) if self.known_flash_times else (None, None)
            imgs.append(CaptureImage(f, cam.name, p.strobe_hz, p.shutter_s, *timing, meta={"pair": p.name}))
        calibrated = self.calibration is not None
        meta = {
            "synthetic": True,
            "description": (f"synthetic pitch ({self.truth.preset.get('name')}, "
                            f"{self.truth.release.speed_mph:.1f} mph, {self.truth.release.spin_rpm:.0f} rpm): "
                            f"front pair at {self.rig.pair('front').strobe_hz:g} Hz, "
                            f"back pair at {self.rig.pair('back').strobe_hz:g} Hz"),
            "rig_calibrated": calibrated,
            "rig_source": ("calibrated from rendered photos (see calibration)" if calibrated
                           else "true rig (calibration skipped)"),
            "preset": self.truth.preset.get("name"),
            "pairs": {p.name: list(p.cameras) for p in self.rig.pairs},
            "flash_times": "known" if self.known_flash_times else "unknown (free-running strobes)",
        }
        if calibrated:
            meta["calibration"] = self.calibration.to_dict()
        if self.ball is not None:
            meta["ball"] = self.ball
        cap = Capture("pitch", self.capture_rig, imgs, self.truth.to_dict(), meta)
        return cap, dict(zip(files, self.images))


def pitch_capture(preset: str | PitchPreset = DEFAULT_PRESET, rng=None, *, calibrate: bool = True,
                  speed_mph: float | None = None, spin_rpm: float | None = None,
                  spin_axis_deg: float | None = None, spin_efficiency: float | None = None,
                  release_m=None, target_m=None, front_hz: float = 80.0, back_hz: float = 50.0,
                  palette: dict | None = None, model="seed", ball=None,
                  variation: ReleaseVariation | None = DEFAULT_VARIATION, release_time_s: float | None = None,
                  image_size=(2560, 1920), sensor: Sensor | None = None, supersample: int = 3,
                  calibration_views: int = 5, known_flash_times: bool = False,
                  progress: Callable[[int, int, str], None] | None = None, lights: str = "default",
                  room_flash: float = 0.0, ball_radius_m: float | None = None) -> PitchCapture:
    """Render a pitch photographed by the seed's rig, with the truth (module docstring).

    Parameters
    ----------
    preset : str or PitchPreset
        :data:`PRESETS` name (default ``"seed-4seam"``).
    rng : np.random.Generator or int, optional
        Same seed, same capture. The pitch, the strobe phases and the photos do not depend on
        ``calibrate``.
    calibrate : bool
        Calibrate the rig from rendered photos (:func:`calibrate_pitch_rig`, slow: ~40 renders
        at full size) or write the true rig (``rig_calibrated: false``).
    speed_mph, spin_rpm, spin_axis_deg, spin_efficiency, release_m, target_m, variation
        See :func:`release_state`.
    front_hz, back_hz : float
        Strobe rates.
    palette : dict, optional
        Marker colours per type (linear RGB).
    model : "seed", "nathan" or FlightModel
        For a ball flying as a baseball; another ball flies by its own flight preset.
    ball : stillcap.ball.ballfile.Ball, optional
        The ball to paint and throw (its markers, radius, mass and flight); default the seed's
        baseball. The capture's ``capture.json`` then holds it (``ball``), so that the analysis
        uses it.
    release_time_s : float, optional
        Release time after the shutters opened (default uniform in 0.2..0.3 s).
    image_size : (width, height)
        Default 2560x1920; smaller 4:3 sizes keep the field of view (quick tests).
    sensor : Sensor, optional
        Default ``Sensor()`` (noise); ``Sensor.ideal()`` for noise-free photos. Its response,
        blur, noise, white balance and JPEG quality are recorded in the truth (``studio``,
        ``camera_response``).
    supersample : int
        Sub-pixel rays per axis at edges.
    calibration_views : int
        Close-up chessboard views per camera.
    known_flash_times : bool
        Write ``first_flash_s`` and ``n_flashes`` per image (default: unknown, as with
        free-running strobes; the truth has them).
    progress : callable(done, total, label), optional
    lights : {"default", "near", "side", "behind"}
        Where each pair's strobe stands (:func:`~stillcap.studio.pitch.place_lights`).
    room_flash : float
        A dark room lit a little by every flash: each flash the strobe fires during the shutter
        adds this much radiance to the room behind the ball (0 = the black room of the seed).
    ball_radius_m : float, optional
        Ball radius, m (default the baseball's); markers keep their angular size.

    Returns
    -------
    PitchCapture
    """
    rng = as_rng(rng)
    if calibrate and _check_size(image_size)[0] < MIN_CALIBRATION_WIDTH:
        raise ValueError(f"calibrate=True needs images at least {MIN_CALIBRATION_WIDTH} px wide (the far field "
                         f"board's squares must stay large enough for corner detection), got {image_size}; "
                         "use calibrate=False for small test images")
    if calibrate and int(calibration_views) < 3:
        raise ValueError(f"calibration needs at least 3 close-up views per camera, got {calibration_views}")
    seeds = rng.integers(0, 2 ** 63 - 1, size=4)
    r_pitch, r_time, r_render, r_calib = (np.random.default_rng(int(s)) for s in seeds)
    flight = flight_model(model) if ball is None or not isinstance(model, str) else ball.flight_model(model)
    rig = place_lights(pitch_rig(front_hz, back_hz, image_size), lights)
    if ball_radius_m is not None and not (np.isfinite(ball_radius_m) and 0.01 <= ball_radius_m <= 0.1):
        raise ValueError(f"ball_radius_m must be between 0.01 and 0.1 m, got {ball_radius_m}")
    if ball_radius_m is not None and ball is not None:
        raise ValueError("give either ball (a ball file, with its radius) or ball_radius_m, not both")
    if not (np.isfinite(room_flash) and room_flash >= 0):
        raise ValueError(f"room_flash must be >= 0, got {room_flash}")
    painted = ball
    ball, layout = ball_sphere(palette, layout=None if painted is None else painted.layout, radius=ball_radius_m)
    supersample = int(supersample)
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    sensor = sensor or Sensor()

    t0 = float(r_time.uniform(0.2, 0.3)) if release_time_s is None else float(release_time_s)
    if not (np.isfinite(t0) and 0 <= t0 < min(p.shutter_s for p in rig.pairs)):
        raise ValueError(f"release_time_s must be within the shutter time "
                         f"(0..{min(p.shutter_s for p in rig.pairs)} s), got {t0}")
    phases = {p.name: float(r_time.uniform(0, 1 / p.strobe_hz)) for p in rig.pairs}
    release = release_state(preset, r_pitch, speed_mph=speed_mph, spin_rpm=spin_rpm, spin_axis_deg=spin_axis_deg,
                            spin_efficiency=spin_efficiency, release_m=release_m, target_m=target_m,
                            variation=variation, model=flight, t0=t0)
    preset_obj = PRESETS[preset] if isinstance(preset, str) else preset
    end = cross_plane(release.p0, release.v0, release.spin, flight, t0=t0, plane_point=(0, END_Y, 0))
    plate = cross_plane(release.p0, release.v0, release.spin, flight, t0=t0)
    if not (end.success and plate.success):
        raise ValueError("the pitch does not reach home plate (too slow or thrown away from it)")
    metrics = pitch_metrics_from_flight(release.p0, release.v0, release.spin, flight, t0=t0).to_dict()
    pairs = [_pair_truth(p, rig.rig, release, end.time, phases[p.name], flight, layout) for p in rig.pairs]
    overrides = {k: v for k, v in (("speed_mph", speed_mph), ("spin_rpm", spin_rpm), ("spin_axis_deg", spin_axis_deg),
                                   ("spin_efficiency", spin_efficiency), ("release_m", release_m),
                                   ("target_m", target_m)) if v is not None}
    ball_info = {"name": layout.name, "radius": layout.radius, "albedo": np.asarray(ball.albedo),
                 "marker_size": layout.marker_size,
                 "palette": {k: list(v) for k, v in layout.palette.items()},
                 "markers": [{"name": n, "type": layout.type_names[t], "shape": s, "direction": d, "color": c}
                             for n, t, s, d, c in zip(layout.names, layout.types, layout.shapes,
                                                      layout.directions, layout.colors)]}
    truth = PitchTruth({**preset_obj.to_dict(), "overrides": overrides,
                        "variation": None if variation is None else vars(variation).copy()},
                       flight.kind, release, float(plate.time), float(end.time), pairs, metrics, ball_info,
                       rig.rig.names)
    truth.studio = {"lights": lights, "room_flash": float(room_flash), "ball_radius_m": float(layout.radius),
                    "blur_px": float(sensor.blur_px), "full_well": sensor.full_well,
                    "read_noise": float(sensor.read_noise), "white_balance": list(sensor.white_balance),
                    "jpeg_quality": sensor.jpeg_quality, "gamma": sensor.gamma.to_json() if isinstance(sensor.gamma, Response) else sensor.gamma, "tone": bool(sensor.tone),
                    "camera_response": {name: sensor.response.to_json() for name in rig.rig.names}}

    n_cal = (calibration_views + len(FRONT_BOARD_SPOTS)) * len(rig.rig) if calibrate else 0
    total = n_cal + len(rig.rig)
    scenes = {}
    for p, pt in zip(rig.pairs, pairs):
        flashes = [Flash([T], float(t)) for T, t, shown in zip(pt.ball2world, pt.times, pt.rendered) if shown]
        exposure = Exposure(flashes, AMBIENT, p.shutter_s, p.strobe_hz, pt.first_flash_s)
        room = ROOM if room_flash == 0 else replace(ROOM, level=ROOM.level + room_flash * pt.n_flashes)
        scenes[p.name] = Scene([ball], exposure, [p.light], backdrop=room)
    images = []
    for i, cam in enumerate(rig.rig):
        images.append(render(cam, scenes[rig.pair_of(cam.name).name], sensor, r_render, supersample))
        report_progress(progress, i + 1, total, f"rendering {cam.name}")

    calibration, capture_rig = None, rig.rig
    if calibrate:
        calibration = calibrate_pitch_rig(
            rig, r_calib, calibration_views, sensor, supersample,
            progress=lambda i, n, label: report_progress(progress, len(rig.rig) + i, total, label))
        capture_rig = calibration.rig
        truth.calibration_error = rig_reprojection_error(
            rig.rig, capture_rig, {c.name: _corridor_points(rig.pair_of(c.name).name) for c in rig.rig})
    report_progress(progress, total, total, "done")
    capture_rig = capture_rig.with_responses(sensor.response)  # the rig written states the true response
    if calibration is not None:
        calibration.rig = capture_rig
    out = PitchCapture(rig, images, truth, capture_rig, calibration, scenes, bool(known_flash_times))
    if painted is not None:
        out.ball = replace(painted, layout=layout).to_dict()
        truth.ball["file"] = out.ball  # the true ball (its flight for the comparison)
    return out
