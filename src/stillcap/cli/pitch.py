"""`stillcap pitch CAPTURE_DIR`: ball flight, spin and pitch metrics from strobe photos (SPEC J1)."""

from __future__ import annotations

import json
import tempfile
import textwrap
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from stillcap.cli._format import num as _f, print_notes, right_table
from stillcap.cli._progress import progress
from stillcap.cli._response import RESPONSE_HELP, parse_response_option
from stillcap.cli._selfchecks import print_failed_checks
from stillcap.cli._outputs import Outputs, check, oserror_text

console = Console()

#: The files ``--report DIR`` writes (checked before the analysis: an existing one must be stillcap's).
REPORT_FILES = ("report.html", "pitch.json", "positions.csv", "metrics.csv", "side.png", "top.png", "spin.png",
                "residuals.png")

# The choices of --spin, --physics and --fit, written out so that the CLI starts without NumPy;
# tests/test_cli_lazy.py checks them against the library's lists.
SPIN_CHOICES = ("global", "seed")  # stillcap.pipelines.pitch.SPIN_METHODS
PHYSICS_CHOICES = ("seed", "nathan")  # stillcap.ball.physics.FLIGHT_MODELS
FIT_CHOICES = ("least-squares", "powell")  # stillcap.pipelines.pitch.FIT_METHODS, "_" written "-"


def _choice(name: str, value: str, allowed) -> str:
    if value not in allowed:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(allowed)}", param_hint=name)
    return value


def pitch(
    captures: list[Path] = typer.Argument(..., help="Pitch capture folder(s) (capture.json, rig.json, images/); "
                                          "several are analysed as a session, with one summary table."),
    as_json: bool = typer.Option(False, "--json",
                                 help="Print the result as JSON (keys as in truth.json, docs/pitch.md)."),
    report: Path = typer.Option(None, "--report", help="Write report.html, pitch.json, positions.csv, metrics.csv "
                                "and plots to this folder."),
    csv_file: Path = typer.Option(None, "--csv", help="Write the per-flash ball positions as CSV to this file."),
    spin: str = typer.Option("global", "--spin", help="Spin method: global (one constant spin fitted to all "
                             "flashes) or seed (the seed's per-flash Powell method)."),
    physics: str = typer.Option("seed", "--physics", help="Flight model of a ball that flies as a baseball: seed "
                                "or nathan (other balls fly by their ball file's flight preset)."),
    ball: str = typer.Option(None, "--ball", help="The ball: a built-in name (stillcap balls lists them) or a "
                             "stillcap-ball file (docs/ball-format.md): radius, mass, flight and painted markers. "
                             "Overrides capture.json's ball; default that, else the seed's baseball."),
    fit: str = typer.Option("least-squares", "--fit", help="Reference-trajectory optimiser: least-squares or "
                            "powell (the seed's)."),
    release_y_ft: float = typer.Option(None, "--release-y-ft", help="Evaluate release at this field y (ft); "
                                       "default: at the front pair's first ball image."),
    expected_speed_mph: float = typer.Option(None, "--expected-speed-mph", help="Anchor the flash spacing "
                                             "(only needed when a pair missed every other flash)."),
    processes: int = typer.Option(None, "--processes", min=0,
                                  help="Worker processes for the stereo pairs' work (0: threads). Default: 0 for "
                                       "one capture, 2 for several (the pool starts once, ~0.5 s, then is reused)."),
    force: bool = typer.Option(False, "--force", help="Overwrite files stillcap did not write (--report, --csv)."),
    response: str = typer.Option(None, "--response", help=RESPONSE_HELP),
    center_sigma_px: float = typer.Option(0.2, "--center-sigma-px", help="Assumed 1-sigma noise of a refined "
                                          "ball centre in the photo (px); the self-checks grow it when the "
                                          "residuals show more."),
    shading_model_error: float = typer.Option(0.1, "--shading-model-error", help="Floor of the relative error of "
                                              "the lit-phase (shading) correction of each ball centre: each "
                                              "capture measures its own share from the model's misfit to its "
                                              "ball images, and the remaining bias is at least this fraction of "
                                              "the correction."),
):
    """Ball positions, release velocity, spin, reference trajectory and pitch metrics of a capture.

    The capture holds one multi-exposure photo per camera of one or more strobed stereo pairs
    (each photo with its strobe_hz). Every number is reported with its 1-sigma uncertainty.
    Exit status 2 with a one-line message for captures that cannot give a flight.

    With several captures (a session): each is analysed in turn (a capture that fails, e.g. a
    missing photo, a bad capture.json or a photo that does not decode, is named in one line and
    skipped), ``--report DIR`` writes one sub-folder per capture, ``--json`` prints a list, one
    table sums up the session, and the exit status is 2 when any capture failed.

    The output locations are checked before the analysis (exit status 2 for one that cannot be
    written); if writing fails afterwards, the result is saved in a temporary folder and the
    message says where.
    """
    camera_response = parse_response_option(response)
    _choice("--spin", spin, SPIN_CHOICES)
    _choice("--physics", physics, PHYSICS_CHOICES)
    _choice("--fit", fit, FIT_CHOICES)
    if processes is None:
        processes = 0 if len(captures) == 1 else 2
    if len(captures) > 1 and csv_file is not None:
        raise ValueError("--csv takes one capture; with several, --report DIR writes positions.csv per capture")
    check(csv_file, "file", "--csv", force)
    session_names = [c.resolve().name or str(c) for c in captures]
    check(report, "folder", "--report", force,
          REPORT_FILES if len(captures) == 1 else [f"{n}/{f}" for n in session_names for f in REPORT_FILES])
    ball_obj = None
    if ball is not None:
        from stillcap.ball.ballfile import load_ball
        ball_obj = load_ball(ball, "--ball")

    def options():
        from stillcap.pipelines.pitch import PitchOptions

        return PitchOptions(spin_method=spin, physics=physics, fit_method=fit.replace("-", "_"),
                            release_y_ft=release_y_ft, expected_speed_mph=expected_speed_mph, processes=processes,
                            ball=ball_obj, response=camera_response, center_sigma_px=center_sigma_px,
                            shading_model_error=shading_model_error)

    if len(captures) > 1:
        _session(captures, options(), report, as_json)
        return
    from stillcap.io.capture import Capture

    with progress("analysing the pitch") as bar:
        cap = Capture.load(captures[0])
        if processes == 0:  # the photos decode on the other core while the pipeline's modules import (~0.5 s)
            cap.start_decoding()
        opts = options()  # its errors (e.g. --expected-speed-mph -1) now come after the capture's
        from stillcap.pipelines.pitch import analyse_pitch

        res = analyse_pitch(cap, opts, progress=bar)
        if cap.truth is not None:  # a studio render: its truth compared (photos from elsewhere have none)
            from stillcap.studio.compare.pitch import add_truth_comparison

            res = add_truth_comparison(res, cap.truth)
    print_failed_checks(res.self_checks, "pitch")  # on stderr, also with --json
    written = []
    outputs = Outputs(lambda: json.dumps(res.to_dict(), indent=1, allow_nan=False) + "\n", "pitch.json")
    if csv_file is not None:
        from stillcap.report.pitch import write_positions_csv
        with outputs.writing(f"--csv {csv_file}"):
            written.append(write_positions_csv(res, csv_file))
            outputs.record(written[-1:])
    if report is not None:
        from stillcap.report.pitch import write_report
        with outputs.writing(f"--report {report}"):
            outputs.claim(report, REPORT_FILES)
            with progress("writing the report"):
                paths = write_report(res, report)
            outputs.record(paths.values(), report)
            written.append(paths["html"])
    if as_json:
        print(json.dumps(res.to_dict(), indent=1, allow_nan=False))
        outputs.finish(printed_json=True)
        return
    print_notes(res.messages)
    t = right_table(f"{len(res.times)} ball positions from {len(res.pairs)} stereo pair(s) ({res.frame} frame)",
                    ("pair", "strobe Hz", "images", "clock offset s", "position sigma mm", "markers 3D / 1 cam"))
    for p in res.pairs:
        offset = f"{p.time_offset_s:.5f} ± {p.time_offset_sigma_s * 1e3:.3f} ms"
        t.add_row(p.name, _f(p.strobe_hz, 0), str(len(p)), offset, _f(p.position_sigma_m * 1e3, 2),
                  f"{p.n_markers_3d} / {p.n_markers_ray}")
    console.print(t)
    m = res.metrics.to_dict()
    s = res.metrics_sigma
    mt = Table(title=f"Pitch metrics (release {res.release['where']}; ± 1 sigma)")
    for c in ("metric", "value", "± sigma"):
        mt.add_column(c, justify="right")
    for k, v in m.items():
        if k in ("nine_parameter", "success", "message"):
            continue
        mt.add_row(k, v if isinstance(v, str) else _f(v, 3), _f(s.get(k), 3))
    console.print(mt)
    from stillcap.pipelines.pitch import TABLE1_COLUMNS

    t1 = Table(title="Seed Table 1: reference trajectory vs measured initial parameters")
    t1.add_column("column")
    t1.add_column("value", justify="right")
    for c, unit in TABLE1_COLUMNS:
        t1.add_row(c, _f(res.table1.get(c), 3))
    console.print(t1)
    if res.spin_available:
        console.print(f"spin ({res.spin.method}): {res.release['spin_rpm']:.1f} ± {res.spin.sigma_rpm:.1f} rpm, axis "
                      f"± {res.spin.sigma_axis_deg:.2f} deg; {res.metrics.spin_tilt or '-'}"
                      + (f"; alias: {res.alias.message}" if res.alias is not None else ""), highlight=False)
    else:
        console.print("spin: unavailable (see notes)")
    for w in written:
        console.print(f"wrote [bold]{w}[/]")
    outputs.finish()


def _session(captures: list[Path], opts, report: Path | None, as_json: bool) -> None:
    """Several captures: one result each (report sub-folders, a JSON list) and a summary table.

    Each result is dropped once its report is written: only its table row (or, with ``--json``,
    its JSON text) is kept, so that memory stays flat over a long session."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from stillcap.files.outputs import record_outputs
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import analyse_pitch
    from stillcap.studio.compare.pitch import add_truth_comparison

    names = [c.resolve().name or str(c) for c in captures]
    if report is not None and len(set(names)) < len(names):
        raise ValueError("--report with several captures needs distinct folder names (one sub-folder each)")
    err = Console(stderr=True)
    kept, failed = [], []  # per capture: its JSON text (--json) or its table row
    fallback = None  # where the results of captures whose report could not be written go
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, transient=True) as bar:
        task = bar.add_task("pitches", total=len(captures))
        for cap, name in zip(captures, names):
            bar.update(task, description=name)
            try:
                loaded = Capture.load(cap)
                res = add_truth_comparison(analyse_pitch(loaded, opts), loaded.truth)
                print_failed_checks(res.self_checks, name)
            except Exception as e:  # noqa: BLE001 - one bad capture must not end the session: name it, go on
                failed.append(name)
                err.print(f"[red]{cap}:[/] {_problem(e)}", highlight=False, soft_wrap=True)
                kept.append(json.dumps({"capture": str(cap), "error": _problem(e)}, indent=1) if as_json
                            else (name, "-", "-", "-", "-", "-", "-", "[red]failed[/]"))  # its reason is above
                bar.advance(task)
                continue
            kept.append(json.dumps(res.to_dict(), indent=1, allow_nan=False) if as_json else _row(name, res))
            if report is not None:
                from stillcap.report.pitch import write_report
                try:
                    record_outputs([report / name / f for f in REPORT_FILES], report / name)
                    paths = write_report(res, report / name)
                    record_outputs(paths.values(), report / name)
                except OSError as e:  # the result is kept in a temporary folder; the message says where
                    failed.append(name)
                    try:
                        fallback = fallback or Path(tempfile.mkdtemp(prefix="stillcap-unsaved-"))
                    except OSError:
                        pass
                    saved = save_fallback_in(fallback, f"{name}.pitch.json", res)
                    err.print(f"[red]{cap}:[/] cannot write --report {report / name} ({oserror_text(e)}); "
                              f"{saved}", highlight=False, soft_wrap=True)
            del res, loaded
            bar.advance(task)
    if as_json:  # as json.dumps(list, indent=1) would print it
        print("[\n" + ",\n".join(textwrap.indent(text, " ") for text in kept) + "\n]")
    else:
        t = Table(title=f"{len(captures)} pitches ({len(failed)} failed)")
        for c in ("capture", "balls", "release mph", "spin rpm", "tilt", "IVB in", "HB in", "notes"):
            t.add_column(c, justify="right")
        for row in kept:
            t.add_row(*row)
        console.print(t)
        if report is not None:
            console.print(f"wrote one report per capture under [bold]{report}[/]")
    if failed:
        raise typer.Exit(2)


def _row(name: str, res) -> tuple:
    """The session table's row of one result."""
    m, s = res.metrics, res.metrics_sigma

    def pm(k, nd=1):  # the sigmas are small: one more digit
        return f"{_f(getattr(m, k), nd)} ± {_f(s.get(k), nd + 1)}"
    spin_ok = res.spin_available
    return (name, str(len(res.times)), pm("release_speed_mph"), pm("spin_rate_rpm", 0) if spin_ok else "-",
            (m.spin_tilt or "-") if spin_ok else "-", pm("induced_vertical_break_in"), pm("horizontal_break_in"),
            str(len(res.messages)))


def _problem(e: Exception) -> str:
    """One line for a capture that failed: the library's message, or the error's kind and text."""
    if isinstance(e, OSError):
        return oserror_text(e)
    if isinstance(e, ValueError):
        return str(e)
    return f"{type(e).__name__}: {e}"


def save_fallback_in(folder: Path | None, name: str, res) -> str:
    """Save ``res`` as JSON in ``folder`` (or print it when even that fails); the end of the
    message saying where it went."""
    from stillcap.files.atomic import write_text

    text = json.dumps(res.to_dict(), indent=1, allow_nan=False) + "\n"
    try:
        if folder is not None:
            return f"the result is saved in {write_text(folder / name, text)}"
    except OSError:
        pass
    print(text)
    return "the result is printed on stdout as JSON"
