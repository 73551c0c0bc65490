"""`stillcap puppet run CAP --palette FILE` reads the palette for the capture's own marker set
(puppet-20 here, 20 names), not the thesis's 16; projects name puppet-20 (stillcap.io.project)."""

import json

import numpy as np
import pytest
from support import run_cli as run

from stillcap.body.markerset import MarkerSet
from stillcap.cli import main
from stillcap.detect.palette import Palette
from stillcap.io.project import BUILTIN_MARKERSETS, Project


@pytest.fixture(scope="module")
def capture20(tmp_path_factory):
    """A rendered T-pose with the puppet-20 beads, 6 turntable views 60 degrees apart."""
    out = tmp_path_factory.mktemp("cli20") / "cap"
    main(["studio", "puppet", "--out", str(out), "--pose", "tpose", "--seed", "3", "--views", "6", "--step-deg", "60",
          "--markers", "puppet-20"])
    return out


def test_puppet_run_palette_uses_the_captures_marker_set(capture20, tmp_path, capsys):
    ms = MarkerSet.puppet("puppet-20")
    pal = tmp_path / "pal.json"
    d = Palette.from_markerset(ms).to_dict()
    pal.write_text(json.dumps(d))
    code, out, err = run(["puppet", "run", capture20, "--palette", pal, "--json"], capsys)
    assert code == 0, err
    res = json.loads(out)
    assert res["markerset"] == "puppet-20" and [m["name"] for m in res["markers"]] == list(ms.names)
    truth = json.loads((capture20 / "truth.json").read_text())
    p = np.array([np.full(3, np.nan) if m["position"] is None else m["position"] for m in res["markers"]], float)
    t = np.array([m["position"] for m in truth["markers"]], float)
    ok = np.all(np.isfinite(p), axis=1)
    assert ok.sum() >= 18 and np.abs(p[ok] - t[ok]).max() < 0.5e-3
    # a palette of the 16 thesis names lacks the capture's 4 new beads: named in the message
    pal16 = tmp_path / "pal16.json"
    pal16.write_text(json.dumps({"colors": d["colors"][:16]}))
    code, _, err = run(["puppet", "run", capture20, "--palette", pal16], capsys)
    assert code == 2 and "lacks the markers" in err and "arm.L4" in err


def test_projects_name_every_builtin_marker_set(tmp_path):
    assert set(BUILTIN_MARKERSETS) >= {"puppet-16", "puppet-20"}
    p = Project.create(tmp_path / "p", markerset="puppet-20")
    assert json.loads(p.path.read_text())["markerset"] == "puppet-20"
    loaded = Project.load(p.root).markerset
    assert loaded.to_dict() == MarkerSet.builtin("puppet-20").to_dict() and len(loaded) == 20
    p16 = Project.create(tmp_path / "p16")
    assert json.loads(p16.path.read_text())["markerset"] == "puppet-16" and len(Project.load(p16.root).markerset) == 16
    with pytest.raises(ValueError, match="unknown marker set 'puppet-99'"):
        Project.create(tmp_path / "p99", markerset="puppet-99")
