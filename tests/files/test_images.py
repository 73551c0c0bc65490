"""files/images.py: every photo is checked (header size, completeness) before OpenCV decodes it."""

import io
import re
import struct
import zlib

import cv2
import numpy as np
import pytest

from stillcap.files.images import MAX_PIXELS, check_image_bytes, check_image_file, decode_image, read_image


def _png(w=64, h=48):
    rng = np.random.default_rng(0)
    return cv2.imencode(".png", rng.integers(0, 255, (h, w, 3), dtype=np.uint8))[1].tobytes()


def _jpeg(w=64, h=48):
    return cv2.imencode(".jpg", np.full((h, w, 3), 120, np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()


def _chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png_claiming(w, h):
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(b"\0" * 100)) + _chunk(b"IEND", b"")


def _jpeg_claiming(w, h):
    data = _jpeg()
    i = data.index(b"\xff\xc0")
    return data[:i + 5] + struct.pack(">HH", h, w) + data[i + 9:]


def test_valid_images_decode_as_opencv_reads_them(tmp_path):
    for name, data in (("a.png", _png()), ("a.jpg", _jpeg())):
        p = tmp_path / name
        p.write_bytes(data)
        h = check_image_file(p)
        assert (h.format, h.width, h.height) == ("PNG" if name.endswith("png") else "JPEG", 64, 48)
        np.testing.assert_array_equal(read_image(p), cv2.imread(str(p)))
        np.testing.assert_array_equal(read_image(p, cv2.IMREAD_GRAYSCALE), cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))


def test_other_formats_through_pillow(tmp_path):
    from PIL import Image

    bio = io.BytesIO()
    Image.new("RGB", (30, 20)).save(bio, "BMP")
    assert check_image_bytes(bio.getvalue(), "a.bmp").width == 30
    p = tmp_path / "a.bmp"
    p.write_bytes(bio.getvalue())
    assert read_image(p).shape == (20, 30, 3)


@pytest.mark.parametrize("data, message", [
    (_png()[:-12], r"^image file x is truncated \(no PNG end chunk IEND\)$"),
    (_png()[:200], r"^image file x is truncated \(PNG chunk 'IDAT' runs past the end of the file\)$"),
    (_png()[:60] + bytes([_png()[60] ^ 0x55]) + _png()[61:], r"^image file x is corrupt \(PNG chunk 'IDAT' fails its CRC check\)$"),
    (_jpeg()[:-2], r"^image file x is truncated \(no JPEG end-of-image marker\)$"),
    (_jpeg(640, 480)[:-100], r"^image file x is truncated \(no JPEG end-of-image marker\)$"),
    (_jpeg()[:100], r"^image file x is truncated \(the JPEG ends before its image data\)$"),
    (b"", r"^image file x is empty$"),
    (b"hello, not an image", r"^image file x is not an image"),
    (_png_claiming(60000, 60000), r"^image file x: its header claims 60000x60000 px \(3600 megapixels\), more than the 100 megapixels"),
    (_jpeg_claiming(60000, 60000), r"^image file x: its header claims 60000x60000 px"),
    (_png_claiming(0, 10), r"^image file x is corrupt \(its header claims 0x10 px\)$"),
])
def test_bad_images_are_refused_before_decoding(data, message):
    with pytest.raises(ValueError, match=message):
        check_image_bytes(data, "x")
    with pytest.raises(ValueError, match=message):
        decode_image(data, "x")


def test_the_limit_is_in_pixels():
    assert MAX_PIXELS == 100_000_000
    check_image_bytes(_png_claiming(10000, 10000), "x")  # 100 Mpx: the limit itself passes the check
    with pytest.raises(ValueError, match="10000x10001 px"):
        check_image_bytes(_png_claiming(10000, 10001), "x")


def test_a_truncated_jpeg_never_reaches_the_decoder(tmp_path, monkeypatch):
    p = tmp_path / "cut.jpg"
    p.write_bytes(_jpeg()[:-200])
    calls = []
    monkeypatch.setattr(cv2, "imdecode", lambda *a: calls.append(a))
    with pytest.raises(ValueError, match=r"cut.jpg is truncated"):
        read_image(p)
    assert calls == []


def test_missing_and_unreadable_files_are_named(tmp_path):
    with pytest.raises(ValueError, match=r"image file .*nope.png does not exist"):
        read_image(tmp_path / "nope.png")
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(ValueError, match=r"dir.png is a folder, not an image file"):
        check_image_file(tmp_path / "dir.png")


def test_cli_calibration_and_project_photos_give_one_line(tmp_path, capsys):
    from stillcap.io.project import Project
    from support import run_cli

    big = tmp_path / "big.png"
    big.write_bytes(_png_claiming(60000, 60000))  # issue 15: a cv2.error in calibrate/intrinsics
    code, _, err = run_cli(["calibrate", "intrinsics", big, "-p", "9x6"], capsys)
    assert code == 2 and "big.png: its header claims 60000x60000 px" in err
    assert len(err.strip().splitlines()) == 1
    Project.create(tmp_path / "proj")
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(_jpeg(640, 480)[:-50])  # issue 15: a truncated JPEG was half used
    for detect in ("--detect", "--no-detect"):
        code, _, err = run_cli(["puppet", "add", tmp_path / "proj", cut, "--angle", "30", detect], capsys)
        assert code == 2 and "cut.jpg is truncated (no JPEG end-of-image marker)" in err, err
        assert len(err.strip().splitlines()) == 1


def _big_jpeg(w=640, h=480):
    rng = np.random.default_rng(1)
    return cv2.imencode(".jpg", rng.integers(0, 255, (h, w, 3), dtype=np.uint8))[1].tobytes()


def _with_app1(data, n):
    """``data`` with an APP1 segment of ``n`` bytes after its SOI (a camera's EXIF, thumbnail)."""
    return data[:2] + b"\xff\xe1" + struct.pack(">H", n + 2) + bytes(n) + data[2:]


@pytest.mark.parametrize("data", [
    _big_jpeg(),
    _big_jpeg() + bytes(10_000),  # data after the end-of-image marker, beyond the tail read
    _with_app1(_big_jpeg(), 65_000),  # marker segments beyond the head read
    _big_jpeg()[:-2],  # truncated
    _big_jpeg()[:-3000],
    _jpeg(),  # smaller than the head read
    _jpeg_claiming(60000, 60000) + bytes(70_000),
])
def test_a_files_check_is_its_bytes_check(tmp_path, data):
    p = tmp_path / "a.jpg"
    p.write_bytes(data)
    try:
        want = check_image_bytes(data, p)
    except ValueError as e:
        with pytest.raises(ValueError, match=re.escape(str(e))):
            check_image_file(p)
    else:
        assert check_image_file(p) == want


def test_a_large_jpeg_is_checked_from_its_head_and_tail(tmp_path, monkeypatch):
    import stillcap.files.images as images

    p = tmp_path / "a.jpg"
    p.write_bytes(_big_jpeg())
    assert p.stat().st_size > images._HEAD_BYTES + images._TAIL_BYTES
    monkeypatch.setattr(images, "_read_bytes", lambda path: pytest.fail("read the whole file"))
    assert check_image_file(p) == images.ImageHeader("JPEG", 640, 480)
