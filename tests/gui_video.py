"""The fake camera's video for the browser tests: the studio's puppet turning on the turntable.

Twelve studio renders (:func:`stillcap.studio.puppet.puppet_scene`, the thesis's turntable, 30
degrees apart), each held for :data:`HOLD_FRAMES` frames at :data:`FPS`, written as a y4m file
(the format Chromium's ``--use-file-for-fake-video-capture`` plays, looping) by ffmpeg
(imageio-ffmpeg): 4:2:0 YUV, BT.601, as a webcam delivers.

The test plays the person at the turntable: it must know which angle the camera shows when it
takes a photo. So each frame carries the index ``k`` of its angle as the grey level of a
:data:`CODE_SIZE` pixel square in its top-left corner (``CODE_BASE + CODE_STEP * k``), which the
test reads from the live video and from the stored photo (a photo taken while the video turned
shows the wrong code and is retaken, as a person would).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

FPS = 4
HOLD_FRAMES = 6  # 1.5 s per angle
CODE_SIZE = 16
CODE_BASE, CODE_STEP = 16, 18


@dataclass
class TurntableVideo:
    path: Path
    scene: object  # the PuppetScene (truth: angles, marker pixels)
    angles_deg: list


def paint_code(img: np.ndarray, k: int) -> np.ndarray:
    out = img.copy()
    out[:CODE_SIZE, :CODE_SIZE] = CODE_BASE + CODE_STEP * k
    return out


def read_code(img: np.ndarray) -> int | None:
    """The angle index a frame or photo carries (None when the corner holds no code)."""
    v = float(np.asarray(img)[2:CODE_SIZE - 2, 2:CODE_SIZE - 2].mean())
    k = round((v - CODE_BASE) / CODE_STEP)
    return k if 0 <= k < 12 and abs(v - (CODE_BASE + CODE_STEP * k)) < CODE_STEP / 3 else None


def write_turntable_video(path: Path, rng: int = 7) -> TurntableVideo:
    import imageio_ffmpeg

    from stillcap.studio.puppet import puppet_scene

    scene = puppet_scene(rng=rng, supersample=1)
    h, w = scene.images[0].shape[:2]
    writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=FPS, codec="wrapped_avframe", pix_fmt_in="rgb24",
                                         pix_fmt_out="yuv420p", macro_block_size=1, quality=None,
                                         output_params=["-f", "yuv4mpegpipe"])
    writer.send(None)
    for k, img in enumerate(scene.images):
        rgb = np.ascontiguousarray(paint_code(img, k)[:, :, ::-1])  # the studio renders BGR, as OpenCV
        for _ in range(HOLD_FRAMES):
            writer.send(rgb)
    writer.close()
    return TurntableVideo(Path(path), scene, [float(a) for a in scene.truth.angles_deg])
