"""`stillcap studio ...`: render synthetic captures (capture folders with truth.json)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from stillcap.cli._progress import progress
from stillcap.files.outputs import check_writable

app = typer.Typer(no_args_is_help=True, add_completion=False,
                  help="Render synthetic captures with ground truth (see docs/studio.md).")
console = Console()


def _check_out(out: Path, force: bool) -> None:
    check_writable(out, "folder", option="--out", force=True)  # a folder, writable; its content is checked here:
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ValueError(f"--out {out} exists and is not empty (use --force to write into it)")


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must look like 1280x960, got {text!r}") from None
    if w < 16 or h < 16:
        raise ValueError(f"--size must be at least 16x16 pixels, got {text!r}")
    return w, h


CAMERA_RESPONSE_HELP = ("The cameras' response the photos are encoded with: srgb (default), linear, gamma:G or "
                        "tone (sRGB with a consumer S-shaped tone curve); written into rig.json as each camera's "
                        "'response' (docs/camera-response.md).")


def _sensor_response(text: str | None):
    """``--camera-response`` as a :class:`stillcap.response.Response` (None: the sensor's default)."""
    if text is None:
        return None
    if text.strip().lower() == "tone":
        return "tone"
    from stillcap.response import Response, parse_response_spec

    r = parse_response_spec(text, "--camera-response")
    if not isinstance(r, Response):
        raise ValueError(f"--camera-response {text!r}: the studio renders a stated response (srgb, linear, gamma:G "
                         "or tone)")
    return r


def _studio_sensor(response):
    """The studio's default sensor with another encoding."""
    from stillcap.studio.sensor import Sensor

    return Sensor(tone=True) if response == "tone" else Sensor(gamma=response)


def _save(capture, images, out: Path, jpeg: int | None) -> None:
    with progress(f"writing {len(images)} images"):
        capture.save(out, images, jpeg_quality=jpeg or 95)
    console.print(f"wrote {len(images)} images to [bold]{out}[/] (capture.json, rig.json, truth.json)")


@app.command()
def chessboard(
    out: Path = typer.Option(..., "--out", help="Capture folder to write."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same capture)."),
    views: int = typer.Option(15, "--views", min=1, help="Number of photos."),
    pattern: str = typer.Option(None, "--pattern",
                                help="Inner corners COLSxROWS (chessboard, default 9x6) or squares (ChArUco, default 7x5)."),
    charuco: bool = typer.Option(False, "--charuco", help="A ChArUco board instead of a chessboard."),
    square_mm: float = typer.Option(None, "--square-mm", help="Square size in mm (default 25, ChArUco 40)."),
    size: str = typer.Option("1280x960", "--size", help="Image size WIDTHxHEIGHT in pixels."),
    jpeg: int = typer.Option(None, "--jpeg", min=1, max=100, help="Write JPEG at this quality instead of PNG."),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty folder."),
    camera_response: str = typer.Option(
        None, "--camera-response", help="The camera's response the photos are encoded with: srgb (default), linear, "
                                        "gamma:G or tone (sRGB with a consumer S-shaped tone curve); recorded in "
                                        "truth.json (the rig stays the nominal, uncalibrated camera)."),
):
    """Photos of a calibration board in random poses; truth = camera and board poses (and the response)."""
    from stillcap.calibrate.targets import CharucoTarget, Chessboard, parse_pattern
    from stillcap.studio.scenes import chessboard_set, default_camera

    response = _sensor_response(camera_response)
    _check_out(out, force)
    camera = default_camera(image_size=_parse_size(size))
    if charuco:
        nx, ny = parse_pattern(pattern or "7x5")
        sq = (square_mm or 40.0) / 1000
        target = CharucoTarget(nx, ny, sq, 0.75 * sq)
    else:
        cols, rows = parse_pattern(pattern or "9x6")
        target = Chessboard(cols, rows, (square_mm or 25.0) / 1000)
    with progress("rendering views", total=views) as update:
        result = chessboard_set(camera, n_views=views, target=target, rng=seed,
                                sensor=None if response is None else _studio_sensor(response),
                                progress=lambda i, n: update(i))
    cap, images = result.to_capture(".jpg" if jpeg else ".png")
    _save(cap, images, out, jpeg)


@app.command()
def markers(
    out: Path = typer.Option(..., "--out", help="Capture folder to write."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same capture)."),
    cameras: int = typer.Option(4, "--cameras", min=1, help="Cameras on the arc."),
    balls: int = typer.Option(10, "--balls", min=0, help="Number of balls."),
    marked: int = typer.Option(None, "--marked", min=0, help="How many of them carry painted markers (default a third)."),
    size: str = typer.Option("1280x960", "--size", help="Image size WIDTHxHEIGHT in pixels."),
    jpeg: int = typer.Option(None, "--jpeg", min=1, max=100, help="Write JPEG at this quality instead of PNG."),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty folder."),
):
    """Balls with painted markers and single-colour marker balls seen by a camera arc; truth = 3D
    centres and true 2D projections."""
    from stillcap.studio.scenes import marker_rig, marker_scene

    _check_out(out, force)
    import numpy as np

    rng = np.random.default_rng(seed)
    rig = marker_rig(cameras, _parse_size(size), rng=rng)
    with progress("rendering cameras", total=cameras) as update:
        result = marker_scene(rig, balls, rng, n_marked=marked, progress=lambda i, n: update(i))
    cap, images = result.to_capture(".jpg" if jpeg else ".png")
    _save(cap, images, out, jpeg)


@app.command()
def puppet(
    out: Path = typer.Option(..., "--out", help="Capture folder to write."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same capture)."),
    pose: str = typer.Option("random", "--pose",
                             help="random[:SEED], tpose or bvh:FILE[:FRAME] (a BVH file, frame 0 by default)."),
    views: int = typer.Option(12, "--views", min=1, help="Number of turntable photos."),
    step_deg: float = typer.Option(30.0, "--step-deg", help="Turntable step between photos, degrees."),
    jpeg: int = typer.Option(85, "--jpeg", min=1, max=100,
                             help="The webcam's JPEG quality (images are written as JPEG)."),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty folder."),
    markers: str = typer.Option("puppet-16", "--markers",
                                help="Marker set: puppet-16 (the thesis's 16 beads), puppet-20 (plus a second bead "
                                     "on each forearm and shin) or a marker-set JSON file. Stored in the capture."),
    camera_response: str = typer.Option(None, "--camera-response", help=CAMERA_RESPONSE_HELP),
    skeleton: Path = typer.Option(None, "--skeleton", help="The puppet's skeleton (a stillcap-skeleton JSON file) "
                                  "instead of the built-in puppet's: render a puppet of other proportions."),
):
    """The thesis's marked puppet on its turntable, photographed by the webcam; truth = pose, 3D
    beads and per-view bead pixels and visibility."""
    from stillcap.body.markerset import MarkerSet
    from stillcap.body.skeleton import Skeleton
    from stillcap.calibrate.turntable import turntable_rig
    from stillcap.studio.puppet import puppet_scene, webcam_sensor

    markerset = MarkerSet.resolve(markers)
    if skeleton is not None and not skeleton.is_file():
        raise ValueError(f"--skeleton {skeleton}: no such file")
    body = Skeleton.load(skeleton) if skeleton is not None else Skeleton.puppet()
    markerset.check_skeleton(body)
    sensor = webcam_sensor(jpeg_quality=None)  # the webcam's JPEG compression happens once, when the capture is written
    if (response := _sensor_response(camera_response)) is not None:
        from dataclasses import replace

        sensor = replace(sensor, tone=True) if response == "tone" else replace(sensor, gamma=response)
    _check_out(out, force)
    rig = turntable_rig(views, step_deg)
    with progress("rendering views", total=views) as update:
        # the webcam's JPEG compression happens once, when the capture is written
        result = puppet_scene(rig, pose, rng=seed, sensor=sensor,
                              progress=lambda i, n: update(i), markerset=markerset, skeleton=body)
    cap, images = result.to_capture(".jpg")
    _save(cap, images, out, jpeg)


@app.command()
def pitch(
    out: Path = typer.Option(None, "--out", help="Capture folder to write."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same capture)."),
    preset: str = typer.Option("seed-4seam", "--preset", help="Pitch preset (see --list-presets)."),
    speed_mph: float = typer.Option(None, "--speed-mph",
                                    help="Release speed, mph (exact; default: the preset's, varied)."),
    spin_rpm: float = typer.Option(None, "--spin-rpm", help="Spin rate, rpm (exact)."),
    spin_axis_deg: float = typer.Option(None, "--spin-axis-deg",
                                        help="Statcast spin axis, degrees: 180 backspin, 0 topspin, "
                                             "90 sidespin toward first base."),
    front_hz: float = typer.Option(80.0, "--front-hz", help="Front pair's strobe rate, Hz."),
    back_hz: float = typer.Option(50.0, "--back-hz", help="Back pair's strobe rate, Hz."),
    model: str = typer.Option("seed", "--model", help="Flight model of a ball flying as a baseball: seed or nathan."),
    ball: str = typer.Option(None, "--ball", help="The ball to paint and throw: a built-in name (stillcap balls) or "
                             "a stillcap-ball file; written into capture.json (ball). Default the seed's baseball."),
    no_variation: bool = typer.Option(False, "--no-variation", help="The exact preset pitch (no release scatter)."),
    no_calibrate: bool = typer.Option(False, "--no-calibrate",
                                      help="Write the true rig instead of calibrating it from rendered photos (fast)."),
    size: str = typer.Option("2560x1920", "--size",
                             help="Image size WIDTHxHEIGHT (4:3; smaller keeps the field of view)."),
    jpeg: int = typer.Option(None, "--jpeg", min=1, max=100, help="Write JPEG at this quality instead of PNG."),
    known_flash_times: bool = typer.Option(False, "--known-flash-times",
                                           help="Write each image's first_flash_s and n_flashes (normally unknown: "
                                                "the strobes run free)."),
    lights: str = typer.Option("default", "--lights",
                               help="Where the strobes stand: default, near (the cameras), side, behind (the cameras)."),
    room_flash: float = typer.Option(0.0, "--room-flash", min=0.0,
                                     help="A dark room lit a little by every flash: radiance each flash adds to the room."),
    blur_px: float = typer.Option(0.5, "--blur-px", min=0.0, help="Lens blur (Gaussian sigma), px."),
    noise: float = typer.Option(1.0, "--noise", min=0.0,
                                help="Sensor noise relative to the default (shot and read noise; 0 = none)."),
    white_balance: str = typer.Option("1,1,1", "--white-balance", help="Colour cast: R,G,B gains on the light."),
    ball_radius_mm: float = typer.Option(None, "--ball-radius-mm", help="Ball radius, mm (default the baseball's)."),
    list_presets: bool = typer.Option(False, "--list-presets", help="List the pitch presets and exit."),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty folder."),
    camera_response: str = typer.Option(None, "--camera-response", help=CAMERA_RESPONSE_HELP),
):
    """A pitched, marked baseball photographed by the seed's two strobed stereo pairs (front 80 Hz,
    back 50 Hz); the rig is calibrated from rendered board photos; truth = flight, orientation per
    flash, true pixels and pitch metrics."""
    from rich.table import Table

    from stillcap.studio.pitch import DEFAULT_VARIATION, PRESETS, pitch_capture

    if list_presets:
        table = Table("preset", "mph", "rpm", "axis deg", "efficiency", "description")
        for p in PRESETS.values():
            table.add_row(p.name, f"{p.speed_mph:g}", f"{p.spin_rpm:g}", f"{p.spin_axis_deg:g}",
                          f"{p.spin_efficiency:g}", p.description)
        console.print(table)
        return
    if out is None:
        raise ValueError("--out is required (the capture folder to write)")
    if preset not in PRESETS:
        raise ValueError(f"unknown --preset {preset!r}; known: {', '.join(PRESETS)}")
    ball_obj = None
    if ball is not None:
        from stillcap.ball.ballfile import load_ball
        ball_obj = load_ball(ball, "--ball")
    sensor = _pitch_sensor(_sensor_response(camera_response), blur_px, noise, white_balance)
    _check_out(out, force)
    with progress("rendering") as update:
        result = pitch_capture(preset, seed, calibrate=not no_calibrate, speed_mph=speed_mph, spin_rpm=spin_rpm,
                               spin_axis_deg=spin_axis_deg, front_hz=front_hz, back_hz=back_hz, model=model,
                               ball=ball_obj,
                               variation=None if no_variation else DEFAULT_VARIATION, image_size=_parse_size(size),
                               known_flash_times=known_flash_times, progress=update, sensor=sensor, lights=lights,
                               room_flash=room_flash,
                               ball_radius_m=None if ball_radius_mm is None else ball_radius_mm / 1000.0)
    if result.truth.studio is not None:
        result.truth.studio["jpeg_quality"] = jpeg  # written below, at this quality
    cap, images = result.to_capture(".jpg" if jpeg else ".png")
    _save(cap, images, out, jpeg)
    tr = result.truth
    axis = tr.metrics["spin_axis_deg"]
    console.print(f"{preset}: {tr.release.speed_mph:.1f} mph, {tr.release.spin_rpm:.0f} rpm, spin axis "
                  + (f"{axis:.0f} deg" if axis is not None else "- (gyro)")
                  + f"; ball images: front {tr.pair('front').visible[0].sum()}, back {tr.pair('back').visible[0].sum()}")
    if result.calibration is None:
        console.print("rig: the true cameras (not calibrated)")
    else:
        worst = max(v["max_px"] for v in tr.calibration_error.values())
        console.print(f"rig: calibrated from rendered board photos; reprojects the corridor within {worst:.2f} px "
                      "of the true rig")
        if not result.calibration.success:
            console.print("[yellow]warning:[/] a camera's board residuals exceed 1 px; see capture.json calibration")


def _pitch_sensor(response, blur_px: float, noise: float, white_balance: str):
    """The studio sensor of ``studio pitch``'s options (``response``: :func:`_sensor_response`'s;
    a bad value: ValueError naming the option)."""
    from stillcap.studio.sensor import Sensor

    try:
        wb = tuple(float(v) for v in white_balance.split(","))
    except ValueError:
        wb = ()
    if len(wb) != 3 or min(wb) <= 0:
        raise ValueError(f"--white-balance must be three positive gains R,G,B, got {white_balance!r}")
    base = Sensor()
    # the JPEG quality is applied when the capture is written (--jpeg); recorded in the truth here
    return Sensor(full_well=None if noise == 0 else base.full_well / noise ** 2, read_noise=base.read_noise * noise,
                  gamma="srgb" if response in (None, "tone") else response, blur_px=blur_px,
                  tone=response == "tone", white_balance=wb, jpeg_quality=None)


@app.command()
def hand(
    out: Path = typer.Option(..., "--out", help="Capture folder to write."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same capture)."),
    preset: str = typer.Option("seed-4seam", "--preset", help="Pitch preset of the ball (see studio pitch --list-presets)."),
    size: str = typer.Option("2560x1920", "--size",
                             help="Image size WIDTHxHEIGHT (4:3; smaller keeps the field of view)."),
    jpeg: int = typer.Option(None, "--jpeg", min=1, max=100, help="Write JPEG at this quality instead of PNG."),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty folder."),
    camera_response: str = typer.Option(None, "--camera-response", help=CAMERA_RESPONSE_HELP),
    calibration_pose: str = typer.Option(None, "--calibration-pose", help="Render a calibration capture for "
                                         "stillcap hand-calibrate instead of a throw: the hand in this pose (flat), "
                                         "then moving (--calibration-motion)."),
    calibration_motion: str = typer.Option("curl", "--calibration-motion", help="The calibration capture's "
                                           "motion: protocol (flat, spread, table top, hook, fist, thumb "
                                           "opposition, half curl, flat; docs/hand-calibration.md), protocol-turned "
                                           "(the protocol ending in a hook with the hand turned 60 deg, the "
                                           "thumb's side toward the cameras) or curl (flat, then a loose fist)."),
    person: int = typer.Option(None, "--person", help="Another person's hand, light and cameras "
                               "(studio.hand_variation.another_hand with this seed)."),
):
    """The pitcher's gloved hand with its 18 markers around release, photographed by 4 cameras
    behind the pitcher in a 75 Hz strobe's light; truth = marker positions, joint angles and the
    ball per flash (see docs/hand.md)."""
    from stillcap.studio.hand import hand_capture

    response = _sensor_response(camera_response)
    _check_out(out, force)
    if calibration_pose is not None:
        from stillcap.body.hand_calibrate import calibration_angles
        from stillcap.body.hand import hand_skeleton

        calibration_angles(calibration_pose, hand_skeleton())  # an unknown pose: one line, exit 2
        from stillcap.studio.hand_calibration import CALIBRATION_MOTIONS

        if calibration_motion not in CALIBRATION_MOTIONS:
            raise ValueError(f"unknown --calibration-motion {calibration_motion!r}; known: {', '.join(CALIBRATION_MOTIONS)}")
    who = None
    if person is not None:
        from stillcap.studio.hand_variation import another_hand

        who = another_hand(person)
    with progress("rendering cameras", total=4) as update:
        result = hand_capture(seed, preset=preset, image_size=_parse_size(size), person=who,
                              calibration_pose=calibration_pose, calibration_motion=calibration_motion,
                              sensor=None if response is None else _studio_sensor(response),
                              progress=lambda i, n, label: update(i, n))
    cap, images = result.to_capture(".jpg" if jpeg else ".png")
    _save(cap, images, out, jpeg)
    tr = result.truth
    back = int((tr.markers_visible[:, :, :3].all(axis=2).sum(axis=0) >= 2).sum())
    console.print(f"{tr.n} flashes at {tr.strobe_hz:g} Hz around release ({tr.release.speed_mph:.1f} mph); "
                  f"back of the hand seen by 2+ cameras in {back}; rig: the true cameras (not calibrated)")
