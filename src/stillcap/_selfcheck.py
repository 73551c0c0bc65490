"""Self-checks: what the photos show compared with what the model expects (issue 12).

Every result carries a list of :class:`SelfCheck`; each compares one observed quantity (an
epipolar residual, a fit's chi-square, a silhouette profile, a bone's residual) with the limit the
model and the stated noise allow. A failed check names what was compared, on what (camera, bone,
marker) and why it matters; the CLI prints failed checks and the JSON result keeps them all.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["SelfCheck", "failed_checks", "checks_to_json", "checks_from_json"]


@dataclass(frozen=True)
class SelfCheck:
    """One self-check.

    Attributes
    ----------
    name : str
        What is checked, snake_case (``"epipolar_residual"``, ``"flight_chi2"``, ``"response"``).
    passed : bool
    value : float or None
        The observed statistic (in the unit ``unit`` names); None when the photos could not give it
        (the check then passes and ``message`` says why it could not be made).
    limit : float
        The largest value the model allows (``passed`` is ``value <= limit`` unless the check
        says otherwise in ``message``).
    message : str
        One line: what was compared and, when failed, what it means and what to do.
    subject : str
        What the check concerns: a camera, bone, marker or pair name ("" for the whole result).
    unit : str
        Unit of ``value`` and ``limit`` ("px", "deg", "mm", "" for a ratio).
    """

    name: str
    passed: bool
    value: float | None
    limit: float
    message: str
    subject: str = ""
    unit: str = ""

    def to_json(self) -> dict:
        return asdict(self)


def failed_checks(checks) -> list[SelfCheck]:
    """The checks that did not pass, in order."""
    return [c for c in checks if not c.passed]


def checks_to_json(checks) -> list[dict]:
    return [c.to_json() for c in checks]


def checks_from_json(items) -> list[SelfCheck]:
    return [SelfCheck(**{k: v for k, v in d.items() if k in SelfCheck.__dataclass_fields__}) for d in items]
