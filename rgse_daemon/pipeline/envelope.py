"""The operating-point check: does the DuT lie where the calibration campaign put its loads?

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
        return cls((0.0, float(a3.max())), (0.0, float(a5.max())), (float(ratio.min()), float(ratio.max())), sign)

    def to_dict(self) -> dict[str, list[float]]:
        return {"torque_a3_nm": list(self.torque_a3_nm), "torque_a5_nm": list(self.torque_a5_nm),
                "ratio_a5_a3": list(self.ratio_a5_a3), **({} if self.sign is None else {"sign": list(self.sign)})}

    @classmethod
    def from_dict(cls, d: Any) -> Envelope:
        try:
            vals = {k: tuple(float(v) for v in d[k]) for k in ("torque_a3_nm", "torque_a5_nm", "ratio_a5_a3")}
            sign = None if d.get("sign") is None else tuple(float(v) for v in d["sign"])
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise DataError(f"operating envelope: malformed {d!r}: {exc}") from exc
        if any(len(v) != 2 or not all(np.isfinite(v)) or v[0] > v[1] for v in vals.values()):
            raise DataError(f"operating envelope: every entry must be a finite [low, high], got {d!r}")
        if sign is not None and (len(sign) != 2 or any(v not in (-1.0, 1.0) for v in sign)):
            raise DataError(f"operating envelope: sign must be two of ±1, got {d['sign']!r}")
        return cls(**vals, sign=sign)  # type: ignore[arg-type]


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
    if worst <= INSIDE_TOLERANCE:
        return EnvelopeCheck("inside", worst, "")
    status = "refused" if worst > limit else "outside"
    return EnvelopeCheck(status, worst, "; ".join(parts) + f" (limit {100 * limit:.0f} %)")

