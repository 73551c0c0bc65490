"""Outputs of a hand capture: a slow-motion animation of the hand and the ball (GIF or MP4),
joint-angle plots and an HTML report (issue 5, section 4; ``docs/hand-outputs.md``).

- :func:`write_hand_animation`: the hand skeleton (bones as lines, joints as dots, glove markers
  in their colours) and the ball (a sphere and its path) in 3D, field-frame axes in metres,
  slowed down so that a 60 ms release lasts seconds; the flashes (keyframes) are highlighted
  and leave a faint copy behind, like the strobe photo. ``.gif`` (Pillow, always available) or
  ``.mp4`` (needs an ffmpeg program: ``pip install imageio-ffmpeg`` or one on the ``PATH``).
- :func:`plot_joint_angles`: one panel per digit plus the hand's orientation, every degree of
  freedom of :func:`stillcap.body.hand.hand_dofs` over time in ms, keyframes as markers, the
  truth dashed; PNG.
- :func:`write_hand_report`: both of them and a ``report.html`` with the per-flash table (fit
  RMS, labelled markers), the joint angles per flash and the release summary, from plain
  dicts and arrays.

The inputs are plain: an :class:`~stillcap.body.Animation`, arrays of times (seconds) and
positions (metres, NaN = not seen), mappings of numbers. Every file is written atomically
(:mod:`stillcap.files.atomic`); matplotlib runs with the Agg backend (no display needed).

Where it is: :mod:`._animation` (the animation), :mod:`._angles` (the joint-angle plot),
:mod:`._report` (the HTML reports), :mod:`._common` (views, formats, colours, checks).
"""

from stillcap.report.hand._angles import plot_joint_angles
from stillcap.report.hand._animation import animation_limits, write_hand_animation
from stillcap.report.hand._common import ANIMATION_FORMATS, VIEWS, animation_frame_times, dof_labels, find_ffmpeg
from stillcap.report.hand._report import write_hand_report, write_result_report

__all__ = ["ANIMATION_FORMATS", "VIEWS", "animation_frame_times", "animation_limits", "dof_labels", "find_ffmpeg", "plot_joint_angles",
           "write_hand_animation", "write_hand_report", "write_result_report"]
