"""The hand pipeline (SPEC J2): multi-exposure photos of a gloved hand -> labelled 3D markers,
hand poses per flash, a smooth animation, and the ball's release.

Wiring only; every step is a stage of its own module (``docs/hand-pipeline.md`` tells the story):

1. **Stereo pairs** (:func:`stillcap.io.capture.stereo_pairs`): the capture's photos grouped
   into strobed stereo pairs; all pairs share one strobe.
2. **Ball** (:func:`~stillcap.pipelines.hand.stages.find_ball`,
   :func:`stillcap.pipelines.hand.ball.hand_ball_positions`): the white ball's centre per flash
   from all views; its discs are masked out of the marker search so that its painted markers
   are not taken for glove markers.
3. **Markers** (:func:`~stillcap.pipelines.hand.stages.find_glove_markers`,
   :func:`stillcap.detect.color_markers.find_color_markers`): colour intervals, connected
   regions above a minimum size, centroids.
4. **3D markers** (:func:`~stillcap.pipelines.hand.stages.triangulate_glove_markers`,
   :func:`stillcap.geometry.marker_points.triangulate_color_markers`): epipolar matching per
   stereo pair, triangulation, a marker seen by both pairs merged; with the strobe's position
   known (``capture.json`` meta ``strobe_position_m`` or the option), the half-lit centroid bias
   is removed.
5. **Labels** (:func:`~stillcap.pipelines.hand.stages.label_markers`,
   :func:`stillcap.body.hand_label.label_hand_markers`): 3D markers clustered into hand poses per
   flash, ordered in time, labelled by colour and fit to the hand model with optimal assignment;
   manual overrides from a file.
6. **Poses** (:func:`~stillcap.pipelines.hand.stages.fit_poses`,
   :func:`stillcap.body.hand_track.fit_hand_sequence`): rigid alignment of the back of the hand,
   then the fingers down their hierarchy, within the joint limits, for every flash whose three
   back-of-hand markers were found.
7. **Animation** (:func:`stillcap.body.hand_track.interpolate_animation`): keyframe interpolation
   of the joint rotations.
8. **Release** (:func:`~stillcap.pipelines.hand.stages.release_and_spin`,
   :func:`stillcap.ball.release.estimate_release`) and the free ball's spin
   (:func:`stillcap.pipelines.hand.ball.hand_ball_spin`, only when two free flashes show markers).

Where things are: :mod:`~stillcap.pipelines.hand.options` (:class:`HandOptions`),
:mod:`~stillcap.pipelines.hand.stages` (steps 2-8, in order), :mod:`~stillcap.pipelines.hand.ball`
(the ball's positions and spin), :mod:`~stillcap.pipelines.hand.result` (:class:`HandResult`),
:mod:`~stillcap.pipelines.hand.analyse` (the entry point :func:`analyse_hand`). Comparing with
the studio's truth: :mod:`stillcap.studio.compare.hand` (the pipeline never sees a truth).

Times are seconds after the first flash in which the hand was found (the strobe runs free, so
the photos do not tell the time since the shutter opened). SI inside; :meth:`HandResult.to_dict`
names units in its keys and shares key names with the studio's ``truth.json``.
"""

from stillcap.pipelines.hand.analyse import analyse_hand
from stillcap.pipelines.hand.ball import HandBalls, HandBallSpin, hand_ball_positions, hand_ball_spin
from stillcap.pipelines.hand.options import HandOptions
from stillcap.pipelines.hand.result import HandResult
from stillcap.pipelines.hand.stages import (find_ball, find_glove_markers, fit_poses, label_markers, release_and_spin,
                                            triangulate_glove_markers)

__all__ = ["HandOptions", "HandResult", "analyse_hand",
           "find_ball", "find_glove_markers", "triangulate_glove_markers", "label_markers", "fit_poses",
           "release_and_spin",
           "HandBalls", "HandBallSpin", "hand_ball_positions", "hand_ball_spin"]
