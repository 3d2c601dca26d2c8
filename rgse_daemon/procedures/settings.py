"""The parameters of a run (``[measurement]`` of the config): what the measurement run and the campaign share."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from rgse_daemon import kinematics as kin
from rgse_daemon import robots
from rgse_daemon.config import Config
from rgse_daemon.pipeline.stopping import MIN_LOOPS, StopRule
from rgse_daemon.pipeline.thermal import DRIFT_PRIOR_PER_K


@dataclass(frozen=True)
class RunSettings:
    """The parameters of a run, from ``[measurement]`` of the config; tests and the demo shorten them."""

    robot: str
    loops: int
    settle_s: float
    trace_period_s: float
    trace_samples: int
    brake_release_deg: float
    warmup_cycles: int
    warmup_amplitude_deg: float
    fixture_mass_kg: float
    payload_lever_max_m: float
    speed_limit_mm_s: float
    program_timeout_s: float
    trace_timeout_s: float
    warmup_until_steady: bool = False
    warmup_steady_k: float = 1.0
    warmup_steady_window_s: float = 300.0
    warmup_max_s: float = 2400.0
    min_loops: int = 3
    stop_loop_share: float = 0.0
    """0 (with no ``stop_target_U_kg``): always ``loops`` loops; the config's default is 0.2."""
    stop_target_U_kg: float | None = None
    replacement_loops: int = 0
    """Loops beyond ``loops`` that may replace loops set aside (the config's default is 3)."""
    drift_prior_per_k: float = DRIFT_PRIOR_PER_K
    """``measurement.drift_prior_per_k``: the outer bound on |β| (1/K) U carries where β is not applied (the offline
    ``rgse mass --drift-prior`` reproduces a result with it)."""
    g_m_s2: float = kin.G_PAPER_M_S2
    lever_difference_m: float = field(default_factory=lambda: robots.active().lever_difference_m)
    meas_pose_deg: tuple[float, ...] = field(default_factory=lambda: tuple(float(v) for v in kin.measurement_pose()))
    time_scale: float = 1.0
    """``controller.time_scale``: 1 on a real KR C4 (the trace's wall time is its configured time divided by it)."""
    identity: dict[str, str] | None = field(default=None, hash=False)
    """Who and what is measured (interfaces §4.3 ``identity``), published with the result; None: not given."""

    @classmethod
    def from_config(cls, cfg: Config, **overrides: Any) -> RunSettings:
        """The run's parameters; durations in the robot's time (settling, the warm-up's windows) are divided by
        ``controller.time_scale`` (1 on a real KR C4, X against ``rgse sim --time-scale X``)."""
        ms = cfg.measurement
        scale = cfg.controller.time_scale
        base = cls(
            robot=cfg.robot.name,
            loops=ms.loops,
            settle_s=ms.settle_s / scale,
            trace_period_s=ms.trace_period_s,
            trace_samples=ms.trace_samples,
            brake_release_deg=ms.brake_release_deg,
            warmup_cycles=ms.warmup_cycles,
            warmup_amplitude_deg=ms.warmup_amplitude_deg,
            fixture_mass_kg=ms.fixture_mass_kg,
            payload_lever_max_m=ms.payload_lever_max_m,
            speed_limit_mm_s=cfg.limits.t1_speed_mm_s,
            program_timeout_s=ms.program_timeout_s,
            trace_timeout_s=ms.trace_timeout_s,
            warmup_until_steady=ms.warmup_until_steady,
            warmup_steady_k=ms.warmup_steady_k,
            warmup_steady_window_s=ms.warmup_steady_window_s / scale,
            warmup_max_s=ms.warmup_max_s / scale,
            min_loops=ms.min_loops,
            stop_loop_share=ms.stop_loop_share,
            stop_target_U_kg=ms.stop_target_U_kg,
            replacement_loops=ms.replacement_loops,
            drift_prior_per_k=ms.drift_prior_per_k,
            lever_difference_m=cfg.robot_model.lever_difference_m,
            meas_pose_deg=tuple(float(v) for v in kin.measurement_pose(robot=cfg.robot_model)),
            time_scale=scale,
        )
        return replace(base, **overrides)

    @property
    def stop_rule(self) -> StopRule:
        return StopRule(self.loops, max(self.min_loops, MIN_LOOPS), self.stop_loop_share, self.stop_target_U_kg,
                        replacements=self.replacement_loops)

    @property
    def trace_time_s(self) -> float:
        return self.trace_samples * self.trace_period_s

    @property
    def trace_wall_s(self) -> float:
        """How long a trace records in wall time (its configured time on a real KR C4)."""
        return self.trace_time_s / self.time_scale

    def to_json(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}
