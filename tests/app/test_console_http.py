"""The console's HTTP face (interfaces §4.4) as an unknown client meets it, over raw sockets against the daemon on
the simulated KR C4: bad bodies get a 4xx with a reason, never a 500; a client that stalls (a body never finished,
headers byte by byte, nothing at all) holds its connection only until a deadline, and does not hold up the daemon's
stop."""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import threading
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from rgse_daemon.config import config_from_mapping
from rgse_daemon.services import console as console_module
from rgse_daemon.store import Store
from simulators.krc4.sim import SimulatedKrc4
from tests.support.daemon import COMMAND_TOKEN, RunningDaemon, daemon_config, running_daemon
from tests.support.polling import wait_until

IO_S = 10.0  # a hang guard on each socket read, not a timing check


@pytest.fixture
async def console(sim: SimulatedKrc4, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> AsyncIterator[RunningDaemon]:
    """The daemon with its console on a free port (tokens configured, no broker), its deadlines short."""
    monkeypatch.setattr(console_module, "BODY_TIMEOUT_S", 0.5)
    monkeypatch.setattr(console_module, "IDLE_TIMEOUT_S", 1.0)
    doc = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir).model_dump(mode="json")
    doc["console"] = {"enabled": True, "host": "127.0.0.1", "port": 0}
    cfg = config_from_mapping({k: v for k, v in doc.items() if v is not None}, "<console http test>")
    async with running_daemon(cfg) as rd:
        yield rd


async def exchange(port: int, request: bytes) -> tuple[int, bytes]:
    """Send ``request`` on a fresh connection; the response's status and body (the server closes)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        async with asyncio.timeout(IO_S):
            raw = await reader.read()
    finally:
        writer.close()
        await writer.wait_closed()
    head, _, body = raw.partition(b"\r\n\r\n")
    return int(head.split(b" ")[1]), body


def post(path: str, body: bytes, csrf: str, **headers: str) -> bytes:
    """A POST as the console's own page sends it (its Host, JSON, the anti-CSRF token); ``headers`` add or replace
    (``Content_Type="text/plain"``; a value ``""`` leaves the header out)."""
    head = {"Host": "127.0.0.1", "Connection": "close", "Content-Type": "application/json", "X-RGSE-CSRF": csrf,
            **{k.replace("_", "-"): v for k, v in headers.items()}}
    lines = "".join(f"{k}: {v}\r\n" for k, v in head.items() if v)
    return (f"POST {path} HTTP/1.1\r\n{lines}"
            f"Content-Length: {len(body)}\r\n\r\n").encode() + body


async def test_a_body_nested_too_deeply_is_a_400_with_its_reason(console: RunningDaemon) -> None:
    port = console.daemon.console.port
    csrf = console.daemon.console.csrf
    for path, body in (("/api/confirm", b"[" * 20000 + b"]" * 20000),
                       ("/api/abort", b'{"reason": "x", "a": ' + b"[" * 5000 + b"]" * 5000 + b"}")):
        status, text = await exchange(port, post(path, body, csrf))
        assert (status, json.loads(text)) == (400, {"ok": False, "error": "a JSON object expected: nested too deeply"})
    status, text = await exchange(port, post("/api/abort", b'{"reason": "x"}', csrf))
    assert status == 409 and json.loads(text)["error"] == "unauthorised: missing or wrong token"
    # larger than a command may be (64 KiB, interfaces §4.3): 413 with the reason, as JSON like every other answer
    big = json.dumps({"reason": "x" * (64 * 1024)}).encode()
    status, text = await exchange(port, post("/api/abort", big, csrf))
    assert (status, json.loads(text)) == (413, {"ok": False, "error": "body larger than 65536 bytes, the limit of a "
                                                                      "command"})


async def test_a_body_with_a_key_given_twice_is_a_400_naming_the_key(console: RunningDaemon) -> None:
    """Issue 31 6e: the console's API is as strict as the MQTT commands: a duplicate key is refused, not last-wins."""
    port = console.daemon.console.port
    csrf = console.daemon.console.csrf
    body = json.dumps({"reason": "x", "token": COMMAND_TOKEN})[:-1].encode() + b', "reason": "y"}'
    status, text = await exchange(port, post("/api/abort", body, csrf))
    assert (status, json.loads(text)) == (400, {"ok": False, "error": "duplicate key 'reason' in the JSON object"})


async def closed_by_server(reader: asyncio.StreamReader) -> bool:
    """Whether the server closes the connection (EOF) within the hang guard, reading whatever it sends first."""
    try:
        async with asyncio.timeout(IO_S):
            await reader.read()
    except TimeoutError:
        return False
    return True


async def test_stalled_clients_are_dropped_at_a_deadline_and_do_not_hold_up_the_stop(console: RunningDaemon) -> None:
    port = console.daemon.console.port
    csrf = console.daemon.console.csrf
    conns = [await asyncio.open_connection("127.0.0.1", port) for _ in range(4)]
    (body_r, body_w), (head_r, head_w), (idle_r, _), (sse_r, sse_w) = conns
    body_w.write(b"POST /api/abort HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                 b"X-RGSE-CSRF: " + csrf.encode() + b"\r\nContent-Length: 100\r\n\r\n{\"re")  # never the rest
    head_w.write(b"GET / HTTP/1.1\r\nHo")  # and never the rest of the headers
    sse_w.write(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")  # a page that reads
    try:
        async with asyncio.timeout(IO_S):
            head = await body_r.readuntil(b"\r\n\r\n")
            assert head.startswith(b"HTTP/1.1 408 "), head
            length = int(next(h for h in head.split(b"\r\n") if h.lower().startswith(b"content-length:"))[15:])
            body = await body_r.readexactly(length)
        assert json.loads(body) == {"ok": False, "error": "request body not received within 0.5 s"}
        assert await closed_by_server(head_r), "a request head that never ends is closed"
        assert await closed_by_server(idle_r), "a connection that never sends anything is closed"
        # the idle deadline does not cut a page's event stream: it gets state events well beyond it
        async with asyncio.timeout(IO_S):
            await sse_r.readuntil(b"event: hello")
            await asyncio.sleep(2.0)
            assert b"event: state" in await sse_r.read(1 << 20) and not sse_r.at_eof()
        # a body never finished and a head never finished, open while the daemon stops
        late = [await asyncio.open_connection("127.0.0.1", port) for _ in range(2)]
        late[0][1].write(b"POST /api/confirm HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                         b"X-RGSE-CSRF: " + csrf.encode() + b"\r\nContent-Length: 100\r\n\r\n{")
        late[1][1].write(b"GET /events HTTP/1.1\r\nHo")
        await asyncio.sleep(0.1)
        assert await console.shutdown() < 5.0
        conns += late
    finally:
        for _, writer in conns:
            writer.close()


async def test_every_action_is_recorded_whatever_its_run_id_and_point(console: RunningDaemon) -> None:
    """Refused actions are recorded too (interfaces §4.4), also with fields of any type or a run id of no stored run:
    the record keeps a value of the right shape as sent, anything else by its type."""
    port = console.daemon.console.port
    csrf = console.daemon.console.csrf
    sent = [
        ("/api/confirm", {"run_id": [1, 2], "point": {"a": 1}}, "unauthorised: missing or wrong token"),
        ("/api/confirm", {"run_id": "r" * 5000, "point": 10**30, "token": COMMAND_TOKEN}, "schema: run_id"),
        ("/api/abort", {"run_id": "no-such-run", "reason": "x", "token": COMMAND_TOKEN}, "no run in progress"),
    ]
    for path, body, error in sent:
        status, text = await exchange(port, post(path, json.dumps(body).encode(), csrf))
        assert status == 409 and json.loads(text)["error"].startswith(error)
    status, text = await exchange(port, post("/api/confirm", b'{"run_id": "r", "point": NaN}', csrf))
    assert status == 409
    await console.shutdown()
    cfg = console.daemon.cfg
    async with await Store.open(cfg.store.url, cfg.paths.data_dir) as store:
        actions = [e.data for e in await store.events() if e.kind == "console_action"]
    assert [(a["verb"], a["run_id"], a["point"], a["ok"]) for a in actions] == [
        ("confirm", "(invalid list)", "(invalid dict)", False),
        ("confirm", "(invalid str)", "(invalid int)", False),
        ("abort", "no-such-run", None, False),
        ("confirm", "r", "(invalid float)", False),
    ]


async def open_stream(port: int) -> tuple[int, asyncio.StreamWriter]:
    """Open ``/events``; the status, and the writer (the stream stays open) once the hello or the refusal is in."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    async with asyncio.timeout(IO_S):
        head = await reader.readuntil(b"\r\n\r\n")
        status = int(head.split(b" ")[1])
        if status == 200:
            await reader.readuntil(b"event: hello")
    return status, writer


async def test_pages_that_open_together_share_one_controller_read_and_their_number_is_capped(
        sim: SimulatedKrc4, console: RunningDaemon, monkeypatch: pytest.MonkeyPatch) -> None:
    """Opening a page must not cost a controller read each (the link the interlock polls): pages that open together
    get one read between them; beyond MAX_STREAMS a page is answered 503 with its reason."""
    page = console.daemon.console
    monkeypatch.setattr(console_module, "MAX_STREAMS", 12)
    page.period_s = 60.0  # the state loop sleeps through the test: every read here is a page's hello
    await asyncio.sleep(0.5)  # (the loop's current short sleep ends; the next is the long one)
    reads = sim.server.counters.by_type[6]  # #6: the snapshot's read of several variables at once
    opened = await asyncio.gather(*(open_stream(page.port) for _ in range(12)))
    try:
        assert [status for status, _ in opened] == [200] * 12
        assert sim.server.counters.by_type[6] - reads == 1
        status, text = await exchange(page.port, get("/events"))
        assert (status, json.loads(text)) == (503, {"ok": False, "error": "12 event streams are open already: "
                                                                          "close a page and reload"})
    finally:
        for _, writer in opened:
            writer.close()
        async with asyncio.timeout(IO_S):
            await asyncio.gather(*(writer.wait_closed() for _, writer in opened), return_exceptions=True)
    await console.shutdown()


def get(path: str) -> bytes:
    return f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode()


async def test_reports_render_on_the_consoles_own_thread_and_a_flood_is_turned_away(
        console: RunningDaemon, monkeypatch: pytest.MonkeyPatch) -> None:
    """A report never takes a thread of the default pool, which the run needs (the static check before every motion
    runs there), however often pages load it: reports render one at a time on the console's own thread, 4 requests
    may wait or render, one more is answered 503 at once, and so is one not rendered within the deadline."""
    con = console.daemon.console
    port, queue = con.port, console_module.REPORT_QUEUE
    gate = threading.Event()
    con._reports.submit(gate.wait, IO_S)  # the console's render thread busy, as with one slow report
    try:
        waiting = [asyncio.create_task(exchange(port, get(f"/report/run/no-such-run-{i}"))) for i in range(queue)]
        await wait_until(lambda: con._reports_pending == queue, "the report requests queued", IO_S)
        assert await exchange(port, get("/report/calibration/c1")) == (
            503, f"{queue} reports are being rendered; try again shortly".encode())
        # the default pool is free while the reports wait
        assert await asyncio.wait_for(asyncio.to_thread(lambda: threading.current_thread().name), IO_S) != \
            "rgse-console-report_0"
    finally:
        gate.set()
    for status, body in await asyncio.gather(*waiting):  # each was queued, not dropped: rendered (none is stored)
        assert status == 404 and body.startswith(b"no report of run no-such-run-"), body
    assert [t.name for t in threading.enumerate() if t.name.startswith("rgse-console-report")] == [
        "rgse-console-report_0"]
    assert con._reports_pending == 0

    monkeypatch.setattr(console_module, "REPORT_TIMEOUT_S", 0.3)
    gate.clear()
    con._reports.submit(gate.wait, IO_S)
    try:
        assert await exchange(port, get("/report/run/r1")) == (
            503, b"the report of run r1 was not rendered within 0.3 s; try again shortly")
    finally:
        gate.set()
    # the late render finishes on its thread and frees its place
    await wait_until(lambda: con._reports_pending == 0, "the late render finished", IO_S)


# --- issue 31 6c: only the console's own page acts ------------------------------------------------------------------
async def answer(port: int, request: bytes) -> tuple[int, dict[str, str], bytes]:
    """Status, headers (lower-case names) and body of the response to ``request`` on a fresh connection."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        async with asyncio.timeout(IO_S):
            raw = await reader.read()
    finally:
        writer.close()
        await writer.wait_closed()
    head, _, body = raw.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.strip().lower(): v.strip() for k, _, v in (ln.partition(":") for ln in lines[1:])}
    return int(lines[0].split(" ")[1]), headers, body


async def hello_csrf(port: int, host: str = "127.0.0.1") -> str | None:
    """The anti-CSRF token of the ``hello`` event, as the page reads it (None if the stream is refused)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(f"GET /events HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())
        async with asyncio.timeout(IO_S):
            head = await reader.readuntil(b"\r\n\r\n")
            if not head.startswith(b"HTTP/1.1 200 "):
                return None
            await reader.readuntil(b"event: hello\ndata: ")
            hello = json.loads(await reader.readuntil(b"\n"))
    finally:
        writer.close()
    return hello["csrf"]


@pytest.fixture
async def open_bench(sim: SimulatedKrc4, tmp_path: Path) -> AsyncIterator[RunningDaemon]:
    """The daemon with its console and no command tokens (``command_auth = "open_lab_bench"``): the mode in which
    the issue's cross-site POST aborted a run."""
    doc = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir).model_dump(mode="json")
    doc["console"] = {"enabled": True, "host": "127.0.0.1", "port": 0, "allowed_hosts": ["rgse.lab.example"]}
    doc["mqtt"] = {**doc["mqtt"], "command_tokens": [], "command_auth": "open_lab_bench"}
    cfg = config_from_mapping({k: v for k, v in doc.items() if v is not None}, "<console csrf test>")
    async with running_daemon(cfg) as rd:
        yield rd


ABORT = b'{"reason": "pwned"}'


@pytest.mark.parametrize(("headers", "status", "error"), [
    # a page on another site: a "simple" request that a browser sends without asking (no preflight)
    ({"Origin": "http://evil.example", "Content_Type": "text/plain", "X_RGSE_CSRF": ""}, 403,
     "cross-origin request from 'http://evil.example'"),
    ({"Origin": "http://evil.example"}, 403, "cross-origin request"),  # even with the token
    ({"Origin": "http://127.0.0.1:1"}, 403, "cross-origin request"),  # another port of this machine: another site
    ({"Sec_Fetch_Site": "cross-site"}, 403, "cross-site request"),
    ({"Content_Type": "text/plain"}, 415, "Content-Type 'text/plain'"),
    ({"Content_Type": "application/x-www-form-urlencoded"}, 415, "an action is application/json"),
    ({"X_RGSE_CSRF": ""}, 403, "missing or wrong X-RGSE-CSRF"),
    ({"X_RGSE_CSRF": "guess"}, 403, "missing or wrong X-RGSE-CSRF"),
    # DNS rebinding: the attacker's name now resolves to this machine; the page is the attacker's
    ({"Host": "evil.example", "Origin": "http://evil.example"}, 421, "Host 'evil.example' is not one"),
])
async def test_a_post_that_is_not_the_pages_own_is_refused_unread(
        open_bench: RunningDaemon, headers: dict[str, str], status: int, error: str) -> None:
    console = open_bench.daemon.console
    got, _, text = await answer(console.port, post("/api/abort", ABORT, console.csrf, **headers))
    assert (got, json.loads(text)["ok"]) == (status, False) and error in json.loads(text)["error"], (got, text)


async def test_the_pages_own_post_reaches_the_handler(open_bench: RunningDaemon) -> None:
    """Same origin (the page at http://127.0.0.1:PORT or behind the configured proxy name), JSON, the token of
    hello: the command is handled (no run in progress, so the abort is refused by the daemon, not the guard)."""
    console = open_bench.daemon.console
    port = console.port
    csrf = await hello_csrf(port)
    assert csrf == console.csrf
    for extra in ({"Origin": f"http://127.0.0.1:{port}", "Host": f"127.0.0.1:{port}", "Sec_Fetch_Site": "same-origin"},
                  {"Origin": "https://rgse.lab.example", "Host": "rgse.lab.example"}, {}):
        got, _, text = await answer(port, post("/api/abort", ABORT, csrf, **extra))
        assert (got, json.loads(text)) == (409, {"ok": False, "error": "no run in progress"}), (extra, text)


async def test_a_rebound_host_gets_neither_the_page_nor_the_token(open_bench: RunningDaemon) -> None:
    port = open_bench.daemon.console.port
    assert await hello_csrf(port, host="evil.example") is None
    status, _, _ = await answer(port, b"GET / HTTP/1.1\r\nHost: evil.example:8080\r\nConnection: close\r\n\r\n")
    assert status == 421


async def test_every_answer_forbids_framing_and_the_page_allows_its_own_script_only(
        open_bench: RunningDaemon) -> None:
    port = open_bench.daemon.console.port
    status, headers, body = await answer(port, b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
    assert status == 200 and headers["x-frame-options"] == "DENY"
    csp = headers["content-security-policy"]
    assert "frame-ancestors 'none'" in csp and "default-src 'none'" in csp and "unsafe-inline" not in \
        csp.split("script-src", 1)[1].split(";", 1)[0], csp
    script = body.decode().split("<script>", 1)[1].split("</script>", 1)[0]
    digest = base64.b64encode(hashlib.sha256(script.encode()).digest()).decode()
    assert f"script-src 'sha256-{digest}'" in csp  # the page's one script, and nothing else, may run
    for request in (get("/api/history"), get("/report/run/none"),
                    post("/api/abort", ABORT, "wrong")):
        _, headers, _ = await answer(port, request)
        assert headers["x-frame-options"] == "DENY" and "frame-ancestors 'none'" in \
            headers["content-security-policy"], headers
