"""The command line imports a command's heavy modules only when the command runs.

Structural checks, not timings (``benchmarks/bench_cli_startup.py`` times ``--help``): building
the typer app loads none of NumPy, SciPy, OpenCV, matplotlib or scikit-image, and the choice
lists the CLI writes out (so as not to import the library) equal the library's.
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
