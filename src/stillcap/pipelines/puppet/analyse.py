"""The puppet pipeline's entry points: :func:`analyse_puppet` on a capture folder or a puppet
project, :func:`analyse_puppet_views` on a rig's photos (or identified 2D markers); both run the
stages of :mod:`~stillcap.pipelines.puppet.stages` in order. Also :func:`capture_markerset`, the
marker set a capture shows.
"""
from __future__ import annotations

import functools
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from stillcap._blas import one_blas_thread, single_blas_thread
from stillcap.body.markerset import MarkerSet
from stillcap.body.bodyfiles import body_entry
from stillcap.body.puppet_checks import (bead_noise, marker_noise_m, partly_hidden_checks, skeleton_checks,
                                         stray_bead_checks, unmeasured_bone_checks)
from stillcap.body.skeleton import Skeleton
from stillcap.camera import Rig
from stillcap.detect.beads import ViewResult, find_bead_candidates, identify_views, refine_bead_candidates
from stillcap.detect.palette import Palette
# imported with the pipeline, not at its first call: reading a capture folder is what
# analyse_puppet does first, and this module's import builds the capture.json schema (pydantic
# models, ~15 ms), a one-off cost of the process like every other import
from stillcap.io.capture import Capture
from stillcap.pipelines.puppet.options import DEFAULT, PuppetOptions, _options_for
from stillcap.pipelines.puppet.result import PuppetResult
from stillcap.pipelines.puppet.stages import (_prepare, detect_view, find_beads, identify_beads, pose_skeleton,
                                              triangulate_beads)
from stillcap.response import Response

__all__ = ["analyse_puppet", "analyse_puppet_views", "capture_markerset", "capture_skeleton"]


@functools.lru_cache(maxsize=1)
def _puppet_skeleton() -> Skeleton:
    """:meth:`Skeleton.puppet` (a frozen dataclass), read and built once: ~2 ms per pose."""
    return Skeleton.puppet()


@one_blas_thread
def analyse_puppet_views(rig: Rig, images=None, *, markerset: MarkerSet | None = None, palette: Palette | None = None,
                         observations=None, options: PuppetOptions = DEFAULT, view_names=None, angles_deg=None,
                         root2world=None, progress: Callable[[int, int], None] | None = None,
                         source: dict | None = None, files=None, skeleton: Skeleton | None = None,
                         detections: Sequence[ViewResult] | None = None) -> PuppetResult:
    """The whole pipeline on a rig's photos (or on already identified 2D markers).

    BLAS (NumPy's and SciPy's) runs on one thread during the call (``threadpoolctl``; the
    caller's setting is restored afterwards): the pipeline's matrices are small, and on a busy
    machine OpenBLAS's threads made the pose fit 15x slower.

    Parameters
    ----------
    rig : Rig, n_views cameras
        The camera of every view (puppet frame).
    images : sequence of n_views BGR images, optional
        The photos. Without ``observations`` they are detected and identified; with them only
        the fill test reads them.
    markerset : MarkerSet, optional
        Default :meth:`MarkerSet.puppet`.
    palette : Palette, optional
        Reference colours in marker-set order; default the marker set's colours.
    observations : array_like, shape (n_views, n_markers, 2), optional
        Identified pixels (e.g. a project's markers with the user's edits); skips detection.
    options : PuppetOptions
    view_names, angles_deg : sequences, optional
        Per view; default the camera names and None.
    root2world : array_like, shape (4, 4), optional
        Pelvis frame; default the skeleton's rest frame (the puppet on the turntable axis).
    progress : callable(done, total), optional
        Called after each detected view.
    source : dict, optional
        Where the photos came from (kept in the result).
    files : sequence of str, optional
        The photo of every view (kept in the result).
    skeleton : Skeleton, optional
        Default :meth:`Skeleton.puppet`; the marker set's bones must be in it.
    detections : sequence of n_views ViewResult, optional
        The views already detected in ``images`` with this palette and ``options``
        (:func:`~stillcap.pipelines.puppet.stages.detect_view`; :func:`analyse_puppet` detects
        while it decodes); skips detection.
    """
    markerset = markerset or MarkerSet.puppet()
    options = _options_for(options, markerset)
    skeleton = skeleton or _puppet_skeleton()
    markerset.check_skeleton(skeleton)
    if palette is None:
        palette = Palette.from_markerset(markerset)
    elif tuple(palette.names) != tuple(markerset.names):
        raise ValueError(f"palette names {list(palette.names)} differ from the marker set's {list(markerset.names)}")
    n = len(rig)
    if images is not None:
        images = list(images)
        if len(images) != n:
            raise ValueError(f"need one image per view ({n}), got {len(images)}")
        for cam, img in zip(rig, images):
            h, w = np.asarray(img).shape[:2]
            if (w, h) != tuple(cam.image_size):
                raise ValueError(f"view {cam.name!r}: image is {w}x{h} px, its camera is "
                                 f"{cam.image_size[0]}x{cam.image_size[1]} px")
        # the beads' colours are sRGB references: each photo as an sRGB camera would have taken it
        images = [(options.response or cam.response).as_srgb(img) for cam, img in zip(rig, images)]
        if options.response is not None:
            rig = rig.with_responses(options.response)
    timings = {}
    views = None
    radii = None
    if observations is None:
        if images is None:
            raise ValueError("give images (to detect markers in) or observations")
        t0 = time.perf_counter()
        if detections is not None:
            views = list(detections)
            if len(views) != n:
                raise ValueError(f"need one detection per view ({n}), got {len(views)}")
        else:
            # 1-2. candidates photo by photo, then all photos named by colour together
            cands, t_det = find_beads(images, options, progress)
            views = identify_beads(images, cands, t_det, palette, options)
        obs = np.stack([v.identification.points for v in views]) if views else np.zeros((0, len(markerset), 2))
        radii = np.stack([v.identification.radii for v in views]) if views else None
        timings["detect_identify"] = (time.perf_counter() - t0 if detections is None
                                      else float(sum(v.time_s for v in views)))
    else:
        obs = np.asarray(observations, float)
    # 3. triangulation (and re-identification after the 3D markers)
    t0 = time.perf_counter()
    solve, raw_obs = triangulate_beads(rig, obs, markerset, images, options, radii, views)
    timings["triangulate"] = time.perf_counter() - t0
    # 4. the pose, each bead weighted by the noise its photos show (bead_noise: the pooled
    # reprojection residuals and each bead's own leave-one-view-out spread), not one stated
    # error for all: fitted that way, a bead resting on three views, one of them partly hidden
    # (0.6 mm off), pulled the pose off the well-measured beads (0.01-0.02 mm) by 0.1-0.4 mm,
    # which the per-bone checks then blamed on the skeleton. The weights are relative: scaled so
    # that the median recovered bead keeps the stated marker_sigma_m, the scale of the fit's
    # robust loss (with the photos' own 0.01-0.1 mm the loss turned every bead of a skeleton
    # unlike the puppet into an outlier: the built-in skeleton on +-15 % puppets went from 6.6
    # to 17.9 deg RMS)
    noise, noise_dof = _bead_noise_m(rig, solve, options)
    t0 = time.perf_counter()
    fit = pose_skeleton(rig, skeleton, markerset, solve, root2world, options,
                        sigma_m=_relative_sigma(noise, solve, options))
    timings["pose"] = time.perf_counter() - t0
    # 5. self-checks: does the skeleton fit the puppet (per bone), which beads are partly hidden
    # a bead nearer another bead's model position than its own is a wrong name or a stray point,
    # not evidence against the skeleton: named on its own and left out of the per-bone checks
    stray = stray_bead_checks(markerset, fit, solve.points)
    off = np.isin(np.asarray(markerset.names), [c.subject for c in stray])
    checks = (skeleton_checks(markerset, fit, solve.points, noise, exclude=solve.partly_hidden | off,
                              noise_dof=noise_dof, tolerance_deg=options.bone_tolerance_deg)
              + partly_hidden_checks(markerset.names, solve.ok, solve.whole_views) + stray
              + unmeasured_bone_checks(skeleton, markerset, solve.ok))
    return PuppetResult(rig, list(view_names) if view_names is not None else list(rig.names),
                        list(angles_deg) if angles_deg is not None else [None] * n, markerset, solve, fit,
                        options, views, dict(source or {}), timings, None, list(files) if files else None, raw_obs,
                        checks)


def _bead_noise_m(rig: Rig, solve, options: PuppetOptions) -> tuple[np.ndarray, np.ndarray]:
    """Expected 3D error of every recovered bead, metres, shape (n_markers,), and the dof behind
    each: :func:`~stillcap.body.puppet_checks.bead_noise` (partly hidden beads left out of the
    pooled pixel noise), and where it has none,
    :func:`~stillcap.body.puppet_checks.marker_noise_m` with ``options.marker_sigma_m`` (stated:
    infinite dof)."""
    stated = marker_noise_m(rig, solve.points, solve.reproj_error_px, options.marker_sigma_m)
    bn = bead_noise(rig, solve.points, solve.observations, solve.used, exclude=solve.partly_hidden)
    have = np.isfinite(bn.sd_m) & (bn.sd_m > 0)
    return np.where(have, bn.sd_m, stated), np.where(have, bn.sd_dof, np.inf)


def _relative_sigma(noise: np.ndarray, solve, options: PuppetOptions) -> np.ndarray:
    """The pose fit's per-bead error: ``noise`` scaled so that its median over the beads seen
    whole is ``options.marker_sigma_m`` (``options.marker_sigma_m`` for all without any)."""
    whole = solve.ok & ~solve.partly_hidden & np.isfinite(noise) & (noise > 0)
    if not whole.any():
        return np.full(len(noise), options.marker_sigma_m)
    scale = options.marker_sigma_m / float(np.median(noise[whole]))
    return np.where(np.isfinite(noise) & (noise > 0), noise * scale, options.marker_sigma_m)


def capture_markerset(folder, cap=None) -> MarkerSet:
    """The marker set a puppet capture shows: its ``markerset`` entry (the whole marker set, as
    ``stillcap studio puppet`` writes it, a built-in name, or ``{"file": PATH}`` inside the
    folder: :func:`body_entry`); captures without one show the thesis's 16 beads. ``cap``: the
    capture already loaded from ``folder``."""
    if cap is None:
        cap = Capture.load(folder)
    entry = (cap.meta or {}).get("markerset", "puppet-16")
    return body_entry(entry, "markerset", Path(folder), f"capture {folder}", str(Path(folder) / "capture.json"),
                      "markerset")


def capture_skeleton(folder, cap=None) -> Skeleton:
    """The skeleton of a puppet capture: its ``skeleton`` entry (built-in name, ``{"file": PATH}``
    inside the folder, or the whole skeleton file embedded: :func:`body_entry`); captures
    without one: the built-in puppet (:meth:`Skeleton.puppet`)."""
    if cap is None:
        cap = Capture.load(folder)
    entry = (cap.meta or {}).get("skeleton")
    if entry is None:
        return _puppet_skeleton()
    return body_entry(entry, "skeleton", Path(folder), f"capture {folder}", str(Path(folder) / "capture.json"),
                      "skeleton")



def _load_capture(folder: Path):
    """A puppet capture folder's :class:`~stillcap.io.capture.Capture` (ValueError for another
    kind or one without images); its ``truth.json`` is not read (the pipeline never sees a truth)."""
    cap = Capture.load(folder, truth=False)
    if cap.kind != "puppet":
        raise ValueError(f"capture {folder} is of kind {cap.kind!r}, not 'puppet' (make one with stillcap studio puppet)")
    if not cap.images:
        raise ValueError(f"capture {folder} has no images")
    return cap


def _capture_inputs(folder: Path, cap):
    """A loaded puppet capture's pieces: ``(rig, view names, angles, files, markerset, skeleton)``
    (:func:`capture_markerset`, :func:`capture_skeleton`)."""
    cams, names, angles, files = [], [], [], []
    for im in cap.images:
        c = cap.rig[im.camera]
        cams.append(c)
        names.append(c.name)
        a = (im.meta or {}).get("angle_deg")
        angles.append(None if a is None else float(a))
        files.append(im.file)
    rig = Rig(cams, cap.rig.world)
    markerset = capture_markerset(folder, cap)
    skeleton = capture_skeleton(folder, cap)
    return rig, names, angles, files, markerset, skeleton


def _analyse_capture(folder, options: PuppetOptions = DEFAULT, palette: Palette | None = None,
                     progress: Callable[[int, int], None] | None = None,
                     workers: int = 2, markerset: MarkerSet | None = None,
                     skeleton: Skeleton | None = None) -> tuple[PuppetResult, list]:
    """The pipeline on a capture folder of kind ``puppet`` (``stillcap studio puppet``).

    With ``workers`` >= 2 a second thread decodes the photos and makes each one's photo-wide
    detection inputs (:func:`~stillcap.detect.beads.prepare_view`: bright region, grey image,
    half-resolution contrast map; OpenCV calls and large NumPy operations, which release the
    GIL) while this one finds the candidates of each photo as soon as it is ready, so that work
    hides behind the detection when a second core is free; the photos found are refined to
    sub-pixel centres and named by colour several at a time
    (:func:`~stillcap.detect.beads.refine_bead_candidates`,
    :func:`~stillcap.detect.beads.identify_views`), while this thread would otherwise wait and
    at the end. The result is the
    same as with ``workers=1`` (decode all, then :func:`~stillcap.pipelines.puppet.stages.detect_view` each). Detecting whole photos
    on two threads was measured slower on the benchmark's two shared cores (the candidate
    search is mostly small NumPy calls that hold the GIL). The decoding starts as soon as the
    capture is loaded; the rest of the set-up (cameras, marker set, skeleton, BLAS's thread
    limit: one-off costs of a process's first call) runs on this thread meanwhile.
    Timings: ``read`` is the capture's loading plus the time spent waiting for decoded photos.
    BLAS runs on one thread during the call (see :func:`analyse_puppet_views`).

    Returns
    -------
    result : PuppetResult
    images : list of ndarray
        The decoded photos (for overlays).
    """
    folder = Path(folder)
    t0 = time.perf_counter()
    cap = _load_capture(folder)
    if workers <= 1 or len(cap.images) <= 1:
        with single_blas_thread():
            rig, names, angles, files, cap_markerset, cap_skeleton = _capture_inputs(folder, cap)
            markerset = markerset or cap_markerset
            skeleton = skeleton or cap_skeleton
            options = _options_for(options, markerset)
            images = [cap.read_image(im) for im in cap.images]
            t_read = time.perf_counter() - t0
            res = analyse_puppet_views(rig, images, markerset=markerset, palette=palette, options=options,
                                       view_names=names, angles_deg=angles, progress=progress,
                                       source={"type": "capture", "path": str(folder)}, files=files, skeleton=skeleton)
        res.timings_s = {"read": t_read, **res.timings_s}
        return res, images

    def read(entry, opts=options):  # the second thread: decode, and the photo-wide part of the detection
        # as analyse_puppet_views sees a photo: re-encoded to sRGB through its camera's response
        # (the options as given: prepare_view does not use the candidate count _options_for raises)
        img = (opts.response or cap.rig[entry.camera].response).as_srgb(cap.read_image(entry))
        return img, _prepare(img, opts)

    images, preps = [], []
    candidates, t_det, idents = [], [], []
    # the decoding starts as soon as the photos are known: the rest of the set-up (cameras,
    # marker set, skeleton, BLAS's thread limit) runs here meanwhile
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = [pool.submit(read, im) for im in cap.images]
        try:
            with single_blas_thread():
                rig, names, angles, files, cap_markerset, cap_skeleton = _capture_inputs(folder, cap)
                markerset = markerset or cap_markerset
                skeleton = skeleton or cap_skeleton
                options = _options_for(options, markerset)
                t_read = time.perf_counter() - t0
                if palette is None:  # analyse_puppet_views's default: the marker set's reference colours
                    palette = Palette.from_markerset(markerset)

                # the template detector's candidates are refined to sub-pixel centres when they
                # are named, several photos' together (the same centres as one by one)
                together = options.detector == "template"
                # while the other thread decodes, found photos are named half the capture's photos
                # at a time (at least two): refine_bead_candidates and identify_views cost ~0.75 ms
                # per call besides their ~0.9 ms per photo, so fewer, larger batches cost less,
                # and while fewer have been found this thread decodes a photo instead (which
                # releases the GIL to the decoding thread), naming them when nothing is left to
                # decode. Measured on the benchmark's 12 photos (first call in a fresh process,
                # best of 10, the machine's other processes held off by real-time scheduling):
                # 81.1 ms naming two or more at a time, 78.2 four, 76.3 six, 77.0 eight.
                min_batch = max(2, len(pending) // 2) if together else 1

                def name(upto) -> float:  # the photos found so far but not yet named, named by colour
                    # together; returns the seconds it took
                    if upto <= len(idents):
                        return 0.0
                    t = time.perf_counter()
                    if together:
                        candidates[len(idents):upto] = refine_bead_candidates(candidates[len(idents):upto],
                                                                              preps[len(idents):upto])
                    new = identify_views(images[len(idents):upto], candidates[len(idents):upto], palette,
                                         options.identify)
                    share = (time.perf_counter() - t) / len(new)
                    for j in range(len(idents), upto):
                        t_det[j] += share
                    idents.extend(new)
                    return share * len(new)

                stolen = {}
                for k, fut in enumerate(pending):
                    if not fut.done() and k - len(idents) >= min_batch:
                        name(k)  # while the other thread still decodes: name what was found
                    t1 = time.perf_counter()
                    naming = 0.0  # seconds of it spent naming (detection time, not reading)
                    # still waiting: decode a photo the other thread has not started (the last
                    # one), here, so that both threads decode while this one has nothing to detect
                    while k not in stolen and not fut.done():
                        j = next((j for j in range(len(pending) - 1, k, -1)
                                  if j not in stolen and pending[j].cancel()), None)
                        if j is None:
                            naming = name(k)  # nothing left to decode here: name what was found
                            break
                        stolen[j] = read(cap.images[j])
                    img, prepared = stolen.pop(k) if k in stolen else fut.result()
                    t2 = time.perf_counter()
                    t_read += t2 - t1 - naming
                    images.append(img)
                    preps.append(prepared)
                    candidates.append(find_bead_candidates(img, options.detector, options.radius_range,
                                                           options.n_circles, options.roi, options.coarse,
                                                           prepared=prepared, refine=not together))
                    t_det.append(time.perf_counter() - t2)
                    if progress is not None:
                        progress(k + 1, len(pending))
                # every photo's candidates named by colour (identify_views: the same identification as
                # detect_view's per photo; the photos named together share its small-matrix calls)
                name(len(images))
                detections = [ViewResult(c, i, t) for c, i, t in zip(candidates, idents, t_det)]
                # the photos were re-encoded to sRGB as they were decoded: not again (a rig whose
                # cameras are all sRGB already is kept: building its cameras again costs ~0.5 ms)
                srgb = Response.srgb()
                if options.response is not None or any(cam.response != srgb for cam in rig):
                    rig, options = rig.with_responses(srgb), replace(options, response=None)
                res = analyse_puppet_views(rig, images, markerset=markerset, palette=palette, options=options,
                                           view_names=names, angles_deg=angles,
                                           source={"type": "capture", "path": str(folder)}, files=files,
                                           detections=detections, skeleton=skeleton)
        finally:
            for fut in pending:
                fut.cancel()
    res.timings_s = {"read": t_read, **res.timings_s}
    return res, images



def _analyse_project(project, options: PuppetOptions = DEFAULT, palette: Palette | None = None, redetect: bool = False,
                     progress: Callable[[int, int], None] | None = None, save: bool = True,
                     markerset: MarkerSet | None = None, skeleton: Skeleton | None = None) -> tuple[PuppetResult, list]:
    """Detect markers in a project's photos, store them, and reconstruct.

    Views without detections (all views with ``redetect``) are detected and identified; their
    detections replace the stored ones (the user's edits stay and still apply) and the project
    is saved (``save``). The 3D markers come from every view's effective markers (detections
    with edits), as :meth:`Project.reconstruct` would, plus the fill test.

    Parameters
    ----------
    project : Project or path
    """
    from stillcap.io.project import Project

    if not isinstance(project, Project):
        project = Project.load(project)
    if not project.views:
        raise ValueError(f"project {project.root} has no views yet (add photos with stillcap puppet add)")
    pal = palette or Palette.from_markerset(project.markerset)
    options = _options_for(options, project.markerset)
    t0 = time.perf_counter()
    images = [project.read_image(v) for v in project.views]
    t_read = time.perf_counter() - t0
    todo = [k for k, v in enumerate(project.views) if redetect or not v.detected]
    t0 = time.perf_counter()
    views: list = [None] * len(images)
    for i, k in enumerate(todo):
        vr = detect_view(images[k], pal, options)
        views[k] = vr
        project.set_detections(k, vr.identification.as_dict())
        if progress is not None:
            progress(i + 1, len(todo))
    t_det = time.perf_counter() - t0
    if todo and save:
        project.save()
    res, _ = _reconstruct_project(project, options, images=images, markerset=markerset, skeleton=skeleton)
    res.views = views if all(v is not None for v in views) else None
    res.timings_s = {"read": t_read, "detect_identify": t_det, **{k: v for k, v in res.timings_s.items()}}
    return res, images


def _reconstruct_project(project, options: PuppetOptions = DEFAULT, images=None, markerset: MarkerSet | None = None,
                         skeleton: Skeleton | None = None) -> tuple[PuppetResult, list]:
    """3D markers and pose from a project's stored markers (detections with the user's edits),
    and the photos.

    ``images`` (the decoded photos, view order) enable the fill test; default: read them.
    """
    from stillcap.io.project import Project

    if not isinstance(project, Project):
        project = Project.load(project)
    names, pts, rig = project.observations()
    if images is None:
        images = [project.read_image(v) for v in project.views]
    if markerset is not None and tuple(markerset.names) != tuple(project.markerset.names):
        raise ValueError(f"marker set {markerset.source}: its markers {list(markerset.names)} differ from project "
                         f"{project.root}'s {list(project.markerset.names)}")
    res = analyse_puppet_views(rig, images, markerset=markerset or project.markerset, observations=pts, options=options,
                               skeleton=skeleton or project.skeleton,
                               view_names=[v.name for v in project.views],
                               angles_deg=[v.angle_deg for v in project.views],
                               source={"type": "project", "path": str(project.root)},
                               files=[v.image for v in project.views])
    return res, images




def analyse_puppet(capture, options: PuppetOptions | None = None, *, palette: Palette | None = None,
                   progress: Callable[[int, int], None] | None = None, redetect: bool = False, detect: bool = True,
                   save: bool = True, workers: int = 2, markerset: MarkerSet | None = None,
                   skeleton: Skeleton | None = None) -> tuple[PuppetResult, list]:
    """The puppet pipeline (SPEC J3) on a capture folder or a puppet project: the beads found and
    named by colour in every photo, triangulated, and the skeleton posed on them.

    Parameters
    ----------
    capture : path or Project
        A capture folder of kind ``puppet`` (``capture.json``, e.g. from ``stillcap studio
        puppet``), or a puppet project (its folder, ``project.json``, or a loaded
        :class:`~stillcap.io.project.Project`).
    options : PuppetOptions, optional
        Default :data:`~stillcap.pipelines.puppet.DEFAULT`; the number of candidate circles is
        raised to the marker set's size.
    palette : Palette, optional
        Reference colours in marker-set order; default the marker set's colours.
    progress : callable(done, total), optional
        Called after each detected view.
    redetect : bool
        Projects: detect every view again (the user's edits still apply); by default only the
        views without detections are detected.
    detect : bool
        Projects: False uses only the stored markers (detections with edits), detecting nothing.
    save : bool
        Projects: save the new detections into the project.
    workers : int
        Capture folders: with 2 or more a second thread decodes the photos while this one
        detects (the same result as with 1).
    markerset, skeleton : MarkerSet, Skeleton, optional
        The puppet's beads and skeleton (``puppet run --markers/--skeleton``) instead of those
        the capture or project names (:func:`capture_markerset`, :func:`capture_skeleton`,
        ``Project.skeleton``). A project's marker set may be replaced only by one with the same
        marker names (its stored markers carry them).

    Returns
    -------
    result : PuppetResult
    images : list of ndarray
        The decoded photos, view order (for overlays).

    Raises
    ------
    ValueError
        A folder that is neither a capture folder nor a project, a capture of another kind, a
        project without views.

    Examples
    --------
    Twelve turntable photos of the studio's puppet written as a capture folder, then analysed
    (``with_options(detector="thesis")`` would run the thesis's own chain):

    >>> import tempfile
    >>> from stillcap.studio.puppet import puppet_scene
    >>> capture, photos = puppet_scene(rng=0).to_capture(".jpg")
    >>> folder = capture.save(tempfile.mkdtemp(), photos)
    >>> result, photos = analyse_puppet(folder)
    >>> len(result.names), result.missing   # markers, and those identified in fewer than two views
    (16, ())
    """
    options = DEFAULT if options is None else options
    if isinstance(capture, (str, os.PathLike)):  # a folder: io.project is imported only for a project (0.1-0.2 s)
        is_project = False
    else:
        from stillcap.io.project import Project

        is_project = isinstance(capture, Project)
    if not is_project:
        folder = Path(capture)
        if not folder.exists():
            raise ValueError(f"folder {folder} does not exist")
        if not folder.is_dir():
            raise ValueError(f"{folder} is not a folder (give a capture folder or a stillcap project)")
        if not (folder / "project.json").is_file():
            if not (folder / "capture.json").is_file():
                raise ValueError(f"{folder} is neither a capture folder (capture.json) nor a stillcap project "
                                 "(project.json)")
            if not detect:
                raise ValueError(f"{folder} is a capture folder, which stores no markers (detect=False is for "
                                 "projects)")
            return _analyse_capture(folder, options, palette, progress, workers, markerset, skeleton)
    body = {"markerset": markerset, "skeleton": skeleton}
    if not detect:
        return _reconstruct_project(capture, options, **body)
    return _analyse_project(capture, options, palette, redetect, progress, save, **body)
