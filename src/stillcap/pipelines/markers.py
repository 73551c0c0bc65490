"""Coloured marker balls seen by a calibrated rig -> labelled 3D points (wiring only).

photos -> bright blobs per image -> colour labels -> N-view correspondence -> triangulation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap.camera import Rig
from stillcap.detect.blobs import MARKER_BALL_COLORS, Blobs, classify_colors, find_blobs
from stillcap.geometry.correspond import correspond
from stillcap.geometry.triangulate import Triangulation, triangulate
from stillcap.response import Response, check_response_option


def default_palette(response: Response | None = None) -> dict[str, tuple[float, float, float]]:
    """The built-in marker-ball colours as they photograph (BGR order, 0-255) through a camera's
    ``response`` (default sRGB).

    Only the hue and chroma matter much to :func:`classify_colors`, so the albedo is encoded
    as if lit to full scale.
    """
    response = Response.srgb() if response is None else response
    return {name: tuple(float(v) for v in response.encode(np.asarray(rgb, float))[::-1])
            for name, rgb in MARKER_BALL_COLORS.items()}


@dataclass
class MarkerReconstruction:
    """Result of :func:`reconstruct_markers`.

    labels : list of length M (colour names); points : (M, 3) metres, rig world frame;
    triangulation : the full :class:`Triangulation` (errors, views used); blobs : per camera.
    """

    labels: list
    points: np.ndarray
    triangulation: Triangulation
    points_2d: np.ndarray
    blobs: list = field(repr=False)

    def to_dict(self) -> dict:
        t = self.triangulation
        return {"units": {"position": "m", "reproj_error": "px"},
                "markers": [{"label": lab, "position_m": p.tolist(), "views": int(n),
                             "reproj_error_px": float(e)}
                            for lab, p, n, e in zip(self.labels, self.points, t.n_views, t.reproj_error_px)]}


def reconstruct_markers(rig: Rig, images, palette: dict | None = None, max_px: float = 2.0,
                        min_area: int = 12, max_color_distance: float = 40.0, min_chroma: float = 20.0,
                        threshold_above_background: float = 12.0, response=None) -> MarkerReconstruction:
    """Find, label, match and triangulate coloured marker balls.

    Parameters
    ----------
    rig : Rig with n_cams cameras
    images : sequence of n_cams BGR images, one per camera in rig order
    palette : {label: (b, g, r)} reference colours, 0-255 (default :func:`default_palette`)
    max_px : epipolar / reprojection tolerance for matching and outlier rejection, pixels
    min_chroma : blobs less colourful than this (Lab chroma; white or grey balls) are ignored
    threshold_above_background : foreground = brighter than the median by this (0-255 units)
    response : None (each camera's own, ``Camera.response``) or a Response for every camera: the
        default palette as each camera photographs it (``docs/camera-response.md``)
    """
    if len(images) != len(rig):
        raise ValueError(f"need one image per camera ({len(rig)}), got {len(images)}")
    response = check_response_option(response)
    if response == "auto":
        raise ValueError("response 'auto' is not available for marker captures yet; give srgb, linear or gamma:G")
    if response is not None:
        rig = rig.with_responses(response)
    blobs: list[Blobs] = []
    pts, labs = [], []
    for cam, img in zip(rig, images):
        h, w = np.asarray(img).shape[:2]
        if (w, h) != cam.image_size:
            raise ValueError(f"camera {cam.name!r}: image is {w}x{h} px, the rig says "
                             f"{cam.image_size[0]}x{cam.image_size[1]}")
        # a low threshold keeps the dim limb of the balls, and the silhouette centre ignores
        # which side the lights make bright (see find_blobs)
        value = np.asarray(img).max(axis=2) if np.asarray(img).ndim == 3 else np.asarray(img)
        b = find_blobs(img, threshold=float(np.median(value)) + threshold_above_background,
                       min_area=min_area, centroid="silhouette")
        pal = palette or default_palette(cam.response)
        lab = classify_colors(b.colors_bgr, list(pal.values()), list(pal), max_color_distance,
                              min_chroma=min_chroma)
        keep = np.array([x is not None for x in lab], bool)
        blobs.append(b)
        pts.append(b.centers[keep])
        labs.append(lab[keep])
    x, _, labels = correspond(rig, pts, labs, max_px=max_px)
    tri = triangulate(rig, x, outlier_px=max_px)
    return MarkerReconstruction(list(labels), tri.points, tri, x, blobs)
