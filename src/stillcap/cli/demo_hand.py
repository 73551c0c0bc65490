"""`stillcap demo hand`: render the pitcher's gloved hand around release, analyse, compare, export.

:func:`hand_demo` is what ``stillcap demo`` calls for ``hand``.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from stillcap.cli._progress import progress

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
    with progress("hand demo: rendering", total=4) as bar:
        hc = hand_capture(seed, preset=preset, image_size=image_size, progress=bar)
        bar.stage("hand demo: writing the capture")
        cap, images = hc.to_capture(".jpg")
        cap.save(out / "capture", images, jpeg_quality=92)
        bar.stage("hand demo: analysing")
        res = analyse_hand(Capture.load(out / "capture"), progress=bar)
        bar.stage("hand demo: comparing with the truth")
        res.truth = compare_with_capture(res)
    tr = hc.truth
    console.print(f"true delivery: {tr.n} flashes at {tr.strobe_hz:g} Hz, release {tr.release.speed_mph:.1f} mph; "
                  "rig: the true cameras")
    print_hand_result(res)
    console.print("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in res.timings_s.items()))
    with progress("hand demo: writing the report") as bar:
        write_text(out / "hand.json", dumps_json(res.to_dict()) + "\n")
        paths = write_result_report(res, out / "report", truth_arrays=None if res.truth is None
                                    else truth_arrays(res.capture.truth), progress=bar)
        written = []
        for name in EXPORTS:
            if res.animation is None and not name.endswith(".c3d"):
                continue
            bar.stage(f"hand demo: exporting {name}")
            written.append(export(out / name, res).name)
    console.print(f"capture, hand.json, {', '.join(written)} written to [bold]{out}[/]; report in "
                  f"[bold]{paths['html']}[/]")
    return res
