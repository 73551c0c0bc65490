"""`stillcap calibrate ...` commands: intrinsics, stereo, rig.

Thin: parse arguments, call :mod:`stillcap.calibrate`, print. Each command also writes the
cameras' response into the rig (``--response``; by default estimated from the board photos,
:mod:`stillcap.calibrate.edge_response`). Lengths (``--square``,
``--marker``) are in metres; translations and baselines come out in the same unit.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from stillcap.cli._outputs import Outputs, check
from stillcap.cli._progress import progress

app = typer.Typer(no_args_is_help=True, help="Calibrate cameras from chessboard or ChArUco photos.")
out_console = Console(highlight=False)
err_console = Console(stderr=True, highlight=False)

Pattern = Annotated[str, typer.Option("--pattern", "-p", help="Chessboard inner corners, COLSxROWS (e.g. 9x6).")]
Square = Annotated[float, typer.Option("--square", "-s",
                                       help="Square size in metres; translations and baselines come out in this unit.")]
Charuco = Annotated[bool, typer.Option("--charuco",
                                       help="The target is a ChArUco board (see --squares, --marker, --dict).")]
Squares = Annotated[str, typer.Option("--squares", help="ChArUco: squares along x and y, e.g. 7x5.")]
Marker = Annotated[float | None, typer.Option("--marker",
                                              help="ChArUco: marker side in metres (default 0.75 x --square).")]
Dict = Annotated[str, typer.Option("--dict", help="ChArUco: ArUco dictionary name, e.g. DICT_5X5_250.")]
Out = Annotated[Path | None, typer.Option("--out", "-o", help="Write a stillcap rig JSON file.")]
AsJson = Annotated[bool, typer.Option("--json", help="Print the result as one JSON object on stdout.")]
Force = Annotated[bool, typer.Option("--force", help="Overwrite an --out file stillcap did not write.")]
ResponseOpt = Annotated[str | None, typer.Option(
    "--response", help="The cameras' response, written into the rig: srgb, linear or gamma:G states it (it wins); "
                       "auto (the default) estimates each camera's from the symmetry of its board photos' blurred "
                       "edges (chessboards only) and writes it where the estimate is sure. See "
                       "docs/camera-response.md.")]


def _stated(response: str | None):
    """``--response`` parsed before the calibration runs (a bad spec: one line, exit status 2)."""
    from stillcap.cli._response import parse_response_option

    return parse_response_option(response)


def _responses(rig, images: dict, target, stated):
    """The rig with the cameras' responses (stated, or estimated from the board photos) and the
    report (:func:`stillcap.calibrate.edge_response.rig_responses`)."""
    from stillcap.calibrate.edge_response import rig_responses

    if stated is not None and stated != "auto":
        return rig_responses(rig, images, target, stated)
    with progress("estimating the response", err_console) as cb:
        return rig_responses(rig, images, target, stated, progress=cb)


def _print_responses(report: dict) -> None:
    from rich.markup import escape

    for m in report["messages"]:
        out_console.print(("  [yellow]" if "not written" in m else "  ") + escape(m))


def _save_rig(rig, out: Path | None) -> Outputs:
    """Write the rig to ``--out``; the :class:`Outputs` whose ``finish`` the caller calls last."""
    outputs = Outputs(lambda: json.dumps(rig.to_dict(), indent=2) + "\n", "rig.json")
    if out is not None:
        with outputs.writing(f"--out {out}"):
            rig.save(out)
    return outputs


def _target(pattern: str, square: float, charuco: bool, squares: str, marker: float | None, dictionary: str):
    import cv2

    from stillcap.calibrate import CharucoTarget, Chessboard, parse_pattern

    if not 0 < square < float("inf"):
        raise ValueError(f"--square must be a positive length in metres, got {square}")
    if not charuco:
        cols, rows = parse_pattern(pattern)
        return Chessboard(cols, rows, square)
    try:
        sx, sy = (int(v) for v in squares.lower().split("x"))
    except ValueError:
        raise ValueError(f"--squares must look like 7x5, got {squares!r}") from None
    if not (2 <= sx <= 100 and 2 <= sy <= 100):
        raise ValueError(f"--squares must be from 2x2 to 100x100, got {squares!r}")
    d = getattr(cv2.aruco, dictionary.upper(), None)
    if not dictionary.upper().startswith("DICT_") or not isinstance(d, int):
        raise ValueError(f"unknown ArUco dictionary {dictionary!r} (e.g. DICT_4X4_50, DICT_5X5_250, DICT_6X6_1000)")
    marker = 0.75 * square if marker is None else marker
    if not 0 < marker < square:
        raise ValueError(f"--marker must be between 0 and --square ({square}), got {marker}")
    return CharucoTarget(sx, sy, square, marker, d)


def _f(x) -> float:
    return round(float(x), 6)


def _intrinsics_table(title: str, res) -> Table:
    t = Table(title=title)
    t.add_column("image")
    t.add_column("reprojection RMS (px)", justify="right")
    for name, e in res.per_image_rms_px.items():
        if name in res.outlier_views:
            t.add_row(f"[red]{name}", f"[red]{e:.3f} outlier")
        else:
            t.add_row(name, f"{e:.3f}")
    for name, why in res.images_skipped.items():
        t.add_row(f"[yellow]{name}", f"[yellow]skipped: {why}")
    return t


def _print_camera(res, suggest: bool = True) -> None:
    s = res.summary()
    out_console.print(f"camera {res.camera.name}: RMS {s['rms_px']:.3f} px over {len(s['images_used'])} images, "
                      f"{s['image_size'][0]}x{s['image_size'][1]} px")
    out_console.print(f"  fx {s['fx']:.2f}  fy {s['fy']:.2f}  cx {s['cx']:.2f}  cy {s['cy']:.2f}  (px)")
    out_console.print("  dist (k1 k2 p1 p2 k3): " + " ".join(f"{v:.5f}" for v in s["dist"]))
    _print_outlier_views(res, suggest)


def _them(n: int) -> str:
    return "it" if n == 1 else "them"


def _print_outlier_views(res, suggest: bool = True) -> None:
    """The outlier views of one camera, with the RMS and fx with and without them."""
    import numpy as np

    if not res.outlier_views:
        return
    med = float(np.median(list(res.per_image_rms_px.values())))
    views = ", ".join(f"{k} ({res.per_image_rms_px[k]:.3f} px, {res.per_image_rms_px[k] / med:.1f}x the median "
                      f"{med:.3f} px)" for k in res.outlier_views)
    out_console.print(f"  [red]outlier view{'s' if len(res.outlier_views) > 1 else ''}:[/] {views}")
    w = res.without_outliers
    if w is None:
        out_console.print("  too few views would remain to calibrate without "
                          f"{_them(len(res.outlier_views))}; take more photos")
        return
    out_console.print(f"  without {_them(len(res.outlier_views))}: RMS {res.rms_px:.3f} -> {w.rms_px:.3f} px, "
                      f"fx {res.camera.K[0, 0]:.2f} -> {w.camera.K[0, 0]:.2f}, "
                      f"fy {res.camera.K[1, 1]:.2f} -> {w.camera.K[1, 1]:.2f}"
                      + (f"; consider dropping {_them(len(res.outlier_views))} and calibrating again" if suggest else ""))


def _camera_dict(c) -> dict:
    return {"fx": _f(c.K[0, 0]), "fy": _f(c.K[1, 1]), "cx": _f(c.K[0, 2]), "cy": _f(c.K[1, 2]),
            "dist": [_f(v) for v in c.dist]}


def _summary(res) -> dict:
    s = res.summary()
    for k in ("rms_px", "fx", "fy", "cx", "cy"):
        s[k] = _f(s[k])
    s["dist"] = [_f(v) for v in s["dist"]]
    s["per_image_rms_px"] = {k: _f(v) for k, v in s["per_image_rms_px"].items()}
    return s


@app.command()
def intrinsics(
    images: Annotated[list[Path], typer.Argument(help="Photos of the board from one camera.")],
    pattern: Pattern = "9x6", square: Square = 0.025, charuco: Charuco = False, squares: Squares = "7x5",
    marker: Marker = None, dictionary: Dict = "DICT_5X5_250",
    name: Annotated[str, typer.Option("--name", help="Camera name in the rig file.")] = "cam0",
    out: Out = None, as_json: AsJson = False, force: Force = False, response: ResponseOpt = None,
):
    """Intrinsics (K, distortion k1 k2 p1 p2 k3) of one camera from board photos, and its response.

    Images where the board is not found are skipped and listed with the reason.
    """
    from stillcap.calibrate import calibrate_intrinsics
    from stillcap.camera import Rig

    target = _target(pattern, square, charuco, squares, marker, dictionary)
    stated = _stated(response)
    check(out, "file", "--out", force)
    with progress("detecting", err_console) as cb:
        res = calibrate_intrinsics(images, target, camera_name=name, progress=cb)
    rig, resp = _responses(Rig([res.camera]), {name: images}, target, stated)
    outputs = _save_rig(rig, out)
    if as_json:
        typer.echo(json.dumps({**_summary(res), "response": resp}, indent=2))
        outputs.finish(printed_json=True)
        return
    out_console.print(_intrinsics_table(name, res))
    _print_camera(res)
    _print_responses(resp)
    if out is not None and not outputs.failed:
        out_console.print(f"wrote {out}")
    outputs.finish()


@app.command()
def stereo(
    images: Annotated[list[Path], typer.Argument(
        help="Photos of both cameras; split by file name: names holding --left-key are left, --right-key right, "
             "paired by the name with the key removed (left01.jpg ~ right01.jpg).")],
    pattern: Pattern = "9x6", square: Square = 0.025, charuco: Charuco = False, squares: Squares = "7x5",
    marker: Marker = None, dictionary: Dict = "DICT_5X5_250",
    left_key: Annotated[str, typer.Option("--left-key", help="Word marking left-camera file names.")] = "left",
    right_key: Annotated[str, typer.Option("--right-key", help="Word marking right-camera file names.")] = "right",
    refine_intrinsics: Annotated[bool, typer.Option(
        "--refine-intrinsics", help="Refine intrinsics in the stereo fit (default: fixed).")] = False,
    out: Out = None, as_json: AsJson = False, force: Force = False, response: ResponseOpt = None,
):
    """Stereo pair: intrinsics of each camera, then R, T of right relative to left (left = world),
    and each camera's response.

    Example: stillcap calibrate stereo data/left*.jpg data/right*.jpg --pattern 9x6 --square 0.025
    """
    import numpy as np

    from stillcap.calibrate import calibrate_stereo
    from stillcap.calibrate.extrinsics import split_stereo_images

    target = _target(pattern, square, charuco, squares, marker, dictionary)
    stated = _stated(response)
    check(out, "file", "--out", force)
    left, right = split_stereo_images(images, (left_key, right_key))
    with progress("detecting", err_console) as cb:
        res = calibrate_stereo(left, right, target, names=(left_key, right_key), keys=(left_key, right_key),
                               fix_intrinsics=not refine_intrinsics, progress=cb)
    rig, resp = _responses(res.rig, dict(zip(res.rig.names, (left, right))), target, stated)
    outputs = _save_rig(rig, out)
    if as_json:
        d = {"rms_px": _f(res.rms_px), "R": [[_f(v) for v in row] for row in res.R], "T": [_f(v) for v in res.T],
             "baseline": _f(res.baseline), "left": _summary(res.left), "right": _summary(res.right),
             "pairs_used": res.pairs_used, "pairs_skipped": res.pairs_skipped,
             "per_pair_rms_px": {k: [_f(a), _f(b)] for k, (a, b) in res.per_pair_rms_px.items()}}
        w = res.without_outliers
        d["outlier_pairs"] = res.outlier_pairs
        d["outlier_files"] = [f for k in res.outlier_pairs for f in res.pair_images[k]]
        d["without_outliers"] = None if w is None else {
            "rms_px": _f(w.rms_px), "T": [_f(v) for v in w.T], "baseline": _f(w.baseline),
            "left_rms_px": _f(w.left.rms_px), "right_rms_px": _f(w.right.rms_px), "pairs_used": w.pairs_used}
        if refine_intrinsics:  # the stereo fit's intrinsics; "left"/"right" stay the single-camera results
            d["refined"] = {"rms_px": _f(res.rms_px), **{c.name: _camera_dict(c) for c in res.rig}}
        d["response"] = resp
        typer.echo(json.dumps(d, indent=2))
        outputs.finish(printed_json=True)
        return
    for r in (res.left, res.right):
        out_console.print(_intrinsics_table(r.camera.name, r))
        _print_camera(r, suggest=False)  # a stereo pair is dropped whole: see the pair line
    out_console.print(f"stereo: RMS {res.rms_px:.3f} px over {len(res.pairs_used)} pairs "
                      f"({'intrinsics refined' if refine_intrinsics else 'intrinsics fixed'})")
    if refine_intrinsics:
        out_console.print("  intrinsics refined in the stereo fit (px; the tables above are each camera alone):")
        for c in res.rig:
            out_console.print(f"    {c.name} fx {c.K[0, 0]:.2f}  fy {c.K[1, 1]:.2f}  cx {c.K[0, 2]:.2f}  "
                              f"cy {c.K[1, 2]:.2f}  dist " + " ".join(f"{v:.5f}" for v in c.dist))
    for k, why in res.pairs_skipped.items():
        out_console.print(f"  [yellow]pair {k} skipped: {why}")
    out_console.print("  T = (" + ", ".join(f"{v:.4f}" for v in res.T) + f"), baseline {res.baseline:.4f} "
                      "(unit of --square)")
    ang = np.degrees(np.arccos(np.clip((np.trace(res.R) - 1) / 2, -1, 1)))
    out_console.print(f"  R: rotation of {ang:.3f} deg")
    _print_outlier_pairs(res)
    _print_responses(resp)
    if out is not None and not outputs.failed:
        out_console.print(f"wrote {out}")
    outputs.finish()


def _print_outlier_pairs(res) -> None:
    n = len(res.outlier_pairs)
    if not n:
        return
    pairs = ", ".join(f"{k} ({', '.join(res.pair_images[k])}; RMS "
                      + (" / ".join(f"{v:.3f}" for v in res.per_pair_rms_px[k]) + " px)" if k in res.per_pair_rms_px
                         else "not used)") for k in res.outlier_pairs)
    out_console.print(f"  [red]outlier pair{'s' if n > 1 else ''}:[/] {pairs}")
    w = res.without_outliers
    if w is None:
        out_console.print(f"  too few pairs would remain to calibrate without {_them(n)}; take more photos")
        return
    out_console.print(f"  without {_them(n)}: stereo RMS {res.rms_px:.3f} -> {w.rms_px:.3f} px, "
                      f"{w.rig.names[0]} {res.left.rms_px:.3f} -> {w.left.rms_px:.3f} px, "
                      f"{w.rig.names[1]} {res.right.rms_px:.3f} -> {w.right.rms_px:.3f} px, "
                      f"baseline {res.baseline:.4f} -> {w.baseline:.4f}; consider dropping "
                      + ", ".join(f for k in res.outlier_pairs for f in res.pair_images[k]) + " and calibrating again")


@app.command()
def rig(
    folder: Annotated[Path, typer.Argument(
        help="One subfolder per camera (natural order; the first is the world frame), each holding board photos; "
             "photos of the same instant share a file name across subfolders.")],
    pattern: Pattern = "9x6", square: Square = 0.025, charuco: Charuco = False, squares: Squares = "7x5",
    marker: Marker = None, dictionary: Dict = "DICT_5X5_250",
    intrinsics_files: Annotated[list[Path] | None, typer.Option(
        "--intrinsics", help="Rig JSON whose cameras (matched by name) give known intrinsics, e.g. from "
                             "`stillcap calibrate intrinsics --name cam0 --out cam0.json` with close-up photos; "
                             "repeat for several files.")] = None,
    refine_intrinsics: Annotated[bool, typer.Option("--refine-intrinsics",
                                                    help="Refine intrinsics in the bundle adjustment too.")] = False,
    out: Out = None, as_json: AsJson = False, force: Force = False, response: ResponseOpt = None,
):
    """N-camera rig: intrinsics per camera, spanning-tree poses, then bundle adjustment; and each
    camera's response.

    Layout: FOLDER/cam0/001.jpg, FOLDER/cam1/001.jpg, ... (same name = same instant).
    """
    from stillcap.calibrate import calibrate_rig
    from stillcap.calibrate.extrinsics import rig_images_from_folder
    from stillcap.camera import Rig

    target = _target(pattern, square, charuco, squares, marker, dictionary)
    stated = _stated(response)
    check(out, "file", "--out", force)
    images, instants = rig_images_from_folder(folder)
    known = {c.name: c for f in intrinsics_files or [] for c in Rig.load(f)} or None
    with progress("detecting", err_console) as cb:
        res = calibrate_rig(images, target, cameras=known, instants=instants, refine_intrinsics=refine_intrinsics,
                            progress=cb)
    rig, resp = _responses(res.rig, images, target, stated)
    outputs = _save_rig(rig, out)
    if as_json:
        cams = []
        for c in res.rig:
            cams.append({"name": c.name, "fx": _f(c.K[0, 0]), "fy": _f(c.K[1, 1]), "cx": _f(c.K[0, 2]),
                         "cy": _f(c.K[1, 2]), "dist": [_f(v) for v in c.dist], "image_size": list(c.image_size),
                         "center": [_f(v) for v in c.center], "world2cam": [[_f(v) for v in r] for r in c.world2cam],
                         "rms_px": _f(res.per_camera_rms_px[c.name])})
        d = {"rms_px": _f(res.rms_px), "initial_rms_px": _f(res.initial_rms_px),
             "per_camera_rms_px": {k: _f(v) for k, v in res.per_camera_rms_px.items()}, "cameras": cams,
             "instants_used": res.instants_used, "images_skipped": res.images_skipped, "success": res.success,
             "per_view_rms_px": {c: {k: _f(v) for k, v in pv.items()} for c, pv in res.per_view_rms_px.items()},
             "outlier_views": res.outlier_views,
             "without_outliers": None if res.without_outliers is None else {
                 "rms_px": _f(res.without_outliers.rms_px),
                 "per_camera_rms_px": {k: _f(v) for k, v in res.without_outliers.per_camera_rms_px.items()}},
             "response": resp}
        typer.echo(json.dumps(d, indent=2))
        outputs.finish(printed_json=True)
        return
    t = Table(title=f"rig: {len(res.rig)} cameras, {len(res.instants_used)} shared instants")
    for col in ("camera", "RMS (px)", "fx", "fy", "cx", "cy", "centre (unit of --square)", "skipped"):
        t.add_column(col, justify="left" if col in ("camera", "skipped") else "right")
    for c in res.rig:
        sk = res.images_skipped.get(c.name, {})
        t.add_row(c.name, f"{res.per_camera_rms_px[c.name]:.3f}", f"{c.K[0, 0]:.1f}", f"{c.K[1, 1]:.1f}",
                  f"{c.K[0, 2]:.1f}", f"{c.K[1, 2]:.1f}", " ".join(f"{v:+.4f}" for v in c.center),
                  ", ".join(sk) if sk else "")
    out_console.print(t)
    out_console.print(f"bundle adjustment: RMS {res.initial_rms_px:.3f} px -> {res.rms_px:.3f} px"
                      + ("" if res.success else f" [red](not converged: {res.message})"))
    for cam, sk in res.images_skipped.items():
        for img, why in sk.items():
            out_console.print(f"  [yellow]{cam}/{img} skipped: {why}")
    odd = [f"{cam}/{img} ({why})" for cam, v in res.outlier_views.items() for img, why in v.items()]
    if odd:
        out_console.print(f"  [red]outlier view{'s' if len(odd) > 1 else ''}:[/] " + "; ".join(odd))
        w = res.without_outliers
        if w is None:
            out_console.print(f"  too few views would remain to calibrate without {_them(len(odd))}; take more photos")
        else:
            out_console.print(f"  without {_them(len(odd))}: RMS {res.rms_px:.3f} -> {w.rms_px:.3f} px ("
                              + ", ".join(f"{k} {res.per_camera_rms_px[k]:.3f} -> {v:.3f}"
                                          for k, v in w.per_camera_rms_px.items())
                              + f"); consider dropping {_them(len(odd))} and calibrating again")
    _print_responses(resp)
    if out is not None and not outputs.failed:
        out_console.print(f"wrote {out}")
    outputs.finish()
