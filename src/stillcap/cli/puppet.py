"""`stillcap puppet ...`: the puppet stop-motion capture (SPEC J3) and its project files.

``stillcap puppet run FOLDER`` runs the pipeline on a capture folder (``stillcap studio puppet``)
or a project; the other commands manage a project (``docs/project-format.md``): ``new``,
``add``, ``edit``, ``show``, ``reconstruct``, ``capture`` (from a camera or a video file),
``import-jj`` / ``export-jj`` (the thesis's JumpingJack files), ``calibrate-palette``.

A click group cannot take a folder argument and also have subcommands (``stillcap puppet new
X`` would read ``new`` as the folder), so the pipeline is the subcommand ``run``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional, Tuple

import typer
from rich.console import Console
from rich.table import Table

from stillcap.cli._outputs import Outputs, check
from stillcap.cli._progress import progress
from stillcap.cli._response import RESPONSE_HELP, parse_response_option

app = typer.Typer(no_args_is_help=True, add_completion=False,
                  help="Puppet capture: turntable photos of a marked puppet -> 3D markers and a posed skeleton "
                       "(see docs/puppet.md), and puppet projects.")
console = Console()

#: The files ``--out DIR`` of ``run`` and ``reconstruct`` writes (checked before the analysis: an
#: existing one must be stillcap's).
OUT_FILES = ("result.json", "report.html", "markers_3d.png", "skeleton_3d.png", "overlays/*.png")
Force = Annotated[bool, typer.Option("--force", help="Overwrite files stillcap did not write.")]


def _settings(detector: str, identify: str):
    from stillcap.detect.beads import DETECTORS, IDENTIFIERS
    from stillcap.pipelines.puppet import DEFAULT, with_options

    if detector not in DETECTORS:
        raise ValueError(f"unknown detector {detector!r}; choose one of {', '.join(DETECTORS)}")
    if identify not in IDENTIFIERS:
        raise ValueError(f"unknown identification {identify!r}; choose one of {', '.join(IDENTIFIERS)}")
    return with_options(DEFAULT, detector=detector, identify=identify)


def _tolerance_settings(settings, bone_tolerance_deg: float):
    """``settings`` with the stated ``--bone-tolerance-deg`` (ValueError naming the option)."""
    import math

    from stillcap.pipelines.puppet import with_options

    if not (math.isfinite(bone_tolerance_deg) and 0 <= bone_tolerance_deg < 90):
        raise ValueError(f"--bone-tolerance-deg must be an angle in [0, 90) degrees, got {bone_tolerance_deg:g}")
    return with_options(settings, bone_tolerance_deg=bone_tolerance_deg)


def load_palette(path: Path | None, markerset=None):
    """A palette file (``stillcap palette --json`` or ``puppet calibrate-palette``) by marker name."""
    if path is None:
        return None
    import numpy as np

    from stillcap.body.markerset import MarkerSet
    from stillcap.detect.palette import Palette

    markerset = markerset or MarkerSet.puppet()
    if not Path(path).is_file():
        raise ValueError(f"palette file {path} does not exist")
    pal = Palette.load(path)
    colors = dict(zip(pal.names, pal.rgb))
    missing = [n for n in markerset.names if n not in colors]
    if missing:
        raise ValueError(f"palette file {path} lacks the markers {missing}")
    return Palette(markerset.names, np.array([colors[n] for n in markerset.names], float))


def _print_result(res, title: str) -> None:
    import numpy as np

    m, cmp = res.markers, res.comparison
    t = Table(title=title)
    cols = ["marker", "x mm", "y mm", "z mm", "views used", "identified in", "reproj px"]
    if cmp is not None:
        cols.append("error mm")
    for c in cols:
        t.add_column(c, justify="right")
    for k, n in enumerate(m.names):
        if m.ok[k]:
            flag = " *" if m.whole_views[k] < 2 else ""
            row = [n + flag, *(f"{v * 1e3:.2f}" for v in m.points[k]), str(int(m.n_views[k])),
                   str(int(m.identified_views[k])),
                   f"{m.reproj_error_px[k]:.2f}" if np.isfinite(m.reproj_error_px[k]) else "-"]
            if cmp is not None:
                row.append(f"{cmp.marker_errors_m[k] * 1e3:.3f}")
        else:
            row = [f"[red]{n}[/]", "[red]missing[/]", "", "", str(int(m.n_views[k])), str(int(m.identified_views[k])), "-"]
            if cmp is not None:
                row.append("-")
        t.add_row(*row)
    console.print(t)
    if m.missing:
        console.print(f"[red]seen in fewer than two views (no 3D position):[/] {', '.join(m.missing)}")
    weak = [n for n, ok, w in zip(m.names, m.ok, m.whole_views) if ok and w < 2]
    if weak:
        console.print(f"* fewer than two views show the whole bead (partly hidden or at the image border): "
                      f"{', '.join(weak)}")
    left = int(m.partial.sum()), int(m.outlier.sum())
    console.print(f"views left out: {left[0]} partly hidden beads, {left[1]} disagreeing views (outliers)")
    fit = res.fit
    console.print(f"pose ({res.options.pose}): markers fitted with RMS {fit.rms_m * 1e3:.3f} mm "
                  f"(thesis bone directions: {np.sqrt(np.nanmean(fit.thesis_residuals_m ** 2)) * 1e3:.2f} mm)")
    _print_bead_pairs(res)
    if cmp is not None:
        print_comparison(cmp)
    from stillcap.cli._selfchecks import print_failed_checks

    print_failed_checks(getattr(res, "self_checks", []), "puppet")


def _print_bead_pairs(res) -> None:
    """The thesis's model-free bead-pair bone directions beside the fitted pose's."""
    import numpy as np

    from stillcap.body.kinematics import normalised
    from stillcap.body.puppet_checks import bead_pair_directions

    pairs = bead_pair_directions(res.markerset, res.markers.points)
    if not pairs:
        return
    model = bead_pair_directions(res.markerset, res.markerset.positions(res.fit.pose))
    vecs = normalised(res.pose.bone_vectors())
    sk = res.pose.skeleton
    t = Table(title="Bone directions: bead pairs (model-free, the thesis's) beside the fitted pose")
    for c in ("bone", "beads", "bead pair x y z", "fitted bone x y z", "pair vs fitted pair deg"):
        t.add_column(c, justify="right")
    for b, d in pairs.items():
        ang = (np.degrees(np.arccos(np.clip(d["direction"] @ model[b]["direction"], -1, 1))) if b in model
               else float("nan"))
        fitted = vecs[sk.index(b)] if b in sk else np.full(3, np.nan)
        t.add_row(b, f"{d['from']} -> {d['to']}", " ".join(f"{v:+.3f}" for v in d["direction"]),
                  " ".join(f"{v:+.3f}" for v in fitted), f"{ang:.2f}")
    console.print(t)


def print_comparison(cmp) -> None:
    """The comparison with the truth, as a table."""
    from stillcap.report.puppet_html import comparison_rows

    t = Table(title="Compared with the truth (truth.json)")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for row in comparison_rows(cmp):
        t.add_row(*row)
    console.print(t)


def _write_outputs(res, images, out: Path | None, truth=None, overlays: bool = True, say: Console = console
                   ) -> Outputs:
    """Write ``--out``; the :class:`Outputs` whose ``finish`` the caller calls after printing.
    ``say``: where the "wrote ..." line goes (stderr when stdout carries JSON)."""
    from stillcap.io.project import dumps_json

    outputs = Outputs(lambda: dumps_json(res.to_dict()) + "\n", "result.json")
    if out is None:
        return outputs
    from stillcap.files.atomic import write_text
    from stillcap.report.puppet import write_report

    with outputs.writing(f"--out {out}"):
        outputs.claim(out, OUT_FILES)
        with progress("writing the report") as bar:
            outputs.record([write_text(out / "result.json", dumps_json(res.to_dict()) + "\n")], out)
            files = write_report(res, images, out, truth, overlays=overlays, progress=bar)
        outputs.record(files, out)
        n_overlays = sum(f.parent.name == "overlays" for f in files)
        say.print(f"wrote result.json, report.html, {n_overlays} overlays, markers_3d.png and skeleton_3d.png to "
                  f"[bold]{out}[/]")
    return outputs


def _body_files(skeleton: Path | None, markers: Path | None) -> dict:
    """``--skeleton`` and ``--markers`` read (ValueError naming the file), as analyse_puppet's keywords."""
    from stillcap.body.markerset import MarkerSet
    from stillcap.body.skeleton import Skeleton

    out = {}
    for key, path, cls, word in (("skeleton", skeleton, Skeleton, "--skeleton"),
                                 ("markerset", markers, MarkerSet, "--markers")):
        if path is None:
            continue
        if not path.is_file():
            raise ValueError(f"{word} {path}: no such file")
        out[key] = cls.load(path)
    if "skeleton" in out and "markerset" in out:
        out["markerset"].check_skeleton(out["skeleton"])
    return out


def _truth_of(folder: Path):
    from stillcap.studio.compare.puppet import capture_truth

    if not (folder / "capture.json").is_file():
        return None
    return capture_truth(folder)


@app.command()
def run(
    folder: Path = typer.Argument(..., help="A puppet capture folder (stillcap studio puppet) or a puppet project."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON (keys shared with truth.json)."),
    out: Path = typer.Option(None, "--out", help="Write result.json, overlays of every view and 3D plots here."),
    detector: str = typer.Option("template", "--detector", help="Bead detector: template (default) or thesis "
                                 "(IsoData + outline + Hough); also hough, blobs, cv2."),
    identify: str = typer.Option("recommended", "--identify", help="recommended (assignment, CIEDE2000, "
                                 "white-balance adaptation) or thesis (greedy HSB)."),
    palette: Path = typer.Option(None, "--palette", help="Reference colours (a palette JSON, e.g. from "
                                 "stillcap puppet calibrate-palette)."),
    redetect: bool = typer.Option(False, "--redetect", help="Projects: detect again in every view (the stored "
                                  "edits still apply); by default only views without detections are detected."),
    skeleton: Path = typer.Option(None, "--skeleton", help="The puppet's skeleton (a stillcap-skeleton JSON file, "
                                  "e.g. from stillcap puppet calibrate-skeleton) instead of the capture's or "
                                  "project's (default: the built-in puppet)."),
    markers: Path = typer.Option(None, "--markers", help="The puppet's beads (a stillcap-markerset JSON file) "
                                 "instead of the capture's or project's."),
    force: Force = False,
    response: str = typer.Option(None, "--response", help=RESPONSE_HELP + " (auto: not for the puppet yet)"),
    bone_tolerance: float = typer.Option(0.5, "--bone-tolerance-deg", help="Bone-direction error you accept, "
                                         "degrees: the per-bone self-checks name a bone only when its misfit is "
                                         "significant and larger than this (0: every significant misfit)."),
):
    """Find, name and triangulate the beads in every photo and pose the skeleton.

    With a synthetic capture (truth.json) the result is compared with the truth. Markers
    identified in fewer than two views are flagged as missing.
    """
    from stillcap.io.project import dumps_json
    from stillcap.pipelines.puppet import analyse_puppet

    settings = _tolerance_settings(_settings(detector, identify), bone_tolerance)
    if response is not None:
        from stillcap.pipelines.puppet import with_options

        settings = with_options(settings, response=parse_response_option(response))
    check(out, "folder", "--out", force, OUT_FILES)
    if not folder.exists():
        raise ValueError(f"folder {folder} does not exist")
    body = _body_files(skeleton, markers)
    markerset = body.get("markerset")
    if markerset is None and (folder / "project.json").is_file():
        from stillcap.io.project import Project

        markerset = Project.load(folder).markerset
    elif markerset is None and palette is not None and (folder / "capture.json").is_file():
        # the capture's own marker set (puppet-20, a file's...), read as analyse_puppet reads it
        from stillcap.pipelines.puppet import capture_markerset

        markerset = capture_markerset(folder)
    pal = load_palette(palette, markerset)
    with progress("detecting beads") as update:
        res, images = analyse_puppet(folder, settings, palette=pal, redetect=redetect, progress=update, **body)
    if res.source.get("type") == "capture":  # a studio capture: compared with its truth
        from stillcap.studio.compare.puppet import compare_with_capture

        res.comparison = compare_with_capture(res, folder)
    outputs = _write_outputs(res, images, out, _truth_of(folder) if out is not None else None,
                             say=Console(stderr=True) if as_json else console)  # stdout: the JSON only
    if as_json:
        from stillcap.cli._selfchecks import print_failed_checks

        print(dumps_json(res.to_dict()))
        print_failed_checks(res.self_checks, "puppet")  # stderr
        outputs.finish(printed_json=True)
        return
    _print_result(res, f"{int(res.markers.ok.sum())} of {len(res.names)} markers from {len(res.rig)} views "
                       f"({settings.detector} + {settings.identify}; puppet frame)")
    outputs.finish()


# --- projects ---------------------------------------------------------------------------------
@app.command()
def new(
    project: Path = typer.Argument(..., help="New project folder."),
    distance_mm: float = typer.Option(400.0, "--distance-mm", help="Turntable: camera centre to the turn axis, mm."),
    height_mm: float = typer.Option(80.0, "--height-mm", help="Turntable: lens centre above the platform, mm."),
    rig: Path = typer.Option(None, "--rig", help="A rig file (several calibrated cameras) instead of a turntable."),
    name: str = typer.Option(None, "--name", help="Project name (default: the folder name)."),
    skeleton: Path = typer.Option(None, "--skeleton", help="The puppet's skeleton (a stillcap-skeleton JSON file, "
                                  "e.g. from puppet calibrate-skeleton), kept in project.json; default the "
                                  "built-in puppet's."),
    markers: Path = typer.Option(None, "--markers", help="The puppet's beads (a stillcap-markerset JSON file), "
                                 "kept in project.json; default puppet-16."),
):
    """Make an empty puppet project (the thesis's turntable and webcam by default)."""
    from stillcap.camera import Rig
    from stillcap.io.project import Project, TurntableSetup

    check(project, "folder", "PROJECT", names=("project.json",))
    body = _body_files(skeleton, markers)
    kw = dict(name=name, skeleton=body.get("skeleton"), markerset=body.get("markerset", "puppet-16"))
    if rig is not None:
        p = Project.create(project, rig=Rig.load(rig), **kw)
        what = f"rig project with cameras {', '.join(p.rig.names)}"
    else:
        p = Project.create(project, turntable=TurntableSetup(distance=distance_mm / 1000, height=height_mm / 1000),
                           **kw)
        what = f"turntable project (camera {distance_mm:g} mm from the axis, {height_mm:g} mm up)"
    console.print(f"created {what} in [bold]{p.root}[/]")


def _view_key(project, view: str):
    """A view by name, turn angle in degrees (turntable projects) or #index."""
    if view.startswith("#"):
        try:
            return project.view(int(view[1:]))
        except ValueError:
            raise ValueError(f"bad view index {view!r} (use #0, #1, ...)") from None
    if any(v.name == view for v in project.views):
        return project.view(view)
    try:
        angle = float(view.removesuffix("deg"))
    except ValueError:
        angle = None
    if angle is not None and project.is_turntable:
        v = project.view_at(angle)
        if v is not None:
            return v
        raise ValueError(f"project has no view at {angle:g} deg (angles: {', '.join(f'{a:g}' for a in project.angles_deg)})")
    raise ValueError(f"no view {view!r} in the project (views: {', '.join(v.name for v in project.views) or 'none'}; "
                     "give a name, a turn angle in degrees or #index)")


def _detector_fn(project, settings, palette=None):
    from stillcap.detect.palette import Palette
    from stillcap.pipelines.puppet import detect_view

    pal = palette or Palette.from_markerset(project.markerset)
    return lambda image: detect_view(image, pal, settings).identification.as_dict()


@app.command()
def add(
    project: Path = typer.Argument(..., help="Project folder."),
    photo: Path = typer.Argument(..., help="Photo file (PNG or JPEG)."),
    angle: float = typer.Option(None, "--angle", help="Turn angle of the photo, degrees (turntable projects)."),
    camera: str = typer.Option(None, "--camera", help="Rig camera that took it (rig projects)."),
    detect: bool = typer.Option(True, "--detect/--no-detect", help="Detect and identify the beads now."),
    replace: bool = typer.Option(False, "--replace", help="Retake a view at the same angle or camera."),
    detector: str = typer.Option("template", "--detector", help="Bead detector (see puppet run)."),
    identify: str = typer.Option("recommended", "--identify", help="Identification (see puppet run)."),
):
    """Add a photo to a project (copied into photos/); its beads are detected and identified."""
    from stillcap.files.images import read_image
    from stillcap.io.project import Project

    p = Project.load(project)
    detections = None
    if detect:
        img = read_image(photo)  # ValueError naming the photo: missing, too large, truncated, not an image
        detections = _detector_fn(p, _settings(detector, identify))(img)
    v = p.add_view(photo, angle_deg=angle, camera=camera, detections=detections, replace=replace)
    p.save()
    console.print(f"added view [bold]{v.name}[/] ({v.image})"
                  + (f": {len(v.detected)} markers identified" if detect else ""))


@app.command()
def edit(
    project: Path = typer.Argument(..., help="Project folder."),
    view: str = typer.Argument(..., help="View: its name (turn_030.0deg), turn angle in degrees (30) or #index."),
    delete: str = typer.Option(None, "--delete", help="Delete this (wrongly identified) marker."),
    relabel: Optional[Tuple[str, str]] = typer.Option(None, "--relabel", help="OLD NEW: the point called OLD is NEW."),
    move: Optional[Tuple[str, float, float]] = typer.Option(None, "--move", help="NAME X Y: put a marker at "
                                                            "pixel (x, y), adding it if absent."),
    clear: bool = typer.Option(False, "--clear", help="Drop the view's edits (back to the automatic detections)."),
):
    """Correct a view's markers (kept when detection runs again)."""
    from stillcap.io.project import Project

    p = Project.load(project)
    v = _view_key(p, view)
    given = [k for k, a in (("--delete", delete), ("--relabel", relabel), ("--move", move), ("--clear", clear)) if a]
    if len(given) != 1:
        raise ValueError(f"edit takes exactly one of --delete, --relabel, --move, --clear; got {given or 'none'}")
    if clear:
        p.clear_edits(v)
    elif delete:
        p.edit(v, delete=delete)
    elif relabel:
        p.edit(v, relabel=relabel)
    else:
        p.edit(v, move=move)
    p.save()
    console.print(f"view [bold]{v.name}[/]: {len(v.markers)} markers, {len(v.edits)} edits")


@app.command()
def show(
    project: Path = typer.Argument(..., help="Project folder."),
    as_json: bool = typer.Option(False, "--json", help="Print views and marker coverage as JSON."),
):
    """List a project's views and how many views identified each marker."""
    from stillcap.io.project import Project

    p = Project.load(project)
    names = list(p.markerset.names)
    count = {n: 0 for n in names}
    for v in p.views:
        for n in v.markers:
            count[n] = count.get(n, 0) + 1
    missing = [n for n in names if count[n] < 2]
    if as_json:
        print(json.dumps({"name": p.name, "kind": "turntable" if p.is_turntable else "rig",
                          "views": [{"name": v.name, "image": v.image, "angle_deg": v.angle_deg, "camera": v.camera,
                                     "detected": len(v.detected), "edits": len(v.edits), "markers": len(v.markers)}
                                    for v in p.views],
                          "views_per_marker": count, "seen_fewer_than_twice": missing}, indent=1))
        return
    t = Table(title=f"project {p.name!r} ({'turntable' if p.is_turntable else 'rig'}, {len(p.views)} views)")
    for c in ("view", "angle deg" if p.is_turntable else "camera", "photo", "detected", "edits", "markers"):
        t.add_column(c, justify="right")
    for v in p.views:
        t.add_row(v.name, f"{v.angle_deg:g}" if p.is_turntable else str(v.camera), v.image, str(len(v.detected)),
                  str(len(v.edits)), str(len(v.markers)))
    console.print(t)
    m = Table(title="views per marker (2+ needed for 3D)")
    for n in names:
        m.add_column(n, justify="right")
    m.add_row(*[f"[red]{count[n]}[/]" if count[n] < 2 else str(count[n]) for n in names])
    console.print(m)
    if missing:
        console.print(f"[red]seen in fewer than two views:[/] {', '.join(missing)}")


@app.command()
def reconstruct(
    project: Path = typer.Argument(..., help="Project folder."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
    out: Path = typer.Option(None, "--out", help="Write result.json, overlays and 3D plots here."),
    force: Force = False,
    skeleton: Path = typer.Option(None, "--skeleton", help="The puppet's skeleton (a stillcap-skeleton JSON file) "
                                  "instead of the project's."),
    markers: Path = typer.Option(None, "--markers", help="The puppet's beads (a stillcap-markerset JSON file with "
                                 "the project's marker names) instead of the project's."),
    bone_tolerance: float = typer.Option(0.5, "--bone-tolerance-deg", help="Bone-direction error you accept, "
                                         "degrees: the per-bone self-checks name a bone only when its misfit is "
                                         "significant and larger than this (0: every significant misfit)."),
):
    """3D markers and the pose from the project's stored markers (detections with edits)."""
    from stillcap.io.project import dumps_json
    from stillcap.pipelines.puppet import DEFAULT, analyse_puppet

    settings = _tolerance_settings(DEFAULT, bone_tolerance)
    check(out, "folder", "--out", force, OUT_FILES)
    body = _body_files(skeleton, markers)
    with progress("triangulating and posing"):
        res, images = analyse_puppet(project, settings, detect=False, **body)
    outputs = _write_outputs(res, images, out, say=Console(stderr=True) if as_json else console)
    if as_json:
        print(dumps_json(res.to_dict()))
        outputs.finish(printed_json=True)
        return
    _print_result(res, f"{int(res.markers.ok.sum())} of {len(res.names)} markers from {len(res.rig)} views")
    outputs.finish()


@app.command()
def capture(
    project: Path = typer.Argument(..., help="Turntable project folder (stillcap puppet new)."),
    source: str = typer.Option("0", "--source", help="Camera index (0, 1, ...) or a video file."),
    angles: str = typer.Option("12x30", "--angles", help="Turn angles: NxSTEP (12x30), NxSTEP@START or a list "
                               "(0,30,90), degrees."),
    average: int = typer.Option(1, "--average", min=1, help="Frames averaged per photo."),
    replace: bool = typer.Option(False, "--replace", help="Retake angles the project already has."),
    detect: bool = typer.Option(True, "--detect/--no-detect", help="Detect and identify the beads in each photo."),
):
    """Take one photo per turn angle from a camera or a video file into a project.

    Before each angle it asks you to turn the table: Enter takes the photo, s skips the angle,
    q stops (photos taken so far stay saved).
    """
    from stillcap.io.camera_capture import ABORT, SKIP, capture_turntable, parse_angles
    from stillcap.io.project import Project

    p = Project.load(project)
    angle_list = parse_angles(angles)
    taken = [a for a in angle_list if p.view_at(a) is not None]
    if taken and not replace:
        raise ValueError(f"project {p.root} already has photos at {', '.join(f'{a:g}' for a in taken)} deg; "
                         "pass --replace to retake them")
    src: int | str = int(source) if source.strip().isdigit() and not Path(source).exists() else source

    def prompt(a: float):
        try:
            answer = typer.prompt(f"turn the table to {a:g} deg; Enter = take, s = skip, q = quit", default="",
                                  show_default=False)
        except typer.Abort:
            return ABORT
        answer = answer.strip().lower()
        if answer in ("q", "quit"):
            return ABORT
        if answer in ("s", "skip"):
            return SKIP
        return None

    det = _detector_fn(p, _settings("template", "recommended")) if detect else None
    res = capture_turntable(p, src, angle_list, prompt=prompt, frames_to_average=average, replace=replace, detect=det)
    for v in res.views:
        console.print(f"  {v.name}: {v.image}" + (f", {len(v.detected)} markers" if detect else ""))
    msg = f"took {len(res.views)} photos"
    if res.skipped_deg:
        msg += f", skipped {', '.join(f'{a:g}' for a in res.skipped_deg)} deg"
    if res.aborted:
        msg += " (stopped)"
    console.print(msg + f"; project saved in [bold]{p.root}[/]")


@app.command("import-jj")
def import_jj(
    juja: Path = typer.Argument(..., help="A JumpingJack .juja file (its photos beside it)."),
    project: Path = typer.Argument(..., help="New project folder."),
):
    """Make a project from the thesis's JumpingJack file (photos and identified markers)."""
    from stillcap.io.jumpingjack import import_jumpingjack

    check(project, "folder", "PROJECT", names=("project.json",))
    p = import_jumpingjack(juja, project)
    console.print(f"imported {len(p.views)} views into [bold]{p.root}[/]")


@app.command("export-jj")
def export_jj(
    project: Path = typer.Argument(..., help="Project folder."),
    juja: Path = typer.Argument(..., help="The .juja file to write (photos are copied beside it)."),
    round_pixels: bool = typer.Option(False, "--round", help="Whole-pixel positions, as the thesis's program wrote."),
    force: bool = typer.Option(False, "--force", help="Overwrite files stillcap did not write (the .juja file and "
                               "the photos beside it)."),
):
    """Write a project as a JumpingJack .juja file (the thesis's format)."""
    from stillcap.files.outputs import record_outputs
    from stillcap.io.jumpingjack import JJ_SUFFIX, export_jumpingjack, exported_files
    from stillcap.io.project import Project

    p = Project.load(project)
    if juja.suffix.lower() != JJ_SUFFIX:
        juja = juja.with_name(juja.name + JJ_SUFFIX)
    check(juja, "file", "JUJA", force)
    for f in exported_files(p, juja):
        check(f, "file", "JUJA (a photo beside it)", force)
    path = export_jumpingjack(p, juja, round_pixels=round_pixels)
    record_outputs([path, *exported_files(p, path)])
    console.print(f"wrote [bold]{path}[/]")


@app.command("calibrate-palette")
def calibrate_palette_cmd(
    folder: Path = typer.Argument(..., help="T-pose photos: a capture folder or a project."),
    out: Path = typer.Option(..., "--out", help="Palette JSON to write (use it with puppet run --palette)."),
    force: Force = False,
    markers: Path = typer.Option(None, "--markers", help="The puppet's beads (a stillcap-markerset JSON file) "
                                 "instead of the capture's or project's."),
    skeleton: Path = typer.Option(None, "--skeleton", help="The puppet's skeleton (a stillcap-skeleton JSON file)."),
):
    """Measure the beads' reference colours from T-pose photos (the thesis's calibration).

    The beads are found and identified with the current colours, then each marker's colour is
    the mean of its patches over all photos.
    """
    import numpy as np

    from stillcap.detect.identify import calibrate_palette
    from stillcap.files.atomic import write_text
    from stillcap.pipelines.puppet import DEFAULT, analyse_puppet

    check(out, "file", "--out", force)
    body = _body_files(skeleton, markers)
    with progress("detecting beads") as update:
        res, images = analyse_puppet(folder, DEFAULT, progress=update, **body)
    pts = [np.where(res.markers.used[k][:, None], res.markers.observations[k], np.nan) for k in range(len(images))]
    from stillcap.detect.palette import Palette

    cal = calibrate_palette(images, pts, Palette.from_markerset(res.markerset), sampler="disc")
    text = json.dumps(cal.palette.to_dict(), indent=1) + "\n"
    outputs = Outputs(lambda: text, "palette.json")
    with outputs.writing(f"--out {out}"):
        outputs.record([write_text(out, text)])
    t = Table(title=f"colours measured in {len(images)} photos")
    for c in ("marker", "reference", "measured", "photos", "spread dE00"):
        t.add_column(c, justify="right")
    ref = Palette.from_markerset(res.markerset)
    for k, n in enumerate(ref.names):
        t.add_row(n, ref.hex[k], cal.palette.hex[k], str(int(cal.n_samples[k])),
                  f"{cal.spread[k]:.2f}" if np.isfinite(cal.spread[k]) else "-")
    console.print(t)
    if not outputs.failed:
        console.print(f"wrote [bold]{out}[/]")
    outputs.finish()


@app.command("calibrate-skeleton")
def calibrate_skeleton_cmd(
    capture: Path = typer.Argument(..., help="A capture folder or project of the puppet in its rest pose (T-pose, "
                                   "every joint at rest)."),
    poses: list[Path] = typer.Option(None, "--pose", help="Further captures of the same puppet in other poses "
                                     "(bent elbows and knees): they fix where the joints lie between the beads. "
                                     "Repeat for several."),
    out: Path = typer.Option(Path("skeleton.json"), "--out", help="Skeleton file to write (stillcap-skeleton)."),
    markers_out: Path = typer.Option(None, "--markers-out", help="Marker-set file to write (default: OUT's name "
                                     "with -markers, e.g. skeleton-markers.json)."),
    skeleton: Path = typer.Option(None, "--skeleton", help="Template skeleton (joint names, limits, rest "
                                  "directions); default the built-in puppet."),
    markers: Path = typer.Option(None, "--markers", help="Template marker set (which bead is on which bone); "
                                 "default the capture's."),
    rest_turn_deg: float = typer.Option(0.0, "--rest-turn-deg", help="How far the puppet in the rest capture is "
                                        "turned about the vertical from the template's rest frame, degrees (0: "
                                        "facing the template's way). Kept unless the beads reject it, then the "
                                        "estimated turn is used and printed."),
    estimate_rest_turn: bool = typer.Option(False, "--estimate-rest-turn", help="Use the estimated rest turn "
                                            "even where the beads do not reject --rest-turn-deg."),
    force: Force = False,
):
    """Estimate the puppet's bone lengths and bead offsets from a rest-pose capture and write a
    skeleton file and a marker-set file (use them with puppet run --skeleton/--markers)."""
    import numpy as np

    from stillcap.body.puppet_calibrate import calibrate_skeleton
    from stillcap.body.puppet_checks import bead_noise
    from stillcap.body.skeleton import Skeleton
    from stillcap.pipelines.puppet import analyse_puppet

    if not np.isfinite(rest_turn_deg):
        raise ValueError(f"--rest-turn-deg must be a finite angle in degrees, got {rest_turn_deg}")
    markers_out = markers_out or out.with_name(out.stem + "-markers.json")
    check(out, "file", "--out", force)
    check(markers_out, "file", "--markers-out", force)
    body = _body_files(skeleton, markers)
    template = body.get("skeleton") or Skeleton.puppet()

    def beads(folder: Path):
        if not folder.exists():
            raise ValueError(f"capture {folder} does not exist")
        with progress(f"detecting beads in {folder}") as update:
            res, _ = analyse_puppet(folder, progress=update, markerset=body.get("markerset"), skeleton=template)
        m = res.markers
        pts = m.points.copy()
        pts[m.partly_hidden] = np.nan  # partly hidden beads: 1-2 mm off, not to calibrate on
        # the bead noise as this capture's photos show it (reprojection residuals), not a stated one
        noise = bead_noise(res.rig, m.points, m.observations, m.used, exclude=m.partly_hidden)
        return res.markerset, pts, noise

    markerset, rest, rest_noise = beads(capture)
    others = [beads(p) for p in (poses or [])]
    noises = [rest_noise] + [o[2] for o in others]
    cal = calibrate_skeleton(rest, template, markerset, [o[1] for o in others], noise_m=[n.sd_m for n in noises],
                             rest_turn_deg=None if estimate_rest_turn else rest_turn_deg)
    cal.skeleton.save(out, "mm")
    cal.markerset.save(markers_out, "mm")
    t = Table(title=f"{cal.skeleton.name}: bone lengths (from {cal.n_poses} capture(s))")
    for c in ("bone", "template mm", "calibrated mm", "ratio", "direction +- deg"):
        t.add_column(c, justify="right")
    for j, n in enumerate(cal.skeleton.names):
        if template.bone_lengths[j] > 0:
            sd = cal.direction_sd_deg.get(n)
            t.add_row(n, f"{template.bone_lengths[j] * 1e3:.1f}", f"{cal.skeleton.bone_lengths[j] * 1e3:.1f}",
                      f"{cal.scales[j]:.3f}", "-" if sd is None else f"{sd:.2f}")
    console.print(t)
    if np.isfinite(cal.rest_turn_estimated_deg):
        how = ("as stated: the estimate's " if cal.rest_turn_stated else "estimated, ") + (
            f"{cal.rest_turn_estimated_deg:.2f} +- {cal.rest_turn_sd_deg:.2f} deg (1 sigma)")
        if not cal.rest_turn_stated and not estimate_rest_turn:
            how += f", rejects the stated {rest_turn_deg:g} deg"
        console.print(f"rest capture turned {cal.rest_turn_deg:.2f} deg about the vertical from the template's "
                      f"rest frame ({how})")
    console.print(f"beads fitted with RMS {cal.rms_m * 1e3:.3f} mm (per capture: "
                  + ", ".join(f"{v * 1e3:.3f}" for v in cal.per_pose_rms_m) + " mm)")
    console.print("bead noise the photos show (per capture): " + ", ".join(
        f"{n.pixel_sd:.2f} px = {n.rms_m * 1e3:.3f} mm" for n in noises)
        + (f"; the calibration's misfit {cal.misfit:.2f} (above 1 widens the predicted errors)"
           if np.isfinite(cal.misfit) else ""))
    if cal.joint_converged is False:
        console.print(f"[yellow]the joint fit stopped after {cal.joint_evaluations} evaluations without converging: "
                      "the bone lengths depend on where it stopped[/]")
    if not poses:
        console.print("[yellow]a rest pose alone places the beads but not where the joints lie between them; "
                      "add --pose captures with bent joints to fix them[/]")
    for bone, need in cal.unfixed.items():
        console.print(f"[yellow]{bone}: {need}[/]")
    for bone, need in cal.uncertain.items():
        console.print(f"[yellow]{bone}: {need}[/]")
    for bone, need in cal.weakly_posed.items():
        console.print(f"[yellow]{bone}: {need}[/]")
    console.print(f"wrote [bold]{out}[/] and [bold]{markers_out}[/]")
