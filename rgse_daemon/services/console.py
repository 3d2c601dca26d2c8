"""The operator's web console, served by the daemon inside its own event loop (aiohttp; ``[console] enabled``).

One page (``console.html``) and a small HTTP API beside it:

``GET /``                  the page
``GET /events``            server-sent events: ``hello`` (everything the page needs to find its place: the state, the
                           current run with its events so far and the pending prompt, whether a token is needed),
                           then ``state`` at the state rate and ``progress`` for every engine event as it happens
``POST /api/confirm``      ``{run_id, point?, message?, token?}``: the ``confirm`` command
``POST /api/abort``        ``{run_id?, reason, token?}``: the ``abort`` command
``POST /api/measure``      ``{loops?, identity?, token?}``: the ``measure`` command (a run for a named DuT)
``POST /api/properties``   ``{loops?, identity?, token?}``: the ``properties`` command
``GET /api/history``       the robot's latest runs with their results (status, warnings, the DuT's identity), the
                           reason of a failed or aborted run, and report links
``GET /report/run/ID``     the HTML report of a run (``/report/calibration/ID`` of a calibration), from the store,
                           rendered on the console's own thread (:data:`REPORT_QUEUE`)

Only the console's own page may act (docs/security.md): every request must name an allowed ``Host`` (against DNS
rebinding); a POST must come from the page's own origin (``Origin`` and ``Sec-Fetch-Site`` when the browser sends
them), be ``application/json`` (a form or ``text/plain`` POST, which any page can send without a preflight, is
refused) and carry the anti-CSRF token of ``hello`` in ``X-RGSE-CSRF``. Every answer forbids framing
(``X-Frame-Options``, ``frame-ancestors``) and the page has a Content-Security-Policy that allows its own script only.

The actions are the MQTT commands: checked by the same :func:`~rgse_daemon.io.commands.parse_command` (schema and
``mqtt.command_tokens``) and answered by the same handler, so the console can confirm only what the daemon asks
for, and start only what MQTT may start (admission's rules alike). Without ``command_tokens`` the console acts only
with ``command_auth = "open_lab_bench"``: the broker's ACL (``broker_acl``) does not see this page. Each action,
accepted or refused, is recorded in the store as an event ``console_action`` with ``source: "console"``.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import hashlib
import hmac
import json
import logging
import math
import re
import secrets
import socket
import time
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from aiohttp import web

from rgse_daemon.config import ConsoleConfig
from rgse_daemon.errors import RgseError
from rgse_daemon.io.commands import MAX_PAYLOAD_BYTES, CommandRefused, DuplicateKey, loads_strict, parse_command
from rgse_daemon.procedures.events import Event
from rgse_daemon.report import build_report
from rgse_daemon.services.signals import STATE_LIGHT
from rgse_daemon.store import Repository, RunKind, Store

log = logging.getLogger(__name__)

#: Engine events kept for a page that (re)connects mid-run.
RUN_EVENTS_KEPT = 500
#: Messages queued per page; a page that falls this far behind is disconnected (it reconnects and resyncs).
CLIENT_QUEUE = 1000
#: Runs listed in the history.
HISTORY_RUNS = 30
TERMINAL = ("done", "failed", "aborted")
#: Torque history the page's plot shows (s).
TORQUE_WINDOW_S = 60.0
#: A page that takes one event longer than this (a stalled browser, a dead network) is dropped.
WRITE_TIMEOUT_S = 10.0
#: A POST body not received within this is answered 408 (a client that never finishes it holds nothing longer).
BODY_TIMEOUT_S = 10.0
#: A connection that has not sent a whole request head within this after it opened (headers byte by byte, or
#: nothing at all), or that stays idle this long between requests, is closed (aiohttp's ``keepalive_timeout``;
#: its default is an hour).
IDLE_TIMEOUT_S = 15.0
#: On stop, requests still in progress (an event stream in a stalled write) get this long, then are cancelled
#: (aiohttp's default, 60 s, is longer than the daemon waits for the console to stop).
SHUTDOWN_TIMEOUT_S = 2.0
#: Event streams open at once; one more is answered 503. Each page costs a queue and its writes; the controller
#: reads do not grow with the pages (one state loop, and a new page's first state is the loop's latest).
MAX_STREAMS = 32
#: Reports render on the console's own thread, one at a time, so that a page's report never takes a thread of the
#: default pool, which the run needs (the static check before every motion, the pipeline, the archive), however
#: often it is loaded. At most this many report requests wait or render at once; one more is answered 503.
REPORT_QUEUE = 4
#: A report not rendered within this (its wait in the queue included) is answered 503; the render still finishes.
REPORT_TIMEOUT_S = 30.0

Handler = Any  # rgse_daemon.io.mqtt.CommandHandler: measure, calibrate, abort, confirm

#: The header that carries the anti-CSRF token of the ``hello`` event on every POST.
CSRF_HEADER = "X-RGSE-CSRF"
#: Sent with every answer: no page may frame the console (clickjacking), nothing is sniffed into another type.
FRAME_HEADERS = {"X-Frame-Options": "DENY", "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer"}
#: The page's policy; ``{script}`` is the hash of its one inline script (no other script runs, none from elsewhere).
PAGE_CSP = ("default-src 'none'; script-src '{script}'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
            "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")
#: Every other answer (the reports, the API): not to be framed.
OTHER_CSP = "frame-ancestors 'none'"
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
WILDCARD_HOSTS = ("0.0.0.0", "::", "")


class Refusal(Exception):
    """A request that is not the console's own page acting: answered ``status`` with ``error``."""

    def __init__(self, status: int, error: str) -> None:
        super().__init__(error)
        self.status = status
        self.error = error


def allowed_hosts(cfg: ConsoleConfig) -> frozenset[str]:
    """The host names (lower case, no port) the console answers to."""
    names = {cfg.host, *LOOPBACK_NAMES, *cfg.allowed_hosts}
    if cfg.host in WILDCARD_HOSTS:  # listening on every address: this machine's own names too
        names |= {socket.gethostname(), socket.getfqdn()}
    return frozenset(n.lower().strip("[]") for n in names if n)


def _host_port(netloc: str) -> tuple[str, int | None]:
    """``(name, port)`` of a ``Host`` header or URL authority (``[::1]:8080`` -> ``("::1", 8080)``); ValueError
    when it is not one."""
    parts = urlsplit(f"//{netloc}")
    if parts.hostname is None or parts.username is not None or parts.path or parts.query or parts.fragment:
        raise ValueError(netloc)
    return parts.hostname.lower(), parts.port


class Console:
    """The web console of one daemon; :meth:`event` is fed every engine event, :meth:`start`/:meth:`stop` bound
    its life to the daemon's."""

    def __init__(self, cfg: ConsoleConfig, *, robot: str, handler: Handler, state: Callable[[], Awaitable[dict]],
                 light: Callable[[], str | None], store: Store, store_url: str | None, data_dir: Path,
                 tokens: Sequence[str], open_bench: bool, rate_hz: float) -> None:
        self.cfg = cfg
        self.robot = robot
        self._handler = handler
        self._state = state
        self._light = light
        self._store = store
        self._store_url = store_url
        self._data_dir = data_dir
        self._tokens = tuple(tokens)
        self._open_bench = open_bench
        self.period_s = 1.0 / rate_hz
        self.port: int | None = None
        self.run: dict[str, Any] | None = None  # {run_id, kind?, events, prompt, state}
        self.last_state: dict[str, Any] | None = None
        self._last_state_at = -math.inf  # time.monotonic() of last_state
        self._reading: asyncio.Future[dict[str, Any]] | None = None  # the state read in flight, shared
        self._streams = 0
        self._reports = ThreadPoolExecutor(1, thread_name_prefix="rgse-console-report")
        self._reports_pending = 0  # report requests waiting for the thread or rendering
        self._hosts = allowed_hosts(cfg)
        self.csrf = secrets.token_urlsafe(32)
        """The anti-CSRF token of this daemon's life: handed to the page in ``hello`` (which only a page of this
        origin can read), required in :data:`CSRF_HEADER` on every POST."""
        self.torque: deque[tuple[float, float, float]] = deque(maxlen=int(TORQUE_WINDOW_S * rate_hz) + 1)
        """(Unix time s, A3 N·m, A5 N·m) of the live state, for the plot of a page that (re)connects."""
        self._clients: set[asyncio.Queue[tuple[str, Any] | None]] = set()
        self._runner: web.AppRunner | None = None
        self._task: asyncio.Task[None] | None = None

    @property
    def url(self) -> str:
        return f"http://{self.cfg.host}:{self.port}/"

    # --- life ----------------------------------------------------------------------------------------------------
    async def start(self) -> None:
        # a body larger than a command may be (interfaces §4.3) is a 413 before it is read whole
        app = web.Application(client_max_size=MAX_PAYLOAD_BYTES, middlewares=[self._guard])
        app.on_response_prepare.append(_security_headers)
        app.add_routes([web.get("/", self._page), web.get("/events", self._events),
                        web.post("/api/confirm", self._confirm), web.post("/api/abort", self._abort),
                        web.post("/api/measure", self._measure), web.post("/api/properties", self._properties),
                        web.get("/api/history", self._history),
                        web.get(r"/report/{what:run|calibration}/{id:[A-Za-z0-9_.\-]+}", self._report)])
        self._runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=SHUTDOWN_TIMEOUT_S,
                                     keepalive_timeout=IDLE_TIMEOUT_S)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.cfg.host, self.cfg.port)
        await site.start()
        sockets = site._server.sockets if site._server is not None else ()  # type: ignore[union-attr]
        self.port = sockets[0].getsockname()[1] if sockets else self.cfg.port
        self._task = asyncio.create_task(self._state_loop(), name="rgse-console-state")
        log.info("console on %s", self.url)

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        for q in list(self._clients):
            self._offer(q, None)  # ends the page's stream
        if self._runner is not None:
            await self._runner.cleanup()
        self._reports.shutdown(wait=False, cancel_futures=True)  # a render under way finishes on its thread

    # --- what goes out -------------------------------------------------------------------------------------------
    def _offer(self, q: asyncio.Queue[tuple[str, Any] | None], item: tuple[str, Any] | None) -> None:
        try:
            q.put_nowait(item)
        except asyncio.QueueFull:
            self._clients.discard(q)
            with contextlib.suppress(asyncio.QueueFull):
                q.get_nowait()
                q.put_nowait(None)

    def _send(self, kind: str, doc: Any) -> None:
        for q in list(self._clients):
            self._offer(q, (kind, doc))

    def event(self, ev: Event) -> None:
        """An engine event: kept for the run's page and sent to every open page."""
        if ev.run_id is None:
            return
        doc = ev.to_json()
        if self.run is None or self.run["run_id"] != ev.run_id:
            self.run = {"run_id": ev.run_id, "events": [], "prompt": None, "state": "running"}
        self.run["events"] = [*self.run["events"], doc][-RUN_EVENTS_KEPT:]
        if ev.kind == "confirm":
            self.run["prompt"] = doc
        elif ev.kind == "state":
            self.run["state"] = ev.data.get("state")
            if ev.data.get("state") != "confirm":
                self.run["prompt"] = None
        self._send("progress", doc)

    def _view(self, state: dict[str, Any]) -> dict[str, Any]:
        """The state document with the stack light: the module's, or without one what it would show."""
        color = self._light()
        if color is None:
            color = STATE_LIGHT.get(str(state.get("engine")), "green" if state.get("connected") else "off")
            return {**state, "stack_light": color, "stack_light_module": False}
        return {**state, "stack_light": color, "stack_light_module": True}

    async def _state_loop(self) -> None:
        while True:
            await asyncio.sleep(self.period_s)
            if not self._clients:
                continue
            try:
                state = await self._read_state()
            except RgseError as exc:
                log.warning("console: state not read: %s", exc)
                continue
            except Exception as exc:  # a bug here must not end the pages' state for the rest of the daemon's life
                log.error("console: state not read: %r", exc)
                continue
            self._keep_torque(state)
            self._send("state", state)

    async def _read_state(self) -> dict[str, Any]:
        """Read the state (the controller's snapshot among it) once for everyone who asks while the read is in
        flight: the state loop and the pages that open meanwhile."""
        if self._reading is None or self._reading.done():
            self._reading = asyncio.ensure_future(self._state())
        state = self._view(await asyncio.shield(self._reading))
        self.last_state, self._last_state_at = state, time.monotonic()
        return state

    async def _fresh_state(self) -> dict[str, Any]:
        """A new page's first state: the state loop's latest if younger than two of its periods, else one read.
        Opening pages never costs a controller read each (the link that the interlock polls)."""
        if self.last_state is not None and time.monotonic() - self._last_state_at <= 2 * self.period_s:
            return self.last_state
        return await self._read_state()

    def _keep_torque(self, state: dict[str, Any]) -> None:
        ctl = state.get("controller") or {}
        tq = ctl.get("torques_nm") if isinstance(ctl, dict) else None
        if isinstance(tq, list) and len(tq) >= 5 and all(isinstance(tq[i], int | float) for i in (2, 4)):
            self.torque.append((time.time(), float(tq[2]), float(tq[4])))

    # --- routes --------------------------------------------------------------------------------------------------
    # --- who may ask ---------------------------------------------------------------------------------------------
    @web.middleware
    async def _guard(self, request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
                     ) -> web.StreamResponse:
        """Every request names an allowed Host; a POST is the page's own (origin, JSON, anti-CSRF token)."""
        try:
            host = self._check_host(request)
            if request.method not in ("GET", "HEAD"):
                self._check_post(request, host)
        except Refusal as exc:
            log.warning("console: %s %s refused: %s (peer %s)", request.method, request.path, exc.error,
                        request.remote)
            return web.json_response({"ok": False, "error": exc.error}, status=exc.status)
        return await handler(request)

    def _check_host(self, request: web.Request) -> tuple[str, int | None]:
        raw = request.headers.get("Host", "")
        try:
            host = _host_port(raw)
        except ValueError:
            raise Refusal(400, f"Host {raw[:100]!r} is not a host name") from None
        if host[0] not in self._hosts:  # a DNS-rebound name: this page is not that site's
            raise Refusal(421, f"Host {host[0][:100]!r} is not one this console answers to (console.allowed_hosts)")
        return host

    def _check_post(self, request: web.Request, host: tuple[str, int | None]) -> None:
        site = request.headers.get("Sec-Fetch-Site")
        if site is not None and site not in ("same-origin", "none"):
            raise Refusal(403, f"cross-site request (Sec-Fetch-Site: {site[:40]}): only the console's own page acts")
        origin = request.headers.get("Origin")
        if origin is not None:
            parts = urlsplit(origin)
            default = 443 if parts.scheme == "https" else 80
            try:
                o_port = parts.port or default
            except ValueError:
                o_port = -1
            if (parts.scheme not in ("http", "https") or (parts.hostname or "").lower() != host[0]
                    or o_port != (host[1] or default)):
                raise Refusal(403, f"cross-origin request from {origin[:100]!r}: only the console's own page acts")
        ctype = request.headers.get("Content-Type", "").split(";", 1)[0].strip().lower()
        if ctype != "application/json":
            raise Refusal(415, f"Content-Type {ctype[:60] or '(none)'!r}: an action is application/json")
        given = request.headers.get(CSRF_HEADER, "")
        if not hmac.compare_digest(given.encode(), self.csrf.encode()):
            raise Refusal(403, f"missing or wrong {CSRF_HEADER} (the token of the page's hello event)")

    async def _page(self, request: web.Request) -> web.Response:
        html = resources.files(__package__).joinpath("console.html").read_text(encoding="utf-8")
        csp = PAGE_CSP.format(script=_script_hash(html))
        return web.Response(text=html, content_type="text/html", charset="utf-8",
                            headers={"Content-Security-Policy": csp})

    async def _events(self, request: web.Request) -> web.StreamResponse:
        if self._streams >= MAX_STREAMS:
            return web.json_response({"ok": False, "error": f"{MAX_STREAMS} event streams are open already: "
                                      f"close a page and reload"}, status=503)
        self._streams += 1
        try:
            return await self._stream(request)
        finally:
            self._streams -= 1

    async def _stream(self, request: web.Request) -> web.StreamResponse:
        resp = web.StreamResponse(headers={"Content-Type": "text/event-stream", "Cache-Control": "no-store"})
        await resp.prepare(request)
        q: asyncio.Queue[tuple[str, Any] | None] = asyncio.Queue(CLIENT_QUEUE)
        hello = {"robot": self.robot, "token_required": bool(self._tokens), "csrf": self.csrf, "run": self.run,
                 "state": await self._fresh_state(), "torque": list(self.torque), "state_period_s": self.period_s}
        self._clients.add(q)
        try:
            async with asyncio.timeout(WRITE_TIMEOUT_S):
                await resp.write(_sse("hello", hello))
            while (item := await q.get()) is not None:
                async with asyncio.timeout(WRITE_TIMEOUT_S):
                    await resp.write(_sse(*item))
        except (ConnectionResetError, RuntimeError, TimeoutError):  # the page went away, or stalled
            pass
        finally:
            self._clients.discard(q)
        return resp

    async def _act(self, verb: str, request: web.Request) -> web.Response:
        try:
            async with asyncio.timeout(BODY_TIMEOUT_S):
                body = await request.json(loads=loads_strict)
        except TimeoutError:
            return web.json_response({"ok": False, "error": f"request body not received within {BODY_TIMEOUT_S:g} s"},
                                     status=408)
        except DuplicateKey as exc:
            return web.json_response({"ok": False, "error": str(exc)}, status=400)
        except ValueError:
            body = None
        except web.HTTPRequestEntityTooLarge:
            return web.json_response({"ok": False, "error": f"body larger than {MAX_PAYLOAD_BYTES} bytes, the limit of "
                                      f"a command"}, status=413)
        except RecursionError:  # nested too deeply for the json module: a RuntimeError, not a ValueError
            return web.json_response({"ok": False, "error": "a JSON object expected: nested too deeply"},
                                     status=400)
        if not isinstance(body, dict):
            return web.json_response({"ok": False, "error": "a JSON object expected"}, status=400)
        doc = {**{k: v for k, v in body.items() if v is not None}, "request_id": f"console-{secrets.token_hex(6)}"}
        # what the client sent, as far as it is a run id and a point: any other value (a list, NaN, a megabyte of
        # text) is recorded by its type only, so that the record can always be stored
        record = {"source": "console", "verb": verb, "run_id": _recordable(body.get("run_id"), RECORDED_RUN_ID),
                  "point": _recordable(body.get("point"), RECORDED_POINT), "peer": request.remote}
        try:
            if not self._tokens and not self._open_bench:
                raise RgseError("the console needs mqtt.command_tokens (broker_acl authenticates MQTT clients only, "
                                "not this page): nothing done")
            cmd = parse_command(verb, json.dumps(doc), self._tokens)
            reply = await getattr(self._handler, verb)(cmd)
        except (CommandRefused, RgseError) as exc:
            error = exc.problem if isinstance(exc, CommandRefused) else str(exc)
            await self._record(f"console {verb} refused: {error}", {**record, "ok": False, "error": error})
            return web.json_response({"ok": False, "error": error}, status=409)
        if verb in ("measure", "properties") and isinstance(reply.get("run_id"), str):
            record["run_id"] = reply["run_id"]  # the run the console started
        await self._record(f"console {verb}", {**record, "ok": True})
        return web.json_response({"ok": True, **reply})

    async def _record(self, message: str, data: dict[str, Any]) -> None:
        run_id = data.get("run_id")
        try:
            try:
                await self._store.add_event("info", "console_action", message, data=data,
                                            run_id=run_id if isinstance(run_id, str) and run_id else None)
            except RgseError:
                if not run_id:
                    raise
                # a run id of no stored run (a typo, a guess): the action is recorded, with the id in its data only
                await self._store.add_event("info", "console_action", message, data=data)
        except RgseError as exc:
            log.error("console action not recorded: %s (%s)", message, exc)

    async def _confirm(self, request: web.Request) -> web.Response:
        return await self._act("confirm", request)

    async def _abort(self, request: web.Request) -> web.Response:
        return await self._act("abort", request)

    async def _measure(self, request: web.Request) -> web.Response:
        return await self._act("measure", request)

    async def _properties(self, request: web.Request) -> web.Response:
        return await self._act("properties", request)

    async def _history(self, request: web.Request) -> web.Response:
        runs = (await self._store.list_runs(robot=self.robot))[-HISTORY_RUNS:]
        rows = []
        for r in reversed(runs):
            results = await self._store.results(r.id)
            res = results[-1].result if results else None
            link = None
            if res is not None:
                link = f"/report/calibration/{res['calibration_id']}" if r.kind == RunKind.CALIBRATION and \
                    res.get("calibration_id") else f"/report/run/{r.id}"
            identity = (r.config.get("settings") or {}).get("identity") if isinstance(r.config, dict) else None
            rows.append({"run_id": r.id, "kind": r.kind.value, "state": str(r.state), "result": res, "report": link,
                         "status": results[-1].status if results else None, "detail": r.detail,
                         "identity": identity, "ended": r.ended_utc.isoformat() if r.ended_utc else None})
        return web.json_response({"robot": self.robot, "runs": rows})

    async def _report(self, request: web.Request) -> web.StreamResponse:
        what, ident = request.match_info["what"], request.match_info["id"]
        if self._reports_pending >= REPORT_QUEUE:
            raise web.HTTPServiceUnavailable(text=f"{REPORT_QUEUE} reports are being rendered; try again shortly")

        def write() -> Path:
            with Repository.open(self._store_url, self._data_dir) as repo:
                return build_report(repo, self._data_dir, self._data_dir / "reports",
                                    run_id=ident if what == "run" else None,
                                    calibration_id=ident if what == "calibration" else None)

        def rendered(f: asyncio.Future[Path]) -> None:
            self._reports_pending -= 1
            if not f.cancelled():
                f.exception()  # retrieved here: the request may have given up waiting (deadline, client gone)

        fut = asyncio.get_running_loop().run_in_executor(self._reports, write)
        self._reports_pending += 1
        fut.add_done_callback(rendered)
        try:
            path = await asyncio.wait_for(asyncio.shield(fut), REPORT_TIMEOUT_S)
        except TimeoutError:
            raise web.HTTPServiceUnavailable(text=f"the report of {what} {ident} was not rendered within "
                                                  f"{REPORT_TIMEOUT_S:g} s; try again shortly") from None
        except RgseError as exc:
            raise web.HTTPNotFound(text=f"no report of {what} {ident}: {exc}") from None
        return web.FileResponse(path, headers={"Content-Type": "text/html; charset=utf-8"})


async def _security_headers(request: web.Request, response: web.StreamResponse) -> None:
    """On every answer (the page, the stream, the API, the reports, the refusals): no framing, no sniffing."""
    for k, v in FRAME_HEADERS.items():
        response.headers.setdefault(k, v)
    response.headers.setdefault("Content-Security-Policy", OTHER_CSP)


def _script_hash(html: str) -> str:
    """``sha256-…`` of the page's one inline script, as a Content-Security-Policy source names it."""
    body = html.split("<script>", 1)[1].split("</script>", 1)[0]
    return "sha256-" + base64.b64encode(hashlib.sha256(body.encode("utf-8")).digest()).decode()


#: The shapes of a run id and a point that a console action's record keeps as sent (interfaces §4.3 bounds).
RECORDED_RUN_ID = re.compile(r"[A-Za-z0-9_.\-]{1,128}")
RECORDED_POINT = range(0, 1001)


def _recordable(value: Any, shape: re.Pattern[str] | range) -> Any:
    """``value`` if it has ``shape`` (or is absent), else what it was: ``"(invalid <type>)"``."""
    if value is None:
        return None
    if isinstance(shape, range):
        if isinstance(value, int) and not isinstance(value, bool) and value in shape:
            return value
    elif isinstance(value, str) and shape.fullmatch(value):
        return value
    return f"(invalid {type(value).__name__})"


def _finite(v: Any) -> Any:
    """NaN and infinities as ``null`` (the browser's JSON has none)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite(x) for x in v]
    return v


def _sse(kind: str, doc: Any) -> bytes:
    text = json.dumps(_finite(doc), separators=(",", ":"), allow_nan=False, default=str)
    return f"event: {kind}\ndata: {text}\n\n".encode()
