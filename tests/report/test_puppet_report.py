"""The puppet report: overlays, 3D plots (readable axes) and report.html, which a real HTML parser
reads with its sections, tables and the images it links."""

from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from stillcap.report.puppet import write_report
from stillcap.report.puppet_html import comparison_rows, puppet_notes


class _Outline(HTMLParser):
    """Sections (h1/h2 id and text), images, table rows, warnings of an HTML page."""

    def __init__(self):
        super().__init__()
        self.sections, self.images, self.rows, self.warnings, self.stack = {}, [], [], [], []
        self._h = None
        self._row = None
        self._warn = None

    VOID = ("meta", "img", "br", "hr", "link", "input")

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag not in self.VOID:
            self.stack.append(tag)
        if tag in ("h1", "h2"):
            self._h = [a.get("id", tag), ""]
        elif tag == "img":
            self.images.append(a["src"])
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._row.append("")
        elif tag == "div" and a.get("class") == "warn":
            self._warn = ""

    def handle_endtag(self, tag):
        assert self.stack and self.stack[-1] == tag, f"</{tag}> closes <{self.stack[-1] if self.stack else None}>"
        self.stack.pop()
        if tag in ("h1", "h2"):
            self.sections[self._h[0]] = self._h[1]
            self._h = None
        elif tag == "tr":
            self.rows.append(self._row)
            self._row = None
        elif tag == "div" and self._warn is not None:
            self.warnings.append(self._warn)
            self._warn = None

    def handle_data(self, data):
        if self._h is not None:
            self._h[1] += data
        if self._row:
            self._row[-1] += data
        if self._warn is not None:
            self._warn += data


@pytest.fixture(scope="module")
def puppet(tmp_path_factory):
    """A rendered random pose (6 turntable views 60 degrees apart), analysed and compared."""
    from stillcap.calibrate.turntable import turntable_rig
    from stillcap.pipelines.puppet import analyse_puppet
    from stillcap.studio.compare.puppet import compare_with_capture
    from stillcap.studio.puppet import puppet_scene, webcam_sensor

    cap = tmp_path_factory.mktemp("puppet") / "capture"
    scene = puppet_scene(turntable_rig(6, 60.0), "random:3", rng=3, sensor=webcam_sensor(jpeg_quality=None))
    c, images = scene.to_capture(".png")
    c.save(cap, images)
    res, photos = analyse_puppet(cap)
    res.comparison = compare_with_capture(res, cap)
    return res, photos, scene.truth


@pytest.fixture(scope="module")
def report(puppet, tmp_path_factory):
    res, photos, truth = puppet
    out = tmp_path_factory.mktemp("report")
    calls = []
    files = write_report(res, photos, out, truth, progress=lambda i, n, label: calls.append((i, n, label)))
    return out, files, calls


def _outline(path: Path) -> _Outline:
    p = _Outline()
    p.feed(path.read_text(encoding="utf-8"))
    p.close()
    assert p.stack == [], p.stack  # every element closed
    return p


def test_report_html_is_written_with_its_images(report):
    out, files, calls = report
    assert files[-1] == out / "report.html" and files[-1].stat().st_size > 1000
    names = {f.relative_to(out).as_posix() for f in files[:-1]}
    assert {"markers_3d.png", "skeleton_3d.png"} <= names
    assert len([n for n in names if n.startswith("overlays/")]) == 6
    page = _outline(out / "report.html")
    # the report links every image written, by its path relative to the report, and no other
    assert set(page.images) == names
    assert all((out / src).is_file() for src in page.images)
    # progress after each file, the last one the report
    assert [c[0] for c in calls] == list(range(1, len(files) + 1)) and calls[-1] == (9, 9, "report.html")


def test_report_html_sections_and_tables(report, puppet):
    res = puppet[0]
    out = report[0]
    page = _outline(out / "report.html")
    assert page.sections["h1"] == "Puppet report"
    for key, title in (("truth", "Compared with the truth"), ("plots", "3D markers and skeleton"),
                       ("markers", "Markers"), ("pose", "Pose: joint angles"), ("views", "Views")):
        assert page.sections[key] == title
    headers = [r for r in page.rows if r and r[0] in ("marker", "joint", "view", "quantity")]
    marker_header = next(r for r in headers if r[0] == "marker")
    assert {"views used", "identified in", "reproj px", "error mm"} <= set(marker_header)
    first_cells = {r[0] for r in page.rows if r}
    assert set(res.names) <= first_cells  # every marker has a row
    assert set(res.pose.skeleton.names) <= first_cells  # every joint has a row of angles
    assert set(res.view_names) <= first_cells
    # the joint angles shown are the pose's, within its limits
    sk = res.pose.skeleton
    row = next(r for r in page.rows if r and r[0] == sk.names[1])
    ang = sk.limit_angles_deg(res.pose.local_rotations)[1]
    assert [float(v) for v in row[2:5]] == pytest.approx(ang, abs=0.051)
    # the markers' notes as warnings
    assert page.warnings == puppet_notes(res)


def test_notes_name_the_missing_markers_and_what_was_left_out(puppet):
    res = puppet[0]
    notes = puppet_notes(res)
    m = res.markers
    if m.missing:
        assert any(all(n in note for n in m.missing) for note in notes)
    if m.partial.any() or m.outlier.any():
        assert any(f"{int(m.partial.sum())} partly hidden" in note for note in notes)


def test_comparison_rows_name_both_denominators(puppet):
    cmp = puppet[0].comparison
    rows = dict(comparison_rows(cmp))
    right = next(k for k in rows if k.startswith("beads identified right"))
    wrong = next(k for k in rows if k.startswith("identifications wrong"))
    assert "whose centre a view shows" in right and rows[right].endswith(f"({cmp.right_visible} of {cmp.visible})")
    assert "of all identifications" in wrong and f"{cmp.wrong} of {cmp.identified};" in rows[wrong]


def test_3d_plots_have_few_mm_ticks_and_no_labels_on_the_end_on_axis(puppet, tmp_path, monkeypatch):
    """skeleton_3d.png had overlapping tick labels: the axis pointing at the viewer showed a pile
    of them, and every axis 8-10 ticks in metres."""
    import matplotlib.pyplot as plt

    from stillcap.report import puppet as rp

    res, _, truth = puppet
    figs = []
    real_close = plt.close
    monkeypatch.setattr(rp.plt, "close", lambda fig: figs.append(fig))
    rp.plot_skeleton_3d(res, tmp_path / "s.png", truth)
    rp.plot_markers_3d(res, tmp_path / "m.png", truth)
    try:
        assert len(figs) == 2
        for fig in figs:
            fig.canvas.draw()
            axes = [ax for ax in fig.axes if hasattr(ax, "zaxis")]
            assert len(axes) == 4
            for ax, (turn, _) in zip(axes, rp._SIDES):
                end_on = ax.xaxis if turn in (90, 270) else ax.yaxis
                for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
                    lo, hi = sorted(axis.get_view_interval())
                    labels = [t.get_text() for t, v in zip(axis.get_ticklabels(), axis.get_majorticklocs())
                              if t.get_text() and lo <= v <= hi]
                    if axis is end_on:
                        assert labels == [] and axis.get_label_text() == ""
                    else:
                        assert 2 <= len(labels) <= 5 and all(s.lstrip("-").isdigit() for s in labels), labels
                        assert axis.get_label_text().endswith("(mm)")
    finally:
        for fig in figs:
            real_close(fig)
    assert np.isfinite(res.markers.points).any()
