"""The command line imports a command's heavy modules only when the command runs.

Structural checks, not timings (``benchmarks/bench_cli_startup.py`` times ``--help`` and
``pitch``): building the typer app loads none of NumPy, SciPy, OpenCV, matplotlib or
scikit-image, and the choice lists the CLI writes out (so as not to import the library) equal
the library's. ``main`` builds only the command it runs: each command built alone is the full
app's, and ``stillcap pitch`` imports no other command's module nor what a pitch does not use
(the studio without a truth, reports, ball files, ``scipy.interpolate``); the photos it decodes
ahead, while the pipeline imports, give the pipeline's own result.
"""

import subprocess
import sys

HEAVY = ("numpy", "scipy", "cv2", "matplotlib", "skimage")


def test_building_the_app_imports_no_heavy_module():
    code = ("import sys, typer\n"
            "import stillcap.cli\n"
            "typer.main.get_command(stillcap.cli.app)\n"
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == []


def test_help_imports_no_heavy_module():
    code = ("import sys\n"
            "from stillcap.cli import main\n"
            "main(['pitch', '--help'])\n"
            f"print('HEAVY:', ' '.join(m for m in {HEAVY!r} if m in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.rstrip().endswith("HEAVY:")


def test_camera_and_rig_import_from_the_package():
    from stillcap import Camera, Rig
    from stillcap.camera import Camera as C, Rig as R

    assert (Camera, Rig) == (C, R)


def test_pitch_choices_equal_the_library_lists():
    from stillcap.ball.physics import FLIGHT_MODELS
    from stillcap.cli.pitch import FIT_CHOICES, PHYSICS_CHOICES, SPIN_CHOICES
    from stillcap.pipelines.pitch import FIT_METHODS, SPIN_METHODS

    assert PHYSICS_CHOICES == tuple(FLIGHT_MODELS)
    assert SPIN_CHOICES == tuple(SPIN_METHODS)
    assert FIT_CHOICES == tuple(m.replace("_", "-") for m in FIT_METHODS)


# --- the one-command apps main() builds (stillcap.cli.COMMANDS) ------------------------------
def _helps(app, name: str) -> dict:
    """``stillcap NAME [SUB] --help`` of ``app``, for the command and each of its sub-commands."""
    import typer
    from typer.testing import CliRunner

    cmd = typer.main.get_command(app).commands[name]
    out = {}
    for sub in [None, *getattr(cmd, "commands", {})]:
        args = [name, *([sub] if sub else []), "--help"]
        r = CliRunner().invoke(app, args, prog_name="stillcap", terminal_width=200)
        assert r.exit_code == 0, (args, r.output)
        out[sub] = r.output
    return out


def test_each_command_alone_is_the_full_apps_command():
    """Every option, default, help text and sub-command of a command built alone (as main does)
    is as in the full app (``stillcap --help``)."""
    from stillcap.cli import COMMANDS, app, build_app

    for name in COMMANDS:
        assert _helps(build_app(name), name) == _helps(app, name), name


def test_a_command_run_alone_behaves_as_in_the_full_app(capsys):
    """Run through main: a command by its name, usage errors, and names that are no command."""
    from support import run_cli

    code, out, _ = run_cli(["balls"], capsys)  # a group's own callback (the list) still runs
    assert code == 0 and "baseball" in out
    code, _, err = run_cli(["pitch"], capsys)  # the argument is missing: click's usage error, exit 2
    assert code == 2 and "Usage: stillcap pitch" in err
    code, _, err = run_cli(["pich", "x"], capsys)  # no command: the full app, which says so
    assert code == 2 and "No such command 'pich'" in err


def _modules_after(args: list, extra: str = "") -> set:
    """The modules a fresh process has imported after ``stillcap ARGS`` (run through main)."""
    code = ("import sys\n"
            "from stillcap.cli import main\n"
            f"main({[str(a) for a in args]!r})\n"
            f"{extra}"
            "print('MODULES', ' '.join(sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return set(r.stdout.rsplit("MODULES", 1)[1].split())


#: Modules `stillcap pitch` on a capture without truth does not need (imported before this issue).
NOT_FOR_A_PITCH = ("stillcap.cli.puppet", "stillcap.cli.hand", "stillcap.cli.studio", "stillcap.cli.calibrate",
                   "stillcap.cli.markers", "stillcap.cli.demo", "stillcap.cli.balls", "stillcap.cli.batch",
                   "stillcap.cli.gui", "stillcap.studio", "stillcap.report", "stillcap.ball.ballfile",
                   "scipy.interpolate", "matplotlib", "pandas", "pyarrow", "dask", "skimage")


def test_a_pitch_imports_only_what_it_needs(tmp_path_factory, tmp_path):
    import json
    import shutil

    from support import studio_pitch

    cap = tmp_path / "cap"
    shutil.copytree(studio_pitch(tmp_path_factory, "fastball"), cap)  # a photo from elsewhere: no truth
    (cap / "truth.json").unlink()
    d = json.loads((cap / "capture.json").read_text())
    d["truth"] = None
    (cap / "capture.json").write_text(json.dumps(d))
    # the photos were handed to the pipeline by the decoding started before its import
    modules = _modules_after(["pitch", cap, "--json"], "from stillcap.io.capture import Capture\n")
    assert "stillcap.pipelines.pitch" in modules and "stillcap.cli.pitch" in modules
    assert not {m for m in modules for p in NOT_FOR_A_PITCH if m == p or m.startswith(p + ".")}


def test_the_pitch_command_gives_the_pipelines_result(tmp_path_factory, capsys):
    """Photos decoded ahead by the command (Capture.start_decoding) give the result of the
    pipeline reading them itself."""
    import json

    from support import run_cli, studio_pitch, untimed

    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import PitchOptions, analyse_pitch
    from stillcap.studio.compare.pitch import add_truth_comparison

    folder = studio_pitch(tmp_path_factory, "fastball")
    code, out, err = run_cli(["pitch", folder, "--json"], capsys)
    assert code == 0, err
    cap = Capture.load(folder)
    direct = add_truth_comparison(analyse_pitch(cap, PitchOptions(processes=0)), cap.truth)
    assert untimed(json.loads(out)) == untimed(json.loads(json.dumps(direct.to_dict(), allow_nan=False)))
