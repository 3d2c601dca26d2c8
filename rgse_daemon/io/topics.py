"""The daemon's MQTT topics (interfaces §4) under one prefix: the one place a topic name is built.

The bridge publishes under them, the store recorder stores a result's outbox message under :meth:`Topics.result`,
the operator's client (``rgse status``/``confirm``/``abort``) reads them. :meth:`Topics.of` derives the prefix from
the configuration (the config already dropped a trailing ``/``), so all three agree.
"""

from __future__ import annotations

from dataclasses import dataclass

from rgse_daemon.config import MqttConfig
from rgse_daemon.errors import ConfigError, RgseError

FORBIDDEN_IN_LEVEL = ("/", "+", "#", "\x00")


class MqttError(RgseError):
    """The MQTT bridge was misused (e.g. started twice) or given an unpublishable message or topic level."""


@dataclass(frozen=True)
class Topics:
    """The topics under ``prefix`` (no trailing ``/``)."""

    prefix: str

    def __post_init__(self) -> None:
        if not self.prefix or self.prefix.endswith("/"):
            raise ConfigError(f"mqtt prefix {self.prefix!r}: must be non-empty and not end with '/'")

    @classmethod
    def of(cls, cfg: MqttConfig, robot: str) -> Topics:
        """The topics of a configuration: ``mqtt.prefix``, or ``rgse/<robot name>`` when it is not set."""
        return cls(cfg.prefix or f"rgse/{robot}")

    @property
    def status(self) -> str:
        return f"{self.prefix}/status"

    @property
    def state(self) -> str:
        return f"{self.prefix}/state"

    @property
    def alarm(self) -> str:
        return f"{self.prefix}/alarm"

    @property
    def prompt(self) -> str:
        """The operator prompt a run waits for (retained, QoS 1): a console or client that connects (again) finds
        it; ``{"pending": false}`` once it is answered or the run ended."""
        return f"{self.prefix}/prompt"

    @property
    def commands(self) -> str:
        """The subscription: every verb, one level (so ``cmd/<verb>/reply`` is not ours to read)."""
        return f"{self.prefix}/cmd/+"

    @property
    def results(self) -> str:
        """The subscription to every run's result."""
        return f"{self.prefix}/run/+/result"

    def command(self, verb: str) -> str:
        return f"{self.prefix}/cmd/{verb}"

    def reply(self, verb: str) -> str:
        return f"{self.prefix}/cmd/{verb}/reply"

    def progress(self, run_id: str) -> str:
        return f"{self.prefix}/run/{level(run_id, 'run id')}/progress"

    def result(self, run_id: str) -> str:
        return f"{self.prefix}/run/{level(run_id, 'run id')}/result"


def level(value: str, what: str) -> str:
    """``value`` if it is one topic level, else :class:`MqttError`."""
    if not isinstance(value, str) or not value or any(c in value for c in FORBIDDEN_IN_LEVEL):
        raise MqttError(f"{what} {value!r}: must be a non-empty topic level without '/', '+', '#'")
    return value
