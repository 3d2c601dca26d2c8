"""The operating-point check: does the DuT lie where the calibration campaign put its loads?

Not a box: the DuT's (M_A3, M_A5) is also measured against the nearest calibrated configuration (each axis
normalised to the campaign's largest torque on it, :meth:`Envelope.nearest`): a DuT in the gap between the mass stack
and the torque rows lies inside the box but far from every point, and is "outside" (wider U, a warning).

A calibration is validated on its own load configurations. A DuT whose per-axis torques or A3/A5 torque ratio lie
outside what the campaign covered is an extrapolation: the models' curves may diverge there and held-out residuals
say nothing about it. Each coordinate's excess is measured as a fraction of the campaign's span in it:

* inside (excess ≤ :data:`INSIDE_TOLERANCE`): a normal result;
* outside by a margin (up to ``limit``): the result carries a warning and U is widened by the spread of the
  admissible models there (:mod:`rgse_daemon.pipeline.inline`);
* far outside (beyond ``limit``, default :data:`DEFAULT_LIMIT`): refused.

The torque ranges start at 0 Nm: the zero-load point is a calibration point (eq. 21 maps M = 0 to 0 for every K).
They are magnitudes in the direction the campaign's loads pulled (:attr:`Envelope.sign`): a DuT whose torque has the
other sign lies below 0, outside.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rgse_daemon.errors import DataError

#: Excess (fraction of the span) still counted as inside.
INSIDE_TOLERANCE = 0.05
#: Excess (fraction of the span) beyond which a measurement is refused unless configured otherwise.
DEFAULT_LIMIT = 0.5
#: Distance to the nearest calibrated configuration (per axis a fraction of the campaign's largest torque on it)
#: still counted as inside: about half the spacing of Table 1's torque rows (A3 0.1, A5 0.17 of the range apart);
#: the mass stack's points lie 0.06 apart. Beyond it, up to the limit, "outside"; beyond the limit, refused. The
#: middle of the gap between the mass stack (A5 ≤ 0.84 kNm) and the torque rows (A5 ≥ 1.8 kNm) lies ~0.23 away.
POINT_INSIDE = 0.12
#: The smallest span of a coordinate, as a fraction of its upper end (a campaign of one lever has a tiny ratio span).
MIN_SPAN_FRACTION = 0.1


class OperatingPointError(DataError):
    """The DuT lies far outside the calibrated envelope: the measurement is refused."""


@dataclass(frozen=True)
class Envelope:
    """What the campaign covered: |M_A3|, |M_A5| (normalised, Nm) and the ratio |M_A5|/|M_A3| of its loaded points."""

    torque_a3_nm: tuple[float, float]
    torque_a5_nm: tuple[float, float]
    ratio_a5_a3: tuple[float, float]
    sign: tuple[float, float] | None = None
    """The sign (±1) of the campaign's loaded A3 and A5 torques (normalised); None if they had both signs, and in
    files written before it."""
    points_nm: tuple[tuple[float, float], ...] | None = None
    """The calibrated configurations: each point's normalised (M_A3, M_A5), signed, the zero point included; None in
    files written before it (then only the box is checked)."""

    @classmethod
    def from_torques(cls, torque_a3_nm: np.ndarray, torque_a5_nm: np.ndarray) -> Envelope:
        s3, s5 = np.asarray(torque_a3_nm, float), np.asarray(torque_a5_nm, float)
        a3, a5 = np.abs(s3), np.abs(s5)
        loaded = a3 > 0
        if not loaded.any():
            raise DataError("operating envelope: the campaign has no loaded point")
        ratio = a5[loaded] / a3[loaded]
        signs = [np.unique(np.sign(s[loaded & (s != 0)])) for s in (s3, s5)]
        sign = (float(signs[0][0]), float(signs[1][0])) if all(len(x) == 1 for x in signs) else None  # else mixed
        points = tuple((float(x3), float(x5)) for x3, x5 in zip(s3, s5, strict=True))
        return cls((0.0, float(a3.max())), (0.0, float(a5.max())), (float(ratio.min()), float(ratio.max())), sign,
                   points)

    def to_dict(self) -> dict[str, Any]:
        return {"torque_a3_nm": list(self.torque_a3_nm), "torque_a5_nm": list(self.torque_a5_nm),
                "ratio_a5_a3": list(self.ratio_a5_a3), **({} if self.sign is None else {"sign": list(self.sign)}),
                **({} if self.points_nm is None else {"points_nm": [list(p) for p in self.points_nm]})}

    def nearest(self, torque_a3_nm: float, torque_a5_nm: float) -> float:
        """Distance from (M_A3, M_A5) to the nearest calibrated configuration, each axis as a fraction of the
        campaign's largest torque on it (:data:`POINT_INSIDE` and the limit apply to it); 0 without points."""
        if not self.points_nm:
            return 0.0
        p = np.asarray(self.points_nm, float)
        x = np.array([float(torque_a3_nm), float(torque_a5_nm)])
        if self.sign is None:  # loads of both signs: magnitudes, as the box
            p, x = np.abs(p), np.abs(x)
        scale = np.maximum(np.abs(p).max(axis=0), 1e-9)
        d = (p - x) / scale
        return float(np.sqrt((d**2).sum(axis=1)).min())

    def neighbour_distances(self) -> np.ndarray:
        """Each calibrated configuration's distance to the nearest *other* one, as :meth:`nearest` measures it: how
        far a held-out configuration lay from what the rest calibrated. Empty without points."""
        if not self.points_nm or len(self.points_nm) < 2:
            return np.zeros(0)
        p = np.asarray(self.points_nm, float)
        if self.sign is None:
            p = np.abs(p)
        d = (p[:, None, :] - p[None, :, :]) / np.maximum(np.abs(p).max(axis=0), 1e-9)
        dist = np.sqrt((d**2).sum(axis=2))
        np.fill_diagonal(dist, np.inf)
        return dist.min(axis=1)

    @classmethod
    def from_dict(cls, d: Any) -> Envelope:
        try:
            vals = {k: tuple(float(v) for v in d[k]) for k in ("torque_a3_nm", "torque_a5_nm", "ratio_a5_a3")}
            sign = None if d.get("sign") is None else tuple(float(v) for v in d["sign"])
            points = None if d.get("points_nm") is None else tuple((float(a), float(b)) for a, b in d["points_nm"])
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise DataError(f"operating envelope: malformed {d!r}: {exc}") from exc
        if any(len(v) != 2 or not all(np.isfinite(v)) or v[0] > v[1] for v in vals.values()):
            raise DataError(f"operating envelope: every entry must be a finite [low, high], got {d!r}")
        if sign is not None and (len(sign) != 2 or any(v not in (-1.0, 1.0) for v in sign)):
            raise DataError(f"operating envelope: sign must be two of ±1, got {d['sign']!r}")
        if points is not None and not (points and np.all(np.isfinite(points))):
            raise DataError(f"operating envelope: points_nm must be finite (M_A3, M_A5) pairs, got {d['points_nm']!r}")
        return cls(**vals, sign=sign, points_nm=points)  # type: ignore[arg-type]


@dataclass(frozen=True)
class EnvelopeCheck:
    status: str
    """``inside``, ``outside`` or ``refused``."""
    excess: float
    """The largest excess over the three coordinates, as a fraction of the campaign's span."""
    detail: str


def check(env: Envelope, torque_a3_nm: float, torque_a5_nm: float, limit: float = DEFAULT_LIMIT) -> EnvelopeCheck:
    """Where the DuT's normalised torques lie relative to the envelope (see the module docstring), each taken in the
    direction of the campaign's loads (:attr:`Envelope.sign`): a torque of the other sign lies below the zero-load
    point, outside (a sign-flipped channel, or no load where one was expected)."""
    if not (np.isfinite(limit) and limit >= INSIDE_TOLERANCE):
        raise DataError(f"envelope limit must be a finite fraction >= {INSIDE_TOLERANCE}, got {limit}")
    if env.sign is None:  # a file without the campaign's signs: magnitudes only
        a3, a5 = abs(float(torque_a3_nm)), abs(float(torque_a5_nm))
    else:
        a3, a5 = env.sign[0] * float(torque_a3_nm), env.sign[1] * float(torque_a5_nm)
    ratio = a5 / a3 if a3 > 0 else float("inf")
    worst, parts = 0.0, []
    for name, x, (lo, hi) in (("A3 torque", a3, env.torque_a3_nm), ("A5 torque", a5, env.torque_a5_nm),
                              ("A5/A3 torque ratio", ratio, env.ratio_a5_a3)):
        span = max(hi - lo, MIN_SPAN_FRACTION * abs(hi), 1e-9)
        excess = max(lo - x, x - hi, 0.0) / span
        if excess > INSIDE_TOLERANCE:
            parts.append(f"{name} {x:.4g} is {100 * excess:.0f} % of the span outside {lo:.4g}..{hi:.4g}")
        worst = max(worst, excess)
    gap = env.nearest(torque_a3_nm, torque_a5_nm)
    if gap > POINT_INSIDE:
        parts.append(f"(M_A3, M_A5) = ({float(torque_a3_nm):.4g}, {float(torque_a5_nm):.4g}) Nm is "
                     f"{100 * gap:.0f} % of the torque range from the nearest calibrated configuration (inside: "
                     f"{100 * POINT_INSIDE:.0f} %): between the calibration's points, not at one")
    if worst <= INSIDE_TOLERANCE and gap <= POINT_INSIDE:
        return EnvelopeCheck("inside", max(worst, gap), "")
    worst = max(worst, gap)
    status = "refused" if worst > limit else "outside"
    return EnvelopeCheck(status, worst, "; ".join(parts) + f" (limit {100 * limit:.0f} %)")

