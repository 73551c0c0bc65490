"""`stillcap demo`: render a synthetic capture, analyse it, compare with the truth."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from stillcap.cli._format import num as _f
from stillcap.files.atomic import write_text

console = Console()
DEMOS = ("rig", "pitch", "hand", "puppet")
#: What ``stillcap demo`` (``all``) runs, in turn.
ALL = ("pitch", "hand", "puppet")


def demo(
    which: str = typer.Argument("all", help=f"Which demo: {', '.join(DEMOS)}, or all ({', '.join(ALL)})."),
    out: Path = typer.Option(Path("stillcap-demo"), "--out", help="Folder for the captures, results and plots."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the synthetic capture."),
    force: bool = typer.Option(False, "--force", help="Write into a folder that holds files stillcap did not write."),
):
    """Render a synthetic capture, analyse it, print recovered vs true values, write plots.

    rig: four distorted cameras are calibrated from rendered chessboard photos (intrinsics per
    camera, then bundle adjustment of the rig), and coloured marker balls rendered in a second
    capture are detected, matched across views and triangulated.

    pitch: a multi-exposure pitch through two calibrated stereo pairs: positions, spin, the
    physics-validated flight, the seed's Table 1 against the truth, metrics and an HTML report.

    hand: the pitcher's gloved hand around release in four cameras and one strobe: glove markers
    labelled automatically, hand poses per flash, a smooth animation, the ball's release, a
    report with an animated GIF, and BVH, glTF and C3D exports.

    puppet: the thesis's turntable webcam photographs a posed puppet; beads are detected,
    identified, triangulated, the skeleton posed and exported (COLLADA, BVH, glTF, C3D).

    all (the default) runs pitch, hand and puppet in turn and prints one summary.
    """
    if which not in DEMOS + ("all",):
        raise ValueError(f"unknown demo {which!r}; choose one of {', '.join(DEMOS)} or all")
    from stillcap.files.outputs import check_writable, mark_folder

    check_writable(out, "folder", option="--out", force=force)  # empty, new, or a folder stillcap made
    mark_folder(out)
    rows = []
    for name in ALL if which == "all" else (which,):
        if name == "rig":
            rig_demo(out / "rig", seed)
        elif name == "puppet":
            from stillcap.cli.demo_puppet import puppet_demo

            rows += puppet_summary(puppet_demo(out / "puppet", seed))
        elif name == "pitch":
            from stillcap.cli.demo_pitch import pitch_demo

            rows += pitch_summary(pitch_demo(out / "pitch", seed))
        elif name == "hand":
            from stillcap.cli.demo_hand import hand_demo

            rows += hand_summary(hand_demo(out / "hand", seed))
    if which == "all":
        t = Table(title=f"stillcap demo: summary against the studio's truth (seed {seed}; results in {out})")
        for c in ("demo", "quantity", "measured", "goal"):
            t.add_column(c, justify="right" if c != "quantity" else "left")
        for r in rows:
            t.add_row(*r)
        console.rule()
        console.print(t)


def pitch_summary(res) -> list:
    c = (res.truth or {}).get("table1", {})
    return [("pitch", "ball position error, mean", f"{_f(c.get('mean_err_mm'), 2)} mm", "<= 2 mm"),
            ("pitch", "release speed error", f"{_f(abs(c.get('speed_diff_mph') or float('nan')), 3)} mph", "<= 0.1 mph"),
            ("pitch", "velocity direction error", f"{_f(c.get('velocity_angle_deg'), 3)} deg", "<= 0.2 deg"),
            ("pitch", "spin rate error", f"{_f(abs(c.get('spin_rate_diff_rpm') or float('nan')), 2)} rpm", "<= 3 rpm"),
            ("pitch", "spin axis error", f"{_f(c.get('spin_axis_angle_deg'), 2)} deg", "<= 0.5 deg")]


def hand_summary(res) -> list:
    c = res.truth or {}
    rows = [("hand", "labels right", f"{_f(c.get('labels_right_pct'), 1)} %", ">= 99.5 %"),
            ("hand", "marker 3D error, RMS", f"{_f(c.get('marker_rms_mm'), 2)} mm", "<= 1 mm"),
            ("hand", "joint angle error, RMS (joints the seen markers fix)",
             f"{_f(c.get('joint_angle_rms_deg'), 2)} deg", "<= 2 deg"),
            ("hand", "flashes with a pose (of those whose back of the hand 2+ cameras see)",
             f"{c.get('flashes_reconstructed', '-')} of {c.get('flashes_back_seen_2plus', '-')}", "all")]
    if "release_speed_mph" in c:
        rows.append(("hand", "release speed error", f"{_f(abs(c['release_speed_mph']), 2)} mph", "-"))
    return rows


def puppet_summary(res) -> list:
    import numpy as np

    c = res.comparison
    if c is None:
        return []
    e = c.marker_errors_m[np.isfinite(c.marker_errors_m)] * 1e3
    full, partial = c.bone_stats("full")[0], c.bone_stats("partial")[0]
    return [("puppet", "beads identified wrong", f"{c.wrong} of {c.identified}", "0"),
            ("puppet", "markers seen twice, recovered", f"{c.recovered_seen_twice} of {c.seen_twice}", "all"),
            ("puppet", "marker 3D error, RMS", f"{np.sqrt(np.mean(e ** 2)):.3f} mm" if len(e) else "-", "<= 0.3 mm"),
            ("puppet", "bone direction error, RMS (bones the beads fix)", f"{_f(full, 2)} deg", "<= 0.5 deg"),
            ("puppet", "bone direction error, RMS (forearms, shins: one bead)", f"{_f(partial, 2)} deg",
             "<= 0.5 deg")]


def rig_demo(out: Path, seed: int) -> None:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from stillcap.studio.rig_demo import run_rig_demo
    from stillcap.report.rig_demo import plot_rig_demo

    console.rule("[bold]stillcap demo: calibrate a 4-camera rig from photos, then triangulate markers")
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True) as bar:
        tasks = {}

        def progress(task, done, total):
            if task not in tasks:
                tasks[task] = bar.add_task(task, total=total)
            bar.update(tasks[task], completed=done)

        res = run_rig_demo(seed=seed, out=out, progress=progress)

    t = Table(title="Calibration from rendered chessboard photos: recovered - true")
    for col in ("camera", "fx %", "fy %", "cx px", "cy px", "k1", "centre mm", "RMS px"):
        t.add_column(col, justify="right")
    for r in res.camera_rows():
        t.add_row(r["camera"], f"{100 * (r['fx'] / r['fx_true'] - 1):+.3f}", f"{100 * (r['fy'] / r['fy_true'] - 1):+.3f}",
                  f"{r['cx'] - r['cx_true']:+.2f}", f"{r['cy'] - r['cy_true']:+.2f}", f"{r['k1'] - r['k1_true']:+.4f}",
                  f"{r['centre_error_mm']:.3f}", f"{r['intrinsics_rms_px']:.3f}")
    console.print(t)
    console.print(f"rig bundle adjustment RMS: {res.rig_rms_px:.3f} px (camera 0 is the world frame)")

    m = Table(title="Marker balls triangulated with the calibrated rig (camera-0 frame)")
    for col in ("label", "true ball", "x mm", "y mm", "z mm", "err mm", "views", "reproj px"):
        m.add_column(col, justify="right")
    tri = res.markers.triangulation
    for lab, tl, p, e, n, rp in zip(res.markers.labels, res.true_labels, res.markers.points, res.marker_errors_m,
                                    tri.n_views, tri.reproj_error_px):
        m.add_row(lab, tl, *(f"{v * 1e3:.1f}" for v in p), f"{e * 1e3:.3f}", str(n), f"{rp:.3f}")
    console.print(m)
    err = res.marker_errors_m * 1e3
    console.print(f"{len(err)} markers: mean error {err.mean():.3f} mm, max {err.max():.3f} mm")
    console.print("time: " + ", ".join(f"{k} {v:.1f} s" for k, v in res.timings_s.items()))
    write_text(out / "results.json", json.dumps(res.to_dict(), indent=2) + "\n")
    png = plot_rig_demo(res, out / "rig-demo.png")
    console.print(f"captures, calibrated rig, results.json and plot written to [bold]{out}[/] ({png.name})")
