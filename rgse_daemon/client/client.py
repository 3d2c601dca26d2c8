"""The asynchronous Python client of a running daemon, over its MQTT commands (docs/interfaces.md §4).

::

    async with RgseClient.from_config(Path("rgse.toml")) as rgse:
        run = await rgse.calibrate(load_points(Path("campaign.toml")))
        result = await run.wait(600, on_prompt=mount_and_say)   # confirms each prompt after ``mount_and_say``
        print(result.loo_mean_abs_err_pct, await rgse.report(run.run_id))

One connection (:class:`rgse_daemon.io.operator.Session`) holds the subscriptions for the client's lifetime: the
daemon's state and status, every run's progress and result, and the alarms; so nothing a run says between two
calls of a script is missed. Every wait takes a deadline; a refusal raises :class:`Refused` with the daemon's
reason, a failed, aborted or interrupted run (its daemon died during it) :class:`RunFailed`, a wait that ends at its
deadline :class:`WaitTimeout`.
"""

from __future__ import annotations

import asyncio
import inspect
import sys
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from rgse_daemon.config import Config, load_config
from rgse_daemon.errors import DataError
from rgse_daemon.io.operator import DEFAULT_TIMEOUT_S, Endpoint, Session, describe_status, endpoint_of
from rgse_daemon.runkind import RunKind

from .types import (
    INTERRUPTED,
    INTERRUPTED_HINT,
    TERMINAL,
    CalibrationResult,
    CampaignPoint,
    DaemonState,
    FixtureFrame,
    Identity,
    MeasurementResult,
    ProgressEvent,
    Prompt,
    PropertiesResult,
    Refused,
    Result,
    ResultRefused,
    RunFailed,
    WaitTimeout,
)

T = TypeVar("T")

#: The operator's answer to a prompt: ``None`` (confirm without a note) or the note recorded with the confirmation.
PromptHandler = Callable[[Prompt], Awaitable[str | None] | str | None]

DEFAULT_ABORT_REASON = "aborted by a script (rgse_daemon.client)"
#: How long a failed run's reason (its ``run_failed`` alarm, published after its last state) is waited for.
REASON_WAIT_S = 2.0


class RgseClient:
    """A connection to one daemon. Use as ``async with``; build it with :meth:`from_config` (the daemon's own
    configuration file gives the broker, prefix, credentials, TLS, command token and store)."""

    def __init__(self, ep: Endpoint, *, config: Config | None = None, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        self.endpoint = ep
        self.config = config
        self.timeout_s = timeout_s
        self.status: dict[str, Any] | None = None
        self._state: DaemonState | None = None
        self._progress: dict[str, list[ProgressEvent]] = {}
        self._results: dict[str, dict[str, Any]] = {}
        self._failures: dict[str, str] = {}
        self._prompt_times: set[str] = set()  # prompts seen (progress or the retained prompt), by their time
        self.alarms: list[dict[str, Any]] = []
        self._waiters: list[asyncio.Future[None]] = []
        t = ep.topics
        self._session = Session(ep, "client", (t.status, t.state, t.alarm, t.prompt, f"{t.prefix}/run/+/progress",
                                               f"{t.prefix}/run/+/result"), self._on_message, timeout_s)

    @classmethod
    def from_config(cls, path: Path, *, timeout_s: float = DEFAULT_TIMEOUT_S) -> RgseClient:
        cfg = load_config(path)
        return cls(endpoint_of(cfg, path), config=cfg, timeout_s=timeout_s)

    @classmethod
    def of(cls, cfg: Config, *, timeout_s: float = DEFAULT_TIMEOUT_S) -> RgseClient:
        return cls(endpoint_of(cfg), config=cfg, timeout_s=timeout_s)

    async def __aenter__(self) -> RgseClient:
        await self._session.__aenter__()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self._session.__aexit__(*exc_info)

    # --- what arrives -------------------------------------------------------------------------------------------
    def _on_message(self, topic: str, doc: Any, retained: bool) -> None:
        t = self.endpoint.topics
        head = f"{t.prefix}/run/"
        if topic == t.state and isinstance(doc, dict):
            self._state = DaemonState.of(doc)
        elif topic == t.status and isinstance(doc, dict):
            self.status = doc
        elif topic == t.alarm and isinstance(doc, dict):
            self.alarms.append(doc)
            if doc.get("kind") == "run_failed" and isinstance(doc.get("run_id"), str):
                self._failures[doc["run_id"]] = str(doc.get("message") or "no reason given")
        elif topic == t.prompt and isinstance(doc, dict):
            # the retained prompt: a client that connects while a run waits learns of the prompt it missed
            run_id = doc.get("run_id")
            if doc.get("pending") is True and isinstance(run_id, str) and self._new_prompt(doc):
                self._progress.setdefault(run_id, []).append(ProgressEvent.of(run_id, doc))
        elif topic.startswith(head) and isinstance(doc, dict):
            run_id, _, leaf = topic[len(head):].partition("/")
            if leaf == "progress" and (doc.get("kind") != "confirm" or self._new_prompt(doc)):
                self._progress.setdefault(run_id, []).append(ProgressEvent.of(run_id, doc))
            elif leaf == "result":
                self._results[run_id] = doc
        for waiter in self._waiters:  # also on "" (the connection was lost): the waiter sees ``failure``
            if not waiter.done():
                waiter.set_result(None)
        self._waiters.clear()

    def _new_prompt(self, doc: dict[str, Any]) -> bool:
        """A prompt arrives twice (progress, QoS 0, and the retained prompt, QoS 1): True the first time."""
        key = f"{doc.get('run_id')}|{doc.get('time')}|{doc.get('message')}"
        if key in self._prompt_times:
            return False
        self._prompt_times.add(key)
        return True

    async def until(self, predicate: Callable[[], T | None], what: str, timeout_s: float) -> T:
        """The first truthy value of ``predicate()``, checked now and after every message; :class:`WaitTimeout`
        after ``timeout_s``; the session's error when the connection is lost."""
        try:
            async with asyncio.timeout(timeout_s):
                while True:
                    if self._session.failure is not None:
                        raise self._session.failure
                    value = predicate()
                    if value:
                        return value
                    waiter: asyncio.Future[None] = asyncio.get_running_loop().create_future()
                    self._waiters.append(waiter)
                    await waiter
        except TimeoutError:
            raise WaitTimeout(f"{what}: not within {timeout_s:g} s; the daemon's state: {self._describe()}") from None

    def _describe(self) -> str:
        s = self._state
        if s is None:
            return f"none received (daemon status: {describe_status(self.status)})"
        return f"engine {s.engine}" + (f", run {s.run_id}" if s.run_id else "") + f" at {s.time or '?'}"

    @property
    def latest_state(self) -> DaemonState | None:
        """The daemon's state as last received (``None`` before any)."""
        return self._state

    async def state(self, timeout_s: float | None = None) -> DaemonState:
        """The daemon's latest state (retained: at once when the daemon is online)."""
        return await self.until(lambda: self._state, "the daemon's state", timeout_s or self.timeout_s)

    async def ready(self, timeout_s: float | None = None) -> DaemonState:
        """The daemon's state once it is connected to its controller and runs nothing (a run may be started)."""
        def idle() -> DaemonState | None:
            s = self._state
            return s if s is not None and s.connected and s.engine in ("idle", *TERMINAL) else None

        return await self.until(idle, "the daemon ready (controller connected, no run)", timeout_s or self.timeout_s)

    def events_of(self, run_id: str) -> list[ProgressEvent]:
        """The progress events of ``run_id`` received so far, in order."""
        return list(self._progress.get(run_id, ()))

    # --- commands -----------------------------------------------------------------------------------------------
    async def _command(self, verb: str, fields: dict[str, Any]) -> dict[str, Any]:
        reply = await self._session.command(verb, fields)
        if reply.get("ok") is not True:
            raise Refused(verb, str(reply.get("error") or "no reason given"))
        return reply

    async def measure(self, *, loops: int | None = None, fixture_mass_kg: float | None = None,
                      dry_run: bool = False, identity: Identity | None = None) -> Run:
        """Start a measurement of the mounted DuT (named by ``identity``); the run's handle (a dry run has
        ``run_id`` ``None``). Its kind is the one the daemon accepted: ``properties`` where every measurement is one
        (``[properties] when = "every_measurement"``), so that :meth:`Run.result` reads its CoG too."""
        reply = await self._command("measure", {"loops": loops, "fixture_mass_kg": fixture_mass_kg,
                                                "dry_run": dry_run or None,
                                                "identity": identity.as_command() if identity else None})
        accepted = reply.get("accepted")
        kind = RunKind(accepted) if accepted in tuple(RunKind) else RunKind.MEASUREMENT
        return Run(self, reply.get("run_id"), kind)

    async def properties(self, *, loops: int | None = None, loops_per_pose: int | None = None,
                         scheme: str | None = None, fixture_mass_kg: float | None = None,
                         fixture: FixtureFrame | None = None, inertia: bool | None = None,
                         dry_run: bool = False, identity: Identity | None = None,
                         mass_method: str | None = None) -> Run:
        """Start a mass-properties run of the mounted DuT: its mass (by ``mass_method``: ``"single"``,
        ``"multipose"`` or ``"auto"``), then its CoG in the poses of ``scheme`` (``"paper"``, ``"full"`` or
        ``"lever"``), with ``inertia`` then its inertia tensor (the run asks the operator to take the
        DuT off for the tare: answer that prompt); ``None`` takes the daemon's ``[measurement]``/``[properties]``
        settings."""
        reply = await self._command("properties", {
            "loops": loops, "loops_per_pose": loops_per_pose, "scheme": scheme, "fixture_mass_kg": fixture_mass_kg,
            "fixture": fixture.as_command() if fixture is not None else None, "inertia": inertia,
            "dry_run": dry_run or None, "identity": identity.as_command() if identity else None,
            "mass_method": mass_method})
        return Run(self, reply.get("run_id"), RunKind.PROPERTIES)

    async def calibrate(self, points: Sequence[CampaignPoint] | None = None, *, method: str | None = None) -> Run:
        """Start a calibration campaign over ``points`` (``None``: paper Table 1) fitted with ``method``."""
        fields: dict[str, Any] = {"method": method}
        if points is not None:
            fields["points"] = [p.as_command() for p in points]
        reply = await self._command("calibrate", fields)
        return Run(self, reply.get("run_id"), RunKind.CALIBRATION)

    async def confirm(self, run_id: str, point: int | None = None, message: str | None = None) -> None:
        """Answer the prompt of ``run_id`` (only the point it waits for is accepted)."""
        await self._command("confirm", {"run_id": run_id, "point": point, "message": message})

    async def abort(self, run_id: str | None = None, reason: str = DEFAULT_ABORT_REASON) -> None:
        """Stop ``run_id`` (``None``: whatever run is in progress) now; the daemon leaves the robot safe."""
        await self._command("abort", {"run_id": run_id, "reason": reason})

    # --- results ------------------------------------------------------------------------------------------------
    async def result(self, run_id: str, kind: RunKind | None = None, timeout_s: float | None = None) -> Result:
        """The result of ``run_id`` (retained on the broker: also of a run that ended before this client);
        :class:`ResultRefused` (a :class:`RunFailed`, state ``refused``, its reason and the result object) for a
        result whose status is ``refused``."""
        doc = await self.until(lambda: self._results.get(run_id), f"the result of run {run_id}",
                               timeout_s or self.timeout_s)
        if doc.get("state") == INTERRUPTED:
            raise RunFailed(run_id, INTERRUPTED, _interrupted_reason(doc))
        if doc.get("status") == "refused":  # no figure: the reason is what there is (rgse_daemon.verdict)
            raise ResultRefused(run_id, doc)
        if kind == RunKind.CALIBRATION or (kind is None and "mass_kg" not in doc):
            return CalibrationResult.of(run_id, doc)
        if kind == RunKind.PROPERTIES or (kind is None and doc.get("cog_m") is not None):
            return PropertiesResult.of(run_id, doc)
        return MeasurementResult.of(run_id, doc)

    def results(self) -> dict[str, dict[str, Any]]:
        """Every result seen so far (the retained ones arrive right after connecting), by run id."""
        return dict(self._results)

    async def report(self, run_id: str | None = None, *, calibration_id: str | None = None,
                     out_dir: Path | None = None) -> Path:
        """Write the HTML report of a run (or of a calibration) from the daemon's store; the file's path. Needs the
        daemon's configuration (:meth:`from_config`) and access to its store."""
        if self.config is None:
            raise DataError("a report needs the daemon's configuration (RgseClient.from_config): its store")
        cfg = self.config
        from rgse_daemon.report import build_report  # matplotlib: only when a report is asked for
        from rgse_daemon.store import Repository

        def write() -> Path:
            with Repository.open(cfg.store.url, cfg.paths.data_dir) as repo:
                return build_report(repo, cfg.paths.data_dir, out_dir or cfg.paths.data_dir / "reports",
                                    run_id=run_id, calibration_id=calibration_id)

        return await asyncio.to_thread(write)


class Run:
    """A run started by this client: its events, prompts, end and result."""

    def __init__(self, client: RgseClient, run_id: str | None, kind: RunKind) -> None:
        self.client = client
        self.run_id = run_id
        self.kind = kind
        self._seen = 0  # events handed out by next_event
        self._prompts_seen = 0

    def _id(self) -> str:
        if self.run_id is None:
            raise DataError("a dry run (or a run that did not start within 10 s) has no run id to follow")
        return self.run_id

    def end_state(self) -> str | None:
        """``done``, ``failed`` or ``aborted`` once the run is over (from its progress or the daemon's state);
        ``interrupted`` when its daemon died during it (the restarted daemon's final result says so)."""
        run_id = self._id()
        result = self.client._results.get(run_id)
        if result is not None and result.get("state") == INTERRUPTED:
            return INTERRUPTED
        for ev in reversed(self.client._progress.get(run_id, ())):
            if ev.state in TERMINAL:
                return ev.state
        s = self.client._state
        if s is not None and s.run_id == run_id and s.engine in TERMINAL:
            return s.engine
        return None  # a result may be out before the run ends (its finaliser still stops trace and program)

    async def next_event(self, timeout_s: float) -> ProgressEvent:
        """The run's next progress event."""
        run_id = self._id()
        events = self.client._progress

        def next_one() -> ProgressEvent | None:
            got = events.get(run_id, ())
            return got[self._seen] if len(got) > self._seen else None

        ev = await self.client.until(next_one, f"the next event of run {run_id}", timeout_s)
        self._seen += 1
        return ev

    async def events(self, timeout_s: float) -> AsyncIterator[ProgressEvent]:
        """The run's progress events until it ends; ``timeout_s`` bounds the wait for each one."""
        while True:
            ev = await self.next_event(timeout_s)
            yield ev
            if ev.state in TERMINAL:
                return

    def _next_prompt(self) -> Prompt | Exception | None:
        prompts = [ev for ev in self.client._progress.get(self._id(), ()) if ev.kind == "confirm"]
        if len(prompts) > self._prompts_seen:
            return Prompt.of(prompts[self._prompts_seen])
        end = self.end_state()
        if end is not None:
            return self._ended(end)
        return None

    def _ended(self, end: str) -> Exception:
        run_id = self._id()
        if end == "done":
            return WaitTimeout(f"run {run_id} is over (done): no prompt will come")
        if end == INTERRUPTED:
            return RunFailed(run_id, end, _interrupted_reason(self.client._results.get(run_id, {})))
        reason = self.client._failures.get(run_id)
        if reason is None:
            said = [ev.message for ev in self.client._progress.get(run_id, ()) if ev.message]
            reason = said[-1] if said else "no reason given"
        return RunFailed(run_id, end, reason)

    async def _with_reason(self, exc: Exception) -> Exception:
        """A failed run's ``run_failed`` alarm (with the reason) follows its last state event: wait briefly for it."""
        if isinstance(exc, RunFailed) and exc.state != INTERRUPTED and self.run_id not in self.client._failures:
            try:
                reason = await self.client.until(lambda: self.client._failures.get(exc.run_id), "the reason",
                                                 REASON_WAIT_S)
            except WaitTimeout:
                return exc
            return RunFailed(exc.run_id, exc.state, reason)
        return exc

    async def _ended_meanwhile(self) -> Exception:
        """Why a confirmation was refused: the run ended meanwhile (its :class:`RunFailed`), else the refusal."""
        refusal = sys.exc_info()[1]
        assert isinstance(refusal, Refused)
        try:
            end = await self.client.until(self.end_state, "the run's end", REASON_WAIT_S)
        except WaitTimeout:
            return refusal
        return await self._with_reason(self._ended(end)) if end != "done" else refusal

    async def next_prompt(self, timeout_s: float) -> Prompt:
        """The next operator prompt of the run; :class:`RunFailed` if it ends failed or aborted first."""
        got = await self.client.until(self._next_prompt, f"a prompt of run {self.run_id}", timeout_s)
        if isinstance(got, Exception):
            raise await self._with_reason(got)
        self._prompts_seen += 1
        return got

    async def confirm(self, prompt: Prompt | None = None, message: str | None = None) -> None:
        """Confirm ``prompt`` (its point only), or whatever the run waits for now."""
        await self.client.confirm(self._id(), None if prompt is None else prompt.point_index, message)

    async def abort(self, reason: str = DEFAULT_ABORT_REASON) -> None:
        await self.client.abort(self._id(), reason)

    async def wait(self, timeout_s: float, on_prompt: PromptHandler | None = None, *, confirm: bool = True) -> Result:
        """Wait for the run's end under one deadline and return its result. Each prompt is handed to
        ``on_prompt`` (which mounts the load, or asks a person to) and then confirmed with the note it returns;
        without ``on_prompt`` a prompt raises :class:`WaitTimeout` (nobody to answer it). With ``confirm=False``
        prompts are only shown to ``on_prompt`` and answered elsewhere (``rgse confirm``, the console).
        :class:`RunFailed` when the run fails or is aborted."""
        run_id = self._id()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s

        def prompt_or_end() -> Prompt | Exception | str | None:
            got = self._next_prompt()
            if isinstance(got, WaitTimeout):  # done: no more prompts
                return "done"
            return got

        while True:
            got = await self.client.until(prompt_or_end, f"the end of run {run_id}", max(deadline - loop.time(), 0))
            if isinstance(got, Exception):
                raise await self._with_reason(got)
            if got == "done":
                break
            assert isinstance(got, Prompt)
            self._prompts_seen += 1
            if on_prompt is None:
                raise WaitTimeout(f"run {run_id} waits for the operator ({got.message}) and no on_prompt was given")
            note = on_prompt(got)
            if inspect.isawaitable(note):
                note = await note
            if confirm:
                try:
                    await self.confirm(got, note)
                except Refused:
                    raise await self._ended_meanwhile() from None
        result = await self.client.result(run_id, self.kind, max(deadline - loop.time(), 0.001))
        # the engine says "done" a moment before the daemon has finished with the run (stored, released): wait for
        # its state to let go of it, so that the next run a script starts right away is not refused as busy
        await self.client.until(lambda: (s := self.client.latest_state) is not None and s.run_id != run_id,
                                f"the daemon to release run {run_id}", max(deadline - loop.time(), 0.001))
        return result


def _interrupted_reason(result: dict[str, Any]) -> str:
    """Why an interrupted run ended, and what to do: the recovery's ``detail`` and :data:`INTERRUPTED_HINT`."""
    detail = result.get("detail")
    return f"{detail if isinstance(detail, str) and detail else 'its daemon stopped'}; {INTERRUPTED_HINT}"
