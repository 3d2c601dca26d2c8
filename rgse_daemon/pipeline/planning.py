"""The campaign planner (issue 35, item 3): which calibration loads cover the DuTs a lab will measure, and what the
campaign will cost in robot time and give in U — a *prediction*, before anything is mounted.

The DuT's operating point in the measurement pose (paper eq. 3/4, Table 1's levers): a load of mass ``m`` whose CoG
lies ``l_A5`` along the flange axis from A5 gives

    M_A5 = g·m·l_A5,    M_A3 = g·m·(l_A5 + Δr),    Δr = D4 (1.025 m, the A3–A5 lever difference).

The candidates are what the equipment can mount (:class:`Equipment`, the paper's §2.4.2–2.4.3): the zero point (the
empty MPA), stacks of 1…10 calibration bodies on the MPA, and the test adapter with 1…10 bodies on its rail at
0.60…1.50 m from A5 — each within the robot's load diagram. The planner starts from the zero point and adds, one at
a time, the candidate that covers the most DuT operating points not yet covered, until every one is
:func:`covered`: inside the calibration's envelope (:mod:`rgse_daemon.pipeline.envelope`, as the in-line mass checks
it: in the box and near a calibrated point), with the envelope's nearest-point distance :data:`NODE_MARGIN` below
its "inside" bound so that the DuTs between the planned-for ones are inside too, *and* within ``max_distance`` of a
calibrated point, the distance being the torque difference per axis over the DuT range's largest torque on that
axis. Then it adds evenly spread body stacks until the campaign has
``min_loaded`` loaded points (a model selection needs some points to hold out).

The expected torques stand in for the measured ones (the drives read them through a gain K ≈ 0.86–1.13, Table 1,
which is monotone: the same for the calibration and the DuT).

**Robot time** (:class:`TimeModel`, each default with its source) = the initial warm-up + one re-warm-up per later
load change + points × loops × one loop. Load changes are the operator's time: the robot stands; they are reported
apart as campaign time, not robot time.

**U** (:func:`predicted_U_kg`) is a stated simple model, not a fit: the scatter a new mounting adds (Table 1's, about
±1 kg per point) holds a DuT's U whatever the loops; the held-out residual the reproducibility is estimated from
holds the curve's error at the left-out point too, so ``u_rep² = σ_mount²·(1 + p/N)`` for ``N`` loaded points and a
curve of ``p`` parameters (the mean leverage of a least-squares fit is p/N); plus the DuT's loop term and the rest
of the budget (model form and curve excess over the interior configurations, reference, g) as issue 35's demo
budget had it. Only inside the envelope: outside it the budget widens by the admissible models' spread.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.errors import DataError
from rgse_daemon.pipeline import envelope as env_mod

#: The default covering distance: the nearest calibrated point within 15 % of the DuT range's largest torque per
#: axis (for 50-250 kg at 0.40-0.90 m: 708 Nm on A3, the A3 torque of about 2.6 bodies on the MPA).
DEFAULT_MAX_DISTANCE = 0.15
#: The envelope's nearest-point distance (:meth:`Envelope.nearest`, "inside" up to ``envelope.POINT_INSIDE``) must
#: hold between the DuTs planned for (the nodes of a :data:`GRID_N` grid) too, so at the nodes it is held this much
#: below: between the nodes of 50-250 kg × 0.40-0.90 m it grew by up to 0.008 over the nodes' (41 × 41 grid).
NODE_MARGIN = 0.01
#: The fewest loaded points a plan has (the demo's campaign has 10; the rehearsal's 7 passes the auto method).
DEFAULT_MIN_LOADED = 6
#: The DuT grid per axis when a range is given (mass × lever). Between its nodes the distance to the nearest
#: calibrated point can exceed the bound a little (0.158 for 0.15 on a 41 × 41 grid over 50-250 kg, 0.40-0.90 m).
GRID_N = 9
#: The paper's campaign: 14 points, "estimated to be 480 min" of measurement time for the torque data (§2.4.4).
PAPER_CAMPAIGN_MIN = 480.0
PAPER_CAMPAIGN_POINTS = 14


@dataclass(frozen=True)
class Equipment:
    """The calibration equipment (procedures/calibration.py's constants; paper §2.4.2–2.4.3, Table 1, Table A1)."""

    cb_mass_kg: float
    """One calibration body."""
    zero_lever_a5_m: float
    """The empty MPA's lever to A5 (the zero point)."""
    stack_lever_a5_m: float
    stack_step_m: float
    """The A5 lever of ``n`` stacked bodies: ``stack_lever_a5_m + stack_step_m·n``."""
    ta_mass_kg: float
    ta_torque_a5_nm: float
    """The test adapter and its A5 torque in the measurement pose."""
    max_bodies: int = 10
    """At most this many bodies on the MPA or the adapter."""
    rail_a5_m: tuple[float, float] = (0.60, 1.50)
    """Where the bodies' common CoG can sit on the adapter's rail (m from A5; the paper's reach is 1.48 m)."""
    rail_step_m: float = 0.05
    lever_difference_m: float = field(default_factory=lambda: robots.active().lever_difference_m)
    g_m_s2: float = kin.G_PAPER_M_S2
    max_payload_kg: float = field(default_factory=lambda: robots.active().max_payload_kg)
    max_a5_torque_nm: float = field(default_factory=lambda: robots.active().max_a5_torque_nm)
    """The load diagram the plan keeps to: by default the active robot's (:mod:`rgse_daemon.robots`; the KR 500
    R2830's 611 kg, 3330 Nm on A5); a lab's ``[limits]`` may be tighter."""


@dataclass(frozen=True)
class PlannedPoint:
    """One load configuration: ``kind`` zero/mass/torque, ``n_cb`` bodies (on the adapter's rail at
    ``cb_lever_a5_m`` for a torque point), the combined load's mass and levers, and its loops."""

    kind: str
    n_cb: int
    mass_kg: float
    lever_a3_m: float
    lever_a5_m: float
    cb_lever_a5_m: float | None
    loops: int = 3

    def torques_nm(self, g_m_s2: float) -> tuple[float, float]:
        """Expected (M_A3, M_A5), Nm, normalised (the empty MPA's bias removed)."""
        return g_m_s2 * self.mass_kg * self.lever_a3_m, g_m_s2 * self.mass_kg * self.lever_a5_m

    @property
    def label(self) -> str:
        if self.kind == "zero":
            return "empty MPA"
        if self.kind == "mass":
            return f"{self.n_cb} bod{'y' if self.n_cb == 1 else 'ies'} on the MPA"
        return f"test adapter + {self.n_cb} bodies at {self.cb_lever_a5_m:.2f} m from A5"


@dataclass(frozen=True)
class TimeModel:
    """The campaign's time per part, s of the real robot. Every default is a measured or configured figure."""

    loop_motion_s: float = 53.0
    """A loop's brake-release move: the measured loop (below) less settling and recording."""
    settle_s: float = 4.0
    """``measurement.settle_s`` (the paper's 2 × 2 s)."""
    record_s: float = 12.0
    """``trace_samples`` × ``trace_period_s`` (1000 × 12 ms)."""
    warmup_initial_s: float = 2400.0
    """The first warm-up runs until A3/A5 are steady, at most ``measurement.warmup_max_s`` (2400 s): the bound."""
    warmup_initial_min_s: float = 300.0
    """... and at least ``warmup_steady_window_s`` (300 s) of motion: the least it takes."""
    rewarm_s: float = 300.0
    """After a load change the campaign warms up again if A3/A5 cooled by more than ``warmup_steady_k`` (1 K); a
    warm-up ends only after ``warmup_steady_window_s`` (300 s) of steady motion: assumed at every load change."""
    load_change_s: float = 600.0
    """Mounting a load and confirming it (the operator; the robot stands): an assumption, not measured."""

    @property
    def loop_s(self) -> float:
        """One loop's robot time: 69 s measured (issue 35: a 10-loop mass run 11.4–11.6 min, ``rgse demo``;
        bench/robot_time.py x50: 65.7 s with 10 loops)."""
        return self.loop_motion_s + self.settle_s + self.record_s


@dataclass(frozen=True)
class CampaignTime:
    """The predicted campaign time (s) by part; ``robot_s`` is their robot part, ``campaign_s`` adds load changes."""

    loops: int
    loop_s: float
    loops_s: float
    """What the campaign result's ``robot_time_s`` counts (the loops' motion, settling, recording)."""
    warmup_initial_s: float
    warmup_initial_min_s: float
    rewarm_s: float
    load_changes_s: float

    @property
    def robot_s(self) -> float:
        """The bound: the first warm-up at its most."""
        return self.loops_s + self.warmup_initial_s + self.rewarm_s

    @property
    def robot_min_s(self) -> float:
        """The first warm-up at its least."""
        return self.loops_s + self.warmup_initial_min_s + self.rewarm_s

    @property
    def campaign_s(self) -> float:
        return self.robot_s + self.load_changes_s


@dataclass(frozen=True)
class UModel:
    """The stated U model (module docstring)."""

    sigma_mount_kg: float = 1.06
    """The scatter a new mounting adds, kg: issue 35's reproducibility term 1.21 kg on the demo's 10 loaded points
    (Table 1-like scatter) over √(1 + 3/10); Table 1 shows about ±1 kg per point."""
    curve_params: int = 3
    """Parameters of the calibration curve per axis (p)."""
    u_loops_kg: float = 0.065
    """The DuT's loop term with 3 loops (issue 35's table)."""
    u_other_kg: float = 0.28
    """The rest of the budget (model form, curve excess, reference, g): issue 35's table, u = 1.244 kg with 3 loops
    less the reproducibility 1.21 kg and the loop term 0.065 kg in quadrature."""
    k: float = 2.0


@dataclass(frozen=True)
class Coverage:
    """Per DuT operating point: the envelope's verdict, its excess and the normalised distance to the nearest
    calibrated point."""

    mass_kg: np.ndarray
    lever_a5_m: np.ndarray
    status: list[str]
    excess: np.ndarray
    distance: np.ndarray
    max_distance: float
    gap: np.ndarray
    """The envelope's own distance to the nearest calibrated point (:meth:`Envelope.nearest`: per axis a fraction
    of the campaign's largest torque), inf without a loaded point."""
    max_gap: float = env_mod.POINT_INSIDE - NODE_MARGIN
    """The bound on ``gap`` at the DuTs planned for (:data:`NODE_MARGIN` below the envelope's inside)."""

    @property
    def covered(self) -> np.ndarray:
        return (np.array([s == "inside" for s in self.status]) & (self.distance <= self.max_distance)
                & (self.gap <= self.max_gap))


@dataclass(frozen=True)
class Plan:
    points: list[PlannedPoint]
    coverage: Coverage
    time: CampaignTime
    U_kg: np.ndarray
    """Predicted U (k = 2) at each DuT operating point of ``coverage``."""
    assumptions: list[str] = field(default_factory=list)

    @property
    def loaded(self) -> int:
        return sum(p.mass_kg > 0 for p in self.points)

    @property
    def uncovered(self) -> list[str]:
        """The DuTs the plan does not cover, each with why (envelope verdict, distance to the nearest point)."""
        c = self.coverage
        return [f"{c.mass_kg[i]:g} kg at {c.lever_a5_m[i]:.3g} m from A5: envelope {c.status[i]} "
                f"(excess {100 * min(c.excess[i], 99.99):.0f} % of the span), nearest calibrated point "
                f"{c.distance[i]:.2f} of the range away (bound {c.max_distance:g}), "
                f"{min(c.gap[i], 99.99):.2f} of the calibration's torques (bound {c.max_gap:.2g})"
                for i in np.flatnonzero(~c.covered)]


# --- input -----------------------------------------------------------------------------------------------------
def check_range(name: str, lo: float, hi: float, unit: str) -> None:
    """A range ``name`` (the argument's name) of finite, non-negative numbers with lo <= hi; :class:`DataError`."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise DataError(f"{name} {lo:g} {hi:g}: must be finite numbers ({unit})")
    if lo < 0 or hi < 0:
        raise DataError(f"{name} {lo:g} {hi:g}: must not be negative ({unit})")
    if lo > hi:
        raise DataError(f"{name} {lo:g} {hi:g}: the minimum is above the maximum")


def dut_targets(mass_kg: Sequence[float], lever_a5_m: Sequence[float], eq: Equipment,
                names: tuple[str, str] = ("--mass", "--lever-a5")) -> None:
    """Refuse DuTs the robot may not carry: mass > 0 and within the payload, A5 torque within the load diagram;
    the message names the argument (``names``)."""
    m, lv = np.asarray(mass_kg, float), np.asarray(lever_a5_m, float)
    if m.shape != lv.shape or m.size == 0:
        raise DataError("no DuT to plan for")
    if not (np.isfinite(m).all() and np.isfinite(lv).all()):
        raise DataError(f"{names[0]}/{names[1]}: must be finite numbers")
    if (m <= 0).any():
        raise DataError(f"{names[0]}: a DuT's mass must be > 0 kg, got {float(m.min()):g}")
    if (lv <= 0).any():
        raise DataError(f"{names[1]}: a CoG lever to A5 must be > 0 m, got {float(lv.min()):g}")
    if (m > eq.max_payload_kg).any():
        raise DataError(f"{names[0]}: {float(m.max()):g} kg is beyond the robot's load diagram "
                        f"({eq.max_payload_kg:g} kg payload)")
    a5 = eq.g_m_s2 * m * lv
    if (a5 > eq.max_a5_torque_nm).any():
        i = int(np.argmax(a5))
        raise DataError(f"{names[0]}/{names[1]}: {m[i]:g} kg at {lv[i]:g} m from A5 gives {a5[i]:.0f} Nm on A5, "
                        f"beyond the robot's load diagram ({eq.max_a5_torque_nm:g} Nm)")


def grid(mass_kg: tuple[float, float], lever_a5_m: tuple[float, float], eq: Equipment, n: int = GRID_N
         ) -> tuple[np.ndarray, np.ndarray]:
    """A mass × lever grid over the range (both refused as :func:`check_range` and :func:`dut_targets` say)."""
    check_range("--mass", *mass_kg, "kg")
    check_range("--lever-a5", *lever_a5_m, "m")
    mm, ll = np.meshgrid(np.linspace(*mass_kg, n), np.linspace(*lever_a5_m, n), indexing="ij")
    dut_targets(mm.ravel(), ll.ravel(), eq)
    return mm.ravel(), ll.ravel()


# --- candidates ------------------------------------------------------------------------------------------------
def zero_point(eq: Equipment, loops: int) -> PlannedPoint:
    return PlannedPoint("zero", 0, 0.0, eq.zero_lever_a5_m + eq.lever_difference_m, eq.zero_lever_a5_m, None, loops)


def stack_point(eq: Equipment, n_cb: int, loops: int) -> PlannedPoint:
    lever = eq.stack_lever_a5_m + eq.stack_step_m * n_cb
    return PlannedPoint("mass", n_cb, eq.cb_mass_kg * n_cb, lever + eq.lever_difference_m, lever, None, loops)


def adapter_point(eq: Equipment, n_cb: int, cb_lever_a5_m: float, loops: int) -> PlannedPoint:
    """The test adapter with ``n_cb`` bodies at ``cb_lever_a5_m`` (procedures.calibration.torque_point's sum)."""
    ta_lever = eq.ta_torque_a5_nm / (eq.g_m_s2 * eq.ta_mass_kg)
    mass = eq.ta_mass_kg + eq.cb_mass_kg * n_cb
    lever = (eq.ta_mass_kg * ta_lever + eq.cb_mass_kg * n_cb * cb_lever_a5_m) / mass
    return PlannedPoint("torque", n_cb, mass, lever + eq.lever_difference_m, lever, cb_lever_a5_m, loops)


def candidates(eq: Equipment, loops: int) -> list[PlannedPoint]:
    """Every load the equipment can mount within the load diagram (stacks, then adapter loads by rail position)."""
    out = [stack_point(eq, n, loops) for n in range(1, eq.max_bodies + 1)]
    steps = round((eq.rail_a5_m[1] - eq.rail_a5_m[0]) / eq.rail_step_m)
    for lever in (round(eq.rail_a5_m[0] + k * eq.rail_step_m, 4) for k in range(steps + 1)):
        out += [adapter_point(eq, n, lever, loops) for n in range(1, eq.max_bodies + 1)]
    return [p for p in out if p.mass_kg <= eq.max_payload_kg and p.torques_nm(eq.g_m_s2)[1] <= eq.max_a5_torque_nm]


# --- coverage --------------------------------------------------------------------------------------------------
def dut_torques_nm(mass_kg: np.ndarray, lever_a5_m: np.ndarray, eq: Equipment) -> np.ndarray:
    """(n, 2) expected (M_A3, M_A5) of DuTs, Nm."""
    m, lv = np.asarray(mass_kg, float), np.asarray(lever_a5_m, float)
    return np.column_stack([eq.g_m_s2 * m * (lv + eq.lever_difference_m), eq.g_m_s2 * m * lv])


def covered(points: Sequence[PlannedPoint], mass_kg: np.ndarray, lever_a5_m: np.ndarray, eq: Equipment,
            max_distance: float = DEFAULT_MAX_DISTANCE) -> Coverage:
    """Where each DuT lies relative to the calibration of ``points`` (module docstring): the envelope's verdict
    and the normalised distance to the nearest calibrated point."""
    cal = np.array([p.torques_nm(eq.g_m_s2) for p in points])
    dut = dut_torques_nm(mass_kg, lever_a5_m, eq)
    scale = np.maximum(dut.max(axis=0), 1e-9)
    dist = np.sqrt((((dut[:, None, :] - cal[None, :, :]) / scale) ** 2).sum(axis=2)).min(axis=1)
    if (cal[:, 0] > 0).any():
        env = env_mod.Envelope.from_torques(cal[:, 0], cal[:, 1])
        checks = [env_mod.check(env, a3, a5) for a3, a5 in dut]
        status, excess = [c.status for c in checks], np.array([c.excess for c in checks])
        gap = np.array([env.nearest(a3, a5) for a3, a5 in dut])
    else:
        status, excess = ["refused"] * len(dut), np.full(len(dut), np.inf)
        gap = np.full(len(dut), np.inf)
    return Coverage(np.asarray(mass_kg, float), np.asarray(lever_a5_m, float), status, excess, dist, max_distance,
                    gap)


def _score(cov: Coverage) -> tuple[int, float]:
    """More DuTs covered, then less total excess and distance beyond the bound."""
    beyond = (np.maximum(cov.distance - cov.max_distance, 0.0).sum() + np.minimum(cov.excess, 10.0).sum()
              + np.minimum(np.maximum(cov.gap - cov.max_gap, 0.0), 10.0).sum())
    return int(cov.covered.sum()), -float(beyond)


def plan_points(mass_kg: np.ndarray, lever_a5_m: np.ndarray, eq: Equipment, loops: int = 3,
                max_distance: float = DEFAULT_MAX_DISTANCE, min_loaded: int = DEFAULT_MIN_LOADED
                ) -> list[PlannedPoint]:
    """The points (module docstring): the zero point, greedily the candidate that covers most, then body stacks up
    to ``min_loaded`` loaded points; ordered as a campaign mounts them (zero, stacks up, adapter loads by rail
    position). DuTs the equipment cannot cover stay uncovered (:attr:`Plan.uncovered` says which)."""
    if loops < 1:
        raise DataError(f"--loops-per-point {loops}: must be >= 1")
    if not max_distance > 0:
        raise DataError(f"--max-distance {max_distance:g}: must be > 0")
    chosen = [zero_point(eq, loops)]
    pool = candidates(eq, loops)
    cov = covered(chosen, mass_kg, lever_a5_m, eq, max_distance)
    while not cov.covered.all():
        best = max(pool, key=lambda p: _score(covered([*chosen, p], mass_kg, lever_a5_m, eq, max_distance)))
        new = covered([*chosen, best], mass_kg, lever_a5_m, eq, max_distance)
        if _score(new) <= _score(cov):  # the equipment cannot do better: the plan reports what stays uncovered
            break
        chosen.append(best)
        pool.remove(best)
        cov = new
    stacks = [p for p in pool if p.kind == "mass"]
    while sum(p.mass_kg > 0 for p in chosen) < min_loaded and stacks:
        have = [p.n_cb for p in chosen if p.kind == "mass"] or [0]
        nxt = max(stacks, key=lambda p: min(abs(p.n_cb - n) for n in have))  # the widest gap in the stacks
        chosen.append(nxt)
        stacks.remove(nxt)
    return sorted(chosen, key=lambda p: ({"zero": 0, "mass": 1, "torque": 2}[p.kind], p.cb_lever_a5_m or 0.0,
                                         p.n_cb))


# --- time and U ------------------------------------------------------------------------------------------------
def campaign_time(points: Sequence[PlannedPoint], tm: TimeModel = TimeModel()) -> CampaignTime:
    """The predicted time (:class:`TimeModel`): loops, the first warm-up, a re-warm-up per later load change, and
    the load changes (operator time)."""
    loops = sum(p.loops for p in points)
    n = len(points)
    return CampaignTime(loops, tm.loop_s, loops * tm.loop_s, tm.warmup_initial_s if n else 0.0,
                        tm.warmup_initial_min_s if n else 0.0, max(n - 1, 0) * tm.rewarm_s, n * tm.load_change_s)


def predicted_U_kg(n_loaded: int, um: UModel = UModel()) -> float:
    """U (k = 2) of a DuT inside the envelope of a campaign of ``n_loaded`` loaded points (the stated model)."""
    if n_loaded < 1:
        raise DataError("a U prediction needs a campaign with loaded points")
    u_rep_sq = um.sigma_mount_kg**2 * (1.0 + um.curve_params / n_loaded)
    return um.k * math.sqrt(u_rep_sq + um.u_loops_kg**2 + um.u_other_kg**2)


def plan(mass_kg: np.ndarray, lever_a5_m: np.ndarray, eq: Equipment, *, loops: int = 3,
         max_distance: float = DEFAULT_MAX_DISTANCE, min_loaded: int = DEFAULT_MIN_LOADED,
         tm: TimeModel = TimeModel(), um: UModel = UModel()) -> Plan:
    """Points, coverage, predicted time and U for DuTs (``mass_kg``, ``lever_a5_m`` of each; :func:`grid` for a
    range)."""
    dut_targets(mass_kg, lever_a5_m, eq)
    points = plan_points(np.asarray(mass_kg, float), np.asarray(lever_a5_m, float), eq, loops, max_distance,
                         min_loaded)
    cov = covered(points, mass_kg, lever_a5_m, eq, max_distance)
    n_loaded = sum(p.mass_kg > 0 for p in points)
    U = np.where(cov.covered, predicted_U_kg(n_loaded, um), np.nan)
    assumptions = [
        f"one loop {tm.loop_s:.0f} s of robot time (issue 35: a 10-loop mass run 11.4-11.6 min in rgse demo; "
        f"bench/robot_time.py x50: 65.7 s), loads of any mass alike (the brake-release move is speed-limited at T1)",
        f"{loops} loops per point: the stop rule's minimum (pipeline/stopping.py), which a campaign reaches when the "
        f"robot has an active calibration; a first campaign takes measurement.loops per point unless set to {loops}",
        f"first warm-up {tm.warmup_initial_min_s:.0f}-{tm.warmup_initial_s:.0f} s (until A3/A5 are steady over "
        f"warmup_steady_window_s, at most measurement.warmup_max_s; the robot time is given at the bound)",
        f"a re-warm-up of {tm.rewarm_s:.0f} s (warmup_steady_window_s) after every load change: the least one takes "
        f"(steady motion over the window), assumed enough because a quick change keeps the motors near their "
        f"temperature; not measured on a real KR C4. A change of minutes with the brakes applied cools them more and "
        f"needs longer (the simulator's thermal model: 13 K in 2 min, a re-warm-up of 17-20 min, docs/accuracy.md); "
        f"the campaign's warm-up events show the lab's own figure",
        f"a load change {tm.load_change_s:.0f} s of the operator (robot standing; not robot time): assumed",
        f"U: sigma_mount {um.sigma_mount_kg:g} kg per mounting (issue 35's 1.21 kg reproducibility on 10 loaded "
        f"points, Table 1's ~±1 kg), x sqrt(1 + {um.curve_params}/N) for the curve in the held-out residuals, DuT "
        f"loop term {um.u_loops_kg:g} kg (3 loops), the rest (model form, ...) {um.u_other_kg:g} kg as issue 35's "
        f"budget had it; inside the envelope only: a prediction, not a result",
        "operating points from expected torques g*m*lever (the drives' gain K is monotone: the same for both)",
    ]
    return Plan(points, cov, campaign_time(points, tm), U, assumptions)


# --- the points file -------------------------------------------------------------------------------------------
#: Levers in a points file: 0.1 mm.
FILE_LEVER_DIGITS = 4


def file_lever_a5_m(p: PlannedPoint, eq: Equipment) -> float:
    """The A5 lever a points file gives for ``p``: rounded to :data:`FILE_LEVER_DIGITS`, a torque point's toward the
    middle of the rail, so that the rail position the daemon derives from it (app.campaign_point) stays on the rail
    (rounded to nearest, 10 bodies at 0.60 m came back at 0.59998 m, off the rail)."""
    if p.kind != "torque" or p.cb_lever_a5_m is None:
        return round(p.lever_a5_m, FILE_LEVER_DIGITS)
    q = 10.0**FILE_LEVER_DIGITS
    inward = math.ceil if p.cb_lever_a5_m <= 0.5 * sum(eq.rail_a5_m) else math.floor
    return inward(p.lever_a5_m * q) / q


def points_toml(points: Sequence[PlannedPoint], eq: Equipment, header: Sequence[str] = ()) -> str:
    """A points file as ``rgse run calibrate --points`` reads it (client.types.load_points): ``[[point]]`` with
    kind, mass, levers (:func:`file_lever_a5_m`), and ``bodies`` (ignored by the schema; the daemon derives them
    from the mass)."""
    lines = [f"# {h}" if h else "#" for h in header]
    for p in points:
        lever_a5 = file_lever_a5_m(p, eq)
        lines += ["", "[[point]]", f'kind = "{p.kind}"', f"mass_kg = {round(p.mass_kg, 4)!r}",
                  f"lever_a3_m = {round(lever_a5 + eq.lever_difference_m, FILE_LEVER_DIGITS)!r}",
                  f"lever_a5_m = {lever_a5!r}", f"bodies = {p.n_cb}"]
    return "\n".join(lines) + "\n"
