"""Spin-rate aliasing of stroboscopic captures and how to resolve it (SPEC J1, "beyond").

With flashes every ``1/f`` s a ball spinning at ``w`` (rad/s) turns by ``theta = |w| / f`` between
flashes, but the photos only show the rotation modulo a full turn: the rotation ``theta`` about
``a`` looks exactly like ``theta + 2 pi n`` about ``a`` for every integer ``n`` (negative ``n``:
``2 pi |n| - theta`` about ``-a``; near half a turn the axis sign itself is in doubt). The
orientation fits (:mod:`stillcap.ball.orientation`) return the *principal* spin (at most half a
turn per interval: ``f / 2`` revolutions per second, 2400 rpm at 80 Hz, 1500 rpm at 50 Hz), so
a 3000 rpm pitch filmed at 80 Hz comes out as 1800 rpm about the opposite axis.

:func:`alias_candidates` lists every spin ``(theta + 2 pi n) f a`` within a plausible range
(default 0-4000 rpm). :func:`resolve_aliases` scores each candidate ``c`` by a chi-square of
its consistency with the independent evidence and ranks them by ``exp(-chi2 / 2)``:

- every strobe measurement ``m`` (a stereo pair at its own frequency, e.g. the front pair at
  80 Hz and the back pair at 50 Hz): the rotation per interval the candidate predicts at
  ``f_m``, ``exp(c / f_m)``, against the measured one ``exp(w_m / f_m)``; the geodesic
  difference is weighed with the measurement's covariance plus a tolerance for the spin
  changing between the pairs (``rate_tolerance_rpm``, ``axis_tolerance_deg``). Both pairs are
  calibrated in one world frame, so axes compare directly; their clocks need not be synchronised
  (only the rotation per interval is used);
- the curvature of the flight (:class:`CurvatureMeasurement`, from
  :func:`stillcap.ball.fit.fit_reference_trajectory` without a spin prior): the Magnus force
  sees the spin transverse to the flight, so each candidate's transverse part (or, for the
  seed's lift law ``C_L = 1.5 r |w| / |v|``, ``|c|`` along the transverse direction) is compared
  with the fitted one, with the fit's covariance plus a relative model tolerance.

The result says ``ambiguous`` when the runner-up's likelihood is within ``ambiguity_ratio`` of
the best (e.g. one strobe rate and a mostly gyro spin, which bends the flight too little), and
also when the best candidate itself does not agree with the evidence: its chi-square above the
``1 - consistency_p`` quantile of a chi-square with its degrees of freedom (3 per strobe
measurement other than its source, 2 for the curvature). Then at least one measurement is wrong
(e.g. a strobe sequence whose few markers gave a wrong principal spin), and the ranking of the
others cannot be trusted: a small likelihood ratio between two bad candidates says nothing.

Evidence that contradicts itself is then examined item by item (deletion diagnostics): each
strobe measurement, and the curvature, is left out in turn. When the rest agrees without it
(consistent at the same quantile, still cross-checked by 2 or more degrees of freedom) and every
such removal points to the same spin, that spin is chosen and the item is named in
``left_out`` and the message. What this catches, measured on the robustness benchmark's
``mlb-high-spin`` pitches (3000 rpm, above both strobes' Nyquist limits) under a white-balance
cast, JPEG 98 and gamma 2.6: the back pair saw about one marker per flash, so no flash fixed the
ball's orientation, and its own constant-spin fit settled on a rotation 43-173 deg per interval
from the truth with a covariance of a few rpm; the front pair and the curvature agreed on the
right alias (chi-square 0.01-0.1 for 2 dof) but the back pair's chi-square of 2600-130000
outweighed them. With two items only (one pair and the curvature, or two pairs) nothing can tell
which is wrong, and the result stays ambiguous.

The strobe measurements are each pair's own fit to part of the markers.
:func:`resolve_joint_fits` ranks fits of one spin to *all* the markers instead (from different
starts: the chosen alias, the others, :func:`flight_informed_spin`), on the markers themselves
and the curvature (:func:`curvature_chi2`); the pitch pipeline uses it when the strobe
ranking's choice is in doubt or another start finds a better minimum
(``stillcap.pipelines.pitch.spin``, ``docs/spin.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation
# chi-square quantile from scipy.special: importing scipy.stats costs 0.4-2 s per CLI call
from scipy.special import chdtri

from stillcap._checks import as_array

from stillcap._numeric import RPM_PER_RAD_S  # noqa: E402 (the one definition)


@dataclass(frozen=True, eq=False)
class StrobeMeasurement:
    """A spin measured from one strobe sequence (any alias of it).

    Attributes
    ----------
    spin : ndarray, shape (3,)
        rad/s, world frame.
    strobe_hz : float
    covariance : ndarray, shape (3, 3)
        Covariance of ``spin``, (rad/s)^2.
    name : str
    """

    spin: np.ndarray
    strobe_hz: float
    covariance: np.ndarray
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "spin", as_array(self.spin, (3,), "spin"))
        object.__setattr__(self, "covariance", as_array(self.covariance, (3, 3), "covariance"))
        if not (self.strobe_hz > 0 and np.isfinite(self.strobe_hz)):
            raise ValueError(f"strobe_hz must be positive, got {self.strobe_hz}")
        if not (np.all(np.isfinite(self.spin)) and np.all(np.isfinite(self.covariance))):
            raise ValueError("spin and covariance must be finite (did the spin fit fail?)")

    @classmethod
    def from_result(cls, result, name: str = "") -> "StrobeMeasurement":
        """From a :class:`stillcap.ball.orientation.SpinResult`."""
        return cls(result.spin, float(result.strobe_hz), result.spin_covariance,
                   name or f"{result.method} {result.strobe_hz:g} Hz")

    @property
    def axis_determined(self) -> bool:
        """False when the rotation per interval is within 3 sigma of none (the alias axes of
        ``n != 0`` are then unknown: e.g. 3000 rpm at 50 Hz is a full turn per flash)."""
        return bool(np.linalg.norm(self.spin) > 3.0 * np.sqrt(max(np.trace(self.covariance), 0) / 3.0))


@dataclass(frozen=True, eq=False)
class CurvatureMeasurement:
    """The spin the flight's curvature implies (Magnus force), from a reference-trajectory fit.

    Attributes
    ----------
    basis : ndarray, shape (3, 2)
        Columns ``e_1, e_2``: two unit vectors perpendicular to the initial velocity (world).
    transverse : ndarray, shape (2,)
        Effective transverse spin in that basis, rad/s.
    covariance : ndarray, shape (2, 2)
        Its covariance, (rad/s)^2.
    lift : {"transverse", "total"}
        ``"transverse"`` (Nathan's model: lift from the transverse spin ``w_perp``) or
        ``"total"`` (the seed's ``C_L = 1.5 r |w| / |v|``: lift ``|w|`` along ``w_perp``).
    """

    basis: np.ndarray
    transverse: np.ndarray
    covariance: np.ndarray
    lift: str = "transverse"

    def __post_init__(self):
        object.__setattr__(self, "basis", as_array(self.basis, (3, 2), "basis"))
        object.__setattr__(self, "transverse", as_array(self.transverse, (2,), "transverse"))
        object.__setattr__(self, "covariance", as_array(self.covariance, (2, 2), "covariance"))
        if self.lift not in ("transverse", "total"):
            raise ValueError(f"lift must be 'transverse' or 'total', got {self.lift!r}")

    def effective(self, spin) -> np.ndarray:
        """What the curvature sees of a spin vector (rad/s, world): shape (2,)."""
        w = as_array(spin, (3,), "spin")
        t = self.basis.T @ w
        if self.lift == "transverse":
            return t
        nt = np.linalg.norm(t)
        return t * (np.linalg.norm(w) / nt) if nt > 0 else t

    @classmethod
    def from_reference_fit(cls, fit, model=None, lift: str | None = None) -> "CurvatureMeasurement":
        """From a :class:`stillcap.ball.fit.ReferenceFit` (best fitted without a spin prior).

        Parameters
        ----------
        fit : ReferenceFit
        model : FlightModel, optional
            The model the fit used; chooses ``lift`` (``"total"`` for the seed model, the
            default model, ``"transverse"`` for Nathan's).
        lift : {"transverse", "total"}, optional
            Overrides the choice from ``model``.
        """
        if lift is None:
            nathan = model is not None and getattr(model, "kind", "seed") in ("nathan", "ball")  # transverse lift
            lift = "transverse" if nathan else "total"
        basis = np.asarray(fit.spin_basis, float)
        s = np.asarray(fit.params[6:9], float)
        C = np.asarray(fit.covariance[6:9, 6:9], float)
        if lift == "transverse":
            return cls(basis[:, 1:], s[1:], C[1:, 1:], "transverse")
        out = cls(basis[:, 1:], s[1:], C[1:, 1:], "total")

        def eff(sv):
            return out.effective(basis @ sv)
        e0 = eff(s)
        J = np.zeros((2, 3))
        for i in range(3):
            h = 1e-4 * max(1.0, abs(s[i]))
            d = np.zeros(3)
            d[i] = h
            J[:, i] = (eff(s + d) - eff(s - d)) / (2 * h)
        return cls(basis[:, 1:], e0, J @ C @ J.T, "total")


@dataclass
class AliasCandidate:
    """One possible true spin.

    Attributes
    ----------
    spin : ndarray, shape (3,)
        rad/s, world frame.
    spin_rpm : float
    axis : ndarray, shape (3,)
    n : int
        Alias index: rotation per interval = principal angle + 2 pi n about the principal axis
        of the source measurement (n < 0: about the opposite axis).
    source : int
        Index of the measurement that generated it.
    axis_determined : bool
        False when the source measurement cannot tell this alias's axis (see
        :attr:`StrobeMeasurement.axis_determined`).
    chi2_strobes : ndarray, shape (n_measurements,)
        Consistency with each strobe measurement (0 for the source).
    chi2_curvature : float
        Consistency with the flight curvature (0 without it).
    chi2_markers : float
        The joint fit's marker misfit above the best solution's (:func:`resolve_joint_fits`; 0
        for candidates ranked on the strobe measurements).
    p_markers : float
        The markers' own test of this solution (:func:`marker_misfit_test`): the probability of a
        misfit this much above the markers' best solution if this one were the truth (1 for
        candidates ranked on the strobe measurements, and when the markers have no redundancy).
    chi2 : float
        Total.
    probability : float
        ``exp(-chi2 / 2)`` normalised over the (merged) candidates.
    """

    spin: np.ndarray
    spin_rpm: float
    axis: np.ndarray
    n: int
    source: int
    axis_determined: bool = True
    chi2_strobes: np.ndarray = field(default_factory=lambda: np.zeros(0))
    chi2_curvature: float = 0.0
    chi2: float = 0.0
    probability: float = float("nan")
    chi2_markers: float = 0.0
    p_markers: float = 1.0


@dataclass
class AliasResolution:
    """Ranked alias candidates (:func:`resolve_aliases`).

    Attributes
    ----------
    candidates : list of AliasCandidate
        Best first.
    best : AliasCandidate
    ambiguous : bool
        The runner-up's likelihood is at least ``ambiguity_ratio`` times the best's, or the
        best candidate is inconsistent with the evidence (``consistent`` False).
    likelihood_ratio : float
        Runner-up / best (0 with a single candidate).
    consistent : bool
        The best candidate's chi-square is below the ``1 - consistency_p`` quantile for its
        degrees of freedom (``dof``).
    dof : int
        Degrees of freedom of the best candidate's chi-square.
    evidence : list of str
        What was used ("80 Hz", "50 Hz", "curvature").
    message : str
    left_out : list of str
        Evidence left out because it contradicts the rest, which agrees without it (see
        :func:`resolve_aliases`); the candidates' ``chi2`` leave it out too (their
        ``chi2_strobes`` still show it).
    undecided : list of AliasCandidate
        Other solutions of the markers' fit that the markers themselves cannot reject at the
        99.9 % level (:data:`UNDECIDED_P`, :func:`marker_misfit_test`) and that are not aliases of
        the best (another rotation per interval at every strobe rate): the markers do not decide
        the spin (:func:`resolve_joint_fits`).
    marker_dof : int
        Degrees of freedom of the markers' noise estimate in that test (-1: not tested).
    withheld : SpinResult or None
        With ``undecided``: the markers' fit the ranking put first, whose spin is withheld; kept
        for the checks of how the markers fit the ball (``ball_layout``, ``spin_noise``).
    """

    candidates: list
    best: AliasCandidate
    ambiguous: bool
    likelihood_ratio: float
    evidence: list
    message: str = ""
    consistent: bool = True
    dof: int = 0
    left_out: list = field(default_factory=list)
    undecided: list = field(default_factory=list)
    marker_dof: int = -1
    withheld: object = None

    def undecided_text(self) -> str:
        """The solutions the markers fit alike, for the pipeline's message and the ``spin_alias``
        self-check: "the markers fit B rpm and C rpm (axis D deg away, p = P) alike"."""
        b = self.best
        return (f"the markers fit {b.spin_rpm:.0f} rpm and "
                + " and ".join(f"{c.spin_rpm:.0f} rpm (axis {np.degrees(np.arccos(np.clip(c.axis @ b.axis, -1, 1))):.0f} "
                               f"deg away, p = {c.p_markers:.2g})" for c in self.undecided[:3])
                + " alike")


def alias_candidates(spin, strobe_hz: float, *, min_rpm: float = 0.0,
                     max_rpm: float = 4000.0) -> list[AliasCandidate]:
    """All spins that look the same as ``spin`` at ``strobe_hz``, within a rate range.

    Parameters
    ----------
    spin : array_like, shape (3,)
        Any alias, rad/s (typically the principal one from a fit).
    strobe_hz : float
    min_rpm, max_rpm : float
        Plausible range of the spin rate.

    Returns
    -------
    list of AliasCandidate
        Ordered by rate; ``n`` counts extra turns per interval about the principal axis.
    """
    w = as_array(spin, (3,), "spin")
    if not strobe_hz > 0:
        raise ValueError(f"strobe_hz must be positive, got {strobe_hz}")
    if not 0 <= min_rpm <= max_rpm:
        raise ValueError(f"need 0 <= min_rpm <= max_rpm, got {min_rpm}, {max_rpm}")
    rho = Rotation.from_rotvec(w / strobe_hz).as_rotvec()  # principal, |rho| <= pi
    theta = float(np.linalg.norm(rho))
    a = rho / theta if theta > 1e-12 else (w / np.linalg.norm(w) if np.linalg.norm(w) > 0
                                           else np.array([0.0, 0.0, 1.0]))
    lo = min_rpm / RPM_PER_RAD_S / strobe_hz
    hi = max_rpm / RPM_PER_RAD_S / strobe_hz
    out = []
    n_max = int(np.ceil(hi / (2 * np.pi))) + 1
    for n in range(-n_max, n_max + 1):
        ang = theta + 2 * np.pi * n  # signed rotation per interval about a
        if lo - 1e-12 <= abs(ang) <= hi + 1e-12:
            c = ang * strobe_hz * a
            rate = abs(ang) * strobe_hz
            out.append(AliasCandidate(c, rate * RPM_PER_RAD_S, c / rate if rate > 0 else a.copy(), n, 0))
    out.sort(key=lambda c: c.spin_rpm)
    return out


def _strobe_chi2(c, m: StrobeMeasurement, rate_tol, axis_tol):
    """Chi-square of the per-interval rotation of candidate c against measurement m."""
    f = m.strobe_hz
    Rm_inv = Rotation.from_rotvec(m.spin / f).inv()
    Rc = Rotation.from_rotvec(c / f)
    delta = (Rc * Rm_inv).as_rotvec()

    def d_of(w):
        return (Rc * Rotation.from_rotvec(w / f).inv()).as_rotvec()
    G = np.zeros((3, 3))
    for i in range(3):
        h = 1e-6 * max(1.0, np.linalg.norm(m.spin))
        e = np.zeros(3)
        e[i] = h
        G[:, i] = (d_of(m.spin + e) - d_of(m.spin - e)) / (2 * h)
    S = G @ m.covariance @ G.T
    # tolerance for the spin changing between measurements, in per-interval rotation: a rate
    # change moves the angle by rate_tol / f, an axis tilt eps moves the rotation by
    # 2 |sin(theta / 2)| eps
    nc = np.linalg.norm(c)
    if nc > 0:
        ch = c / nc
        tilt = 2.0 * abs(np.sin(nc / f / 2.0)) * axis_tol
        T = (rate_tol / f) ** 2 * np.outer(ch, ch) + tilt ** 2 * (np.eye(3) - np.outer(ch, ch))
    else:
        T = (rate_tol / f) ** 2 * np.eye(3)
    S = S + T + 1e-12 * np.eye(3)
    return float(delta @ np.linalg.solve(S, delta))


def resolve_aliases(measurements, curvature: CurvatureMeasurement | None = None, *,
                    min_rpm: float = 0.0, max_rpm: float = 4000.0,
                    rate_tolerance_rpm: float = 30.0, axis_tolerance_deg: float = 2.0,
                    curvature_rel_sigma: float = 0.1, curvature_floor: float = 5.0,
                    ambiguity_ratio: float = 0.05, merge_rpm: float = 60.0,
                    merge_deg: float = 10.0, consistency_p: float = 1e-3) -> AliasResolution:
    """Rank the alias candidates of one or more strobe measurements (module docstring).

    Parameters
    ----------
    measurements : StrobeMeasurement, SpinResult, or a sequence of them
        Spins of the same pitch from strobes at their own frequencies (e.g. the front pair at
        80 Hz and the back pair at 50 Hz). Candidates come from each of them.
    curvature : CurvatureMeasurement, optional
        What the flight's curvature says about the transverse spin.
    min_rpm, max_rpm : float
        Plausible spin rates.
    rate_tolerance_rpm, axis_tolerance_deg : float
        How much the spin may differ between measurements beyond their covariances (spin
        decay over the flight, model error).
    curvature_rel_sigma, curvature_floor : float
        Model tolerance of the curvature comparison: ``rel * |measured| (+) floor`` (rad/s)
        added in quadrature to each component's sigma (the lift law is uncertain).
    ambiguity_ratio : float
        Flag ``ambiguous`` when runner-up / best likelihood >= this.
    merge_rpm, merge_deg : float
        Candidates from different measurements closer than both are the same spin (the
        better-scoring one is kept).
    consistency_p : float
        Flag ``ambiguous`` when the best candidate's chi-square exceeds the ``1 - consistency_p``
        quantile of its chi-square distribution (the evidence contradicts itself).
        Then each item of evidence is left out in turn, and one whose removal leaves evidence that
        agrees (module docstring) is left out (``AliasResolution.left_out``).

    Returns
    -------
    AliasResolution
    """
    if isinstance(measurements, (StrobeMeasurement,)) or hasattr(measurements, "spin_covariance"):
        measurements = [measurements]
    meas = [m if isinstance(m, StrobeMeasurement) else StrobeMeasurement.from_result(m)
            for m in measurements]
    if not meas:
        raise ValueError("need at least one strobe measurement, got 0")
    if not 0 < ambiguity_ratio < 1:
        raise ValueError(f"ambiguity_ratio must be in (0, 1), got {ambiguity_ratio}")
    rate_tol = rate_tolerance_rpm / RPM_PER_RAD_S
    axis_tol = np.radians(axis_tolerance_deg)
    cands = []
    for i, m in enumerate(meas):
        for c in alias_candidates(m.spin, m.strobe_hz, min_rpm=min_rpm, max_rpm=max_rpm):
            c.source = i
            c.axis_determined = m.axis_determined or c.n == 0
            cands.append(c)
    if not cands:
        raise ValueError(f"no alias candidate within {min_rpm}-{max_rpm} rpm")
    evidence = [m.name or f"{m.strobe_hz:g} Hz" for m in meas]
    if curvature is not None:
        evidence.append("curvature")
    for c in cands:
        c.chi2_strobes = np.array([0.0 if j == c.source else
                                   _strobe_chi2(c.spin, m, rate_tol, axis_tol)
                                   for j, m in enumerate(meas)])
        if curvature is not None:
            c.chi2_curvature = curvature_chi2(curvature, c.spin, rel_sigma=curvature_rel_sigma,
                                              floor=curvature_floor)
    use_all = np.ones(len(meas), bool)
    merged, ratio, dof, consistent = _rank(cands, use_all, curvature is not None, merge_rpm, merge_deg, consistency_p)
    left_out = []
    if not consistent:
        # Deletion diagnostics: the evidence contradicts itself, so at least one item is wrong
        # (typically a pair whose few markers - one per flash - let its own fit settle on a
        # wrong rotation with a small covariance). Leave each item out in turn; when exactly one
        # removal leaves evidence that agrees with itself (still cross-checked: 2+ degrees of
        # freedom) that item is the wrong one. When several removals agree, they must pick the
        # same spin; otherwise nothing can be told and the full ranking stays, flagged.
        trials = []
        items = [("strobe", j) for j in range(len(meas))] + ([("curvature", -1)] if curvature is not None else [])
        for kind, j in items:
            use = use_all.copy()
            if kind == "strobe":
                use[j] = False
            use_curv = curvature is not None and kind != "curvature"
            if not use.any():
                continue
            r = _rank(cands, use, use_curv, merge_rpm, merge_deg, consistency_p)
            if r[0] and r[3] and r[2] >= 2:
                trials.append((kind, j, r))
        if trials:
            b0 = trials[0][2][0][0]
            same = all(abs(t[2][0][0].spin_rpm - b0.spin_rpm) < merge_rpm
                       and np.degrees(np.arccos(np.clip(t[2][0][0].axis @ b0.axis, -1, 1))) < merge_deg
                       for t in trials)
            if same:
                # the removal whose remaining evidence agrees best (largest p-value of its chi-square)
                kind, j, r = max(trials, key=lambda t: _chi2_sf(t[2][0][0].chi2, t[2][2]))
                merged, ratio, dof, consistent = r
                left_out = ["curvature" if kind == "curvature" else (meas[j].name or f"{meas[j].strobe_hz:g} Hz")]
                left_chi2 = (merged[0].chi2_curvature if kind == "curvature" else
                             (0.0 if merged[0].source == j else float(merged[0].chi2_strobes[j])))
    best = merged[0]
    ambiguous = ratio >= ambiguity_ratio or not consistent
    msg = f"best {best.spin_rpm:.0f} rpm (p = {best.probability:.3f})"
    if len(merged) > 1:
        msg += f", runner-up {merged[1].spin_rpm:.0f} rpm (likelihood ratio {ratio:.3g})"
    if left_out:
        msg += (f"; {left_out[0]} left out: it contradicts the rest of the evidence (chi-square {left_chi2:.1f} "
                "against the chosen spin), which agrees without it")
    if not consistent:
        msg += (f"; the evidence disagrees (chi-square {best.chi2:.1f} with {dof} degrees of freedom): "
                "a strobe measurement or the curvature is wrong")
    if ratio >= ambiguity_ratio:
        msg += ": ambiguous, add a second strobe rate or the flight curvature"
    elif ambiguous:
        msg += ": ambiguous"
    if not best.axis_determined:
        msg += "; the best candidate's axis is not determined by its measurement"
    return AliasResolution(merged, best, bool(ambiguous), ratio, evidence, msg, bool(consistent), int(dof),
                           left_out)


def curvature_chi2(curvature: CurvatureMeasurement, spin, *, rel_sigma: float = 0.1, floor: float = 5.0) -> float:
    """Chi-square of a spin vector (rad/s, world) against what the flight's curvature shows:
    the difference of :meth:`CurvatureMeasurement.effective` from the fitted transverse spin,
    weighed with the fit's covariance plus the lift law's tolerance ``rel_sigma * |measured|
    (+) floor`` (rad/s) per component (2 degrees of freedom; :func:`resolve_aliases`)."""
    e = curvature.transverse
    tol2 = (rel_sigma * np.linalg.norm(e)) ** 2 + floor ** 2
    d = curvature.effective(spin) - e
    return float(d @ np.linalg.solve(curvature.covariance + tol2 * np.eye(2), d))


def flight_informed_spin(curvature: CurvatureMeasurement, spin) -> np.ndarray:
    """A start for the markers' fit: ``spin``'s part along the flight (which the curvature cannot
    see) with the transverse part the flight's curvature shows (rad/s, world).

    With a few markers per flash the constant-spin fit has several minima, and which one a
    start falls into can turn on a single marker (issue 12: a pair's own fit found the right
    rate about an axis 91 deg off; started from this spin, the fit of all pairs' markers fell
    into the minimum that explains every marker). With the seed's lift law (``"total"``: the
    curvature sees ``|w|`` along the transverse direction) the transverse part gets the
    direction the curvature shows and the length that keeps ``|w|`` the curvature's; when the
    part along the flight alone exceeds that rate, it is kept and the transverse part dropped."""
    w = as_array(spin, (3,), "spin")
    B = curvature.basis
    along = np.cross(B[:, 0], B[:, 1])
    along = along / np.linalg.norm(along)
    g = float(w @ along)
    e = curvature.transverse
    if curvature.lift == "transverse":
        return g * along + B @ e
    ne = float(np.linalg.norm(e))
    if not ne > 0:
        return g * along
    return g * along + np.sqrt(max(ne * ne - g * g, 0.0)) * (B @ (e / ne))


def same_solution(a, b, same_p: float = 0.05) -> bool:
    """Whether two spin fits agree within their summed covariances (the ``1 - same_p`` quantile of a
    3-dof chi-square), the test :func:`resolve_joint_fits` merges solutions by."""
    return _same_solution(a, b, float(chdtri(3, same_p)))


def _same_solution(a, b, limit: float) -> bool:
    C = np.asarray(a.spin_covariance, float) + np.asarray(b.spin_covariance, float)
    dw = np.asarray(a.spin, float) - np.asarray(b.spin, float)
    if not (np.all(np.isfinite(C)) and np.all(np.isfinite(dw))):
        return False
    try:
        return float(dw @ np.linalg.solve(C + 1e-12 * np.eye(3), dw)) <= limit
    except np.linalg.LinAlgError:
        return False


#: An observation further than this many noise sigmas (the reference solution's) from its
#: marker counts as an outlier in :func:`marker_misfit_test`: it costs the same in every solution
#: that misses it (``fit_spin``'s own outlier rule, 4 robust sigmas).
MARKER_OUTLIER_SIGMAS = 4.0
#: Level of the markers' own test below which a solution counts as rejected (:func:`resolve_joint_fits`):
#: 99.9 %, the level at which the curvature and the strobes contradict a spin (``consistency_p``).
UNDECIDED_P = 1e-3


def marker_misfit_test(solutions) -> tuple[int, int, np.ndarray]:
    """Which fits of one constant spin to the same markers do the markers themselves reject?

    A few marker directions have little redundancy: each observation gives two residual
    components (one for a marker cut by the limb, :attr:`SpinResult.residual_ranks`) and the fit
    has six parameters (orientation and spin), so five observations can leave 2 degrees of
    freedom or none, and every local minimum then fits them almost exactly. The noise level is
    estimated from the reference solution's own residuals: ``s^2 = S_ref / dof`` with ``dof`` its
    inliers' components minus 6. For another solution ``i`` the misfit
    ``S_i`` (every observation, each capped at ``MARKER_OUTLIER_SIGMAS`` noise sigmas: an outlier
    costs the same everywhere) above ``S_ref`` tests whether its spin is inside the markers'
    confidence region: ``F = (S_i - S_ref) / (3 s^2)`` has an F(3, dof) distribution if ``i`` were
    the truth (the likelihood region of nonlinear least squares with the noise estimated from the
    same residuals, the orientation profiled out; not a chi-square with a known sigma, which a
    noise level taken from a few near-exact residuals would make absurdly confident). Without
    redundancy (``dof < 1`` for every solution) nothing is rejected. The reference is the most
    likely solution under the fit's own noise model (each component Gaussian with the noise its
    inliers show, an observation beyond the cap costing the cap; the noise profiled), so neither a
    wrong minimum that keeps more observations at a larger noise nor one that keeps a few at a
    tiny noise is the yardstick.

    Parameters
    ----------
    solutions : sequence of SpinResult
        Fits to the same observations with ``residuals_noise`` and ``residual_ranks`` (the
        global fit's); without them the angles ``residuals_deg`` and 2 components each.

    Returns
    -------
    (reference index, dof, p-values (n,))
        ``p[i]``: the upper tail of F(3, dof) at solution ``i``'s statistic (1 for the reference,
        a solution fitting at least as well, or ``dof < 1``).
    """
    from scipy.special import fdtrc

    sols = list(solutions)
    if not sols:
        raise ValueError("need at least one spin solution, got 0")
    res, ranks, inl = [], [], []
    for s in sols:
        e = getattr(s, "residuals_noise", None)
        k = getattr(s, "residual_ranks", None)
        if e is None or k is None:
            e, k = np.radians(np.asarray(s.residuals_deg, float)), np.full(len(s.residuals_deg), 2)
        res.append(np.asarray(e, float))
        ranks.append(np.asarray(k, int))
        inl.append(np.asarray(s.inliers, bool))
    if len({len(e) for e in res}) > 1:
        raise ValueError("the spin solutions must be fits to the same observations (residuals of equal length)")
    dofs = np.array([int(np.sum(k[m])) - 6 for k, m in zip(ranks, inl)])
    s2s = np.array([float(np.nansum(e[m] ** 2)) / d if d >= 1 else np.inf for e, m, d in zip(res, inl, dofs)])
    p = np.ones(len(sols))
    if not np.any(np.isfinite(s2s)):
        return int(np.argmax(dofs)), int(dofs.max()), p

    def capped(s2):
        c2 = MARKER_OUTLIER_SIGMAS ** 2 * s2
        return np.array([float(np.sum(np.minimum(np.nan_to_num(e ** 2, nan=c2), c2))) for e in res])

    # the reference: the most likely solution under the fit's own noise model (each component Gaussian
    # with the noise its inliers show, an observation beyond the cap costing the cap; K components):
    # -2 log L = sum min(e^2 / s^2, cap^2) + K log s^2. A minimum keeping a few observations at a tiny
    # noise pays the cap for every one it drops ("light to the side" #7)
    cap2 = MARKER_OUTLIER_SIGMAS ** 2
    with np.errstate(over="ignore"):
        nll = np.array([float(np.sum(np.minimum(np.nan_to_num(e ** 2 / max(s2, 1e-300), nan=cap2), cap2))
                              + np.sum(k) * np.log(max(s2, 1e-300))) if np.isfinite(s2) else np.inf
                        for e, k, s2 in zip(res, ranks, s2s)])
    ref = int(np.argmin(nll))
    dof, s2 = int(dofs[ref]), max(float(s2s[ref]), 1e-300)
    cost = capped(s2)
    for i in range(len(sols)):
        f = max(cost[i] - cost[ref], 0.0) / (3.0 * s2)
        p[i] = 1.0 if i == ref else float(fdtrc(3, dof, f))
    return ref, int(dof), p


def _is_alias(a, b, strobes_hz, rate_tol: float, axis_tol: float, p: float = 0.05) -> bool:
    """Whether spin fit ``a`` turns the ball as ``b`` does between flashes at one of the strobe
    rates (``b``'s covariance, the strobe comparison's tolerances; the ``1 - p`` quantile of 3
    dof): the markers of that rate cannot tell two such spins apart, and they belong to the
    alias family :func:`alias_candidates` enumerates, which the flight's curvature and the other
    rate decide (the other rate's markers may be too few to)."""
    lim = float(chdtri(3, p))
    cov = np.asarray(b.spin_covariance, float)
    if not np.all(np.isfinite(cov)):
        return False
    return any(
        _strobe_chi2(np.asarray(a.spin, float), StrobeMeasurement(np.asarray(b.spin, float), f, cov), rate_tol,
                     axis_tol) <= lim for f in strobes_hz)


def resolve_joint_fits(solutions, curvature: CurvatureMeasurement | None = None, measurements=(), *,
                       cap_deg: float = 8.0, curvature_rel_sigma: float = 0.1, curvature_floor: float = 5.0,
                       rate_tolerance_rpm: float = 30.0, axis_tolerance_deg: float = 2.0,
                       ambiguity_ratio: float = 0.05, same_p: float = 0.05,
                       consistency_p: float = 1e-3, strobes_hz=(), undecided_p: float = UNDECIDED_P) -> AliasResolution:
    """Rank fits of one constant spin to the same marker observations (from different starts:
    other aliases, the flight's transverse spin, no start) by the full evidence: the markers
    themselves and the flight's curvature.

    The strobe measurements that :func:`resolve_aliases` weighs are the pairs' own fits, each to
    part of these markers; a pair whose markers fix the ball's orientation at few flashes can
    settle on a wrong minimum with a small covariance. Here every solution is scored on all the
    markers at once: its capped cost ``sum min(d_i, cap)^2`` over every observation (the
    robust cost the fit itself chooses its starts by; ``d_i`` the angle to the assigned marker)
    in units of the marker noise the best-fitting solution shows (``sigma^2`` the mean ``d^2``
    of its inliers: the chi-square of a Gaussian marker noise, an observation beyond ``cap``
    costing the same in every solution it misses), plus :func:`curvature_chi2`. The markers'
    term is reported relative to the lowest (``chi2_markers``).

    Solutions whose spins agree within their summed covariances (``1 - same_p`` quantile of a
    chi-square with 3 degrees of freedom) are one solution (the better-scoring one is kept).
    ``ambiguous`` when the runner-up's likelihood ``exp(-chi2 / 2)`` is at least
    ``ambiguity_ratio`` of the best's, or when the best disagrees with the curvature beyond its
    ``1 - consistency_p`` quantile (2 degrees of freedom). ``measurements`` (the pairs' own
    spins, :class:`StrobeMeasurement`) are compared with each solution for the record
    (``chi2_strobes``); those the best solution contradicts at the same quantile (3 degrees of
    freedom) are named in ``left_out``. They add nothing to ``chi2``: their markers are in it.

    The markers' own test (:func:`marker_misfit_test`) sets each candidate's ``p_markers``. The
    other solutions it does not reject (``p_markers >= undecided_p``, :data:`UNDECIDED_P`) that are
    not aliases of the best at the strobe rates ``strobes_hz`` (the same rotation per interval,
    which the curvature and a second rate decide) are listed in ``undecided``: the markers do not
    decide between different rotations per interval, so the minima found are only a sample of the
    spins they allow, and the curvature, which sees two of the spin's three components, cannot
    decide the third. Also when the markers reject the best itself (the curvature chose it
    against their own best): the evidence contradicts itself (docs/spin.md).

    Parameters
    ----------
    solutions : sequence of SpinResult
        Successful fits to the same observations (``residuals_deg`` and ``inliers`` of equal
        length); the first is the one the strobe measurements chose.

    Returns
    -------
    AliasResolution
        Candidates best first; ``source`` of each is its index in ``solutions``.
    """
    sols = list(solutions)
    if not sols:
        raise ValueError("need at least one spin solution, got 0")
    m = len(sols[0].residuals_deg)
    if any(len(s.residuals_deg) != m or len(s.inliers) != m for s in sols):
        raise ValueError("the spin solutions must be fits to the same observations (residuals of equal length)")
    meas = [mm if isinstance(mm, StrobeMeasurement) else StrobeMeasurement.from_result(mm) for mm in measurements]
    rate_tol = rate_tolerance_rpm / RPM_PER_RAD_S
    axis_tol = np.radians(axis_tolerance_deg)
    capped = []
    for s in sols:
        d = np.nan_to_num(np.asarray(s.residuals_deg, float), nan=cap_deg)
        capped.append(float(np.sum(np.minimum(d, cap_deg) ** 2)))
    ref = sols[int(np.argmin(capped))]
    d_ref = np.asarray(ref.residuals_deg, float)[np.asarray(ref.inliers, bool)]
    sigma2 = max(float(np.mean(d_ref ** 2)) if len(d_ref) else 0.0, 1e-6)
    cands = []
    for i, (s, c) in enumerate(zip(sols, capped)):
        w = np.asarray(s.spin, float)
        n = float(np.linalg.norm(w))
        k = AliasCandidate(w.copy(), n * RPM_PER_RAD_S, w / n if n > 0 else np.full(3, np.nan), 0, i)
        k.chi2_markers = c / sigma2
        k.chi2_strobes = np.array([_strobe_chi2(w, mm, rate_tol, axis_tol) for mm in meas])
        if curvature is not None:
            k.chi2_curvature = curvature_chi2(curvature, w, rel_sigma=curvature_rel_sigma, floor=curvature_floor)
        k.chi2 = k.chi2_markers + k.chi2_curvature
        cands.append(k)
    lo = min(k.chi2_markers for k in cands)
    for k in cands:
        k.chi2_markers -= lo
        k.chi2 -= lo
    order = sorted(range(len(cands)), key=lambda i: cands[i].chi2)
    same_lim = float(chdtri(3, same_p))
    kept = []
    for i in order:
        if not any(_same_solution(sols[i], sols[j], same_lim) for j in kept):
            kept.append(i)
    merged = [cands[i] for i in kept]
    chi = np.array([c.chi2 for c in merged])
    like = np.exp(-0.5 * (chi - chi.min()))
    for c, p in zip(merged, like / like.sum()):
        c.probability = float(p)
    ratio = float(like[1] / like[0]) if len(merged) > 1 else 0.0
    best = merged[0]
    dof = 2 if curvature is not None else 0
    consistent = dof == 0 or best.chi2_curvature <= float(chdtri(dof, consistency_p))
    strobe_lim = float(chdtri(3, consistency_p))
    left_out = [mm.name or f"{mm.strobe_hz:g} Hz" for mm, c2 in zip(meas, best.chi2_strobes) if c2 > strobe_lim]
    evidence = ["markers of all pairs"] + (["curvature"] if curvature is not None else [])
    msg = f"all pairs' markers together{' and the flight curvature' if curvature is not None else ''}: best " \
          f"{best.spin_rpm:.0f} rpm (p = {best.probability:.3f})"
    if len(merged) > 1:
        r = merged[1]
        ang = float(np.degrees(np.arccos(np.clip(r.axis @ best.axis, -1, 1))))
        msg += f", runner-up {r.spin_rpm:.0f} rpm, axis {ang:.0f} deg away (chi-square {r.chi2 - best.chi2:.1f} worse)"
    if left_out:
        msg += f"; the own spin of {', '.join(left_out)} contradicts it (a wrong minimum of its few markers)"
    if not consistent:
        msg += (f"; the flight's curvature disagrees (chi-square {best.chi2_curvature:.1f} with 2 degrees of "
                "freedom): the markers or the flight model are wrong")
    ref, m_dof, p_mk = marker_misfit_test(sols)
    for k in cands:
        k.p_markers = float(p_mk[k.source])
    undecided = [c for c in merged[1:] if c.p_markers >= undecided_p
                 and not _is_alias(sols[c.source], sols[best.source], strobes_hz, rate_tol, axis_tol)]
    if undecided:
        u = undecided[0]
        ang = float(np.degrees(np.arccos(np.clip(u.axis @ best.axis, -1, 1))))
        msg += (f"; spin alias undecided: the markers cannot reject {u.spin_rpm:.0f} rpm (axis {ang:.0f} deg away, "
                f"p = {u.p_markers:.2g} with {m_dof} degrees of freedom of their residuals"
                + (f"; they reject the best itself, p = {best.p_markers:.2g}" if best.p_markers < undecided_p else "")
                + ")")
    ambiguous = ratio >= ambiguity_ratio or not consistent
    if ambiguous:
        msg += ": ambiguous"
    return AliasResolution(merged, best, bool(ambiguous), ratio, evidence, msg, bool(consistent), int(dof), left_out,
                           undecided, int(m_dof))


def _chi2_sf(x: float, dof: int) -> float:
    """Upper tail of a chi-square with ``dof`` degrees of freedom (1 for ``dof = 0``)."""
    from scipy.special import chdtrc

    return float(chdtrc(dof, x)) if dof > 0 else 1.0


def _rank(cands: list, use: np.ndarray, use_curvature: bool, merge_rpm: float, merge_deg: float,
          consistency_p: float):
    """The candidates of the measurements ``use`` (a mask) ranked on those measurements (and the
    curvature when ``use_curvature``): copies with ``chi2`` and ``probability`` set, merged.

    Returns ``(merged candidates best first, likelihood ratio runner-up / best, dof, consistent)``;
    an empty list when no candidate comes from the measurements used."""
    out = []
    for c in cands:
        if not use[c.source]:
            continue
        k = replace(c)
        k.chi2 = float(c.chi2_strobes[use].sum() + (c.chi2_curvature if use_curvature else 0.0))
        out.append(k)
    if not out:
        return [], 0.0, 0, False
    out.sort(key=lambda c: c.chi2)
    merged = []
    for c in out:
        dup = False
        for k in merged:
            ang = np.degrees(np.arccos(np.clip(c.axis @ k.axis, -1, 1)))
            if abs(c.spin_rpm - k.spin_rpm) < merge_rpm and (ang < merge_deg or c.spin_rpm < merge_rpm):
                dup = True
                break
        if not dup:
            merged.append(c)
    chi = np.array([c.chi2 for c in merged])
    like = np.exp(-0.5 * (chi - chi.min()))
    for c, p in zip(merged, like / like.sum()):
        c.probability = float(p)
    ratio = float(like[1] / like[0]) if len(merged) > 1 else 0.0
    dof = 3 * (int(use.sum()) - 1) + (2 if use_curvature else 0)
    consistent = dof == 0 or merged[0].chi2 <= float(chdtri(dof, consistency_p))
    return merged, ratio, dof, bool(consistent)
