"""Puppet stop-motion capture (SPEC J3): photos of a marked puppet -> named 2D markers -> 3D
markers -> posed skeleton.

::

    photo of every view
      -> find_beads                  candidates in the bright region (detect.beads: find_circles
                                     template | thesis)
      -> identify_beads              candidates named by colour (identify_markers recommended | thesis)
      -> observations (n_views, n_markers, 2), NaN = not identified
      -> triangulate_beads           reidentify: candidates named after first 3D markers (a 2 px
                                     view-pair consensus of the colour names, projected;
                                     detect.beads), then 3D markers of the final names
                                     (solve_markers: bead_fill, how whole each bead looks, then
                                     geometry.triangulate.triangulate_markers with outlier
                                     rejection); markers seen in fewer than 2 views: NaN, listed
                                     in ``missing``
      -> pose_skeleton               joint rotations within the limits, twist where a joint frame
                                     has 3+ points (body.puppet_pose.fit_pose); the thesis's
                                     bone directions beside it
      -> PuppetResult                to_dict() keys shared with the studio's truth.json

Where things are:

- :mod:`~stillcap.pipelines.puppet.options`: :class:`PuppetOptions`, the presets :data:`DEFAULT`
  and :data:`THESIS_CHAIN`, :func:`with_options`;
- :mod:`~stillcap.pipelines.puppet.stages`: the stages above, in order, and :func:`detect_view`
  (stages 1-2 for one photo), :func:`solve_markers`;
- :mod:`~stillcap.pipelines.puppet.result`: :class:`MarkerSolve`, :class:`PuppetResult`;
- :mod:`~stillcap.pipelines.puppet.analyse`: the entry points :func:`analyse_puppet` (a capture
  folder or a project) and :func:`analyse_puppet_views` (a rig's photos or identified markers),
  :func:`capture_markerset`.

Reading a result file back: :func:`stillcap.io.puppet_result.load_result`. Comparing with the
studio's truth: :mod:`stillcap.studio.compare.puppet` (the pipeline never sees a truth).

Units: metres and radians inside; pixels ``(x, y)`` (``docs/conventions.md``); the result's
``to_dict`` says its units. See ``docs/puppet.md``.
"""
from stillcap.pipelines.puppet.analyse import analyse_puppet, analyse_puppet_views, capture_markerset
from stillcap.pipelines.puppet.options import DEFAULT, THESIS_CHAIN, PuppetOptions, with_options
from stillcap.pipelines.puppet.result import MarkerSolve, PuppetResult
from stillcap.pipelines.puppet.stages import (detect_view, find_beads, identify_beads, pose_skeleton, solve_markers,
                                              triangulate_beads)

__all__ = ["PuppetOptions", "DEFAULT", "THESIS_CHAIN", "with_options",
           "find_beads", "identify_beads", "triangulate_beads", "pose_skeleton", "detect_view", "solve_markers",
           "MarkerSolve", "PuppetResult",
           "analyse_puppet", "analyse_puppet_views", "capture_markerset"]
