"""Centre of gravity of a flange payload from static axis torques (pure numpy/scipy), issue #14.

* :func:`cog_paper`: the paper's lever system (eq. 5–7). With the mass known (eq. 4/15), the linear moment gives
  the lever ``a`` along the arm, the torsional moment at 0° gives ``c``, and at 90° (rotated about ``a``) ``b``.
* :func:`cog_poses`: the static poses of a scheme. ``paper`` is eq. 5–7's 0°/90°. ``full`` is A6 at
  0/90/180/270°, A5 ±45°, and A4 ±90° with A5 +45°. A4 and A6 always enter a pose from below.
* The torsional calibration (:func:`fit_torsional`). Loads of known mass and position are measured in every pose
  against the bare MPA (the bias of each pose). Each axis A3..A6 gets a gain K(x) on its payload torque x
  (:class:`AxisGain`), chosen and validated by leaving out whole points.
* :func:`estimate_cog_gls`: static holding torques are linear in θ = [m, m·c] (``kinematics.gravity_regressor``).
  So K⁻¹ of the bias-corrected readings over all poses gives the DuT's m·c by generalised least squares, with the
  mass fixed from the mass run and a reading offset per axis for the DuT's mounting. U per coordinate adds K and the
  mass. :func:`to_dut_frame` rotates the result into the DuT's frame.

Torques are the controller's holding torques (sign as in ``rgse_daemon.kinematics``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.errors import DataError


def cog_paper(
    mass_kg: float,
    m_linear_0_nm: float,
    m_torsion_0_nm: float,
    m_torsion_90_nm: float,
    g_m_s2: float = kin.G_PAPER_M_S2,
) -> np.ndarray:
    """CoG levers (a, b, c) in m by the paper's eq. 5–7.

    ``m_linear_0_nm``: linear moment M_2 at the reference axis (e.g. A5, bias removed), ``m_torsion_0_nm``: the
    torsional moment M_T (A4 or A6) in the same pose, ``m_torsion_90_nm``: M_T after turning the body 90° about a.
    """
    if not mass_kg > 0:
        raise DataError(f"cog_paper: mass must be > 0 kg, got {mass_kg}")
    w = mass_kg * g_m_s2
    a = m_linear_0_nm / w  # eq. 5
    c = m_torsion_0_nm / w  # eq. 6
    b = m_torsion_90_nm / w  # eq. 7
    return np.array([a, b, c])


# ---------------------------------------------------------------------------------------------------------------------
# Pose schemes of a mass-properties run
# ---------------------------------------------------------------------------------------------------------------------
SCHEMES = ("paper", "full", "lever")

#: Tilts of the "full" scheme (deg), relative to the measurement pose: (name, ΔA4, ΔA5, ΔA6).
#: A6 at 0/90/180/270° puts each flange-transverse CoG coordinate under the A4/A6 torque twice with opposite signs
#: (a constant per-axis offset separates from it); A5 ±45° changes the lever of the flange-axial coordinate cz on
#: A5 (cos 45°), and A4 ±90° with A5 +45° puts cz under the torsional axis A4 (sin 45°), whose gain is near 1.
_FULL_TILTS: tuple[tuple[str, float, float, float], ...] = (
    ("meas", 0.0, 0.0, 0.0),
    ("A6+90", 0.0, 0.0, 90.0),
    ("A6+180", 0.0, 0.0, 180.0),
    ("A6+270", 0.0, 0.0, 270.0),
    ("A5+45", 0.0, 45.0, 0.0),
    ("A5-45", 0.0, -45.0, 0.0),
    ("A4+90/A5+45", 90.0, 45.0, 0.0),
    ("A4-90/A5+45", -90.0, 45.0, 0.0),
)
_PAPER_TILTS: tuple[tuple[str, float, float, float], ...] = (("meas", 0.0, 0.0, 0.0), ("A6+90", 0.0, 0.0, 90.0))


@dataclass(frozen=True)
class CogPose:
    """One static pose of a mass-properties run: its name (e.g. ``"meas"``, ``"A6+90"``) and A1..A6 in deg."""

    name: str
    q_deg: tuple[float, ...]
    q_approach_deg: tuple[float, ...] = ()
    """Where the last motion into the pose starts: A4 and A6 ``APPROACH_DEG`` below their target, so that both
    axes always arrive from the same side (friction hysteresis, see :func:`cog_poses`); () = no such rule."""


#: A4 and A6 arrive at every pose from this many degrees below it (A5's last motion is the brake-release move's
#: way back, the same in every pose).
APPROACH_DEG = 5.0


def cog_poses(measurement_pose_deg: Sequence[float], scheme: str = "full") -> list[CogPose]:
    """The static poses of a CoG scheme around the measurement pose, in the order they are measured.

    ``"paper"``: eq. 5–7's scheme, the measurement pose (A5 gives the lever a, A6 the offset c) and A6 turned by 90°
    (A6 gives b). ``"lever"``: the paper's poses and the multi-pose mass's lever poses (the robot's
    ``multipose_a3_deg``: A3 turned, A5 turned back, :mod:`rgse_daemon.pipeline.multipose`). ``"full"``: A6 at
    0/90/180/270°, A5 tilted ±45° and A4 ±90° with A5 +45° (see ``_FULL_TILTS``).
    Every pose lies within the axis ranges (DataError otherwise). A plan moves to ``q_approach_deg`` and then to
    ``q_deg`` (then the brake-release move), in the calibration campaign as in the properties run: every axis
    arrives at each pose from the same side in both, so the friction hysteresis cancels in the bias-corrected
    torque.
    """
    tilts = {"paper": _PAPER_TILTS, "full": _FULL_TILTS, "lever": _PAPER_TILTS}.get(scheme)
    if tilts is None:
        raise DataError(f"unknown CoG scheme {scheme!r}; use one of {', '.join(SCHEMES)}")
    turns = [(name, 0.0, d4, d5, d6) for name, d4, d5, d6 in tilts]
    if scheme == "lever":  # the multi-pose mass's lever poses (issue #35): A3 turned, A5 against it
        # (names as pipeline.multipose.pose_name gives them)
        turns += [(f"A3{d:+g}", d, 0.0, -d, 0.0) for d in robots.active().multipose_a3_deg if d != 0.0]
    base = np.asarray(measurement_pose_deg, dtype=float)
    if base.shape != (6,) or not np.all(np.isfinite(base)):
        raise DataError(f"measurement pose must be six finite angles A1..A6 (deg), got {measurement_pose_deg!r}")
    out = []
    for name, d3, d4, d5, d6 in turns:
        q = base + np.array([0.0, 0.0, d3, d4, d5, d6])
        if not kin.within_limits(q):
            raise DataError(f"CoG pose {name} {q.tolist()} is outside the axis ranges")
        approach = q - np.array([0.0, 0.0, 0.0, APPROACH_DEG, 0.0, APPROACH_DEG])
        if not kin.within_limits(approach):
            raise DataError(f"CoG pose {name}: its approach {approach.tolist()} is outside the axis ranges")
        out.append(CogPose(name, tuple(float(v) for v in q), tuple(float(v) for v in approach)))
    return out


# ---------------------------------------------------------------------------------------------------------------------
# Per-axis calibration of the payload torque (the torsional section of CAL.json)
# ---------------------------------------------------------------------------------------------------------------------
#: Gain models of the bias-corrected reading r of one axis against the true payload torque x (Nm), with their number
#: of parameters. Polynomial (like eq. 19): r = x · (k0 + k1·|x|/1 kNm + k2·(|x|/1 kNm)²), the first 1, 2 or 3
#: terms. Saturating (like eq. 20's exponentials, at a fixed scale τ): r = x · (k0 + k1·(1 − exp(−|x|/τ))),
#: ``sat<τ in Nm>`` (any τ > 0; :func:`gain_models` sets the grid). Like Table 1's K: the reading's gain depends on
#: the load torque, on A5 strongly.
POLY_MODELS = {"linear": 1, "poly2": 2, "poly3": 3}
#: The saturating models' scales τ as fractions of the largest payload torque the axis' points cover, so that every
#: axis and every robot meets the same shapes over its own range (a polynomial is scale-free by itself). On the
#: KR 500's campaign A4 and A5 reach 0.7-1 kNm, where these are the 100-800 Nm of the fixed grid they replace; A6
#: (0.12 kNm) had only nearly linear sat terms there, A3 (2.2 kNm) only sharp ones.
SAT_SCALE_FRACTIONS = (0.125, 0.25, 0.375, 0.625, 1.0)


def gain_model_params(model: str) -> int | None:
    """Number of parameters of a gain model name (:data:`POLY_MODELS` or ``sat<τ in Nm>``); None if not one."""
    if model in POLY_MODELS:
        return POLY_MODELS[model]
    tau = _sat_scale_nm(model)
    return 2 if tau is not None and math.isfinite(tau) and tau > 0 else None


def gain_models(x_nm: np.ndarray) -> tuple[str, ...]:
    """The catalogue for an axis whose points cover the payload torques ``x_nm``: the polynomials, and the
    saturating models at :data:`SAT_SCALE_FRACTIONS` of the largest |x| (τ in the name to 4 significant digits)."""
    top = float(np.max(np.abs(x_nm))) if np.size(x_nm) else 0.0
    sat = [f"sat{f * top:.4g}" for f in SAT_SCALE_FRACTIONS] if top > 0 else []
    return (*POLY_MODELS, *sat)


#: Axes whose payload torque the torsional calibration fits (A1 carries none in these poses, A2 is not needed).
COG_AXES = (3, 4, 5, 6)


def _sat_scale_nm(model: str) -> float | None:
    if not model.startswith("sat"):
        return None
    try:
        return float(model[3:])
    except ValueError:
        return None


def gain_basis(x_nm: np.ndarray, model: str) -> np.ndarray:
    """The columns of ``model`` at payload torques x: the reading r = basis @ k."""
    x = np.asarray(x_nm, dtype=float)
    tau = _sat_scale_nm(model)
    if tau is not None:
        return np.stack([x, x * (1.0 - np.exp(-np.abs(x) / tau))], axis=-1)
    return np.stack([x * (np.abs(x) / 1000.0) ** j for j in range(POLY_MODELS[model])], axis=-1)


def gain_slope(x_nm: np.ndarray, model: str, k: np.ndarray) -> np.ndarray:
    """dr/dx of ``model`` with parameters k."""
    xa = np.abs(np.asarray(x_nm, dtype=float))
    tau = _sat_scale_nm(model)
    if tau is not None:
        e = np.exp(-xa / tau)
        return k[0] + k[1] * (1.0 - e) + k[1] * (xa / tau) * e
    return sum((j + 1) * k[j] * (xa / 1000.0) ** j for j in range(len(k)))


@dataclass(frozen=True)
class GainCandidate:
    """One gain model the leave-one-point-out validation fitted for an axis (CAL.json ``evaluation.models``): its
    parameters on all points, the held-out RMS of whole points (Nm) and its parameters' jackknife covariance (None
    when the file did not keep it)."""

    model: str
    params: tuple[float, ...]
    heldout_rms_nm: float
    covariance: tuple[tuple[float, ...], ...] | None = None


#: One-sided level at which a candidate gain model's held-out error counts as no worse than the chosen model's
#: (:meth:`AxisGain.admissible_candidates`).
CANDIDATE_LEVEL = 0.95


@dataclass(frozen=True)
class AxisGain:
    """K of one axis for the CoG: reading r (bias-corrected, Nm) = basis(x) @ params for payload torque x, the
    basis of ``model`` (:func:`gain_models`: polynomial or saturating gain).

    ``covariance``: of the params (fit). ``u_point_nm``: standard deviation of the held-out residuals of whole points
    (one mounting each): the scatter a new mounting adds, fixed over the poses of that mounting.
    ``torque_range_nm``: the payload torques the campaign covered."""

    axis: int
    model: str
    params: tuple[float, ...]
    covariance: tuple[tuple[float, ...], ...]
    u_point_nm: float
    torque_range_nm: tuple[float, float]
    u_fit_nm: float = 0.0
    """RMS of the held-out residuals within the points: how far one reading strays from K beyond its noise (model
    form, seating of the load in a tilted pose, drift); every CoG equation gets it as an independent error."""
    n_points: int = 0
    """Loaded points the jackknife covariance rests on (0: unknown, no Student factor)."""
    candidates: tuple[GainCandidate, ...] = ()
    """Every model the validation fitted (the chosen one among them), for the model-form part of the slope's
    uncertainty (:meth:`slope_u_rel`); () when the calibration did not keep them (older CAL.json)."""

    def student_factor(self) -> float:
        """(t₀.₉₇₅(n − 1) / 1.96)²: the jackknife variance of a few points, widened so that k = 2 keeps ~95 %."""
        if self.n_points < 2:
            return 1.0
        return float((stats.t.ppf(0.975, self.n_points - 1) / stats.norm.ppf(0.975)) ** 2)

    def admissible_candidates(self) -> tuple[GainCandidate, ...]:
        """The candidate models the calibration's points cannot tell from the chosen one: those whose held-out mean
        square (leave one point out) is within the F distribution's ``CANDIDATE_LEVEL`` quantile with
        (n_points, n_points) degrees of freedom of the chosen model's. The points, not the poses, are the independent
        samples of a held-out error (a mounting's error is shared by its poses), so with four points a candidate
        up to ~2.5 times the chosen's held-out RMS still fits them as well as chance allows: the selection's 5 %
        rule picks one of them, it does not rule out the others. Without ``n_points`` every validated candidate
        counts."""
        if not self.candidates:
            return ()
        own = [c.heldout_rms_nm for c in self.candidates if c.model == self.model]
        ref = own[0] if own else min(c.heldout_rms_nm for c in self.candidates)
        if self.n_points < 2:
            return self.candidates
        bound = float(np.sqrt(stats.f.ppf(CANDIDATE_LEVEL, self.n_points, self.n_points)))
        return tuple(c for c in self.candidates if c.heldout_rms_nm <= bound * ref)

    def _slope_and_u_par(self, model: str, params: Sequence[float], cov: np.ndarray | None, x_nm: float
                         ) -> tuple[float, float]:
        """Slope of ``model`` at x and its standard uncertainty from the parameters' covariance (widened by the
        Student factor of the points; numerical Jacobian)."""
        k = np.asarray(params, float)
        xs = np.array([float(x_nm)])
        slope = float(gain_slope(xs, model, k)[0])
        if cov is None:
            return slope, 0.0
        jac = np.empty(len(k))
        for i in range(len(k)):
            h = 1e-6 * max(abs(k[i]), 1e-6)
            kp = k.copy()
            kp[i] += h
            jac[i] = (float(gain_slope(xs, model, kp)[0]) - slope) / h
        return slope, math.sqrt(max(float(jac @ (np.asarray(cov, float) * self.student_factor()) @ jac), 0.0))

    def slope_u_rel_parts(self, x_nm: float) -> tuple[float, float]:
        """Relative standard uncertainty of the slope dr/dx at payload torque ``x_nm``: (the chosen model's
        parameters alone, with the model form).

        *Parameters*: the chosen model's jackknife covariance (widened by the Student factor of its few points),
        propagated to the slope at x. *With the model form*: the truth may follow any admissible candidate
        (:meth:`admissible_candidates`, the chosen one among them) as well as the chosen model. For each candidate c
        the chosen slope's error is then its deviation d_c = s_c(x) − s(x), taken as the half-width of a
        rectangular distribution (/√3: the candidates are no random sample of models, five saturating scales lie
        close together and the list is ours, so their standard deviation would depend on how densely the list is
        populated; the largest deviation would not), plus the candidate's own parameter uncertainty u_c(x) (its
        slope is fitted from the same few points). The slope's standard uncertainty is the largest
        √(d_c²/3 + u_c²) over the candidates; for the chosen model itself that is its parameter part. Both parts
        grow where the points lie far from x (an operating point beyond the calibrated torques).

        Why not the chosen model's parameters alone: they are blind to a model that fits the points as well but has
        another curvature between or beyond them. Why the candidates' own u_c too: when the points' scatter makes a
        curved truth look straight, the curved candidates fitted to the same points come out too straight as well,
        and their deviation alone is too small (on a curved truth G = 0.91 + 0.28·tanh(|x|/500 Nm), four points to
        480 Nm with 11 Nm scatter each, the deviation alone covered the true slope error at k = 2 in 80 % of draws,
        with u_c in 92–96 %; tests/physics/test_gain_slope.py)."""
        slope, u_par = self._slope_and_u_par(self.model, self.params, np.asarray(self.covariance, float), x_nm)
        if not slope > 0:
            return math.inf, math.inf
        u = u_par
        for c in self.admissible_candidates():
            if gain_model_params(c.model) != len(c.params):
                continue
            cov = None if c.covariance is None else np.asarray(c.covariance, float)
            s_c, u_c = self._slope_and_u_par(c.model, c.params, cov, x_nm)
            u = max(u, math.sqrt((s_c - slope) ** 2 / 3.0 + u_c**2))
        return u_par / slope, u / slope

    def slope_u_rel(self, x_nm: float) -> float:
        """Relative standard uncertainty of the slope at payload torque ``x_nm``, model form included
        (:meth:`slope_u_rel_parts`)."""
        return self.slope_u_rel_parts(x_nm)[1]

    def reading_nm(self, x_nm: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        k = np.asarray(self.params if params is None else params, dtype=float)
        return gain_basis(x_nm, self.model) @ k

    def slope(self, x_nm: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        """dr/dx."""
        return gain_slope(x_nm, self.model, np.asarray(self.params if params is None else params, dtype=float))

    def payload_torque_nm(self, reading_nm: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        """Invert r(x) by Newton's method (r is odd and monotone over the calibrated range; checked)."""
        r = np.asarray(reading_nm, dtype=float)
        k = np.asarray(self.params if params is None else params, dtype=float)
        x = r / k[0]
        for _ in range(50):
            step = (self.reading_nm(x, k) - r) / self.slope(x, k)
            x = x - step
            if np.all(np.abs(step) < 1e-9):
                break
        if np.any(self.slope(x, k) <= 0):
            raise DataError(f"A{self.axis}: the torque calibration is not monotone at {x.tolist()} Nm")
        return x

    def to_dict(self) -> dict:
        d = {"model": self.model, "params": list(self.params), "covariance": [list(r) for r in self.covariance],
             "u_point_nm": self.u_point_nm, "u_fit_nm": self.u_fit_nm, "torque_range_nm": list(self.torque_range_nm),
             "n_points": self.n_points}
        if self.candidates:
            d["evaluation"] = {"models": {c.model: _candidate_dict(c) for c in self.candidates}}
        return d

    @staticmethod
    def from_dict(axis: int, d: dict) -> AxisGain:
        try:
            model = str(d["model"])
            params = tuple(float(v) for v in d["params"])
            cov = tuple(tuple(float(v) for v in row) for row in d["covariance"])
            u = float(d["u_point_nm"])
            lo, hi = (float(v) for v in d["torque_range_nm"])
            u_fit = float(d.get("u_fit_nm", 0.0))
            n_points = int(d.get("n_points", 0))
            candidates = _candidates(d.get("evaluation"))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise DataError(f"torsional.axes.A{axis}: malformed entry ({exc!r})") from None
        n = gain_model_params(model)
        if n is None or len(params) != n or np.shape(cov) != (n, n):
            raise DataError(f"torsional.axes.A{axis}: model {model!r} needs {n} params and an {n}x{n} covariance")
        if not (np.all(np.isfinite(params)) and np.all(np.isfinite(cov)) and np.isfinite(u) and u >= 0
                and np.isfinite(u_fit) and u_fit >= 0):
            raise DataError(f"torsional.axes.A{axis}: non-finite parameters")
        if params[0] <= 0:
            raise DataError(f"torsional.axes.A{axis}: gain k0 must be > 0, got {params[0]}")
        bad = [c.model for c in candidates if gain_model_params(c.model) != len(c.params)
               or not (np.all(np.isfinite(c.params)) and np.isfinite(c.heldout_rms_nm) and c.heldout_rms_nm >= 0)
               or (c.covariance is not None and (np.shape(c.covariance) != (len(c.params),) * 2
                                                 or not np.all(np.isfinite(c.covariance))))]
        if bad:
            raise DataError(f"torsional.axes.A{axis}.evaluation: malformed candidate model(s) {', '.join(bad)}")
        return AxisGain(axis, model, params, cov, u, (lo, hi), u_fit, n_points, candidates)


def _candidates(evaluation: object) -> tuple[GainCandidate, ...]:
    """The candidate models of a CAL.json axis' ``evaluation`` record (optional: () without it, or for an entry
    without its ``params``, as files written before they were kept)."""
    if not isinstance(evaluation, dict) or not isinstance(evaluation.get("models"), dict):
        return ()
    out = []
    for model, rec in evaluation["models"].items():
        if not isinstance(rec, dict) or "params" not in rec:
            continue
        cov = rec.get("covariance")
        out.append(GainCandidate(str(model), tuple(float(v) for v in rec["params"]), float(rec["heldout_rms_nm"]),
                                 None if cov is None else tuple(tuple(float(v) for v in row) for row in cov)))
    return tuple(out)


def _candidate_dict(c: GainCandidate) -> dict:
    d: dict = {"heldout_rms_nm": c.heldout_rms_nm, "params": list(c.params)}
    if c.covariance is not None:
        d["covariance"] = [list(r) for r in c.covariance]
    return d


def fit_gain(axis: int, x_nm: np.ndarray, r_nm: np.ndarray, sigma_nm: np.ndarray, group: np.ndarray, model: str,
             point_offsets: bool = False) -> tuple[AxisGain, np.ndarray]:
    """Fit one gain model on calibration observations (true payload torque x, bias-corrected reading r, its σ,
    the point each belongs to); returns the gain and the held-out residuals (leave one point out: every pose of
    that point is predicted by a fit on the other points, Nm).

    ``point_offsets``: each point (one mounting) also gets its own reading offset δ_p, r = K(x) + δ_p, so that the
    seating scatter of the mountings does not tilt K; held-out residuals are then taken about the held-out point's
    own mean (its offset is not K's business). ``u_point_nm`` is the scatter of the offsets: what a mounting adds
    when the CoG poses cannot fit one (:func:`estimate_cog_gls`)."""
    n = gain_model_params(model)
    if n is None:
        raise DataError(f"A{axis}: unknown gain model {model!r}")
    x, r, s, grp = (np.asarray(v) for v in (x_nm, r_nm, sigma_nm, group))
    points = np.unique(grp)
    if len(points) < n + 2:
        raise DataError(f"A{axis}: {len(points)} loaded torsional points cannot validate a {n}-parameter gain")
    heldout = np.empty_like(r, dtype=float)
    k_loo = []
    for p in points:
        out = grp == p
        k, _ = _gain_lsq(x[~out], r[~out], s[~out], model, grp[~out] if point_offsets else None)
        k_loo.append(k)
        res = r[out] - gain_basis(x[out], model) @ k
        heldout[out] = res - res.mean() if point_offsets else res
    k, offsets = _gain_lsq(x, r, s, model, grp if point_offsets else None)
    span = np.linspace(0.0, max(abs(x.min()), abs(x.max())), 50)
    if not (k[0] > 0 and np.all(gain_slope(span, model, k) > 0)):
        raise DataError(f"A{axis}: gain model {model} is not monotone over the calibrated torques (k = {k.tolist()})")
    # jackknife over points: a mounting's error is shared by all its poses, so the points, not the poses, are the
    # independent samples (the least-squares covariance, which counts poses, would be too small)
    dk = np.array(k_loo) - np.mean(k_loo, axis=0)
    cov = (len(points) - 1) / len(points) * dk.T @ dk
    if point_offsets:
        u_point = float(np.sqrt(np.mean(offsets**2)))
    else:
        u_point = float(np.sqrt(np.mean(np.array([heldout[grp == p].mean() for p in points]) ** 2)))
    u_fit = float(np.sqrt(np.mean([np.var(heldout[grp == p]) for p in points])))
    gain = AxisGain(axis, model, tuple(float(v) for v in k), tuple(tuple(float(v) for v in row) for row in cov),
                    u_point, (float(x.min()), float(x.max())), u_fit, len(points))
    return gain, heldout


def _gain_lsq(x: np.ndarray, r: np.ndarray, s: np.ndarray, model: str, group: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares r = basis(x) @ k (+ δ_group); returns k and the group offsets (empty without)."""
    a = gain_basis(x, model)
    n = a.shape[1]
    groups = np.unique(group) if group is not None else np.empty(0)
    if group is not None:
        a = np.hstack([a, (group[:, None] == groups[None, :]).astype(float)])
    w = 1.0 / np.maximum(s, 1e-6)
    k, *_ = np.linalg.lstsq(a * w[:, None], r * w, rcond=None)
    return k[:n], k[n:]


def offsets_identifiable(x_nm: np.ndarray, group: np.ndarray) -> bool:
    """Whether a per-point offset can be told from K: the payload torque must vary within the points (over their
    poses) by at least a fifth of its spread over all points (not so for A3/A5 in the paper's two poses)."""
    x, grp = np.asarray(x_nm, dtype=float), np.asarray(group)
    within = np.sqrt(np.mean([np.var(x[grp == p]) for p in np.unique(grp)]))
    return bool(within > 0.2 * np.std(x)) and len(x) > len(np.unique(grp)) + 3


def select_gain(axis: int, x_nm: np.ndarray, r_nm: np.ndarray, sigma_nm: np.ndarray, group: np.ndarray
                ) -> tuple[AxisGain, dict]:
    """Every gain model that the points can validate, the one with the smallest held-out RMS chosen (a richer one
    only if it beats the simpler by 5 %); returns it and the evaluation record."""
    evaluations: dict = {}
    best: tuple[AxisGain, float] | None = None
    point_offsets = offsets_identifiable(x_nm, group)
    for model in gain_models(x_nm):
        try:
            gain, heldout = fit_gain(axis, x_nm, r_nm, sigma_nm, group, model, point_offsets)
        except DataError:
            continue
        rms = float(np.sqrt(np.mean(heldout**2)))
        evaluations[model] = {"heldout_rms_nm": rms, "params": list(gain.params),
                              "covariance": [list(r) for r in gain.covariance]}
        if best is None or rms < 0.95 * best[1]:
            best = (gain, rms)
    if best is None:
        raise DataError(f"A{axis}: too few torsional points to fit any gain model")
    candidates = _candidates({"models": evaluations})
    chosen = replace(best[0], candidates=candidates)
    return chosen, {"chosen": chosen.model, "point_offsets": point_offsets, "models": evaluations}


# ---------------------------------------------------------------------------------------------------------------------
# The estimator: weighted least squares over poses, mass fixed, with its full uncertainty budget
# ---------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseTorques:
    """Bias-corrected readings of one pose: r = reading − bias (Nm, A1..A6, NaN where absent), their standard
    uncertainty from the trace (u_reading) and from the bias (u_bias)."""

    name: str
    q_deg: tuple[float, ...]
    r_nm: tuple[float, ...]
    u_reading_nm: tuple[float, ...]
    u_bias_nm: tuple[float, ...]


@dataclass(frozen=True)
class CogFit:
    """DuT CoG in the flange frame (m), its covariance (m²) split by source, and diagnostics."""

    cog_m: np.ndarray
    cov_m2: np.ndarray
    cov_parts_m2: dict[str, np.ndarray]
    offsets_nm: dict[str, float]
    residual_nm: np.ndarray
    chi2_red: float
    n_equations: int
    fitted_offsets: bool
    outside_range: tuple[str, ...]


def _design(poses: Sequence[PoseTorques], gains: dict[int, AxisGain], params: dict[int, np.ndarray],
            offsets_nm: dict[int, float], g_m_s2: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows of the regressor, payload torques x = K⁻¹(r − o) with the current reading offsets o, their variance,
    the axis of each row, and dx/do = 1/K'(x)."""
    rows, xs, var, axis_of, dxdo = [], [], [], [], []
    for p in poses:
        y_full = kin.gravity_regressor(p.q_deg, g_m_s2)
        for ax, gain in gains.items():
            r = p.r_nm[ax - 1]
            if not np.isfinite(r):
                continue
            x = float(gain.payload_torque_nm(np.array([r - offsets_nm.get(ax, 0.0)]), params[ax])[0])
            slope = float(gain.slope(np.array([x]), params[ax])[0])
            rows.append(y_full[ax - 1])
            xs.append(x)
            var.append((p.u_reading_nm[ax - 1] ** 2 + p.u_bias_nm[ax - 1] ** 2 + gain.u_fit_nm**2) / slope**2)
            axis_of.append(ax)
            dxdo.append(1.0 / slope)
    return np.array(rows).reshape(-1, 4), np.array(xs), np.array(var), np.array(axis_of), np.array(dxdo)


@dataclass(frozen=True)
class _Gls:
    theta: np.ndarray
    cov_theta: np.ndarray
    design: np.ndarray
    b: np.ndarray
    cov_obs: np.ndarray
    axis_of: np.ndarray
    axes: list[int]
    x_nm: np.ndarray
    offsets_nm: dict[int, float]


def _gls(poses: Sequence[PoseTorques], gains: dict[int, AxisGain], params: dict[int, np.ndarray],
         total_mass_kg: float, known_moment_kgm: np.ndarray, fit_offsets: bool, g_m_s2: float) -> _Gls:
    """GLS for the unknown first moment m·c (kg·m) of the DuT, and, when fitted, a reading offset o_i per axis
    (r = K(x) + o_i: the offset is in the reading, so it enters x-space as o/K'(x); solved by a few Gauss-Newton
    steps, each re-inverting K at r − o)."""
    offsets: dict[int, float] = {}
    for _ in range(4 if fit_offsets else 1):
        y_mat, x, var, axis_of, dxdo = _design(poses, gains, params, offsets, g_m_s2)
        if len(x) == 0:
            raise DataError("CoG: no usable axis torques")
        axes = sorted(set(axis_of.tolist()))
        b = x - y_mat[:, 0] * total_mass_kg - y_mat[:, 1:] @ known_moment_kgm
        design = y_mat[:, 1:]
        cov_obs = np.diag(var)
        if fit_offsets:
            design = np.hstack([design, (axis_of[:, None] == np.array(axes)[None, :]) * dxdo[:, None]])
        else:
            # a mounting's offset is the same in every pose: correlated within an axis
            for ax in axes:
                sel = axis_of == ax
                u = gains[ax].u_point_nm * dxdo[sel]
                cov_obs[np.ix_(sel, sel)] += np.outer(u, u)
        if design.shape[0] < 3 or not _well_posed(design[:, :3]):
            rank = np.linalg.matrix_rank(design[:, :3]) if design.shape[0] else 0
            raise DataError(f"CoG: the poses do not determine all three CoG coordinates (rank {rank} of 3 from "
                            f"{design.shape[0]} axis torques); use a scheme that turns A6 and tilts A4/A5")
        if fit_offsets and (design.shape[0] < design.shape[1] or not _well_posed(
                np.hstack([design[:, :3], (axis_of[:, None] == np.array(axes)[None, :]).astype(float)]))):
            raise DataError("CoG: these poses cannot tell a per-axis reading offset from the CoG")
        w = np.linalg.inv(cov_obs)
        cov_theta = np.linalg.inv(design.T @ w @ design)
        theta = cov_theta @ design.T @ w @ b
        if fit_offsets:
            step = dict(zip(axes, theta[3:], strict=True))
            offsets = {ax: offsets.get(ax, 0.0) + float(step[ax]) for ax in axes}
            if max(abs(v) for v in step.values()) < 1e-9:
                break
    if fit_offsets:  # the last step's offsets are increments: report the totals, b and theta at convergence
        theta = np.concatenate([theta[:3], [offsets[ax] for ax in axes]])
    return _Gls(theta, cov_theta, design, b, cov_obs, axis_of, axes, x, offsets)


#: Smallest ratio of the smallest to the largest singular value of a (column-normalised) design that counts as
#: determined: below it the poses leave a combination of the unknowns to the noise (e.g. A6 turns alone and the
#: flange-axis coordinate against the A3/A5 offsets).
WELL_POSED_RATIO = 1e-3


def _well_posed(design: np.ndarray) -> bool:
    norms = np.linalg.norm(design, axis=0)
    if design.shape[0] < design.shape[1] or np.any(norms == 0):
        return False
    sv = np.linalg.svd(design / norms, compute_uv=False)
    return bool(sv[-1] / sv[0] > WELL_POSED_RATIO)


def estimate_cog_gls(poses: Sequence[PoseTorques], gains: dict[int, AxisGain], *, dut_mass_kg: float,
                     u_dut_mass_kg: float, fixture_mass_kg: float, fixture_cog_m: Sequence[float],
                     fit_offsets: bool | None = None, g_m_s2: float = kin.G_PAPER_M_S2) -> CogFit:
    """CoG of a DuT (flange frame, m) from bias-corrected readings in several poses, with the mass fixed.

    Model per pose p and axis i (eq. 5–7 generalised to any pose, docs/controller.md §7):
    r_pi = K_i(Y_pi · [m_DuT + m_fix, m_fix·c_fix + m_DuT·c]) (+ o_i, a reading offset of this mounting).
    Generalised least squares for m_DuT·c with the observation covariance (trace noise, bias, and, when the offsets
    are not fitted, the calibration's per-mounting scatter, fully correlated over the poses of an axis). The
    covariance of c adds, by first-order propagation (numerical Jacobians): the K parameters of every axis and the
    mass. When the fit leaves more scatter than the inputs explain (reduced χ² > 1) the noise part is scaled by it.
    ``fit_offsets``: None fits them when the poses determine them with at least two equations to spare.
    """
    if not dut_mass_kg > 0:
        raise DataError(f"CoG: DuT mass must be > 0 kg, got {dut_mass_kg}")
    if not gains:
        raise DataError("CoG: no axis has a torque calibration")
    params = {ax: np.asarray(g.params, dtype=float) for ax, g in gains.items()}
    known = fixture_mass_kg * np.asarray(fixture_cog_m, dtype=float)
    total = dut_mass_kg + fixture_mass_kg
    if fit_offsets is None:
        n_rows = sum(int(np.isfinite(p.r_nm[ax - 1])) for p in poses for ax in gains)
        n_axes = len({ax for p in poses for ax in gains if np.isfinite(p.r_nm[ax - 1])})
        fit_offsets = n_rows >= 3 + n_axes + 2
        if fit_offsets:
            try:
                _gls(poses, gains, params, total, known, True, g_m_s2)
            except DataError:
                fit_offsets = False
    sol = _gls(poses, gains, params, total, known, fit_offsets, g_m_s2)
    resid = sol.b - sol.design[:, :3] @ sol.theta[:3]  # b already has the fitted offsets removed (x = K⁻¹(r − o))
    dof = len(sol.b) - sol.design.shape[1]
    w = np.linalg.inv(sol.cov_obs)
    chi2_red = float(resid @ w @ resid / dof) if dof > 0 else float("nan")
    scale = max(chi2_red, 1.0) if dof > 0 else 1.0
    cog = sol.theta[:3] / dut_mass_kg
    cov_noise = sol.cov_theta[:3, :3] * scale / dut_mass_kg**2

    def cog_with(p: dict[int, np.ndarray], m: float) -> np.ndarray:
        return _gls(poses, gains, p, m + fixture_mass_kg, known, fit_offsets, g_m_s2).theta[:3] / m

    # calibration (K) term: along the eigenvectors of each axis' parameter covariance
    cov_k = np.zeros((3, 3))
    for ax, g in gains.items():
        vals, vecs = np.linalg.eigh(np.asarray(g.covariance, dtype=float) * g.student_factor())
        for val, vec in zip(vals, vecs.T, strict=True):
            if val <= 0:
                continue
            step = np.sqrt(val) * vec
            col = (cog_with({**params, ax: params[ax] + step}, dut_mass_kg)
                   - cog_with({**params, ax: params[ax] - step}, dut_mass_kg)) / 2.0
            cov_k += np.outer(col, col)
    cov_m = np.zeros((3, 3))
    if u_dut_mass_kg > 0:
        col = (cog_with(params, dut_mass_kg + u_dut_mass_kg) - cog_with(params, dut_mass_kg - u_dut_mass_kg)) / 2.0
        cov_m = np.outer(col, col)
    outside = []
    for ax in sol.axes:
        lo, hi = gains[ax].torque_range_nm
        xs = sol.x_nm[sol.axis_of == ax]
        margin = 0.1 * (hi - lo)
        if np.any(xs < lo - margin) or np.any(xs > hi + margin):
            outside.append(f"A{ax}")
    offsets = {f"A{ax}": v for ax, v in sol.offsets_nm.items()}
    parts = {"noise": cov_noise, "calibration": cov_k, "mass": cov_m}
    return CogFit(cog, cov_noise + cov_k + cov_m, parts, offsets, resid, chi2_red, len(sol.b), fit_offsets,
                  tuple(outside))


def kuka_rotation(abc_deg: Sequence[float]) -> np.ndarray:
    """R = Rz(A)·Ry(B)·Rx(C) of KUKA angles (deg), intrinsic Z-Y-X: the columns are the frame's axes in the parent
    frame (``kinematics.kuka_abc_deg`` is its inverse)."""
    return Rotation.from_euler("ZYX", np.asarray(abc_deg, dtype=float), degrees=True).as_matrix()


def to_dut_frame(cog_flange_m: np.ndarray, cov_flange_m2: np.ndarray, origin_flange_m: Sequence[float],
                 abc_deg: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """CoG and its covariance in the DuT frame: c_DuT = Rᵀ (c − o), Σ_DuT = Rᵀ Σ R."""
    rot = kuka_rotation(abc_deg)
    c = rot.T @ (np.asarray(cog_flange_m, dtype=float) - np.asarray(origin_flange_m, dtype=float))
    return c, rot.T @ cov_flange_m2 @ rot


# ---------------------------------------------------------------------------------------------------------------------
# The torsional calibration campaign: bias per pose and K per axis from loads of known position
# ---------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseMean:
    """Mean torque A1..A6 of one pose (Nm, NaN where not traced) and the standard error of each mean."""

    torque_nm: tuple[float, ...]
    sigma_nm: tuple[float, ...]


@dataclass(frozen=True)
class TorsionalPoint:
    """One loaded point of the campaign: the load beyond the MPA (mass kg, CoG in the flange frame m) and its mean
    torques in every pose of the scheme (by pose name)."""

    mass_kg: float
    cog_flange_m: tuple[float, float, float]
    poses: dict[str, PoseMean]


@dataclass(frozen=True)
class TorsionalFit:
    """Result of the torsional calibration: bias per pose (Nm, standard uncertainty), K per axis with the
    evaluation of every gain model, and the held-out residuals (Nm) of the chosen ones."""

    bias: dict[str, PoseMean]
    gains: dict[int, AxisGain]
    evaluations: dict[int, dict]
    heldout_nm: dict[int, np.ndarray]


def fit_torsional(poses: Sequence[CogPose], bias: dict[str, PoseMean], points: Sequence[TorsionalPoint],
                  axes: Sequence[int] = COG_AXES, g_m_s2: float = kin.G_PAPER_M_S2) -> TorsionalFit:
    """Per-axis K from loads of known mass and position measured in every pose, against the bare reading (MPA
    only) of the same pose: r = reading − bias, x = Y(q)·[m, m·c] (the gravity regressor), r = K(x) fitted per axis
    over all points and poses, the gain model chosen by leave-one-point-out error (:func:`select_gain`)."""
    names = [p.name for p in poses]
    missing = [n for n in names if n not in bias]
    if missing:
        raise DataError(f"torsional calibration: no bare (MPA only) reading in pose(s) {', '.join(missing)}")
    xs: dict[int, list[float]] = {ax: [] for ax in axes}
    rs: dict[int, list[float]] = {ax: [] for ax in axes}
    ss: dict[int, list[float]] = {ax: [] for ax in axes}
    grp: dict[int, list[int]] = {ax: [] for ax in axes}
    for k, pt in enumerate(points):
        if not pt.mass_kg > 0:
            raise DataError(f"torsional point #{k + 1}: mass must be > 0 kg (the bias point is separate)")
        theta = pt.mass_kg * np.array([1.0, *pt.cog_flange_m])
        for pose in poses:
            if pose.name not in pt.poses:
                raise DataError(f"torsional point #{k + 1}: not measured in pose {pose.name}")
            x = kin.gravity_regressor(pose.q_deg, g_m_s2) @ theta
            m, b = pt.poses[pose.name], bias[pose.name]
            for ax in axes:
                r = m.torque_nm[ax - 1] - b.torque_nm[ax - 1]
                if not np.isfinite(r):
                    continue
                xs[ax].append(float(x[ax - 1]))
                rs[ax].append(float(r))
                s = np.hypot(m.sigma_nm[ax - 1], b.sigma_nm[ax - 1])
                ss[ax].append(float(s) if np.isfinite(s) and s > 0 else 1.0)
                grp[ax].append(k)
    gains, evaluations, heldout = {}, {}, {}
    for ax in axes:
        if not xs[ax]:
            continue
        x, r, s, g = (np.array(v) for v in (xs[ax], rs[ax], ss[ax], grp[ax]))
        gain, ev = select_gain(ax, x, r, s, g)
        gains[ax] = gain
        evaluations[ax] = ev
        heldout[ax] = fit_gain(ax, x, r, s, g, gain.model, ev["point_offsets"])[1]
    if not gains:
        raise DataError("torsional calibration: no axis A3..A6 was traced")
    return TorsionalFit(dict(bias), gains, evaluations, heldout)
