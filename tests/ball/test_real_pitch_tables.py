"""Statcast and Rapsodo checks on the real files in ../shared/data, and `stillcap metrics`."""

import sys
from pathlib import Path

import numpy as np
import pytest
from support import shared_data

from stillcap.ball.metrics import parse_clock_deg
from stillcap.cli import main
from stillcap.io.pitch_table import read_pitch_table, table_metrics

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))


def _file(*parts):
    path = shared_data(parts[0]).joinpath(*parts[1:])
    if not path.exists():
        pytest.skip(f"real data {path} is absent (see shared/data/README.md)")
    return path


def test_statcast_pfx_spin_axis_and_plate_location_reproduce_the_file():
    from bench_real_pitches import _col

    path = _file("statcast", "statcast-2019-one-pitcher-part.csv")
    tab = read_pitch_table(path)
    assert tab.kind == "statcast" and len(tab.rows) == 539  # one untracked row skipped
    m = table_metrics(tab)
    med = lambda d: float(np.nanmedian(np.abs(d)))
    assert med(m["pfx_x_in"] - 12 * _col(path, "pfx_x", tab.rows)) < 0.1
    assert med(m["pfx_z_in"] - 12 * _col(path, "pfx_z", tab.rows)) < 0.1
    assert med((m["spin_axis_from_movement_deg"] - _col(path, "spin_axis", tab.rows) + 180) % 360 - 180) < 0.5
    assert np.nanmax(np.abs(m["plate_x_ft"] - _col(path, "plate_x", tab.rows))) < 0.011
    assert med(m["plate_x_ft"] - _col(path, "plate_x", tab.rows)) < 0.01
    assert med(m["plate_z_ft"] - _col(path, "plate_z", tab.rows)) < 0.01


def test_rapsodo_spin_break_predicted_from_release():
    from bench_real_pitches import rapsodo_predictions, read_rapsodo

    rows = read_rapsodo(_file("rapsodo", "rapsodo-2022-04-19-pitcher-a.csv"))
    pred = rapsodo_predictions(rows)
    vb = np.array([float(r["VB (spin)"]) for r in rows])
    hb = np.array([float(r["HB (spin)"]) for r in rows])
    assert np.median(np.abs(pred[:, 0] - vb)) < 1.5
    assert np.median(np.abs(pred[:, 1] - hb)) < 1.5


@pytest.mark.parametrize("text, deg", [("12:00", 180.0), ("1:00", 210.0), ("1:8", 214.0), ("0:52", 206.0),
                                       ("6:00", 0.0)])
def test_parse_clock(text, deg):
    assert parse_clock_deg(text) == pytest.approx(deg)


def test_parse_clock_bad():
    with pytest.raises(ValueError, match="'13:00'"):
        parse_clock_deg("13:00")


def test_cli_metrics_writes_statcast_columns(tmp_path, capsys):
    path = _file("statcast", "statcast-2019-one-pitcher-part.csv")
    out = tmp_path / "m.csv"
    main(["metrics", str(path), "--out", str(out)])
    head = out.read_text().splitlines()[0].split(",")
    for c in ("pfx_x", "pfx_z", "plate_x", "spin_axis", "x0", "z0", "induced_vertical_break_in",
              "pitchfx_pfx_z_in", "vertical_approach_angle_deg"):
        assert c in head


def test_cli_metrics_bad_cell_names_file_row_column(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("x0,y0,z0,vx0,vy0,vz0,ax,ay,az\n-1,50,6,5,-130,-5,-8,28,-15\n-1,50,six,5,-130,-5,-8,28,-15\n")
    with pytest.raises(SystemExit) as e:
        main(["metrics", str(bad)])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "bad.csv: row 2, column z0: 'six' is not a number" in " ".join(err.split())


def test_cli_metrics_unknown_table(tmp_path, capsys):
    bad = tmp_path / "other.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(SystemExit):
        main(["metrics", str(bad)])
    assert "neither a Statcast export" in " ".join(capsys.readouterr().err.split())


def test_cli_metrics_json_pitchfx(tmp_path, capsys):
    good = tmp_path / "p.csv"
    good.write_text("x0,y0,z0,vx0,vy0,vz0,ax,ay,az\n-1,50,6,5,-130,-5,-8,28,-15\n")
    main(["metrics", str(good), "--json"])
    import json

    d = json.loads(capsys.readouterr().out)
    assert d["kind"] == "pitchfx" and d["pitches"][0]["pitchfx_pfx_x_in"] < 0
    assert d["pitches"][0]["pfx_x_in"] is None  # Statcast movement needs a release point
