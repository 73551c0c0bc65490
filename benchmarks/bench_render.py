"""Render-speed benchmark of the synthetic studio (prints a table; not a test).

    /work/venv/bin/python benchmarks/bench_render.py [--repeat 5]

Cases:
- pitch: one 2560x1920 multi-exposure photo (SPEC J1 front camera, 3.5 m from the flight,
  80 Hz strobe), a baseball with the 12 painted markers at 10 flashes. Goal <= 0.5 s.
- 10 balls x 8 flashes: the same camera, ten marked balls flying side by side (80 ball images).
- chessboard 1280x960 and 2560x1920: one calibration photo (9x6 board, distorted lens).

Times include everything `render` does (ray casting, shading, lens blur, noise, sRGB encoding);
the table shows the best and the median wall time of ``--repeat`` runs and the best CPU time
of the process (the machine may be shared: wall times then grow, CPU times much less).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial.transform import Rotation

from stillcap.calibrate.targets import Chessboard
from stillcap.camera import Camera, look_at, pose_matrix
from stillcap.studio import Backdrop, Exposure, PointLight, Scene, Sensor, Sphere, render
from stillcap.studio.markers import baseball_markers
from stillcap.studio.scenes import BASEBALL_RADIUS, default_camera, random_board_pose, target_scene

GOAL_S = 0.5


def pitch_camera() -> Camera:
    cam = Camera.from_intrinsics("front", 1800.0, 1800.0, 1279.5, 959.5, (2560, 1920),
                                 dist=[-0.08, 0.04, 0.0005, -0.0005, 0.0])
    return cam.with_pose(look_at([0.0, -3.5, 1.5], [0.0, 0.0, 1.5]))


def flight_scene(n_balls: int, n_flashes: int, rng) -> Scene:
    balls = [Sphere(BASEBALL_RADIUS, markers=baseball_markers()) for _ in range(n_balls)]
    start = np.column_stack([np.full(n_balls, -1.9), np.zeros(n_balls), np.linspace(0.9, 2.1, n_balls)])
    vel = np.array([28.0, 0.0, 0.0]) + rng.normal(0, 0.5, (n_balls, 3))
    spin = rng.normal(0, 1, (n_balls, 3))
    spin *= 167.0 / np.linalg.norm(spin, axis=1, keepdims=True)  # 1600 rpm in rad/s

    def poses(t):
        return [pose_matrix(Rotation.from_rotvec(spin[i] * t).as_matrix(), start[i] + vel[i] * t)
                for i in range(n_balls)]

    return Scene(balls, Exposure.strobe(poses, 80.0, n_flashes, ambient=0.01),
                 [PointLight([0.4, -3.5, 1.9], 9.0)], backdrop=Backdrop(0.004, 0.3))


def timed(fn, repeat: int) -> tuple[float, float, float]:
    """Best and median wall time, and best CPU time of this process (all threads), seconds."""
    times, cpu = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return min(times), float(np.median(times)), min(cpu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    sensor = Sensor()

    cases = []
    cam = pitch_camera()
    for label, nb, nf in (("pitch: 1 ball x 10 flashes, 12 markers", 1, 10),
                          ("10 balls x 8 flashes, 12 markers each", 10, 8)):
        scene = flight_scene(nb, nf, rng)
        cases.append((label, cam, scene, nb * nf, GOAL_S))
    board = Chessboard(9, 6, 0.025)
    for size in ((1280, 960), (2560, 1920)):
        c = default_camera("cb", size)
        pose = random_board_pose(c, board, rng)
        cases.append((f"chessboard 9x6, {size[0]}x{size[1]}", c, target_scene(c, board, pose, rng), 0, None))

    table = Table(title=f"studio render times ({args.repeat} runs each)")
    for col in ("case", "image", "ball images", "best s", "median s", "cpu s", "goal s", "best / goal"):
        table.add_column(col, justify="left" if col == "case" else "right")
    for label, c, scene, n_img, goal in cases:
        render(c, scene, sensor, rng)  # warm-up (imports, caches)
        best, med, cpu = timed(lambda: render(c, scene, sensor, rng), args.repeat)
        table.add_row(label, "{}x{}".format(*c.image_size), str(n_img), f"{best:.3f}", f"{med:.3f}", f"{cpu:.3f}",
                      "-" if goal is None else f"{goal:.2f}", "-" if goal is None else f"{best / goal:.2f}")
    Console(width=120).print(table)


if __name__ == "__main__":
    main()
