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
