"""`stillcap hand CAPTURE_DIR`: labelled glove markers, hand poses per flash, animation, ball release (SPEC J2)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from stillcap.cli._format import num as _f, print_notes, right_table
from stillcap.cli._response import RESPONSE_HELP, parse_response_option
from stillcap.cli._selfchecks import print_failed_checks
from stillcap.cli._progress import progress
from stillcap.cli._outputs import Outputs, check

console = Console()

#: The files ``--report DIR`` writes (checked before the analysis: an existing one must be stillcap's).
REPORT_FILES = ("report.html", "hand.json", "hand.gif", "joint_angles.png")


def _point(text: str | None, name: str):
    if text is None:
        return None
    import numpy as np

    try:
        v = [float(s) for s in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 3 or not all(np.isfinite(v)):
        raise typer.BadParameter(f"expected three numbers X,Y,Z in metres, got {text!r}", param_hint=name)
    return tuple(v)


def hand(
    capture: Path = typer.Argument(..., help="Hand capture folder (capture.json, rig.json, images/)."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON (keys as in truth.json, "
                                 "docs/hand-pipeline.md)."),
    report: Path = typer.Option(None, "--report", help="Write report.html, hand.gif, joint_angles.png and "
                                "hand.json to this folder."),
    export: list[Path] = typer.Option([], "--export", help="Export the animation and labelled markers "
                                      "(.bvh, .glb, .gltf, .dae, .c3d, .csv, .json); repeatable."),
    overrides: Path = typer.Option(None, "--overrides", help="Manual label corrections (JSON, "
                                   "docs/hand-labelling.md)."),
    personalise: str = typer.Option(None, "--personalise", help="Scale the hand model to the person: best "
                                    "(from the flash with most markers) or joint (all flashes)."),
    frame_rate: float = typer.Option(1000.0, "--frame-rate", help="Frames per second of the animation."),
    interpolation: str = typer.Option("spline", "--interpolation", help="spline (smooth) or slerp."),
    strobe_position: str = typer.Option(None, "--strobe-position", help="The strobe's position X,Y,Z in "
                                        "metres (rig world); default from capture.json meta."),
    slow_motion: float = typer.Option(1.0, "--slow-motion", help="Stretch time in the exported animation "
                                      "(BVH, glTF, COLLADA) by this factor, e.g. 40 to play a 60 ms take in 2.4 s "
                                      "(Blender plays a 1000 fps take within one 24 fps frame otherwise)."),
    force: bool = typer.Option(False, "--force", help="Overwrite files stillcap did not write (--report, --export)."),
    response: str = typer.Option(None, "--response", help=RESPONSE_HELP),
    hand_model: str = typer.Option(None, "--hand-model", help="The person's hand model: a stillcap-skeleton file "
                                   "or a built-in name (docs/hand.md); default capture.json hand_model, else "
                                   "hand-right-adult."),
    markers: str = typer.Option(None, "--markers", help="The glove's marker set: a stillcap-markerset file or a "
                                "built-in name (docs/hand-markers.md); default capture.json hand_markers, else "
                                "hand-18."),
    adapt_model: bool = typer.Option(False, "--adapt-model", help="Experimental: adapt the hand model to this "
                                     "capture before labelling (docs/hand.md: it did not reach 2 deg on other hands)."),
):
    """Glove markers, labels, hand poses per flash, a smooth animation and the ball's release.

    The capture holds one multi-exposure photo per camera of two stereo pairs lit by one strobe.
    Exit status 2 with a one-line message for captures that cannot give 3D markers.
    """
    import numpy as np

    from stillcap.pipelines.hand import HandOptions, analyse_hand

    if personalise not in (None, "best", "joint"):
        raise typer.BadParameter(f"{personalise!r} is not one of best, joint", param_hint="--personalise")
    if interpolation not in ("spline", "slerp"):
        raise typer.BadParameter(f"{interpolation!r} is not one of spline, slerp", param_hint="--interpolation")
    if overrides is not None:  # a bad file is named before the analysis runs
        from stillcap.body.hand_label import read_label_overrides

        read_label_overrides(overrides)
    if hand_model is not None or markers is not None:  # bad files are named before the analysis runs
        from stillcap.body.hand_files import load_hand, read_hand_markers, read_hand_model

        if hand_model is not None and markers is not None:
            load_hand(hand_model, markers)
        elif hand_model is not None:  # the other may come from capture.json: checked together in the analysis
            read_hand_model(hand_model)
        else:
            read_hand_markers(markers)
    opts = HandOptions(strobe_position_m=_point(strobe_position, "--strobe-position"), overrides=overrides,
                       personalise=personalise, frame_rate=frame_rate, interpolation=interpolation,
                       response=parse_response_option(response), hand_model=hand_model, hand_markers=markers,
                       adapt_model=adapt_model)
    if not (np.isfinite(slow_motion) and slow_motion > 0):
        raise typer.BadParameter(f"must be a positive factor, got {slow_motion}", param_hint="--slow-motion")
    from stillcap.io.export import EXPORTERS, known_extensions

    for path in export:
        if path.suffix.lower() not in EXPORTERS:
            raise ValueError(f"--export {path}: unknown extension {path.suffix.lower() or '(none)'!r}; "
                             f"known: {', '.join(known_extensions())}")
        check(path, "file", "--export", force)
    check(report, "folder", "--report", force, REPORT_FILES)
    with progress("analysing the hand") as bar:
        res = analyse_hand(capture, opts, progress=bar)
    from stillcap.studio.compare.hand import compare_with_capture, truth_arrays

    res.truth = compare_with_capture(res)  # a studio capture: compared with its truth
    from stillcap.cli._selfchecks import print_failed_checks

    print_failed_checks(res.self_checks, "hand")
    written = []
    outputs = Outputs(lambda: json.dumps(res.to_dict(), indent=1, allow_nan=False) + "\n", "hand.json")
    for path in export:
        from stillcap.io.export import export as export_file

        motion = path.suffix.lower() in (".bvh", ".glb", ".gltf", ".dae")
        if res.animation is None and motion:
            raise ValueError(f"cannot write {path.name}: the capture gave fewer than two hand poses (no animation)")
        with outputs.writing(f"--export {path}"):
            if motion and slow_motion != 1.0:
                from stillcap.body.skeleton import Animation

                an = res.animation
                written.append(export_file(path, Animation(an.skeleton, (an.times - an.times[0]) * slow_motion,
                                                           an.root2world, an.local_rotations)))
            else:
                written.append(export_file(path, res))
            outputs.record(written[-1:])
    if report is not None:
        from stillcap.report.hand import write_result_report

        with outputs.writing(f"--report {report}"):
            outputs.claim(report, REPORT_FILES)
            with progress("writing the report") as bar:
                paths = write_result_report(res, report, truth_arrays=None if res.truth is None
                                            else truth_arrays(res.capture.truth), progress=bar)
            outputs.record(paths.values(), report)
            written.append(paths["html"])
    if as_json:
        print(json.dumps(res.to_dict(), indent=1, allow_nan=False))
        outputs.finish(printed_json=True)
        return
    print_hand_result(res)
    for w in written:
        console.print(f"wrote [bold]{w}[/]")
    outputs.finish()


def print_hand_result(res) -> None:
    """Tables of the flashes, the poses and the release (and the truth comparison if any)."""
    import numpy as np

    print_notes(res.messages)
    print_failed_checks(res.self_checks, "hand")
    lab = res.labels
    pts = res.points
    console.print(f"{len(pts)} glove markers in 3D from pairs {', '.join(res.pairs)} "
                  f"({int(np.sum(pts.n_views > 2))} seen by both pairs, {int(np.sum(pts.partly_hidden))} partly hidden: "
                  f"listed apart in --json partly_hidden); strobe {res.strobe_hz:g} Hz")
    t = right_table(f"{lab.n_flashes} flashes with the hand ({int(lab.reconstructed.sum())} with a pose)",
                    ("flash", "time ms", "labelled", "fit RMS mm", "pose", "ball"))
    t.caption = "no pose: the reason in short (in full in the notes and in --json)" \
        if any(lab.skipped) else None
    held = res.ball_held()
    for k in range(lab.n_flashes):
        o = int(lab.order[k])
        ball = {True: "held", False: "free"}.get(held.get(o), "-")
        pose = "yes" if lab.reconstructed[k] else f"[red]no[/]: {short_reason(lab.skipped[k])}"
        t.add_row(str(o), _f(lab.times[k] * 1e3, 1), f"{int(np.sum(lab.point_index[k] >= 0))} / {len(lab.marker_names)}",
                  _f(lab.rms[k] * 1e3, 2), pose, ball)
    console.print(t)
    if res.sequence is not None:
        from stillcap.body.hand import hand_dofs

        seq = res.sequence
        a = Table(title="Joint angles per pose (flexion, deg)")
        a.add_column("joint")
        for o in lab.order[seq.flashes]:
            a.add_column(f"flash {int(o)}", justify="right")
        sk = seq.skeleton
        hidden = res.angles_partly_hidden()[seq.flashes]
        for i in sorted({i for i, ax in hand_dofs(sk) if ax == 1}):
            a.add_row(sk.names[i], *(_f(ang[i, 1], 1) + ("*" if h[i, 1] else "")
                                     for ang, h in zip(seq.angles_deg, hidden)))
        if hidden[:, :, 1].any():
            a.caption = ("*: rests only on partly hidden markers (their centroids shift by up to a few mm): "
                         "less sure than the others")
        console.print(a)
        if res.animation is not None:
            console.print(f"animation: {res.animation.n_frames} frames at {res.animation.frame_rate or 0:.0f} fps "
                          f"({(res.animation.times[-1] - res.animation.times[0]) * 1e3:.1f} ms)")
    rel = res.release
    if rel is not None and rel.success:
        console.print(f"release: {rel.t_release * 1e3:.2f} ± {rel.t_release_sigma * 1e3:.2f} ms, "
                      f"{rel.speed_mph:.1f} ± {rel.speed_sigma_mph:.1f} mph, direction "
                      f"{rel.horizontal_deg:+.1f} / {rel.vertical_deg:+.1f} deg (horizontal / vertical) "
                      f"± {rel.direction_sigma_deg:.1f}; velocity from {rel.velocity_source}", highlight=False)
    if res.spin is not None and res.spin.available:
        console.print(f"spin candidates: {', '.join(f'{r:.0f}' for r in res.spin.candidates_rpm)} rpm"
                      + (" (ambiguous: one strobe cannot tell them apart)" if res.spin.ambiguous else ""))
    if res.truth is not None:
        print_hand_comparison(res.truth)


def short_reason(why: str, width: int = 40) -> str:
    """A flash's no-pose reason for a table cell: its first clause (up to a parenthesis, colon or
    semicolon), at most ``width`` characters; the full text is in the notes and the JSON."""
    import re

    head = re.split(r" \(|: |; ", why or "", maxsplit=1)[0].strip() or "-"
    return head if len(head) <= width else head[: width - 3].rstrip() + "..."


def print_hand_comparison(cmp: dict) -> None:
    t = Table(title="Compared with the truth (truth.json)")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    rows = [("flashes with a pose / with the back of the hand in 2+ cameras",
             f"{cmp.get('flashes_reconstructed_back_seen', cmp['flashes_reconstructed'])} / "
             f"{cmp['flashes_back_seen_2plus']} (all posed: {cmp['flashes_reconstructed']})"),
            ("labels right", f"{_f(cmp['labels_right_pct'], 2)} %  ({cmp['labels_right']} of {cmp['labels']})"),
            ("markers seen in 2+ cameras, labelled right", f"{_f(cmp['markers_recovered_pct'], 1)} % fully seen + "
             f"{_f(cmp.get('markers_recovered_partly_hidden_pct'), 1)} % partly hidden"),
            ("marker 3D error RMS / max (fully seen)", f"{_f(cmp['marker_rms_mm'], 3)} / {_f(cmp['marker_max_mm'], 3)} mm"),
            ("partly hidden markers: labelled right, 3D error RMS / max",
             f"{cmp.get('partly_hidden_labels_right', 0)} of {cmp.get('partly_hidden_labels', 0)}, "
             f"{_f(cmp.get('partly_hidden_rms_mm'), 2)} / {_f(cmp.get('partly_hidden_max_mm'), 2)} mm"),
            ("joint angles RMS / max", f"{_f(cmp['joint_angle_rms_deg'], 2)} / {_f(cmp['joint_angle_max_deg'], 2)} deg"),
            ("joint positions RMS", f"{_f(cmp['joint_rms_mm'], 2)} mm")]
    if "ball_mean_mm" in cmp:
        rows.append(("ball positions mean / max", f"{_f(cmp['ball_mean_mm'], 2)} / {_f(cmp['ball_max_mm'], 2)} mm "
                     f"({cmp['ball_positions']} flashes)"))
    if "release_time_ms" in cmp:
        rows += [("release time", f"{_f(cmp['release_time_ms'], 2)} ms (1 sigma {_f(cmp['release_time_sigma_ms'], 2)})"),
                 ("release point", f"{_f(cmp['release_point_mm'], 1)} mm"),
                 ("release speed", f"{_f(cmp['release_speed_mph'], 2)} mph (1 sigma {_f(cmp['release_speed_sigma_mph'], 2)})"),
                 ("release direction", f"{_f(cmp['release_direction_deg'], 2)} deg")]
    for r in rows:
        t.add_row(*r)
    console.print(t)
