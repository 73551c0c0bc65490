"""`stillcap demo hand`: render the pitcher's gloved hand around release, analyse, compare, export.

:func:`hand_demo` is what ``stillcap demo`` calls for ``hand``.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

console = Console()

#: Files the demo exports (docs/exports.md).
EXPORTS = ("hand.bvh", "hand.glb", "markers.c3d")


def hand_demo(out: Path, seed: int, *, preset: str = "seed-4seam", image_size=(2560, 1920)):
    """Render a hand capture with the studio, analyse it with the hand pipeline, print the
    comparison with the truth, write the report and the exports.

    Writes ``out/capture`` (4 JPEG photos, rig, truth), ``out/hand.json``, ``out/report/``
    (report.html, hand.gif, joint_angles.png) and ``hand.bvh``, ``hand.glb``, ``markers.c3d``.

    Returns
    -------
    HandResult
    """
    from stillcap.cli.hand import print_hand_result
    from stillcap.files.atomic import write_text
    from stillcap.io.capture import Capture
    from stillcap.io.export import export
    from stillcap.io.project import dumps_json
    from stillcap.pipelines.hand import analyse_hand
    from stillcap.report.hand import write_result_report
    from stillcap.studio.compare.hand import compare_with_capture, truth_arrays
    from stillcap.studio.hand import hand_capture

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    console.rule(f"[bold]stillcap demo: a pitcher's gloved hand around release ({preset}), 4 cameras, one strobe")
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task("rendering", total=4)
        hc = hand_capture(seed, preset=preset, image_size=image_size,
                          progress=lambda i, n, label: bar.update(task, completed=i, total=n, description=label))
        cap, images = hc.to_capture(".jpg")
        cap.save(out / "capture", images, jpeg_quality=92)
        bar.update(task, description="analysing", total=None, completed=0)
        res = analyse_hand(Capture.load(out / "capture"),
                           progress=lambda i, n, label: bar.update(task, completed=i, total=n, description=label))
    res.truth = compare_with_capture(res)
    tr = hc.truth
    console.print(f"true delivery: {tr.n} flashes at {tr.strobe_hz:g} Hz, release {tr.release.speed_mph:.1f} mph; "
                  "rig: the true cameras")
    print_hand_result(res)
    console.print("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in res.timings_s.items()))
    write_text(out / "hand.json", dumps_json(res.to_dict()) + "\n")
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), console=console,
                  transient=True) as bar:
        task = bar.add_task("writing the animation", total=None)
        paths = write_result_report(res, out / "report", truth_arrays=None if res.truth is None
                                    else truth_arrays(res.capture.truth),
                                    progress=lambda i, n, label: bar.update(task, completed=i, total=n))
    written = []
    for name in EXPORTS:
        if res.animation is None and not name.endswith(".c3d"):
            continue
        written.append(export(out / name, res).name)
    console.print(f"capture, hand.json, {', '.join(written)} written to [bold]{out}[/]; report in "
                  f"[bold]{paths['html']}[/]")
    return res
