"""Puppet skeletons and marker sets from files: Skeleton.resolve/builtin/with_offsets and the
capture/project entries (stillcap.body.bodyfiles), paths confined to the folder."""

import json

import numpy as np
import pytest

from stillcap.body.bodyfiles import body_entry, body_entry_dict
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import BUILTIN_SKELETONS, Skeleton


def test_skeleton_resolve_names_files_and_dicts(tmp_path):
    base = Skeleton.puppet()
    assert "puppet" in BUILTIN_SKELETONS and Skeleton.resolve(None).to_dict() == base.to_dict()
    assert Skeleton.resolve(base) is base
    other = base.with_offsets(base.offsets * 1.1, name="big")
    path = other.save(tmp_path / "sk.json", "mm")
    back = Skeleton.resolve(path)
    assert back.name == "big" and np.allclose(back.offsets, base.offsets * 1.1)
    assert Skeleton.resolve(other.to_dict()).name == "big"
    with pytest.raises(ValueError, match="neither a built-in .* nor an existing file"):
        Skeleton.resolve(tmp_path / "absent.json")
    with pytest.raises(ValueError, match=r"offsets must have shape \(20, 3\)"):
        base.with_offsets(np.zeros((3, 3)))


def test_body_entry_reads_builtin_file_and_embedded_and_refuses_paths_outside(tmp_path):
    sk = Skeleton.puppet().with_offsets(Skeleton.puppet().offsets * 0.9, name="small")
    sk.save(tmp_path / "sk.json", "mm")
    got = body_entry({"file": "sk.json"}, "skeleton", tmp_path, "capture x", "x/capture.json", "skeleton")
    assert got.name == "small"
    assert body_entry("puppet", "skeleton", tmp_path, "w", "s", "skeleton").name == "puppet-210mm"
    assert body_entry(sk.to_dict("mm"), "skeleton", tmp_path, "w", "s", "skeleton").name == "small"
    assert len(body_entry("puppet-20", "markerset", tmp_path, "w", "s", "markerset")) == 20
    with pytest.raises(ValueError, match="leaves the folder"):
        body_entry({"file": "../sk.json"}, "skeleton", tmp_path / "sub", "w", "s", "skeleton")
    with pytest.raises(ValueError, match=r"capture x: unknown skeleton 'giant' \(built-in: puppet"):
        body_entry("giant", "skeleton", tmp_path, "capture x", "s", "skeleton")
    with pytest.raises(ValueError, match="skeleton file .* does not exist"):
        body_entry({"file": "none.json"}, "skeleton", tmp_path, "w", "s", "skeleton")
    with pytest.raises(ValueError, match=r"x/capture.json: skeleton.joints"):
        body_entry({"format": "stillcap-skeleton", "joints": "no"}, "skeleton", tmp_path, "w", "x/capture.json",
                   "skeleton")
    assert body_entry_dict(Skeleton.puppet()) == "puppet" and body_entry_dict(MarkerSet.puppet()) == "puppet-16"
    assert body_entry_dict(sk)["name"] == "small"


def test_project_keeps_its_skeleton_file(tmp_path):
    from stillcap.io.project import Project

    p = Project.create(tmp_path / "p")
    sk = Skeleton.puppet().with_offsets(Skeleton.puppet().offsets * 1.05, name="mine")
    sk.save(p.root / "skeleton.json", "mm")
    d = json.loads(p.path.read_text())
    d["skeleton"] = {"file": "skeleton.json"}
    p.path.write_text(json.dumps(d))
    q = Project.load(p.root)
    assert q.skeleton.name == "mine"
    q.save()
    assert json.loads(q.path.read_text())["skeleton"] == {"file": "skeleton.json"}  # the file, not a copy
    d["skeleton"] = {"file": "../outside.json"}
    p.path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match="leaves the folder"):
        Project.load(p.root)
