"""`stillcap demo puppet`: render a puppet pose on the turntable, reconstruct it, compare, export.

:func:`puppet_demo` is what ``stillcap demo`` calls for ``puppet``.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from stillcap.cli._progress import progress

console = Console()

#: Files the demo exports (docs/exports.md).
EXPORTS = ("pose.dae", "pose.bvh", "pose.glb", "markers.c3d")


def puppet_demo(out: Path, seed: int, pose: str | None = None) -> Path:
    """Render the thesis's turntable photos of a random puppet pose, reconstruct, compare, export.

    Writes ``out/capture`` (the 12 rendered JPEG photos, rig and truth), ``out/result.json``,
    ``out/report.html``, ``out/overlays/*.png``, ``out/markers_3d.png``, ``out/skeleton_3d.png`` and the exports
    ``pose.dae``, ``pose.bvh``, ``pose.glb``, ``markers.c3d``.

    Parameters
    ----------
    out : Path
        Output folder (created; files in it are replaced).
    seed : int
        Random pose and sensor noise.
    pose : str, optional
        A pose spec instead of ``random:SEED`` (``tpose``, ``bvh:FILE[:FRAME]``).

    Returns
    -------
    PuppetResult
        The reconstruction, with its comparison with the truth.
    """
    from stillcap.cli.puppet import _print_result
    from stillcap.files.atomic import write_text
    from stillcap.io.project import dumps_json
    from stillcap.io.export import export
    from stillcap.pipelines.puppet import analyse_puppet
    from stillcap.report.puppet import write_report
    from stillcap.studio.compare.puppet import compare_with_capture
    from stillcap.studio.puppet import puppet_scene, webcam_sensor

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    spec = pose or f"random:{seed}"
    console.rule(f"[bold]stillcap demo: puppet on a turntable ({spec}), 12 webcam photos -> 3D markers -> pose")
    with progress("puppet demo: rendering views", total=12) as bar:
        scene = puppet_scene(pose=spec, rng=seed, sensor=webcam_sensor(jpeg_quality=None), progress=bar)
        bar.stage("puppet demo: writing the capture")
        cap, images = scene.to_capture(".jpg")
        cap.save(out / "capture", images, jpeg_quality=85)
        bar.stage("puppet demo: detecting beads", total=len(images))
        res, photos = analyse_puppet(out / "capture", progress=bar)
        bar.stage("puppet demo: comparing with the truth")
        res.comparison = compare_with_capture(res, out / "capture")
    _print_result(res, f"{int(res.markers.ok.sum())} of {len(res.names)} markers from {len(res.rig)} rendered photos "
                       "(puppet frame)")
    t = res.timings_s
    console.print("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in t.items()))
    with progress("puppet demo: writing the report") as bar:
        write_text(out / "result.json", dumps_json(res.to_dict()) + "\n")
        write_report(res, photos, out, scene.truth, progress=bar)
        for name in EXPORTS:
            bar.stage(f"puppet demo: exporting {name}")
            export(out / name, res)
    console.print(f"capture, result.json, report.html, overlays, 3D plots and {', '.join(EXPORTS)} written to "
                  f"[bold]{out}[/]")
    return res
