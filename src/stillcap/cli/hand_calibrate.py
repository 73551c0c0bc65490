"""``stillcap hand-calibrate``: the person's hand model from a calibration capture."""

from __future__ import annotations

from pathlib import Path

import typer


def hand_calibrate(
    capture: list[Path] = typer.Argument(..., help="Calibration capture folder(s) (a hand capture of the gloved hand "
                                         "held in the pose, then through the protocol's steps; "
                                         "docs/hand-calibration.md). Several captures of the same hand and glove are "
                                         "fitted together (more bends: fewer parameters left at the template's)."),
    out: Path = typer.Option(..., "--out", help="The hand model to write (stillcap-skeleton JSON), for "
                             "stillcap hand --hand-model."),
    markers_out: Path = typer.Option(None, "--markers-out", help="The glove marker set to write (default: "
                                     "OUT with .markers.json), for stillcap hand --markers."),
    pose: str = typer.Option("flat", "--pose", help="The calibration pose: flat (hand flat, fingers extended "
                             "and together, thumb alongside)."),
    markers: str = typer.Option(None, "--markers", help="The glove's marker set (file or built-in name; default "
                                "hand-18)."),
    template: str = typer.Option(None, "--template", help="The hand model to start from (file or built-in name; "
                                 "default hand-right-adult)."),
    report: Path = typer.Option(None, "--report", help="Also write the calibration report (stillcap-hand-calibration "
                                "JSON: every estimated length, knuckle place, marker height and thumb axis with its "
                                "1-sigma, the self-checks)."),
    max_length_sigma: float = typer.Option(None, "--max-length-sigma", help="Refuse (exit 2) when a bone length "
                                           "is known worse than this 1-sigma (mm): the capture did not bend that "
                                           "joint enough."),
    marker_noise: str = typer.Option("own", "--marker-noise", help="How the fit weighs each 3D marker: own (its "
                                     "own noise from the photos: a partly hidden marker, whose centre shifts, counts "
                                     "less the less of it a camera saw) or common (every marker alike, 0.4 mm)."),
):
    """Estimate the person's hand model (phalanx lengths, marker places, knuckles, thumb) from a
    capture of the hand in a known pose; write it and its marker set.

    Exit status 2 with one line when the capture is not in the stated pose.
    """
    from rich.console import Console

    from stillcap.body.hand_calibrate import CALIBRATION_POSES, UNFIXED_SIGMA_RATIO
    from stillcap.cli._selfchecks import print_failed_checks
    from stillcap.body.hand_files import load_hand
    from stillcap.pipelines.hand.calibration import MARKER_NOISES, calibrate_hand_capture

    if pose not in CALIBRATION_POSES:
        raise typer.BadParameter(f"{pose!r} is not one of {', '.join(CALIBRATION_POSES)}", param_hint="--pose")
    if marker_noise not in MARKER_NOISES:
        raise typer.BadParameter(f"{marker_noise!r} is not one of {', '.join(MARKER_NOISES)}",
                                 param_hint="--marker-noise")
    sk, ms = load_hand(template, markers, model_what="--template")
    markers_out = markers_out or out.with_name(out.name.removesuffix(".json") + ".markers.json")
    cal = calibrate_hand_capture(capture if len(capture) > 1 else capture[0], pose, skeleton=sk, markerset=ms,
                                 max_length_sigma_m=None if max_length_sigma is None else max_length_sigma * 1e-3,
                                 marker_noise=marker_noise)
    cal.skeleton.save(out)
    cal.markerset.save(markers_out)
    if report is not None:
        import json

        from stillcap.files.atomic import write_text
        from stillcap.files.jsonable import to_jsonable

        write_text(report, json.dumps(to_jsonable(cal.to_dict()), indent=1) + "\n")
    con = Console()
    for m in cal.messages:
        con.print(f"[yellow]{m}[/]", highlight=False)
    con.print(f"hand size {cal.size:.3f} x the template; fit residual {cal.rms * 1e3:.2f} mm RMS "
              f"({cal.pose_rms * 1e3:.2f} mm in the {pose} pose; {cal.n_posed} flash(es) in it, {cal.n_free} in other poses)")
    con.print("estimated (1-sigma; template scaled to the hand, and the prior's 1-sigma about it; "
              "'not fixed': the capture narrowed the prior little):")
    for p in cal.parameters:
        flag = "  not fixed" if p.fixed > UNFIXED_SIGMA_RATIO else ""
        con.print(f"  {p.name:26s} {p.value:7.1f} +- {p.sigma:4.1f} {p.unit:3s} (template {p.template:6.1f} "
                  f"+- {p.prior_sigma:4.1f}){flag}", highlight=False)
    con.print(f"wrote {out} and {markers_out}: stillcap hand CAPTURE --hand-model {out} --markers {markers_out}")
    print_failed_checks(cal.self_checks, "hand-calibrate")
