"""`stillcap export RESULT --to FILE [--to FILE ...]`: write a result in formats real tools open."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from stillcap.cli._outputs import check

console = Console()


def load_exportable(source: Path):
    """What ``stillcap export`` exports from ``source``: an object with ``pose`` and ``markers``.

    ``source`` is a puppet result (``result.json`` from ``stillcap puppet run --out``, or the
    output of ``--json``), a puppet project folder (reconstructed from its stored markers) or a
    puppet capture folder (the pipeline runs on it).
    """
    from stillcap.io.puppet_result import load_result
    from stillcap.pipelines.puppet import analyse_puppet

    if not source.exists():
        raise ValueError(f"{source} does not exist")
    if source.is_dir():
        if (source / "project.json").is_file():
            res, _ = analyse_puppet(source, detect=False)
        elif (source / "capture.json").is_file():
            res, _ = analyse_puppet(source)
        else:
            raise ValueError(f"{source} is neither a puppet project (project.json) nor a capture folder "
                             "(capture.json); give a result.json, a project or a capture")
        return _Exportable(res.pose, res.trajectories)
    return load_result(source)


class _Exportable:
    def __init__(self, pose, markers):
        self.pose, self.markers = pose, markers


def export(
    result: Path = typer.Argument(..., help="A puppet result JSON (stillcap puppet run --out DIR writes "
                                  "DIR/result.json), a puppet project folder or a puppet capture folder."),
    to: list[Path] = typer.Option(..., "--to", help="File to write; the extension picks the format: "
                                  ".dae .bvh .gltf .glb .c3d .csv .json (repeat --to for several)."),
    force: bool = typer.Option(False, "--force", help="Overwrite files stillcap did not write."),
):
    """Export a puppet result: the pose (COLLADA, BVH, glTF) and the 3D markers (C3D, CSV, JSON).

    Lengths: metres in COLLADA, glTF, CSV and JSON; centimetres in BVH; millimetres in C3D
    (see docs/exports.md).
    """
    from stillcap.io.export import EXPORTERS, export as write, known_extensions

    bad = [str(p) for p in to if p.suffix.lower() not in EXPORTERS]
    if bad:
        raise ValueError(f"cannot export to {', '.join(bad)}: unknown extension; known: {', '.join(known_extensions())}")
    for path in to:
        check(path, "file", "--to", force)
    data = load_exportable(result)
    from stillcap.files.outputs import record_outputs

    for path in to:
        out = write(path, data)
        record_outputs([out])
        console.print(f"wrote [bold]{out}[/]")
