"""JumpingJack (.juja) project files: the thesis's format, round trips, hostile XML and paths."""

import os
import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pytest

from stillcap.camera import Camera, Rig
from stillcap.io.jumpingjack import (
    export_jumpingjack,
    import_jumpingjack,
    parse_jumpingjack,
    read_jumpingjack,
)
from stillcap.io.project import PROJECT_FILE, Project, TurntableSetup

W, H = 640, 480

# The listing of the thesis (section 7.1.2), letter-spacing of the PDF extraction removed.
THESIS_XML = """<?xml version="1.0" encoding="UTF-8"?>
<JJProject name="my_project.juja">
<image name="0" normal_src="my_project_0.jpg" pro_src="my_project_0p.jpg">
<marker name="leg.L1" x="380" y="267" />
<marker name="head.1" x="349" y="23" />
</image>
<image name="30" normal_src="my_project_30.jpg" pro_src="my_project_30p.jpg">
<marker name="leg.R1" x="313" y="262" />
</image>
</JJProject>
"""


def photo(seed=0, size=(W, H)):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)


@pytest.fixture
def thesis_folder(tmp_path):
    folder = tmp_path / "jj"
    folder.mkdir()
    for k, a in enumerate((0, 30)):
        cv2.imwrite(str(folder / f"my_project_{a}.jpg"), photo(k))
        cv2.imwrite(str(folder / f"my_project_{a}p.jpg"), photo(k + 10))
    (folder / "my_project.juja").write_text(THESIS_XML)
    return folder


def test_reads_the_thesis_listing(thesis_folder):
    jj = read_jumpingjack(thesis_folder / "my_project.juja")
    assert jj.name == "my_project.juja"
    assert [im.name for im in jj.images] == ["0", "30"]
    assert [im.angle_deg for im in jj.images] == [0.0, 30.0]
    assert jj.images[0].normal_src == "my_project_0.jpg" and jj.images[0].pro_src == "my_project_0p.jpg"
    assert jj.images[0].markers == {"leg.L1": (380.0, 267.0), "head.1": (349.0, 23.0)}
    assert jj.images[1].markers == {"leg.R1": (313.0, 262.0)}


def test_import_makes_a_project(thesis_folder, tmp_path):
    p = import_jumpingjack(thesis_folder / "my_project.juja", tmp_path / "proj")
    assert p.name == "my_project"
    q = Project.load(tmp_path / "proj")
    assert q.angles_deg == [0.0, 30.0]
    # pixel coordinates map one to one (same origin and axes as the thesis)
    assert q.views[0].detected == {"leg.L1": (380.0, 267.0), "head.1": (349.0, 23.0)}
    assert q.views[0].edits == []
    for k, a in enumerate((0, 30)):
        v = q.views[k]
        assert (q.root / v.image).read_bytes() == (thesis_folder / f"my_project_{a}.jpg").read_bytes()
        assert (q.root / v.processed).read_bytes() == (thesis_folder / f"my_project_{a}p.jpg").read_bytes()
    # the thesis's turntable is assumed
    assert q.turntable.distance == 0.4 and q.turntable.camera.K[0, 0] == 859.016


def test_round_trip(tmp_path):
    p = Project.create(tmp_path / "proj")
    for k, a in enumerate((0, 22.5, 30, 330)):
        p.add_view(photo(k), angle_deg=a, processed=photo(k + 5) if k % 2 else None,
                   detections={"head.1": (349.125, 23.0 + a), "torso.2": (1e-3, 479.5), "leg.L1": (0.1 + 0.2, 267)})
    p.edit(1, delete="torso.2")
    p.edit(2, relabel=("head.1", "head.2"))
    p.edit(3, move=("arm.R3", 10.333333333333334, 20))
    p.save()
    out = export_jumpingjack(p, tmp_path / "export" / "puppet")
    assert out.name == "puppet.juja"
    names = sorted(f.name for f in out.parent.iterdir())
    assert names == ["puppet.juja", "puppet_0.png", "puppet_22.5.png", "puppet_22.5p.png", "puppet_30.png",
                     "puppet_330.png", "puppet_330p.png"]
    root = ET.parse(out).getroot()
    assert root.tag == "JJProject" and root.get("name") == "puppet.juja"
    assert [im.get("name") for im in root] == ["0", "22.5", "30", "330"]
    assert out.read_text().startswith('<?xml version="1.0" encoding="UTF-8"?>')

    q = import_jumpingjack(out, tmp_path / "again")
    assert q.angles_deg == p.angles_deg
    assert [v.markers for v in q.views] == [v.markers for v in p.views]  # exact floats
    for v, w in zip(p.views, q.views):
        assert (q.root / w.image).read_bytes() == (p.root / v.image).read_bytes()
        assert (w.processed is None) == (v.processed is None)
    # and once more: export of the import is the same file
    out2 = export_jumpingjack(q, tmp_path / "export2" / "puppet.juja")
    assert out2.read_bytes() == out.read_bytes()


def test_round_pixels_writes_whole_pixels_like_the_thesis(tmp_path):
    p = Project.create(tmp_path / "proj")
    p.add_view(photo(0), angle_deg=0, detections={"head.1": (349.6, 22.4)})
    out = export_jumpingjack(p, tmp_path / "e.juja", round_pixels=True)
    m = ET.parse(out).getroot().find("image/marker")
    assert (m.get("x"), m.get("y")) == ("350", "22")


def test_rig_projects_use_camera_names(tmp_path):
    rig = Rig([Camera.from_intrinsics(n, 800, 800, 320, 240, (W, H)) for n in ("left", "right")])
    p = Project.create(tmp_path / "proj", rig=rig)
    p.add_view(photo(0), camera="left", detections={"head.1": (1, 2)})
    p.add_view(photo(1), camera="right", detections={"head.1": (3, 4)})
    out = export_jumpingjack(p, tmp_path / "e" / "stereo.juja")
    assert [im.get("name") for im in ET.parse(out).getroot()] == ["left", "right"]
    q = import_jumpingjack(out, tmp_path / "again", rig=rig)
    assert [v.camera for v in q.views] == ["left", "right"]
    assert [v.markers for v in q.views] == [v.markers for v in p.views]
    with pytest.raises(ValueError,
        match=r"stereo.juja: image #0 \('left'\): name 'left' is not a turn angle in degrees$"):
        import_jumpingjack(out, tmp_path / "again2")


def test_import_with_another_turntable(thesis_folder, tmp_path):
    cam = Camera.from_intrinsics("cam", 900, 900, 320, 240, (W, H))
    p = import_jumpingjack(thesis_folder / "my_project.juja", tmp_path / "p", turntable=TurntableSetup(cam, 0.5, 0.1))
    assert Project.load(p.root).turntable.distance == 0.5


# --- hostile XML ------------------------------------------------------------------------------
BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
 <!ENTITY lol9 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
]>
<JJProject name="&lol9;"></JJProject>
"""

EXTERNAL_ENTITY = """<?xml version="1.0"?>
<!DOCTYPE JJProject [ <!ENTITY xxe SYSTEM "file:///etc/passwd"> ]>
<JJProject name="x"><image name="0" normal_src="&xxe;"/></JJProject>
"""

DTD_ONLY = """<?xml version="1.0"?>
<!DOCTYPE JJProject SYSTEM "http://example.com/jj.dtd">
<JJProject name="x"/>
"""


@pytest.mark.parametrize("text", [BILLION_LAUGHS, EXTERNAL_ENTITY, DTD_ONLY], ids=["billion-laughs", "xxe", "dtd"])
def test_dtds_and_entities_are_refused(tmp_path, text):
    f = tmp_path / "evil.juja"
    f.write_text(text)
    with pytest.raises(ValueError, match=r"evil.juja: refused: the file declares a DTD or entities"):
        read_jumpingjack(f)
    with pytest.raises(ValueError, match="refused"):
        import_jumpingjack(f, tmp_path / "p")
    assert not (tmp_path / "p" / PROJECT_FILE).exists()


def project_xml(src, pro=None, marker='<marker name="head.1" x="1" y="2"/>', name="0"):
    pro_attr = f' pro_src="{pro}"' if pro else ""
    return f'<JJProject name="t.juja"><image name="{name}" normal_src="{src}"{pro_attr}>{marker}</image></JJProject>'


@pytest.mark.parametrize("src, message", [
    ("../../etc/passwd", r"normal_src: path '../../etc/passwd' leaves the project folder"),
    ("/etc/passwd", r"normal_src: path '/etc/passwd' is absolute"),
    ("C:\\Windows\\win.ini", r"is absolute"),
    ("sub/../../x.jpg", r"leaves the project folder"),
])
def test_file_attributes_must_stay_in_the_folder(tmp_path, src, message):
    f = tmp_path / "jj" / "t.juja"
    f.parent.mkdir()
    f.write_text(project_xml(src))
    with pytest.raises(ValueError, match=rf"t.juja: image #0 \('0'\): .*{message}"):
        read_jumpingjack(f)


def test_pro_src_must_stay_in_the_folder(thesis_folder):
    f = thesis_folder / "t.juja"
    f.write_text(project_xml("my_project_0.jpg", pro="../x.jpg"))
    with pytest.raises(ValueError, match=r"pro_src: path '../x.jpg' leaves"):
        read_jumpingjack(f)


def test_symlinked_photo_outside_is_refused(thesis_folder, tmp_path):
    outside = tmp_path / "outside.jpg"
    cv2.imwrite(str(outside), photo(0))
    os.symlink(outside, thesis_folder / "link.jpg")
    f = thesis_folder / "t.juja"
    f.write_text(project_xml("link.jpg"))
    with pytest.raises(ValueError, match=r"normal_src: path 'link.jpg' leads outside the project folder"):
        read_jumpingjack(f)


@pytest.mark.parametrize("text, message", [
    ("<JJProject><image", "is not well-formed XML"),
    ("<COLLADA/>", r"not a JumpingJack project \(root element <COLLADA>"),
    ('<JJProject><image normal_src="a.jpg"/></JJProject>', "missing the name attribute"),
    ('<JJProject><image name="0"/></JJProject>', "missing the normal_src attribute"),
    (project_xml("a.jpg", marker='<marker name="head.1" x="abc" y="2"/>'), r"marker 'head.1' x must be a number"),
    (project_xml("a.jpg", marker='<marker name="head.1" x="nan" y="2"/>'), r"marker 'head.1' x must be finite"),
    (project_xml("a.jpg", marker='<marker x="1" y="2"/>'), "a marker has no name"),
    (project_xml("a.jpg", marker='<marker name="head.1" x="1" y="2"/><marker name="head.1" x="1" y="2"/>'),
     "marker 'head.1' is listed twice"),
    ('<JJProject><image name="0" normal_src="a.jpg"/><image name="0" normal_src="b.jpg"/></JJProject>',
     r"image #1 \('0'\): listed twice"),
])
def test_malformed_files(text, message):
    with pytest.raises(ValueError, match=message):
        parse_jumpingjack(text.encode(), "t.juja")


def test_import_errors_name_the_image(thesis_folder, tmp_path):
    f = thesis_folder / "t.juja"
    f.write_text(project_xml("my_project_0.jpg", marker='<marker name="nose" x="1" y="2"/>'))
    with pytest.raises(ValueError, match=r"t.juja: image #0 \('0'\): .*unknown marker 'nose'"):
        import_jumpingjack(f, tmp_path / "p")
    assert not (tmp_path / "p" / PROJECT_FILE).exists()  # a failed import leaves no project
    f.write_text(project_xml("missing.jpg"))
    with pytest.raises(ValueError, match=r"t.juja: image #0 \('0'\): photo .*missing.jpg does not exist"):
        import_jumpingjack(f, tmp_path / "p")
    cv2.imwrite(str(thesis_folder / "small.jpg"), photo(0, (320, 240)))
    f.write_text(project_xml("small.jpg"))
    with pytest.raises(ValueError, match=r"t.juja: image #0 \('0'\): .*320x240 px but the camera is 640x480"):
        import_jumpingjack(f, tmp_path / "p")
    with pytest.raises(ValueError, match="does not exist"):
        read_jumpingjack(thesis_folder / "nothing.juja")
    import_jumpingjack(thesis_folder / "my_project.juja", tmp_path / "ok")
    with pytest.raises(ValueError, match="already holds a project"):
        import_jumpingjack(thesis_folder / "my_project.juja", tmp_path / "ok")


def test_huge_files_are_refused(tmp_path, monkeypatch):
    import stillcap.io.jumpingjack as jjmod

    monkeypatch.setattr(jjmod, "MAX_XML_BYTES", 100)
    f = tmp_path / "big.juja"
    f.write_text("<JJProject>" + " " * 200 + "</JJProject>")
    with pytest.raises(ValueError, match="too large"):
        read_jumpingjack(f)
