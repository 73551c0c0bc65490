"""Running a batch on a Dask cluster: hash, skip what is done, submit, collect, write.

:func:`run_batch` is given a :class:`distributed.Client` (a ``LocalCluster``'s or a running
cluster's; :func:`stillcap.batch.cluster.connect`) and the captures
(:func:`stillcap.batch.inputs.read_inputs`). It

1. hashes every capture's inputs (:func:`~stillcap.batch.inputs.content_hash`) and reads the
   results folder's table: a capture whose hash has a row with status ``ok`` and whose JSON file
   is there is skipped (its row is kept);
2. submits one task per remaining capture (:func:`stillcap.batch.tasks.analyse_capture`: the
   folder's path goes, the worker reads the files), at most ``in_flight`` at a time so that the
   client and the scheduler hold a bounded number of results;
3. as each task ends, writes its JSON (``captures/NAME/<kind's file>``) and keeps its row; the
   table is rewritten every ``save_every_s`` and at the end (atomically), so a batch that stops
   half-way resumes from the last table;
4. writes the session summary (:func:`stillcap.batch.summary.write_summary`).

Rows of captures not in this batch stay in the table (a results folder can gather a season);
a capture given again replaces its old row.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from stillcap import __version__
from stillcap._progress import report_progress
from stillcap.batch.inputs import BatchInput, content_hash
from stillcap.batch.table import TABLE_FILE, read_rows, write_rows
from stillcap.batch.tasks import JSON_FILES, analyse_capture, options_of, problem_line
from stillcap.files.atomic import write_text
from stillcap.files.outputs import record_outputs

__all__ = ["BatchRun", "OUTPUT_NAMES", "run_batch"]

#: What a batch writes into its results folder (glob patterns; for the overwrite check).
OUTPUT_NAMES = (TABLE_FILE, "summary.md", "summary_*.png", "captures/*/*.json")


@dataclass
class BatchRun:
    """What :func:`run_batch` did.

    ``rows``: this batch's rows in the order given; ``analysed``, ``skipped``, ``failed``:
    capture names; ``files``: what was written; ``seconds``: wall time."""

    rows: list = field(default_factory=list)
    analysed: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    files: list = field(default_factory=list)
    seconds: float = 0.0


def _hashes(inputs: list[BatchInput], threads: int) -> list[str]:
    opts = {k: {"stillcap": __version__, "kind": k, "options": options_of(k)} for k in {i.kind for i in inputs}}
    with ThreadPoolExecutor(max(1, threads)) as pool:  # hashlib releases the GIL on large chunks
        return list(pool.map(lambda i: content_hash(i, opts[i.kind]), inputs))


def _row(inp: BatchInput, digest: str, json_file: str | None, res: dict) -> dict:
    row = {"capture": inp.path, "name": inp.name, "kind": inp.kind, "pitch_type": inp.pitch_type,
           "status": res["status"], "error": res["error"], "content_hash": digest, "seconds": res["seconds"],
           "worker": res["worker"], "json_file": json_file if res["status"] == "ok" else None}
    row.update(res["metrics"])
    return row


def run_batch(inputs: list[BatchInput], out, client, *, finish=None, threads: int = 1, in_flight: int | None = None,
              save_every_s: float = 10.0, progress=None) -> BatchRun:
    """Analyse ``inputs`` on ``client``'s cluster into the results folder ``out``.

    Parameters
    ----------
    inputs : list of BatchInput
    out : path
        The results folder (created): ``results.parquet``, ``captures/NAME/*.json``,
        ``summary.md`` and its plots.
    client : distributed.Client
    finish : callable, optional
        ``finish(kind, source, result) -> dict`` on the worker (:mod:`stillcap.batch.tasks`).
    threads : int
        Threads of one capture's analysis (pitch: its photo decoding).
    in_flight : int, optional
        Most tasks submitted and not yet collected (default: 2 per worker thread, at least 4).
    save_every_s : float
        Rewrite the table at most this often while the batch runs.
    progress : callable, optional
        ``progress(done, total, label)`` after each capture (skipped ones included).

    Returns
    -------
    BatchRun
    """
    from distributed import as_completed

    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table = out / TABLE_FILE
    previous = read_rows(table)
    digests = _hashes(inputs, 4)
    here = {i.path for i in inputs}
    kept_old = [r for r in previous if r.get("capture") not in here]
    done = {r["content_hash"]: r for r in previous
            if r.get("status") == "ok" and r.get("json_file") and (out / r["json_file"]).is_file()}
    file_of = {(r.get("capture"), r.get("kind")): r["json_file"] for r in previous if r.get("json_file")}
    taken = {f for (path, _), f in file_of.items() if path not in here}  # other captures' files
    run = BatchRun()
    rows: list = [None] * len(inputs)
    todo = []
    for k, (inp, digest) in enumerate(zip(inputs, digests)):
        old = done.get(digest)
        if old is not None and old.get("kind") == inp.kind:
            rows[k] = dict(old, capture=inp.path, name=inp.name, pitch_type=inp.pitch_type)
            run.skipped.append(inp.name)
            continue
        json_file = file_of.get((inp.path, inp.kind))  # analysed before: its file is replaced
        n = 1
        while json_file is None or json_file in taken:
            json_file = f"captures/{inp.name}{'' if n == 1 else f'-{n}'}/{JSON_FILES[inp.kind]}"
            n += 1
        taken.add(json_file)
        todo.append((k, inp, digest, json_file))
    total, count = len(inputs), len(run.skipped)
    report_progress(progress, count, total, f"{count} already done" if count else "starting")

    def save():
        path = write_rows(table, [r for r in rows if r is not None] + kept_old)
        record_outputs([path], out)
        return path

    if todo:
        if in_flight is None:
            n_threads = sum(client.nthreads().values()) or 1
            in_flight = max(4, 2 * n_threads)
        pending = iter(todo)
        meta = {}

        def submit(item):
            k, inp, digest, json_file = item
            fut = client.submit(analyse_capture, inp.path, inp.kind, finish, threads, pure=False,
                                key=f"stillcap-batch-{inp.name}-{digest[:12]}-{time.time_ns()}")
            meta[fut.key] = item
            return fut

        ac = as_completed([submit(item) for _, item in zip(range(in_flight), pending)])
        last_save = time.perf_counter()
        for fut in ac:
            k, inp, digest, json_file = meta.pop(fut.key)
            try:
                res = fut.result()
            except Exception as e:  # noqa: BLE001 - the worker died (KilledWorker), lost, ...: this capture's row
                res = {"status": "error", "error": problem_line(e), "seconds": float("nan"), "worker": None,
                       "metrics": {}, "json": None}
            fut.release()
            if res["status"] == "ok":
                try:
                    path = write_text(out / json_file, res["json"])
                    record_outputs([path], out)
                    run.files.append(path)
                except OSError as e:
                    res = dict(res, status="error", error=f"cannot write {out / json_file}: {problem_line(e)}")
            rows[k] = _row(inp, digest, json_file, res)
            (run.analysed if res["status"] == "ok" else run.failed).append(inp.name)
            del res
            count += 1
            report_progress(progress, count, total, inp.name)
            nxt = next(pending, None)
            if nxt is not None:
                ac.add(submit(nxt))
            if time.perf_counter() - last_save > save_every_s:
                save()
                last_save = time.perf_counter()
    run.files.append(save())
    run.rows = rows
    from stillcap.batch.summary import write_summary

    all_rows = rows + kept_old
    paths = write_summary(all_rows, out)
    record_outputs(paths, out)
    run.files.extend(paths)
    run.seconds = time.perf_counter() - t0
    return run
