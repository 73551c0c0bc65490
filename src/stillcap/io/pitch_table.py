"""Pitch tables from Statcast and PITCHf/x exports: reading them and recomputing their metrics.

A Statcast export (Baseball Savant search CSV) is recognised by ``vx0, vy0, vz0, ax, ay, az``
with ``release_pos_x, release_pos_y, release_pos_z`` and no ``x0``: its ``x0, z0`` are rebuilt
by carrying the release point along the 9-parameter fit (:func:`stillcap.ball.nine_parameter.
nine_from_release`). A PITCHf/x export (pitchRx, Gameday) has the nine columns
``x0 ... az``. Every metric is recomputed from each pitch's 9-parameter fit
(:func:`stillcap.ball.metrics.nine_parameter_metrics`); the output uses Statcast's column names
where the meaning is the same (``pfx_x``, ``pfx_z`` and ``plate_x``, ``plate_z`` in feet,
``spin_axis``, ``release_extension``, ``release_speed``) and unit-named ones for the rest.
"""

from __future__ import annotations

import csv
import io as _io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stillcap.files.table import number_cell
from stillcap.ball.metrics import nine_parameter_metrics
from stillcap.ball.nine_parameter import NINE_NAMES, Y0_FT, nine_from_release

__all__ = ["STATCAST_COLUMNS", "PitchTable", "read_pitch_table", "table_metrics", "write_metrics_csv"]

_FIT = ("vx0", "vy0", "vz0", "ax", "ay", "az")
_RELEASE = ("release_pos_x", "release_pos_y", "release_pos_z")
#: our metric -> (Statcast column, factor from our unit): the same meaning under Statcast's name
STATCAST_COLUMNS = {
    "pfx_x_in": ("pfx_x", 1.0 / 12.0), "pfx_z_in": ("pfx_z", 1.0 / 12.0),
    "plate_x_ft": ("plate_x", 1.0), "plate_z_ft": ("plate_z", 1.0),
    "spin_axis_from_movement_deg": ("spin_axis", 1.0), "release_extension_ft": ("release_extension", 1.0),
    "release_speed_mph": ("release_speed", 1.0), "release_pos_x_ft": ("release_pos_x", 1.0),
    "release_pos_y_ft": ("release_pos_y", 1.0), "release_pos_z_ft": ("release_pos_z", 1.0),
}
#: the rest, in this order (unit-named)
OTHER_COLUMNS = ("start_speed_mph", "induced_vertical_break_in", "horizontal_break_in", "pfx_x_in", "pfx_z_in",
                 "rapsodo_vb_in", "rapsodo_hb_in", "pitchfx_pfx_x_in", "pitchfx_pfx_z_in", "pitchfx_spin_dir_deg",
                 "vertical_approach_angle_deg", "horizontal_approach_angle_deg", "plate_time_s")
#: input columns copied to the output to identify each pitch (when present)
ID_COLUMNS = ("pitch_type", "game_date", "game_pk", "at_bat_number", "pitch_number", "player_name", "pitcher",
              "p_throws", "num", "id", "sv_id", "pitcher_name")


@dataclass
class PitchTable:
    """The pitches of one export.

    Attributes
    ----------
    path : Path
    kind : {"statcast", "pitchfx"}
    nine : ndarray, shape (N, 9)
        ``x0 ... az`` (ft, ft/s, ft/s^2) at ``y0``; Statcast's ``x0, z0`` rebuilt from the release.
    release_y_ft : ndarray, shape (N,) or None
        Statcast ``release_pos_y`` (None for PITCHf/x, which has no release point).
    ids : list of dict
        The identifying columns of each pitch (:data:`ID_COLUMNS` present in the file).
    rows : list of int
        The file's row number (1 = the first data row) of each pitch.
    """

    path: Path
    kind: str
    nine: np.ndarray
    release_y_ft: np.ndarray | None
    ids: list = field(default_factory=list)
    rows: list = field(default_factory=list)


def _kind(path: Path, header) -> str:
    cols = set(header)
    if set(_FIT) <= cols and set(NINE_NAMES) <= cols:
        return "pitchfx"
    if set(_FIT) <= cols and set(_RELEASE) <= cols:
        return "statcast"
    missing = sorted((set(_FIT) | {"x0", "y0", "z0"}) - cols)
    raise ValueError(f"{path}: neither a Statcast export (vx0 ... az and release_pos_x/y/z) nor a PITCHf/x "
                     f"export (x0 ... az); missing columns: {', '.join(missing)}")


def read_pitch_table(path, progress=None) -> PitchTable:
    """Read a Statcast or PITCHf/x CSV export (recognised by its columns).

    A row whose fit columns are empty (Statcast leaves untracked pitches blank) is skipped; a
    value that is not a number is an error naming the file, row and column.

    Parameters
    ----------
    path : path
    progress : callable, optional
        ``progress(done, total)`` while the rows are read.

    Raises
    ------
    ValueError
        ``FILE: row R, column C: 'text' is not a number``; a file with neither kind's columns,
        or with no pitch.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a text CSV file ({e.reason} at byte {e.start})") from None
    reader = csv.reader(_io.StringIO(text, newline=""))
    header = next(reader, None)
    if not header:
        raise ValueError(f"{path}: empty file (a Statcast or PITCHf/x CSV export was expected)")
    header = [h.strip() for h in header]
    kind = _kind(path, header)
    col = {}
    for i, h in enumerate(header):
        col.setdefault(h, i)  # Savant repeats some columns (pitcher, fielder_2): the first one
    need = list(NINE_NAMES) if kind == "pitchfx" else list(_FIT) + list(_RELEASE)
    body = list(reader)
    vals, ids, rows = [], [], []
    for r, line in enumerate(body, start=1):
        if not any(c.strip() for c in line):
            continue
        if len(line) < len(header) and len(line) <= max(col[c] for c in need):
            raise ValueError(f"{path}: row {r}: {len(line)} fields, the header has {len(header)}")
        cells = [line[col[c]].strip() for c in need]
        if all(c in ("", "NA", "null") for c in cells):
            continue  # not tracked
        nums = []
        for c, s in zip(need, cells):
            nums.append(number_cell(s, f"{path}: row {r}, column {c}"))
        vals.append(nums)
        ids.append({k: line[col[k]] for k in ID_COLUMNS if k in col and col[k] < len(line)})
        rows.append(r)
        if progress is not None and r % 200 == 0:
            progress(r, len(body))
    if progress is not None:
        progress(len(body), len(body))
    if not vals:
        raise ValueError(f"{path}: no pitch with a 9-parameter fit ({', '.join(need)})")
    a = np.array(vals)
    if kind == "pitchfx":
        vy = a[:, 4]
        bad = np.flatnonzero(vy >= 0)
        if len(bad):
            raise ValueError(f"{path}: row {rows[bad[0]]}, column vy0: {vy[bad[0]]} is not toward the plate (< 0)")
        return PitchTable(path, kind, a, None, ids, rows)
    vy = a[:, 1]
    bad = np.flatnonzero(vy >= 0)
    if len(bad):
        raise ValueError(f"{path}: row {rows[bad[0]]}, column vy0: {vy[bad[0]]} is not toward the plate (< 0)")
    bad = np.flatnonzero(~(a[:, 7] > 1.0))
    if len(bad):
        raise ValueError(f"{path}: row {rows[bad[0]]}, column release_pos_y: {a[bad[0], 7]} is not in front of "
                         "the plate (ft)")
    nine = nine_from_release(a[:, 6:9], a[:, 0:3], a[:, 3:6], Y0_FT)
    return PitchTable(path, kind, nine, a[:, 7].copy(), ids, rows)


def table_metrics(table: PitchTable) -> dict:
    """Every metric of every pitch, ``{name: ndarray (N,)}`` (PitchMetrics field names)."""
    return nine_parameter_metrics(table.nine, table.release_y_ft)


def write_metrics_csv(table: PitchTable, metrics: dict, path) -> Path:
    """The metrics as CSV: the identifying columns, ``row``, ``x0 ... az``, Statcast's names where
    the meaning is the same (:data:`STATCAST_COLUMNS`), then the rest with units in the names."""
    from stillcap.files.atomic import write_text

    id_keys = [k for k in ID_COLUMNS if any(k in d for d in table.ids)]
    ours = [k for k in STATCAST_COLUMNS if k in metrics]
    rest = [k for k in OTHER_COLUMNS if k in metrics]
    header = id_keys + ["row"] + list(NINE_NAMES) + [STATCAST_COLUMNS[k][0] for k in ours] + rest
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)

    def fmt(v):
        return "" if not np.isfinite(v) else f"{v:.6g}"

    for i in range(len(table.nine)):
        w.writerow([table.ids[i].get(k, "") for k in id_keys] + [table.rows[i]]
                   + [fmt(v) for v in table.nine[i]]
                   + [fmt(metrics[k][i] * STATCAST_COLUMNS[k][1]) for k in ours]
                   + [fmt(metrics[k][i]) for k in rest])
    return write_text(path, buf.getvalue())
