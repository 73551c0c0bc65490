"""`stillcap markers CAPTURE`: triangulate coloured marker balls of a capture folder."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from stillcap.cli._progress import progress
from stillcap.cli._outputs import Outputs, check
from stillcap.cli._response import RESPONSE_HELP, parse_response_option

console = Console()


def markers(
    capture: Path = typer.Argument(..., help="Capture folder (capture.json, rig.json, images/)."),
    palette: Path = typer.Option(None, "--palette", help='JSON {"label": [b, g, r], ...} marker colours (0-255); '
                                 "default: the studio's marker-ball colours."),
    max_px: float = typer.Option(2.0, "--max-px", help="Matching and outlier tolerance, pixels."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
    out: Path = typer.Option(None, "--out", help="Also write the result as JSON to this file."),
    force: bool = typer.Option(False, "--force", help="Overwrite a file stillcap did not write (--out)."),
    response: str = typer.Option(None, "--response", help=RESPONSE_HELP + " (auto: not for markers yet)"),
):
    """Find coloured marker balls in every photo, match them across cameras, triangulate them.

    One photo per camera of the capture's rig. With a synthetic capture (truth.json) the
    result is compared with the true ball centres.
    """
    from stillcap.files.atomic import write_text
    from stillcap.io.capture import Capture
    from stillcap.pipelines.markers import reconstruct_markers

    camera_response = parse_response_option(response)
    check(out, "file", "--out", force)
    pal = None
    if palette is not None:  # a bad file is named before the photos are read
        from stillcap.detect.palette import read_bgr_palette

        pal = read_bgr_palette(palette)
    cap = Capture.load(capture)
    images = []
    with progress("reading photos", total=len(cap.rig)) as bar:
        for cam in cap.rig:
            shots = cap.images_of(cam.name)
            if not shots:
                raise ValueError(f"capture {capture}: camera {cam.name!r} has no photo")
            images.append(cap.read_image(shots[0]))
            bar(len(images), item=cam.name)
    with progress("finding and triangulating markers"):
        rec = reconstruct_markers(cap.rig, images, pal, max_px=max_px, response=camera_response)
    result = result_with_truth(rec, cap.truth)
    truth = cap.truth if cap.truth and cap.truth.get("kind") == "markers" else None
    outputs = Outputs(lambda: json.dumps(result, indent=2) + "\n", "markers.json")
    if out is not None:
        with outputs.writing(f"--out {out}"):
            outputs.record([write_text(out, json.dumps(result, indent=2) + "\n")])
    if as_json:
        print(json.dumps(result, indent=2))
        outputs.finish(printed_json=True)
        return
    t = Table(title=f"{len(rec.labels)} markers triangulated from {len(cap.rig)} cameras ({cap.rig.world} frame)")
    cols = ["label", "x mm", "y mm", "z mm", "views", "reproj px"] + (["true ball", "err mm"] if truth else [])
    for c in cols:
        t.add_column(c, justify="right")
    for m in result["markers"]:
        row = [m["label"], *(f"{v * 1e3:.1f}" for v in m["position_m"]), str(m["views"]), f"{m['reproj_error_px']:.3f}"]
        if truth:
            row += [m["true_ball"], f"{m['error_mm']:.3f}"]
        t.add_row(*row)
    console.print(t)
    outputs.finish()


def result_with_truth(rec, truth: dict | None) -> dict:
    """``rec.to_dict()`` and, with a studio truth of kind markers, each marker's nearest true
    ball and its distance (``true_ball``, ``error_mm``)."""
    import numpy as np

    result = rec.to_dict()
    if truth and truth.get("kind") == "markers":
        balls = [b for b in truth["balls"] if b["kind"] == "marker"]
        centers = np.array([b["center"] for b in balls], float).reshape(-1, 3)
        for m, p in zip(result["markers"], rec.points):
            d = np.linalg.norm(centers - p, axis=1)
            m["true_ball"], m["error_mm"] = balls[int(d.argmin())]["name"], float(d.min() * 1e3)
    return result
