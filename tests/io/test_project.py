"""Puppet projects: files, views, manual edits over automatic detections, safety, 3D markers."""

import json
import os

import cv2
import numpy as np
import pytest

from stillcap.body import MarkerSet
from stillcap.calibrate.turntable import turntable_rig
from stillcap.camera import Camera, Rig, look_at
from stillcap.io.project import PROJECT_FILE, Project, TurntableSetup, dumps_json, safe_relpath

W, H = 640, 480


def photo(seed=0, size=(W, H)):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)


def puppet_points(n=16, seed=1):
    """Points in a 210 mm puppet's volume around the turn axis (puppet frame, metres)."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.06, 0.06, n), rng.uniform(0.02, 0.2, n), rng.uniform(-0.04, 0.04, n)])


@pytest.fixture
def project(tmp_path):
    p = Project.create(tmp_path / "proj")
    for k, a in enumerate((0, 30, 60)):
        p.add_view(photo(k), angle_deg=a, detections={"head.1": (300, 100 + a), "head.2": (310.25, 200.5)})
    p.save()
    return p


# --- files -----------------------------------------------------------------------------------
def test_create_save_load_round_trip(project):
    project.edit(0, delete="head.2")
    project.edit(1, relabel=("head.1", "torso.1"))
    project.edit(2, move=("arm.L1", 10.5, 20.25))
    project.save()
    q = Project.load(project.root)
    assert [v.angle_deg for v in q.views] == [0.0, 30.0, 60.0]
    assert [v.markers for v in q.views] == [v.markers for v in project.views]
    assert q.views[0].markers == {"head.1": (300.0, 100.0)}
    assert q.views[1].markers == {"head.2": (310.25, 200.5), "torso.1": (300.0, 130.0)}
    assert q.views[2].markers["arm.L1"] == (10.5, 20.25)
    assert q.to_dict() == project.to_dict()
    for v in q.views:
        assert v.image.startswith("photos/")
        assert np.array_equal(q.read_image(v), photo(q.views.index(v)))  # PNG: lossless
    d = json.loads((project.root / PROJECT_FILE).read_text())
    assert d["format"] == "stillcap-puppet-project" and d["version"] == 1
    assert d["units"] == {"angle": "deg", "pixel": "px", "length": "m"}
    assert d["markerset"] == "puppet-16"
    assert d["turntable"]["distance_m"] == 0.4 and d["turntable"]["height_m"] == 0.08
    assert d["views"][0]["edits"] == [{"op": "delete", "marker": "head.2"}]
    # the folder or its project.json both open it
    assert Project.load(project.root / PROJECT_FILE).name == "proj"


def test_dumps_json_is_json_and_compact():
    d = {"a": [1.5, 2], "b": {"c": [[1, 0], [0, 1]], "d": "x[1,2]"}, "e": [], "f": {}}
    text = dumps_json(d)
    assert json.loads(text) == d
    assert "[1.5, 2]" in text and '"x[1,2]"' in text
    with pytest.raises(ValueError):
        dumps_json({"x": float("nan")})


def test_create_refuses_an_existing_project(project):
    with pytest.raises(ValueError, match="already holds a project"):
        Project.create(project.root)


def test_add_view_copies_the_file_byte_for_byte(tmp_path):
    src = tmp_path / "shot.jpg"
    cv2.imwrite(str(src), photo(3))
    p = Project.create(tmp_path / "p")
    v = p.add_view(src, angle_deg=90)
    assert v.image == "photos/turn_090.0deg.jpg"
    assert (p.root / v.image).read_bytes() == src.read_bytes()
    assert v.name == "turn_090.0deg"


def test_add_view_errors(tmp_path, project):
    with pytest.raises(ValueError, match=r"does not exist"):
        project.add_view(tmp_path / "nope.jpg", angle_deg=90)
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(ValueError, match=r"bad.png is not an image"):
        project.add_view(bad, angle_deg=90)
    with pytest.raises(ValueError, match=r"320x240 px but the camera is 640x480"):
        project.add_view(photo(0, (320, 240)), angle_deg=90)
    with pytest.raises(ValueError, match=r"already has a view at 30 deg"):
        project.add_view(photo(0), angle_deg=30)
    with pytest.raises(ValueError, match=r"already has a view at 390 deg"):
        project.add_view(photo(0), angle_deg=390)  # modulo 360
    with pytest.raises(ValueError, match="turntable project: give angle_deg"):
        project.add_view(photo(0), camera="cam_0")
    with pytest.raises(ValueError, match=r"unknown marker 'nose'"):
        project.add_view(photo(0), angle_deg=90, detections={"nose": (1, 2)})
    with pytest.raises(ValueError, match=r"outside the 640x480 px image"):
        project.add_view(photo(0), angle_deg=90, detections={"head.1": (480, 640)})
    assert len(project.views) == 3


def test_retake_replaces_the_view_and_deletes_its_old_photo_on_save(project):
    old = project.root / project.views[1].image
    v = project.add_view(photo(9), angle_deg=30, replace=True)
    assert project.views[1] is v and v.detected == {} and v.edits == []
    assert old.exists()  # still referenced by project.json on disk until save
    assert (project.root / v.image) != old
    project.save()
    assert not old.exists()
    assert np.array_equal(Project.load(project.root).read_image(1), photo(9))


def test_remove_view(project):
    f = project.root / project.views[0].image
    project.remove_view("turn_000.0deg")
    project.save()
    assert not f.exists()
    assert Project.load(project.root).angles_deg == [30.0, 60.0]


def test_view_lookup(project):
    assert project.view(1).angle_deg == 30
    assert project.view("turn_060.0deg") is project.views[2]
    assert project.view_at(-330) is project.views[1]
    assert project.view_at(45) is None
    with pytest.raises(ValueError, match="no view named 'x'"):
        project.view("x")
    with pytest.raises(ValueError, match="out of range"):
        project.view(7)


# --- edits -------------------------------------------------------------------------------------
def test_edits_survive_re_detection(project):
    project.edit(0, delete="head.2")
    project.edit(0, relabel=("head.1", "torso.1"))
    project.edit(0, move=("arm.L1", 50, 60))
    assert project.views[0].markers == {"torso.1": (300.0, 100.0), "arm.L1": (50.0, 60.0)}
    # detection runs again and finds slightly different positions plus a new marker
    project.set_detections(0, {"head.1": (301, 101), "head.2": (311, 201), "leg.L1": (200, 400)})
    assert project.views[0].markers == {"leg.L1": (200.0, 400.0), "torso.1": (301.0, 101.0),
                                        "arm.L1": (50.0, 60.0)}
    assert project.views[0].detected["head.2"] == (311.0, 201.0)  # automatic data kept apart
    project.save()
    assert Project.load(project.root).views[0].markers == project.views[0].markers
    project.clear_edits(0)
    assert project.views[0].markers == project.views[0].detected


def test_moving_a_marker_twice_keeps_one_edit(project):
    project.edit(1, move=("head.1", 10, 10))
    project.edit(1, move=("head.1", 12, 11))
    assert [e.to_dict() for e in project.views[1].edits] == [{"op": "move", "marker": "head.1", "xy": [12.0, 11.0]}]


def test_relabel_replaces_nothing_silently(project):
    with pytest.raises(ValueError, match=r"already has a marker 'head.2'; delete it"):
        project.edit(0, relabel=("head.1", "head.2"))
    project.edit(0, delete="head.2")
    project.edit(0, relabel=("head.1", "head.2"))
    assert project.views[0].markers == {"head.2": (300.0, 100.0)}


def test_edit_errors(project):
    with pytest.raises(ValueError, match="exactly one of"):
        project.edit(0)
    with pytest.raises(ValueError, match="exactly one of"):
        project.edit(0, delete="head.1", move=("head.1", 1, 1))
    with pytest.raises(ValueError, match=r"has no marker 'arm.L1' to delete"):
        project.edit(0, delete="arm.L1")
    with pytest.raises(ValueError, match=r"unknown marker 'nose'"):
        project.edit(0, relabel=("head.1", "nose"))
    with pytest.raises(ValueError, match=r"unknown marker 'nose'"):
        project.edit(0, move=("nose", 1, 1))
    with pytest.raises(ValueError, match=r"outside the 640x480"):
        project.edit(0, move=("head.1", -3, 1))
    with pytest.raises(ValueError, match=r"move must be \(name, x, y\)"):
        project.edit(0, move=("head.1", 1))
    assert project.views[0].edits == []


# --- geometry ----------------------------------------------------------------------------------
def test_view_cameras_are_the_turntable_rig():
    tt = TurntableSetup()
    rig = turntable_rig(12, 30.0)
    for k in range(12):
        c = tt.camera_at(30.0 * k)
        assert c.name == rig[k].name
        np.testing.assert_allclose(c.world2cam, rig[k].world2cam, atol=1e-15)
        np.testing.assert_allclose(c.K, rig[k].K)


def test_reconstruct_recovers_ground_truth_and_flags_missing(tmp_path):
    ms = MarkerSet.puppet()
    truth = puppet_points(len(ms))
    p = Project.create(tmp_path / "p")
    angles = (0, 30, 60, 90)
    for k, a in enumerate(angles):
        px = p.turntable.camera_at(a).project(truth)
        det = {n: tuple(xy) for i, (n, xy) in enumerate(zip(ms.names, px))
               if not (n == "leg.R3" and k > 0) and not (n == "leg.R2")}
        p.add_view(photo(k), angle_deg=a, detections=det)
    p.save()
    q = Project.load(p.root)
    names, pts, rig = q.observations()
    assert names == ms.names and pts.shape == (4, 16, 2) and len(rig) == 4
    assert rig.names == [v.name for v in q.views]
    assert np.isnan(pts[:, names.index("leg.R2")]).all()
    m3 = q.reconstruct()
    assert set(m3.missing) == {"leg.R2", "leg.R3"}  # seen never / once
    ok = m3.ok
    np.testing.assert_allclose(m3.points[ok], truth[ok], atol=1e-9)
    assert np.isnan(m3.points[~ok]).all()
    assert m3.n_views[names.index("head.1")] == 4 and m3.n_views[names.index("leg.R3")] < 2
    np.testing.assert_allclose(m3.points_mm[ok], truth[ok] * 1000, atol=1e-6)
    assert m3.as_dict()["leg.R2"] is None
    # the thesis's midpoint method agrees
    np.testing.assert_allclose(q.reconstruct(method="midpoint").points[ok], truth[ok], atol=1e-9)


def test_a_relabel_edit_fixes_a_swapped_identification(tmp_path):
    ms = MarkerSet.puppet()
    truth = puppet_points(len(ms), seed=4)
    p = Project.create(tmp_path / "p")
    for k, a in enumerate((0, 30, 60)):
        px = p.turntable.camera_at(a).project(truth)
        det = dict(zip(ms.names, map(tuple, px)))
        if k == 1:  # the detector swapped two colours in one view
            det["arm.L1"], det["arm.R1"] = det["arm.R1"], det["arm.L1"]
        p.add_view(photo(k), angle_deg=a, detections=det)
    bad = p.reconstruct()
    i = ms.names.index("arm.L1")
    assert np.linalg.norm(bad.points[i] - truth[i]) > 1e-3
    p.edit(1, delete="arm.R1")
    p.edit(1, relabel=("arm.L1", "arm.R1"))
    p.edit(1, move=("arm.L1", *p.turntable.camera_at(30).project(truth[i])))
    np.testing.assert_allclose(p.reconstruct().points, truth, atol=1e-9)


def test_rig_project(tmp_path):
    cams = []
    for k in range(3):
        a = 2 * np.pi * k / 3
        cams.append(Camera.from_intrinsics(f"cam_{k}", 800, 800, 320, 240, (W, H),
                                           world2cam=look_at((2 * np.cos(a), 2 * np.sin(a), 0.5), (0, 0, 0))))
    rig = Rig(cams)
    ms = MarkerSet.puppet()
    truth = puppet_points(len(ms)) * 3
    p = Project.create(tmp_path / "p", rig=rig, rig_file="rig.json")
    for k, c in enumerate(rig):
        p.add_view(photo(k), camera=c.name, detections=dict(zip(ms.names, map(tuple, c.project(truth)))))
    with pytest.raises(ValueError, match=r"unknown camera 'cam_9'"):
        p.add_view(photo(0), camera="cam_9")
    with pytest.raises(ValueError, match=r"rig project: give camera="):
        p.add_view(photo(0), angle_deg=30)
    with pytest.raises(ValueError, match=r"already has a view of camera 'cam_1'"):
        p.add_view(photo(0), camera="cam_1")
    p.save()
    d = json.loads(p.path.read_text())
    assert d["rig"] == {"file": "rig.json"} and "turntable" not in d
    q = Project.load(p.root)
    assert q.rig.names == rig.names and q.rig_file == "rig.json"
    np.testing.assert_allclose(q.reconstruct().points, truth, atol=1e-9)
    # embedded rig
    p2 = Project.create(tmp_path / "p2", rig=rig)
    assert json.loads(p2.path.read_text())["rig"]["format"] == "stillcap-rig"
    assert Project.load(p2.root).rig.names == rig.names


def test_custom_markerset_is_embedded(tmp_path):
    d = MarkerSet.puppet().to_dict()
    d["name"] = "puppet-4"
    d["markers"] = d["markers"][:4]
    keep = {"head.1", "head.2", "torso.1", "torso.2"}
    d["bone_rules"] = [r for r in d["bone_rules"] if {r.get("from"), r.get("to")} <= keep]
    ms = MarkerSet.from_dict(d)
    p = Project.create(tmp_path / "p", markerset=ms)
    assert json.loads(p.path.read_text())["markerset"]["name"] == "puppet-4"
    assert Project.load(p.root).markerset.names == ms.names
    with pytest.raises(ValueError, match="unknown marker set 'hand'"):
        Project.create(tmp_path / "p3", markerset="hand")


# --- damaged and hostile files -----------------------------------------------------------------
def edit_json(project, fn):
    d = json.loads(project.path.read_text())
    fn(d)
    project.path.write_text(json.dumps(d))


@pytest.mark.parametrize("path, message", [
    ("/etc/passwd", "is absolute"),
    ("C:\\photos\\a.png", "is absolute"),
    ("\\\\server\\share\\a.png", "is absolute"),
    ("../outside.png", r"leaves the project folder \('\.\.'"),
    ("photos/../../outside.png", r"leaves the project folder"),
    ("", "non-empty string"),
])
def test_unsafe_photo_paths_are_refused(project, path, message):
    edit_json(project, lambda d: d["views"][1].__setitem__("image", path))
    with pytest.raises(ValueError, match=rf"view 'turn_030.0deg': image: .*{message}"):
        Project.load(project.root)


def test_symlink_out_of_the_folder_is_refused(project, tmp_path):
    outside = tmp_path / "secret.png"
    cv2.imwrite(str(outside), photo(0))
    link = project.root / "photos" / "link.png"
    os.symlink(outside, link)
    edit_json(project, lambda d: d["views"][0].__setitem__("image", "photos/link.png"))
    with pytest.raises(ValueError, match=r"view 'turn_000.0deg': photo: path 'photos/link.png' leads outside"):
        Project.load(project.root)
    (project.root / "sub").symlink_to(tmp_path)  # a linked folder is the same escape
    edit_json(project, lambda d: d["views"][0].__setitem__("image", "sub/secret.png"))
    with pytest.raises(ValueError, match="leads outside the project folder"):
        Project.load(project.root)


def test_unsafe_rig_and_markerset_files_are_refused(project):
    edit_json(project, lambda d: (d.pop("turntable"), d.__setitem__("rig", {"file": "../rig.json"})))
    with pytest.raises(ValueError, match=r"rig file: path '../rig.json' leaves the project folder"):
        Project.load(project.root)
    edit_json(project, lambda d: d.__setitem__("markerset", {"file": "/etc/markers.json"}))
    with pytest.raises(ValueError, match=r"markerset file: path '/etc/markers.json' is absolute"):
        Project.load(project.root)


def test_damaged_project_files(project):
    pfile = project.path
    good = pfile.read_text()
    pfile.write_text(good[: len(good) // 2])
    with pytest.raises(ValueError, match=rf"{pfile.name} is not valid JSON"):
        Project.load(project.root)
    pfile.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(ValueError, match="not a stillcap puppet project"):
        Project.load(project.root)
    pfile.write_text(good)
    edit_json(project, lambda d: d.__setitem__("version", 99))
    with pytest.raises(ValueError, match="version 99 is newer"):
        Project.load(project.root)
    pfile.write_text(good)
    edit_json(project, lambda d: d["views"][2]["detected"].__setitem__("nose", [1, 2]))
    with pytest.raises(ValueError, match=r"view 'turn_060.0deg': detections: unknown marker 'nose'"):
        Project.load(project.root)
    pfile.write_text(good)
    edit_json(project, lambda d: d["views"][2]["edits"].append({"op": "relabel", "marker": "head.1", "to": "nose"}))
    with pytest.raises(ValueError, match=r"view 'turn_060.0deg': relabel edit: unknown marker 'nose'"):
        Project.load(project.root)
    pfile.write_text(good)
    edit_json(project, lambda d: d["views"][0].__setitem__("angle", 5))
    with pytest.raises(ValueError,
        match=r"project.json: views\.0\.angle: unknown key \(not part of the format; check its spelling\) \(got 5\)$"):
        Project.load(project.root)
    pfile.write_text(good)
    edit_json(project, lambda d: d["views"][1].__setitem__("angle_deg", 0))
    with pytest.raises(ValueError, match=r"same turn angle 0 deg"):
        Project.load(project.root)
    pfile.write_text(good)
    (project.root / project.views[1].image).unlink()
    with pytest.raises(ValueError, match=r"view 'turn_030.0deg': photo .*turn_030.0deg.png does not exist"):
        Project.load(project.root)
    with pytest.raises(ValueError, match="does not exist"):
        Project.load(project.root / "nowhere")
    with pytest.raises(ValueError, match="is not a stillcap project"):
        Project.load(project.root / "photos")


def test_unknown_camera_in_a_rig_project(tmp_path):
    rig = Rig([Camera.from_intrinsics("a", 800, 800, 320, 240, (W, H))])
    p = Project.create(tmp_path / "p", rig=rig)
    p.add_view(photo(0), camera="a")
    p.save()
    edit_json(p, lambda d: d["views"][0].__setitem__("camera", "b"))
    with pytest.raises(ValueError, match=r"view 'a': unknown camera 'b'; the rig has \['a'\]"):
        Project.load(p.root)


def test_save_never_writes_half_a_file(project, monkeypatch):
    before = project.path.read_bytes()
    project.views[0].detected["nose"] = (1.0, 2.0)  # invalid: refused before writing
    with pytest.raises(ValueError, match="unknown marker 'nose'"):
        project.save()
    assert project.path.read_bytes() == before
    del project.views[0].detected["nose"]
    project.edit(0, delete="head.1")

    def fail(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        project.save()
    assert project.path.read_bytes() == before
    assert sorted(p.name for p in project.root.iterdir()) == ["photos", PROJECT_FILE]  # no temp files left


def test_safe_relpath_normalises():
    assert safe_relpath("photos\\a.png", "x") == "photos/a.png"
    assert safe_relpath("./photos//a.png", "x") == "photos/a.png"
    with pytest.raises(ValueError, match="names no file"):
        safe_relpath(".", "x")


def test_turntable_setup_validation():
    with pytest.raises(ValueError, match="distance must be"):
        TurntableSetup(distance=0)
    tt = TurntableSetup.from_dict(TurntableSetup().to_dict())
    assert tt.distance == 0.4 and tt.camera.image_size == (640, 480)
    with pytest.raises(ValueError, match=r"unknown keys \['distance'\]"):
        TurntableSetup.from_dict({"distance": 400, "height_m": 0.08, "camera": {}})


def test_reconstruct_with_too_few_views(tmp_path):
    p = Project.create(tmp_path / "p")
    with pytest.raises(ValueError, match="has no views yet"):
        p.reconstruct()
    p.add_view(photo(0), angle_deg=0, detections={"head.1": (300, 100)})
    m3 = p.reconstruct()
    assert len(m3.missing) == 16 and np.isnan(m3.points).all()


def test_project_photos_are_checked_before_decoding(project):
    # issue 15: a truncated or oversized photo of a project is named, at load and at read
    path = project.root / project.views[1].image
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])
    with pytest.raises(ValueError, match=r"view 'turn_030.0deg': photo: image file .*turn_030.0deg.png is truncated"):
        Project.load(project.root)
    with pytest.raises(ValueError, match=r"view 'turn_030.0deg': image file .*turn_030.0deg.png is truncated"):
        project.read_image(1)
    big = data[:16] + (60000).to_bytes(4, "big") * 2 + data[24:]  # IHDR claims 60000x60000 (its CRC now fails)
    path.write_bytes(big)
    with pytest.raises(ValueError, match=r"turn_030.0deg.png: its header claims 60000x60000 px"):
        project.read_image(1)
