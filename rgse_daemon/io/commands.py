"""Schemas of the commands that arrive over MQTT on ``<prefix>/cmd/<verb>`` (interfaces §4).

Why a schema: a command moves a robot arm, so anything that is not exactly one of these shapes is refused
before it reaches the daemon — unknown fields are an error (a misspelt ``dry_run`` must not silently become a
real run), types are strict (``"3"`` is not a loop count, ``"yes"`` is not a boolean) and every number is
bounded. :func:`parse_command` turns a verb and raw payload bytes into one of the models below, or raises
:class:`CommandRefused` with a one-line reason and whatever ``request_id`` could be read, so that the refusal
can still be answered.

Verbs and fields (units in the names):

``measure``    ``{request_id, loops?, fixture_mass_kg?, dry_run?, identity?, token?}``
``properties`` ``{request_id, loops?, loops_per_pose?, scheme?, fixture_mass_kg?, fixture?, inertia?, dry_run?,
               identity?, token?}``: mass, then the CoG poses (then the inertia); ``fixture`` = ``{cog_flange_m,
               dut_origin_flange_m?, dut_abc_deg?}``; ``identity`` = ``{dut_name?, serial_number?, part_number?,
               project?, operator?, note?}``
``calibrate``  ``{request_id, points?, method?, token?}``; a point is a manifest ``[[point]]`` without traces
``abort``      ``{request_id, run_id?, reason, token?}``
``confirm``    ``{request_id, run_id, point?, token?}``: the operator confirms the load of a campaign point

Authorisation: when tokens are configured (``MqttConfig.command_tokens``), ``token`` must equal one of them;
it is checked before the schema, so an unauthorised sender learns nothing about the schema. The token never
reaches the handler's arguments' ``repr`` (it is excluded) nor the logs.
"""

from __future__ import annotations

import hmac
import json
from collections.abc import Sequence
from typing import Annotated, Any, ClassVar, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from rgse_daemon import robots
from rgse_daemon.errors import RgseError
from rgse_daemon.logs import escape_controls
from rgse_daemon.trace.names import name_problem


def _plain(value: str) -> str:
    """A run id names a run directory: a plain name, never ``.`` or ``..``."""
    problem = name_problem(value)
    if problem is not None:
        raise ValueError(problem)
    return value


RequestId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:\-]+$")]
RunId = Annotated[str, Field(min_length=1, max_length=128, pattern=r"^[A-Za-z0-9_.\-]+$"),
                  AfterValidator(_plain)]
#: Free text of an operator (an abort reason, a confirmation note): kept, with control characters escaped (a NUL
#: or an escape sequence would otherwise reach the log, the terminal and the store as they are).
Text = Annotated[str, Field(min_length=1, max_length=500), AfterValidator(escape_controls)]
Token = Annotated[str | None, Field(default=None, max_length=256, repr=False)]

#: The largest command payload accepted, in bytes; anything longer is refused unread.
MAX_PAYLOAD_BYTES = 64 * 1024
#: How much of a verb a refusal repeats in its message, the log and the alarm (an unknown verb is a topic level of
#: up to 64 KiB, chosen by whoever can publish, before any token is checked).
VERB_SHOWN = 64


def shown_verb(verb: str) -> str:
    """``verb``, cut to :data:`VERB_SHOWN` characters (and ``…``) when longer."""
    return verb if len(verb) <= VERB_SHOWN else verb[:VERB_SHOWN] + "…"


class CommandRefused(RgseError):
    """A command that is refused without effect: malformed, unauthorised, of unknown verb or against the schema."""

    def __init__(self, verb: str, message: str, request_id: str | None = None) -> None:
        super().__init__(f"cmd/{shown_verb(verb)}: {message}")
        self.verb = verb
        """The whole verb (the reply goes to its topic); :func:`shown_verb` in messages."""
        self.problem = message
        self.request_id = request_id


class _Command(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)
    VERB: ClassVar[str]

    request_id: RequestId
    """Chosen by the sender; copied into the reply so that it can match answers to questions."""
    token: Token = None


def _within_the_load_diagram(mass_kg: float) -> float:
    limit = robots.active().max_payload_kg
    if mass_kg > limit:
        raise ValueError(f"{mass_kg:g} kg exceeds the {robots.active().title}'s load diagram ({limit:g} kg)")
    return mass_kg


#: A mass on the flange: at most the active robot's largest load (its load diagram).
Mass_kg = Annotated[float, Field(ge=0.0), AfterValidator(_within_the_load_diagram)]
Coordinate = Annotated[float, Field(ge=-3.0, le=3.0)]
Angle = Annotated[float, Field(ge=-360.0, le=360.0)]


#: One line of an identity (a name, a serial number): at most 200 characters, control characters escaped.
Line = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(escape_controls)]


class Identity(BaseModel):
    """Who and what is measured (interfaces §4.3 ``identity``): stored with the run, shown in its report, published
    with its result. Every field is optional; an empty identity is no identity."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    dut_name: Line | None = None
    """The DuT's name, e.g. the spacecraft's."""
    serial_number: Line | None = None
    part_number: Line | None = None
    project: Line | None = None
    operator: Line | None = None
    """Who runs the measurement."""
    note: Text | None = None
    """A free note of the operator."""

    def as_json(self) -> dict[str, str] | None:
        """The fields given, or None when none is."""
        doc = self.model_dump(exclude_none=True)
        return doc or None


class MeasureCommand(_Command):
    """Start an in-line mass measurement of the mounted DuT."""

    VERB: ClassVar[str] = "measure"
    loops: int | None = Field(None, ge=1, le=100)
    """Measurement loops; ``None``: the configured default."""
    fixture_mass_kg: Mass_kg | None = None
    """Mass of the fixture (MPA, adapters) subtracted from the gross mass; ``None``: the configured value."""
    dry_run: bool = False
    """Check the plan and the interlock, render and check the KRL, but move nothing."""
    identity: Identity | None = None
    """The DuT's name, serial and part number, project, operator and a note (:class:`Identity`)."""




class FixtureFrameSpec(BaseModel):
    """The fixture and the DuT's frame of a properties run (replaces ``[properties.fixture]`` of the config)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    cog_flange_m: tuple[Coordinate, Coordinate, Coordinate]
    """The fixture's CoG in the flange frame (m)."""
    dut_origin_flange_m: tuple[Coordinate, Coordinate, Coordinate] = (0.0, 0.0, 0.0)
    """The DuT frame's origin in the flange frame (m)."""
    dut_abc_deg: tuple[Angle, Angle, Angle] = (0.0, 0.0, 0.0)
    """The DuT frame's KUKA A, B, C (Z-Y-X, deg) in the flange frame."""


class PropertiesCommand(_Command):
    """Start a mass-properties run of the mounted DuT: its mass, then its centre of gravity in the CoG poses."""

    VERB: ClassVar[str] = "properties"
    loops: int | None = Field(None, ge=1, le=100)
    """Mass loops in the measurement pose; ``None``: ``measurement.loops``."""
    loops_per_pose: int | None = Field(None, ge=1, le=20)
    """Loops in each CoG pose; ``None``: ``properties.loops_per_pose``."""
    scheme: Literal["paper", "full", "lever"] | None = None
    """The CoG poses; ``None``: ``properties.scheme``."""
    mass_method: Literal["single", "multipose", "auto"] | None = None
    """Where the mass comes from; ``None``: ``properties.mass_method``."""
    fixture_mass_kg: Mass_kg | None = None
    fixture: FixtureFrameSpec | None = None
    """``None``: ``properties.fixture`` of the config."""
    inertia: bool | None = None
    """Also the inertia (DuT and tare excitation, a prompt to take the DuT off); ``None``: ``properties.inertia``."""
    dry_run: bool = False
    identity: Identity | None = None
    """As the ``measure`` command's."""


class CalibrationPoint(BaseModel):
    """One load configuration of a calibration campaign (interfaces §2 ``[[point]]``, without the traces)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    kind: Literal["zero", "mass", "torque"]
    mass_kg: Mass_kg
    lever_a3_m: float = Field(ge=-5.0, le=5.0)
    lever_a5_m: float = Field(ge=-5.0, le=5.0)


class CalibrateCommand(_Command):
    """Run a calibration campaign (and fit it)."""

    VERB: ClassVar[str] = "calibrate"
    points: tuple[CalibrationPoint, ...] | None = Field(None, min_length=1, max_length=50)
    """The campaign's load configurations in order; ``None``: the configured campaign."""
    method: str | None = Field(None, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.\-]+$")
    """``paper``, ``auto`` or a model name (as ``rgse calibrate --method``); ``None``: the configured one."""


class AbortCommand(_Command):
    """Stop the running (or the named) run now and leave the robot safe."""

    VERB: ClassVar[str] = "abort"
    run_id: RunId | None = None
    reason: Text


class ConfirmCommand(_Command):
    """The operator confirms a step a run waits for (e.g. the calibration load of a campaign point is mounted)."""

    VERB: ClassVar[str] = "confirm"
    run_id: RunId
    point: int | None = Field(None, ge=0, le=1000)
    """Index of the campaign point whose load is mounted; ``None``: the step the run waits for now."""
    message: Text | None = None
    """The operator's note, recorded with the confirmation (e.g. 'bodies 1-3 mounted, bolts torqued')."""


Command = MeasureCommand | PropertiesCommand | CalibrateCommand | AbortCommand | ConfirmCommand

#: The verbs accepted on ``<prefix>/cmd/<verb>`` and their schemas.
COMMANDS: dict[str, type[_Command]] = {
    "measure": MeasureCommand,
    "properties": PropertiesCommand,
    "calibrate": CalibrateCommand,
    "abort": AbortCommand,
    "confirm": ConfirmCommand,
}


def _schema_problem(exc: ValidationError) -> str:
    problems = []
    for err in exc.errors(include_url=False, include_input=False):
        where = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = "unknown field" if err["type"] == "extra_forbidden" else err["msg"]
        problems.append(f"{where}: {msg}")
    return "schema: " + "; ".join(problems)


def _readable_id(rid: object) -> str | None:
    return rid if isinstance(rid, str) and 0 < len(rid) <= 64 else None


def _request_id(payload: bytes | str) -> str | None:
    """The ``request_id`` of a payload refused for a duplicate key (another key), so that the refusal is answered."""
    doc = json.loads(payload)  # parsed once already: it is valid JSON
    return _readable_id(doc.get("request_id")) if isinstance(doc, dict) else None


def _token_ok(given: object, tokens: Sequence[str]) -> bool:
    if not isinstance(given, str):
        return False
    ok = False
    for t in tokens:  # compare against every token, in constant time each
        ok |= hmac.compare_digest(given.encode(), t.encode())
    return ok


class DuplicateKey(ValueError):
    """A JSON object that gives one key twice (the json module would keep the last silently)."""

    def __init__(self, key: str) -> None:
        super().__init__(f"duplicate key {key!r} in the JSON object")
        self.key = key


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    for key, value in pairs:
        if key in doc:
            raise DuplicateKey(key)
        doc[key] = value
    return doc


def loads_strict(text: bytes | str) -> Any:
    """``json.loads``, refusing an object (at any depth) that gives a key twice with :class:`DuplicateKey`.

    Every JSON the daemon takes in as a command (MQTT, the console's API) is read by this: the schema is strict, and
    ``{"dry_run": true, "dry_run": false}`` is not one of its shapes."""
    return json.loads(text, object_pairs_hook=_unique_pairs)


def authorised(payload: bytes | str, tokens: Sequence[str]) -> bool:
    """Whether ``payload`` is a JSON object (within the size limit) with one of ``tokens`` (any payload when there
    are none): the cheap check that lets a command take the urgent lane before the whole schema is read."""
    if not tokens:
        return True
    if len(payload) > MAX_PAYLOAD_BYTES:
        return False
    try:
        doc = loads_strict(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return False
    return isinstance(doc, dict) and _token_ok(doc.get("token"), tokens)


def parse_command(verb: str, payload: bytes | str, tokens: Sequence[str] = ()) -> Command:
    """Validate one command; raises :class:`CommandRefused` (with the ``request_id`` if readable) otherwise.

    Order: verb, size, JSON object (no key given twice), authorisation (if ``tokens``), schema.
    """
    if verb not in COMMANDS:
        raise CommandRefused(verb, f"unknown verb {shown_verb(verb)!r}; expected one of {', '.join(COMMANDS)}")
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise CommandRefused(verb, f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    try:
        doc: Any = loads_strict(payload)
    except DuplicateKey as exc:
        raise CommandRefused(verb, str(exc), None if exc.key == "request_id" else _request_id(payload)) from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise CommandRefused(verb, f"malformed JSON: {exc}") from exc
    except RecursionError:  # e.g. 60 000 nested '[': a RuntimeError, not a ValueError, from the json module
        raise CommandRefused(verb, "malformed JSON: nested too deeply") from None
    if not isinstance(doc, dict):
        raise CommandRefused(verb, f"malformed command: a JSON object expected, got {type(doc).__name__}")
    request_id = _readable_id(doc.get("request_id"))
    if tokens and not _token_ok(doc.get("token"), tokens):
        raise CommandRefused(verb, "unauthorised: missing or wrong token", request_id)
    try:
        # JSON mode: strict types as JSON knows them (an array is a tuple, an object a nested model).
        return COMMANDS[verb].model_validate_json(payload)  # type: ignore[return-value]
    except ValidationError as exc:
        raise CommandRefused(verb, _schema_problem(exc), request_id) from exc
