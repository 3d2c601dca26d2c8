"""Per-axis gain K of the payload torque: the torsional section of CAL.json, issue #14.

The bias-corrected reading r of one axis (A3..A6) is a function K(x) of the true payload torque x. The gain models
(polynomial like eq. 19, saturating like eq. 20) are fitted per axis on the torsional campaign's points
(:func:`fit_gain`), one chosen and validated by leaving out whole points (:func:`select_gain`). :class:`AxisGain`
holds the chosen K with its covariance, the scatter of a mounting, and the candidate models for the model-form part
of the slope's uncertainty; it reads and writes its CAL.json entry.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from rgse_daemon.errors import DataError

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
