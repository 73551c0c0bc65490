import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton
from stillcap.files.jsonfile import read_json


def test_missing_and_invalid_files_name_the_file(tmp_path):
    (tmp_path / "bad.json").write_text("{nope")
    with pytest.raises(ValueError, match="rig file .*none.json does not exist"):
        read_json(tmp_path / "none.json", "rig file")
    with pytest.raises(ValueError, match="bad.json is not valid JSON"):
        read_json(tmp_path / "bad.json")
    (tmp_path / "latin1.json").write_bytes(b'{"a": "\xe9"}')
    with pytest.raises(ValueError, match="latin1.json is not valid JSON"):
        read_json(tmp_path / "latin1.json")
    # the loaders that use it report the same way (a missing skeleton used to be FileNotFoundError)
    with pytest.raises(ValueError, match="skel.json does not exist"):
        Skeleton.load(tmp_path / "skel.json")
    with pytest.raises(ValueError, match="bad.json is not valid JSON"):
        MarkerSet.load(tmp_path / "bad.json")


def test_package_json_is_the_file_importlib_resources_gives(monkeypatch):
    """read_package_json reads stillcap/data's file directly where the package is a folder on
    disk, and through importlib.resources otherwise (e.g. a zip): the same content both ways."""
    import json
    from importlib import resources

    from stillcap.files import jsonfile

    names = sorted(p.name for p in resources.files("stillcap").joinpath("data").iterdir() if p.name.endswith(".json"))
    assert "puppet_skeleton.json" in names and "puppet_markers.json" in names
    for name in names:
        expected = json.loads(resources.files("stillcap").joinpath("data", name).read_text(encoding="utf-8"))
        assert jsonfile.read_package_json(name) == (expected, f"stillcap/data/{name}")
    # no folder on disk where the module says it lives: importlib.resources reads it
    monkeypatch.setattr(jsonfile, "__file__", "/nonexistent-stillcap/stillcap/files/jsonfile.py")
    for name in names:
        expected = json.loads(resources.files("stillcap").joinpath("data", name).read_text(encoding="utf-8"))
        assert jsonfile.read_package_json(name) == (expected, f"stillcap/data/{name}")
