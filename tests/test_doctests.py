"""The Examples in the docstrings of the main public functions run and give what they show."""

import doctest
import importlib

import pytest

MODULES = [
    "stillcap.geometry.triangulate",       # triangulate
    "stillcap.geometry.robust",            # consensus
    "stillcap.ball.orientation._global",   # fit_spin
    "stillcap.pipelines.pitch.analyse",    # analyse_pitch
    "stillcap.pipelines.puppet.analyse",   # analyse_puppet
]


@pytest.mark.parametrize("name", MODULES)
def test_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0
