import cv2
import numpy as np
import pytest

from stillcap.detect.blobs import classify_colors, find_blobs


def draw(centers, colors, size=(480, 640), radius=6, ss=8):
    """Anti-aliased discs drawn at 8x and averaged down, so centres are sub-pixel exact."""
    big = np.zeros((size[0] * ss, size[1] * ss, 3), np.float32)
    for (x, y), c in zip(centers, colors):
        cv2.circle(big, (int(round((x + 0.5) * ss - 0.5)), int(round((y + 0.5) * ss - 0.5))), radius * ss, c, -1)
    return cv2.resize(big, (size[1], size[0]), interpolation=cv2.INTER_AREA).astype(np.uint8)


def test_centroids_are_subpixel_and_colors_classified():
    rng = np.random.default_rng(0)
    centers = rng.uniform([30, 30], [610, 450], (12, 2))
    centers = (np.round((centers + 0.5) * 8 - 0.5) + 0.5) / 8 - 0.5  # where draw() really puts them
    palette = np.array([[40, 40, 230], [230, 80, 40], [60, 220, 60]], float)  # red, blue, green (BGR)
    which = np.arange(12) % 3
    img = draw(centers, palette[which])
    b = find_blobs(img, min_area=20)
    assert len(b) == 12
    order = [np.argmin(np.linalg.norm(b.centers - c, axis=1)) for c in centers]
    assert np.abs(b.centers[order] - centers).max() < 0.05
    names = classify_colors(b.colors_bgr[order], palette, ["red", "blue", "green"])
    assert list(names) == [["red", "blue", "green"][w] for w in which]
    # a dim red (same hue, half the light) is still red; grey is nothing
    assert list(classify_colors([[20, 20, 115], [128, 128, 128]], palette, ["r", "b", "g"])) == ["r", None]


def test_area_limits_background_and_empty():
    img = draw([(100, 100), (300, 300)], [(255, 255, 255)] * 2)
    cv2.circle(img, (500, 400), 1, (255, 255, 255), -1)  # a speck
    assert len(find_blobs(img, min_area=20)) == 2
    assert len(find_blobs(img, min_area=20, max_area=50)) == 0
    assert len(find_blobs(img, min_area=20, background=img)) == 0
    assert len(find_blobs(np.zeros((50, 50), np.uint8))) == 0


def test_bad_input():
    with pytest.raises(ValueError, match=r"image must have shape .* got \(5, 5, 4\)"):
        find_blobs(np.zeros((5, 5, 4)))
    with pytest.raises(ValueError, match="background has shape"):
        find_blobs(np.zeros((5, 5)), background=np.zeros((4, 4)))
    with pytest.raises(ValueError, match="2 names for 3 palette colours"):
        classify_colors([[0, 0, 0]], np.zeros((3, 3)), ["a", "b"])
