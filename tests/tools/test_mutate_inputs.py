"""The mutation campaign (tools/mutate_inputs.py), bounded for CI: every invalid capture.json,
rig.json or photo it makes gives exit status 2 and one line; and the campaign itself can see a
bad outcome (an accepted input, a traceback)."""

import importlib.util
import json
import sys

import pytest

from support import REPO, studio_pitch


def _tool():
    spec = importlib.util.spec_from_file_location("mutate_inputs", REPO / "tools" / "mutate_inputs.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def tool():
    return _tool()


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    from stillcap.cli import main

    root = tmp_path_factory.mktemp("mutate")
    main(["studio", "markers", "--out", str(root / "markers"), "--seed", "4", "--cameras", "2", "--balls", "3",
          "--jpeg", "90"])
    main(["studio", "puppet", "--out", str(root / "puppet"), "--seed", "2", "--views", "4", "--step-deg", "90"])
    return [studio_pitch(tmp_path_factory, "fastball"), root / "markers", root / "puppet"]


def test_a_bounded_campaign_gives_exit_2_and_one_line_for_every_case(tool, captures, tmp_path):
    out = tmp_path / "failures.json"
    res = tool.campaign(captures, 40, seed=1, out=out, log=lambda *a: None)
    failures = json.loads(out.read_text())
    assert failures == [], tool.table(res["counts"]) + "\n" + json.dumps(failures[:3], indent=1)
    assert sum(c.get("ok", 0) for c in res["counts"].values()) == 40
    assert "| **total** | **40** |" in tool.table(res["counts"])


@pytest.mark.parametrize("capture", [0, 1], ids=["pitch-png", "markers-jpeg"])
def test_every_mutation_once(tool, captures, capture):
    for name in tool.MUTATIONS:
        if name == "wrong_kind" and capture == 1:
            continue  # stillcap markers reads any kind
        res = tool.campaign([captures[capture]], 1, seed=3, out=None, kinds=[name], log=lambda *a: None)
        assert res["counts"][name].get("ok") == 1, (name, res["failures"])


def test_the_campaign_sees_bad_outcomes(tool, captures, monkeypatch):
    ok = tool.run_command(["markers", str(captures[1])])  # a valid capture: accepted
    assert ok["outcome"] == "exit0" and ok["exit"] == 0
    refused = tool.run_command(["markers", str(captures[1] / "missing")])
    assert refused["outcome"] == "ok" and len(refused["stderr"]) == 1
    import stillcap.io.capture as capture

    def boom(path):
        raise TypeError("an escaped error")

    monkeypatch.setattr(capture.Capture, "load", staticmethod(boom))
    bad = tool.run_command(["markers", str(captures[1])])
    assert bad["outcome"] == "traceback" and "TypeError: an escaped error" in bad["traceback"]
