"""Shared fixtures."""

import pytest

from support import ring_rig


@pytest.fixture
def rig4():
    """Four cameras on a 3 m circle around the origin, with lens distortion."""
    return ring_rig(4, dist=(-0.12, 0.05, 0.001, -0.0005, 0.0))


def pytest_configure(config):
    """The suite's ``stillcap`` processes start no warm server on the default socket (docs/serve.md:
    a run without one starts one); tests/test_cli_serve.py tests that on sockets of its own."""
    import os

    os.environ.setdefault("STILLCAP_SERVER", "manual")
