"""The pitch scenario (SPEC J1, seed sections 3-4): a pitched, marked baseball photographed by two
strobed stereo pairs, with the truth.

Everything is in the baseball **field frame** (origin at the back tip of home plate, y toward the
pitcher, z up, x to the catcher's right), SI units; times are seconds since the shutters opened
(all four cameras are triggered together).

The seed's rig (:func:`pitch_rig`), 4 cameras of 2560x1920 px (Olympus C5050 class):

- **front pair** ``front_top``, ``front_bottom``: 3.5 m beside the flight path (on the third-base
  side, so the ball flies from left to right as in the seed's Figure 5), vertical baseline 0.8 m,
  looking across the path at the stretch right after release;
  its field of view spans about 3.3 m of flight (the seed's "6-10 ball images at 80 Hz"); a
  strobe (:class:`~stillcap.studio.scene.PointLight`) beside the pair flashes at 80 Hz and
  lights the balls from the cameras' side (full discs); shutter 1.0 s.
- **back pair** ``back_left``, ``back_right``: 2.8 m high, 4 m apart on both sides of the
  corridor, behind the last third of the flight and looking down it toward home plate; its strobe
  (50 Hz) stands beside the corridor, so the balls are lit from the side and show as half moons;
  shutter 1.3 s.
- The room is black (:class:`~stillcap.studio.scene.Backdrop` near 0); each pair photographs
  only with its own strobe, and the two strobes run free: each has a random phase
  (``first_flash_s``) relative to the shutters, so the time offset between the pairs is unknown
  to a pipeline (it is in the truth).

The ball: the seed's 12-marker layout (:class:`stillcap.ball.layout.BallLayout`) with a
configurable palette; its flight is integrated by :mod:`stillcap.ball.physics` (seed model by
default) from the release state, and its orientation turns with the spin:
``ball2world(t) = [exp([w_hat] theta(t)) R0 | p(t)]`` with ``theta = |w| (t - t0)`` (the
Nathan model's spin decay is integrated into ``theta``).

The rig file of the capture comes from **rendered calibration photos** processed by stillcap's
calibration (:func:`calibrate_pitch_rig`, which renders them and calls
:func:`stillcap.calibrate.surveyed.calibrate_camera_from_surveyed_boards`): each camera
photographs a chessboard close up and a large chessboard standing at three surveyed spots in
front of its pair; intrinsics from all of those photos, the pose in the field frame by PnP on the
large board's corners. So calibration error is part of every accuracy measured on the capture;
``calibrate=False`` writes the true rig instead (flagged ``rig_calibrated: false``).

See ``docs/studio.md`` ("Pitch") for the presets, the truth keys and the measured accuracy.

Where it is:

- :mod:`._release`: :data:`PRESETS`, :class:`ReleaseVariation`, :func:`release_state`;
- :mod:`._rig`: :func:`pitch_rig` (:class:`PitchRig`, :class:`StrobePair`), :func:`field_look_at`;
- :mod:`._calibration`: :func:`calibrate_pitch_rig` (the board photos rendered and detected),
  :func:`rig_reprojection_error`;
- :mod:`._truth`: :func:`ball_sphere`, the ball's poses, :class:`PairTruth`, :class:`PitchTruth`;
- :mod:`._capture`: :func:`pitch_capture` (:class:`PitchCapture`), the room and its ambient light.
"""

from stillcap.studio.pitch._calibration import (BACK_BOARD_SPOTS, CALIBRATION_BOARD, FIELD_BOARD, FRONT_BOARD_SPOTS,
                                                PitchCalibration, calibrate_pitch_rig, rig_reprojection_error)
from stillcap.studio.pitch._capture import AMBIENT, ROOM, PitchCapture, pitch_capture
from stillcap.studio.pitch._release import (DEFAULT_VARIATION, PRESETS, PitchPreset, ReleaseState, ReleaseVariation,
                                            release_state)
from stillcap.studio.pitch._rig import LIGHT_PLACEMENTS, PitchRig, StrobePair, field_look_at, pitch_rig, place_lights
from stillcap.studio.pitch._truth import PairTruth, PitchTruth, ball_sphere

__all__ = ["AMBIENT", "LIGHT_PLACEMENTS", "place_lights", "BACK_BOARD_SPOTS", "CALIBRATION_BOARD", "DEFAULT_VARIATION", "FIELD_BOARD",
           "FRONT_BOARD_SPOTS", "PRESETS", "ROOM", "PairTruth", "PitchCalibration", "PitchCapture", "PitchPreset",
           "PitchRig", "PitchTruth", "ReleaseState", "ReleaseVariation", "StrobePair", "ball_sphere",
           "calibrate_pitch_rig", "field_look_at", "pitch_capture", "pitch_rig", "release_state",
           "rig_reprojection_error"]
