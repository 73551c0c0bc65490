"""`stillcap batch CAPTURES... --out RESULTS`: many captures of any kind on a Dask cluster (docs/batch.md)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

err = Console(stderr=True, highlight=False)


def batch(
    captures: list[Path] = typer.Argument(None, help="Capture folders (pitch, hand, puppet or markers; the kind is "
                                          "read from each capture.json)."),
    from_list: Path = typer.Option(None, "--from", help="A text file listing capture folders, one a line (# comments; "
                                   "relative paths from the file's folder)."),
    out: Path = typer.Option(..., "--out", help="Results folder: results.parquet, captures/NAME/*.json, summary.md "
                             "and plots. Given again, captures already done (same content hash) are skipped."),
    scheduler: str = typer.Option(None, "--scheduler", help="Address of a running Dask scheduler "
                                  "(tcp://host:8786); default: a local cluster on this machine."),
    workers: int = typer.Option(None, "--workers", help="Worker processes of the local cluster (default: one per core)."),
    threads: int = typer.Option(1, "--threads", help="Threads per worker (and per capture's photo decoding)."),
    force: bool = typer.Option(False, "--force", help="Write into --out even if it holds files stillcap did not write."),
):
    """Analyse many captures in parallel on a Dask cluster: one Parquet table, the per-capture JSON
    (as each kind's own command writes it) and a session summary per pitch type.

    A capture that fails is named in its row (status error) and the batch goes on; the exit status
    is then 1, after the batch. Bad input (a missing capture, an unknown kind, a scheduler that
    cannot be reached) stops before any work with one line and exit status 2.
    """
    from stillcap.cli._outputs import check
    from stillcap.batch import OUTPUT_NAMES, connect, read_capture_list, read_inputs, run_batch

    given = list(captures or [])
    if from_list is not None:
        given += read_capture_list(from_list)
    if not given:
        raise ValueError("no captures: give capture folders or --from LIST")
    check(out, "folder", "--out", force, OUTPUT_NAMES)
    inputs = read_inputs(given)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with connect(scheduler, workers, threads) as client:
        n_workers = len(client.scheduler_info().get("workers", {}))
        err.print(f"{len(inputs)} captures on {n_workers} Dask worker(s) at {client.scheduler.address}; "
                  f"dashboard: {client.dashboard_link}", soft_wrap=True)
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=err, transient=True) as bar:
            task = bar.add_task("hashing", total=len(inputs))

            def progress(done, total, label=None):
                bar.update(task, completed=done, total=total, description=label or "")

            run = run_batch(inputs, out, client, finish=finish_with_truth, threads=threads, progress=progress)
    err.print(f"{len(run.analysed)} analysed, {len(run.skipped)} skipped (already done), {len(run.failed)} failed "
              f"in {run.seconds:.1f} s; results in {out}", soft_wrap=True)
    for name in run.failed:
        row = next(r for r in run.rows if r["name"] == name)
        err.print(f"[red]{row['capture']}:[/] {row['error']}", soft_wrap=True, markup=True)
    if run.failed:
        raise typer.Exit(1)


def finish_with_truth(kind: str, source, result) -> dict:
    """A result's JSON document as the kind's own command writes it: with a studio capture's
    comparison against its truth (runs on the worker; the batch package never reads a truth)."""
    if kind == "pitch":
        from stillcap.studio.compare.pitch import add_truth_comparison

        return add_truth_comparison(result, source.truth).to_dict()
    if kind == "hand":
        from stillcap.studio.compare.hand import compare_with_capture

        result.truth = compare_with_capture(result)
        return result.to_dict()
    if kind == "puppet":
        if result.source.get("type") == "capture":
            from stillcap.studio.compare.puppet import compare_with_capture

            result.comparison = compare_with_capture(result, source)
        return result.to_dict()
    if kind == "markers":
        from stillcap.cli.markers import result_with_truth

        return result_with_truth(result, source.truth)
    raise ValueError(f"unknown capture kind {kind!r}")
