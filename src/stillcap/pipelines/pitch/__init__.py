"""The pitch pipeline (SPEC J1): strobe photos of a pitched, marked baseball -> flight, spin, metrics.

Wiring only; the domain maths lives in :mod:`stillcap.ball` and the capture's files in
:mod:`stillcap.io` (``docs/pitch.md`` tells the whole story). What is where:

- :func:`analyse_pitch` (``analyse.py``): the entry point; it runs the stages in order.
- ``stages.py``: one function per stage, in the order of the method: find balls -> number
  flashes -> fit flight -> markers and spin -> refit with spin -> metrics and uncertainty.
- ``spin.py``: the spin step's parts (a pair's markers and own spin, the alias choice, one spin
  over all pairs).
- ``workers.py``: scheduling only: the thread pool or the worker processes of the per-pair work,
  and the workers' photo cache (``PitchOptions.processes``).
- :class:`PitchOptions` and the option names (``options.py``); :class:`PairResult`,
  :class:`PitchResult` and :data:`TABLE1_COLUMNS` (``result.py``).

The comparison with a studio truth is the studio's
(:func:`stillcap.studio.compare.pitch.compare_with_truth`): the pipeline never reads a truth.
"""

from stillcap.pipelines.pitch.analyse import analyse_pitch
from stillcap.pipelines.pitch.options import FIT_METHODS, PHYSICS, SIGMA_METHODS, SPIN_METHODS, PitchOptions
from stillcap.pipelines.pitch.result import TABLE1_COLUMNS, PairResult, PitchResult

__all__ = ["FIT_METHODS", "PHYSICS", "SIGMA_METHODS", "SPIN_METHODS", "TABLE1_COLUMNS", "PairResult", "PitchOptions",
           "PitchResult", "analyse_pitch"]
