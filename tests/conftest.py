"""Shared fixtures."""

import signal

import pytest

from support import ring_rig


@pytest.fixture
def rig4():
    """Four cameras on a 3 m circle around the origin, with lens distortion."""
    return ring_rig(4, dist=(-0.12, 0.05, 0.001, -0.0005, 0.0))


@pytest.fixture(autouse=True)
def _sigint_untouched():
    """A test that leaves the test process's SIGINT handler changed fails here, and the handler is
    put back: every process a later test starts inherits an ignored SIGINT (a Ctrl-C test of the
    CLI then sees its command ignore the signal, far from the test that caused it)."""
    before = signal.getsignal(signal.SIGINT)
    yield
    after = signal.getsignal(signal.SIGINT)
    if after is not before:
        signal.signal(signal.SIGINT, before)
        pytest.fail(f"the test left the process's SIGINT handler changed: {before!r} -> {after!r}")


def pytest_configure(config):
    """The suite's ``stillcap`` processes start no warm server on the default socket (docs/serve.md:
    a run without one starts one); tests/test_cli_serve.py tests that on sockets of its own."""
    import os

    os.environ.setdefault("STILLCAP_SERVER", "manual")
