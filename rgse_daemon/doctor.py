"""``rgse doctor``: the commissioning check of a controller and its surroundings, run first on a new KR C4 and after
any change. It never moves the robot: it reads, writes only values a variable already has (and the watchdog's timer,
line 9a), and does one small file round trip in the TRACE folder.

:func:`run_doctor` returns a :class:`DoctorReport`: one :class:`Check` per line, in this order, each failed one with
the fix. Checks that need the controller are not run (and fail) when it cannot be reached.

1. ``controller``: reachable; the protocol (C3 Bridge or plain KUKAVARPROXY), the version and the round-trip time.
2. ``protocol``: C3 Bridge ≥ 1.2 (multi-read #6, file messages) or, for plain KVP, the mounted share.
3. ``mode and safety``: ``$MODE_OP`` T1, no stop message, operator safety closed, no program running.
4. ``variables``: every variable the daemon reads answers and parses.
5. ``handshake globals``: every global of ``krl/rgse_globals.dat`` is declared; an installed data list matches it.
6. ``resident program``: ``KRC:\\R1\\PROGRAM\\RGSE_RESIDENT.SRC`` is the one ``rgse krl render`` makes (SHA-256).
7. ``trace configuration``: the daemon's trace configuration file can be written into TRACE and reads back.
8. ``file round trip``: write, list, read back, delete a file in TRACE; this finds the path form and listing format
   that work and measures the file rate; the result is recorded in ``<data_dir>/controller_layout.json``
   (:mod:`rgse_daemon.filelayout`), which the daemon then uses.
9. ``allowed writes``: every variable on the write allow-list (and the handshake globals) accepts the value it has.
9a. ``controller watchdog``: the controller-side watchdog (docs/security.md) is installed and armed: the resident
   program holds the rendered watchdog (``resident program`` checks it is the current rendering; this line runs the
   static check's ``WATCHDOG`` rule on what is installed), ``$TIMER[16]`` exists and counts milliseconds, and a
   daemon's heartbeat keeps it fresh. With no daemon beating and no program running, the doctor times the timer
   itself (it sets it to minus the bound, lets it run 0.3 s and stops it again: nothing can move, a program that
   waits for a heartbeat is not running; one started by hand in those 0.3 s would move until the doctor stops the
   timer, as with a daemon that dies); with a program running and no heartbeat, it writes nothing.
10. ``safety I/O`` / 11. ``scale``: answer, if configured.
12. ``broker`` (if MQTT is enabled) and 13. ``store``.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import re
import statistics
import time
from collections.abc import Awaitable
from dataclasses import dataclass, field
from pathlib import Path

from rgse_daemon.config import Config, Protocol
from rgse_daemon.controller import WRITABLE_VARIABLES, Controller
from rgse_daemon.errors import RgseError
from rgse_daemon.filelayout import TRACE_DIR_CANDIDATES, FileLayout, save_layout
from rgse_daemon.krc import SNAPSHOT_VARIABLES, DirEntry, KrcController
from rgse_daemon.krl import ast as k
from rgse_daemon.krl.parser import parse_dat, parse_src
from rgse_daemon.krl.render import TemplateDefaults, default_params, globals_dat_text, render
from rgse_daemon.link import frames as fr
from rgse_daemon.link.krlvalue import parse_value
from rgse_daemon.safety.allowlist import WATCHDOG_TIMER
from rgse_daemon.safety.static import CheckContext, watchdog_violations

#: Where the KRL of krl/README.md is installed on the controller.
PROGRAM_DIR = "KRC:\\R1\\PROGRAM\\"
RESIDENT = "rgse_resident"
GLOBALS_FILE = PROGRAM_DIR + "RGSE_GLOBALS.DAT"
#: The round trip's file: big enough to measure the controller's file rate, small enough to be quick.
ROUND_TRIP_NAME = "RGSE_DOCTOR.TXT"
ROUND_TRIP_BYTES = 32 * 1024
#: Variables the daemon reads besides the snapshot (trace control).
READ_VARIABLES: tuple[str, ...] = (*SNAPSHOT_VARIABLES, "$TRACE.MODE", "$TRACE.CONFIG[]", "$TRACE.NAME[]")
#: C3 Bridge version the daemon needs: #6 multi-read and the file messages (1.2.0).
MIN_VERSION = (1, 2)
PING_SAMPLES = 10
#: Deadline of each external check (s) besides the controller's own request deadlines.
CHECK_TIMEOUT_S = 30.0
#: The broker check's bound of each wait for the broker (CONNACK, the DISCONNECT) and of closing a connect given up.
BROKER_TIMEOUT_S = 5.0


#: The checks that need the controller's link, in their order after the ``controller`` line.
CONTROLLER_CHECKS = ("protocol", "mode and safety", "variables", "handshake globals", "resident program",
                     "trace configuration", "file round trip", "allowed writes", "controller watchdog")


@dataclass(frozen=True)
class Check:
    """One line of the checklist: ``ok`` None means not applicable (not configured)."""

    name: str
    ok: bool | None
    detail: str
    fix: str = ""

    def line(self) -> str:
        mark = {True: "PASS", False: "FAIL", None: "skip"}[self.ok]
        text = f"[{mark}] {self.name}: {self.detail}"
        return text + (f"\n       fix: {self.fix}" if self.ok is False and self.fix else "")


@dataclass
class DoctorReport:
    checks: list[Check] = field(default_factory=list)
    layout: FileLayout | None = None
    layout_file: Path | None = None

    @property
    def ok(self) -> bool:
        return all(c.ok is not False for c in self.checks)

    def text(self) -> str:
        lines = [c.line() for c in self.checks]
        if self.layout_file is not None:
            lines.append(f"recorded the controller's file layout in {self.layout_file}")
        lines.append("all checks passed" if self.ok else
                     f"{sum(c.ok is False for c in self.checks)} check(s) failed")
        return "\n".join(lines)


def handshake_globals() -> list[str]:
    """Names of the GLOBALs declared in ``krl/rgse_globals.dat``."""
    data = parse_dat(globals_dat_text(), "rgse_globals.dat")
    return [dn.name for d in data.decls if isinstance(d, k.Decl) and d.is_global for dn in d.names]


def krl_bytes(text: str) -> bytes:
    """KRL as it lies on the controller: ISO-8859-1, CRLF line ends (as ``rgse krl render`` writes it)."""
    return text.replace("\r\n", "\n").replace("\n", "\r\n").encode("latin-1")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


async def run_doctor(cfg: Config, krl_defaults: TemplateDefaults, *, record: bool = True) -> DoctorReport:
    """Run every check (module docstring); ``record`` saves the file layout found into the data directory."""
    report = DoctorReport()
    add = report.checks.append
    try:
        async with Controller.connect(cfg.controller) as krc:
            add(await _reachable(krc, cfg))
            add(await _protocol(krc, cfg))
            add(await _guarded("mode and safety", _mode_and_safety(krc)))
            add(await _guarded("variables", _variables(krc)))
            add(await _guarded("handshake globals", _globals(krc)))
            add(await _guarded("resident program", _resident(krc, krl_defaults)))
            add(await _guarded("trace configuration", _trace_config(krc, cfg)))
            check, layout = await _round_trip(krc, cfg)
            add(check)
            if layout is not None and record:
                report.layout, report.layout_file = layout, save_layout(cfg.paths.data_dir, layout)
            add(await _guarded("allowed writes", _allowed_writes(krc)))
            add(await _guarded("controller watchdog", _watchdog(krc, cfg)))
    except (RgseError, OSError) as exc:
        where = f"{cfg.controller.host}:{cfg.controller.port}"
        add(Check("controller", False, f"cannot talk to {where}: {type(exc).__name__}: {exc}",
                  "check the controller's address and port (controller.host/port), the network and the firewall, "
                  "and that C3 Bridge (or KUKAVARPROXY) runs on the KR C4 (Windows side, port 7000)"))
        # one line for what depends on the link, not one failed line each: one thing is wrong, and it is above
        add(Check("controller checks", None, "not run until the controller answers: " + ", ".join(CONTROLLER_CHECKS)))
    add(await _guarded("safety I/O", _modbus(cfg)))
    add(await _guarded("scale", _scale(cfg)))
    add(await _guarded("broker", _broker(cfg)))
    add(await _guarded("store", _store(cfg)))
    return report


async def _guarded(name: str, aw: Awaitable[Check]) -> Check:
    """A check with a deadline; an unexpected failure becomes a failed line, never a crash of the checklist."""
    try:
        async with asyncio.timeout(CHECK_TIMEOUT_S):
            return await aw
    except TimeoutError:
        return Check(name, False, f"no answer within {CHECK_TIMEOUT_S:g} s", "see the lines above; retry")
    except (RgseError, OSError) as exc:
        return Check(name, False, f"{type(exc).__name__}: {exc}", "see the message; retry after fixing it")


# --- the controller ---------------------------------------------------------------------------------------------------
async def _reachable(krc: KrcController, cfg: Config) -> Check:
    rtts = []
    for _ in range(PING_SAMPLES):
        t0 = time.monotonic()
        await krc.read_raw("PING")
        rtts.append(time.monotonic() - t0)
    what = "C3 Bridge" if krc.protocol is Protocol.C3BRIDGE else "plain KUKAVARPROXY"
    where = f"{cfg.controller.host}:{cfg.controller.port}"
    return Check("controller", True, f"{where} answers ({what}); PING round trip median "
                 f"{statistics.median(rtts) * 1e3:.1f} ms, max {max(rtts) * 1e3:.1f} ms")


async def _protocol(krc: Controller, cfg: Config) -> Check:
    # the server's version and message types: a question to the TCP server itself, not to any KrcController
    if krc.protocol is Protocol.KVP:
        if cfg.controller.share_dir is None:
            return Check("protocol", False, "plain KUKAVARPROXY: no program control, and files only over the share",
                         "install C3 Bridge on the KR C4, or mount its roboter share and set controller.share_dir")
        return Check("protocol", True, f"plain KUKAVARPROXY; files over the share {cfg.controller.share_dir}")
    rsp = await krc.pool.request(fr.ProxyInfo())
    if not isinstance(rsp, fr.ProxyInfoReply) or not rsp.success:
        return Check("protocol", False, f"C3 Bridge does not answer #13 (code {rsp.code})",
                     "update C3 Bridge on the KR C4 to 1.2 or later")
    version = f"{rsp.major}.{rsp.minor} on {rsp.computer_name}"
    missing = [t for t in (fr.MsgType.READ_MULTI, fr.MsgType.PROGRAM_CONTROL, fr.MsgType.READ_CONTENT,
                           fr.MsgType.WRITE_CONTENT, fr.MsgType.NAME_LIST, fr.MsgType.DELETE)
               if not krc.pool.supports(t)]
    if (rsp.major, rsp.minor) < MIN_VERSION or missing:
        return Check("protocol", False, f"C3 Bridge {version}: too old (missing message types "
                     f"{', '.join(str(int(t)) for t in missing) or 'none'})",
                     f"update C3 Bridge on the KR C4 to {MIN_VERSION[0]}.{MIN_VERSION[1]} or later")
    return Check("protocol", True, f"C3 Bridge {version}")


async def _mode_and_safety(krc: KrcController) -> Check:
    snap = await krc.snapshot()
    problems, fixes = [], []
    if snap.mode_op != "T1":
        problems.append(f"$MODE_OP is #{snap.mode_op}")
        fixes.append("turn the mode selector (key switch) to T1")
    if snap.stopmess is not False:
        problems.append(f"$STOPMESS is {snap.stopmess}")
        fixes.append("acknowledge the stop messages on the smartPAD")
    if snap.user_saf is not True:
        problems.append(f"$USER_SAF is {snap.user_saf}")
        fixes.append("close the safety gate / operator safety")
    if snap.pro_state1 == "P_ACTIVE":
        problems.append(f"program {snap.pro_name1} is running")
        fixes.append("stop and cancel the running program before commissioning")
    if problems:
        return Check("mode and safety", False, "; ".join(problems), "; ".join(fixes))
    return Check("mode and safety", True, f"T1, no stop message, operator safety closed, interpreter "
                 f"#{snap.pro_state1}")


async def _variables(krc: KrcController) -> Check:
    values = await krc.read_many(READ_VARIABLES)
    bad = []
    for name in READ_VARIABLES:
        got = values.get(name)
        if not isinstance(got, str):
            bad.append(f"{name} ({got})")
            continue
        try:
            parse_value(got)
        except RgseError as exc:
            bad.append(f"{name} (not a KRL value: {exc})")
    if bad:
        return Check("variables", False, f"{len(bad)} of {len(READ_VARIABLES)} unreadable: {'; '.join(bad)}",
                     "these system variables must be readable over the link: check the KSS version and that "
                     "C3 Bridge runs with the controller's Cross3 interface")
    return Check("variables", True, f"all {len(READ_VARIABLES)} variables the daemon reads answer")


async def _globals(krc: KrcController) -> Check:
    names = handshake_globals()
    values = await krc.read_many(names)
    missing = [n for n in names if not isinstance(values.get(n), str)]
    if missing:
        return Check("handshake globals", False, f"not declared on the controller: {', '.join(missing)}",
                     "install krl/rgse_globals.dat in KRC:\\R1\\Program (or its globals in $CONFIG.DAT), see "
                     "krl/README.md; on the simulator: rgse sim --globals rgse_globals.dat (from rgse krl render)")
    detail = f"all {len(names)} declared"
    try:
        installed = await krc.get_file(GLOBALS_FILE)
    except RgseError:
        return Check("handshake globals", True, detail + " (no RGSE_GLOBALS.DAT: declared elsewhere)")
    if _sha(krl_bytes(installed.decode("latin-1"))) != _sha(krl_bytes(globals_dat_text())):
        return Check("handshake globals", False, f"{GLOBALS_FILE} differs from krl/rgse_globals.dat",
                     "install the current krl/rgse_globals.dat (rgse krl render) and re-select it")
    return Check("handshake globals", True, detail + f"; {GLOBALS_FILE} is current")


async def _resident(krc: KrcController, defaults: TemplateDefaults) -> Check:
    name = PROGRAM_DIR + RESIDENT.upper() + ".SRC"
    expected = krl_bytes(render(RESIDENT, default_params(RESIDENT, defaults)).src_text)
    fix = "rgse krl render --out build/krl --config FILE, then copy build/krl/rgse_resident.src to KRC:\\R1\\Program"
    try:
        installed = await krc.get_file(name)
    except RgseError as exc:
        return Check("resident program", False, f"{name} not readable ({exc})", fix)
    got, want = _sha(krl_bytes(installed.decode("latin-1"))), _sha(expected)
    if got != want:
        return Check("resident program", False, f"{name} is not the current rendering (sha256 {got[:12]}…, "
                     f"expected {want[:12]}…)", fix)
    return Check("resident program", True, f"{name} current (sha256 {want[:12]}…)")


async def _trace_config(krc: KrcController, cfg: Config) -> Check:
    from rgse_daemon.procedures.programs import TRACE_CONFIG_NAME, trace_config_xml
    from rgse_daemon.procedures.settings import RunSettings

    data = trace_config_xml(RunSettings.from_config(cfg)).encode("utf-8")
    name = TRACE_DIR_CANDIDATES[0] + TRACE_CONFIG_NAME
    await krc.put_file(name, data)
    if await krc.get_file(name, size_bytes=len(data)) != data:
        return Check("trace configuration", False, f"{name} reads back different", "check the controller's disk")
    return Check("trace configuration", True, f"{name} written and read back ({len(data)} bytes)")


def _listing_kind(entry: DirEntry, size: int) -> str:
    if entry.size_bytes == size:
        return "fields"
    if entry.listed_as:
        return "bare"
    return "text"


async def _round_trip(krc: KrcController, cfg: Config) -> tuple[Check, FileLayout | None]:
    """Write, list, read back and delete a file in TRACE with each path form until one works."""
    data = bytes((i * 7 + 3) % 251 for i in range(ROUND_TRIP_BYTES))
    if krc.protocol is Protocol.KVP:
        try:
            await _one_round_trip(krc, TRACE_DIR_CANDIDATES[0], data)
        except (RgseError, OSError) as exc:
            return Check("file round trip", False, f"on the share: {exc}", "check controller.share_dir's mount "
                         "(read and write access to the roboter share)"), None
        return Check("file round trip", True, "write, list, read, delete on the share"), None
    tried = []
    for trace_dir in TRACE_DIR_CANDIDATES:
        for trailing in (True, False):
            krc.layout = FileLayout(trace_dir, trailing)
            try:
                async with asyncio.timeout(CHECK_TIMEOUT_S):
                    entry, rate = await _one_round_trip(krc, trace_dir, data)
            except (RgseError, OSError, TimeoutError) as exc:
                tried.append(f"{krc.layout.folder(trace_dir)}: {exc}")
                continue
            layout = FileLayout(trace_dir, trailing, _listing_kind(entry, len(data)), round(rate))
            detail = (f"{trace_dir}{ROUND_TRIP_NAME}: written, listed as {entry.listed_as or entry.name!r} (info "
                      f"{entry.info!r}: {layout.listing}), read back, deleted; folder listed as "
                      f"{layout.folder(trace_dir)!r}; file rate ≈ {rate / 1000:.0f} kB/s")
            if cfg.controller.file_rate_bytes_s > rate:
                return Check("file round trip", False, detail + " — slower than the file deadlines assume",
                             f"file deadlines are sized with controller.file_rate_bytes_s = "
                             f"{cfg.controller.file_rate_bytes_s:g}: set it to about {rate / 2:.0f} (half the "
                             f"measured rate)"), layout
            return Check("file round trip", True, detail), layout
    krc.layout = None
    return Check("file round trip", False, "no path form worked: " + " | ".join(tried),
                 "check that C:\\KRC\\ROBOTER\\TRACE exists and C3 Bridge may write there; then rerun"), None


async def _one_round_trip(krc: KrcController, trace_dir: str, data: bytes) -> tuple[DirEntry, float]:
    name = trace_dir + ROUND_TRIP_NAME
    await krc.put_file(name, data)
    try:
        entries = [e for e in await krc.list_dir(trace_dir) if e.base_name.upper() == ROUND_TRIP_NAME]
        if not entries:
            raise RgseError(f"{ROUND_TRIP_NAME} written but not listed")
        t0 = time.monotonic()
        back = await krc.get_file(name, size_bytes=len(data))
        rate = len(data) / max(time.monotonic() - t0, 1e-6)
        if back != data:
            raise RgseError(f"{ROUND_TRIP_NAME} reads back different ({len(back)} bytes)")
    finally:
        await krc.delete_file(name)
    if any(e.base_name.upper() == ROUND_TRIP_NAME for e in await krc.list_dir(trace_dir)):
        raise RgseError(f"{ROUND_TRIP_NAME} still listed after delete")
    return entries[0], rate


async def _allowed_writes(krc: KrcController) -> Check:
    names = [*sorted(WRITABLE_VARIABLES), *handshake_globals()]
    refused, skipped = [], []
    for name in names:
        try:
            value = await krc.read_raw(name)
        except RgseError as exc:
            refused.append(f"{name} (unreadable: {exc})")
            continue
        if name == "$TRACE.MODE" and value.strip().upper() != "#T_STOP":
            skipped.append(f"{name} (is {value}: a trace is running, not touched)")
            continue
        try:
            await krc.write_raw(name, value)  # the value it has: nothing changes, nothing moves
        except RgseError as exc:
            refused.append(f"{name} ({exc})")
    if refused:
        return Check("allowed writes", False, f"refused: {'; '.join(refused)}",
                     "the daemon must write these (trace control, override, handshake): check C3 Bridge's write "
                     "access and that the variables are declared and not write-protected")
    extra = f"; not tried: {'; '.join(skipped)}" if skipped else ""
    return Check("allowed writes", True, f"all {len(names) - len(skipped)} accept their own value{extra}")


#: How long the doctor lets the watchdog's timer run to see it count (s).
TIMER_PROBE_S = 0.3
#: How long the doctor watches ``$TIMER[16]`` for a live heartbeat's rewrites before it takes it for none (s).
HEARTBEAT_WATCH_S = 2.0


async def _watchdog(krc: KrcController, cfg: Config) -> Check:
    name = "controller watchdog"
    fix_install = ("install the current rendering of the resident program (rgse krl render), see the 'resident "
                   "program' line")
    try:
        installed = (await krc.get_file(PROGRAM_DIR + RESIDENT.upper() + ".SRC")).decode("latin-1")
        module = parse_src(installed, RESIDENT + ".src")
    except RgseError as exc:  # (KrlSyntaxError is one)
        return Check(name, False, f"the resident program cannot be read or parsed ({exc})", fix_install)
    problems, _ = watchdog_violations(module, CheckContext(require_watchdog=True))
    if problems:
        return Check(name, False, f"the installed resident program does not arm the watchdog: {problems[0]}",
                     fix_install)
    timer, stop, flag = (f"${v}[{WATCHDOG_TIMER}]" for v in ("TIMER", "TIMER_STOP", "TIMER_FLAG"))

    async def read() -> tuple[int, bool, bool]:
        raw = await krc.read_many([timer, stop, flag])
        bad = [n for n in (timer, stop, flag) if not isinstance(raw.get(n), str)]
        if bad:
            raise RgseError(f"{', '.join(bad)} not readable on the controller: {raw.get(bad[0])}")
        value = parse_value(raw[timer])  # type: ignore[arg-type]
        if not isinstance(value, int) or isinstance(value, bool):
            raise RgseError(f"{timer} is {raw[timer]!r}, not an INT")
        return value, str(raw[stop]).strip().upper() == "TRUE", str(raw[flag]).strip().upper() == "TRUE"

    bound_ms = round(cfg.controller.watchdog_bound_s * 1000.0)
    value, stopped, tripped = await read()
    # a live heartbeat rewrites the timer every watchdog_period_s: watched for a change over at least
    # HEARTBEAT_WATCH_S, so that a heartbeat a few periods late on a busy PC is not taken for none (and the probe
    # below then not run against it: seen under a test suite's load, "counted 81 ms in 301 ms")
    # The watch runs its whole length even if the timer is stopped or tripped when first read: a heartbeat that is
    # just starting (a daemon starting beside the doctor) sets it running within a beat or two, and the probe below
    # must not run against it (seen under the suite's load: "counted 79 ms in 301 ms" with the first read stopped).
    period_s = cfg.controller.watchdog_period_s
    watch_until = time.monotonic() + max(3 * period_s, HEARTBEAT_WATCH_S)
    while time.monotonic() < watch_until:
        await asyncio.sleep(period_s)
        value2, stopped2, tripped2 = await read()
        if not stopped2 and not tripped2 and (value2 != value or stopped or tripped):
            return Check(name, True, f"armed: the resident program arms it, and a heartbeat keeps {timer} fresh "
                                     f"({value2} ms, trips at 0)")
        value, stopped, tripped = value2, stopped2, tripped2
    state = (await krc.read_raw("$PRO_STATE1")).strip().upper()
    if state == "#P_ACTIVE":
        return Check(name, False, f"no fresh heartbeat ({timer} = {value} ms, {stop} {stopped}) while a program "
                     "runs: a daemon program waits or has halted", "start the daemon (rgse daemon), or stop the "
                     "program; then run rgse doctor again")
    await krc.write_raw(timer, str(-bound_ms))
    await krc.write_raw(stop, "FALSE")
    try:
        t0 = time.monotonic()
        await asyncio.sleep(TIMER_PROBE_S)
        value2, _, flag2 = await read()
        elapsed_ms = (time.monotonic() - t0) * 1000.0
    finally:
        await krc.write_raw(stop, "TRUE")
    counted_ms = value2 + bound_ms
    if not (0.5 * elapsed_ms <= counted_ms <= 1.5 * elapsed_ms + 100.0) or flag2 != (value2 >= 0):
        return Check(name, False, f"{timer} counted {counted_ms} ms in {elapsed_ms:.0f} ms (flag {flag2})",
                     "the controller's system timer does not count as KSS documents: check the KSS version")
    return Check(name, True, f"installed (the resident program arms it; {timer} counted {counted_ms} ms in "
                             f"{elapsed_ms:.0f} ms); no daemon heartbeat now: programs wait for one before they move")


# --- around the controller -------------------------------------------------------------------------------------------
async def _modbus(cfg: Config) -> Check:
    if cfg.modbus is None:
        return Check("safety I/O", None, "no Modbus I/O configured (AUT is then refused)")
    from rgse_daemon.io.modbus import SafetyIo

    where = f"{cfg.modbus.host}:{cfg.modbus.port}"
    async with SafetyIo(cfg.modbus) as io:
        if not io.inputs.valid:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(cfg.modbus.connect_timeout_s + 10 * cfg.modbus.poll_period_s), \
                        io.changes() as changes:
                    async for seen in changes:
                        if seen.valid:
                            break
        inputs = io.inputs
    if not inputs.valid:
        return Check("safety I/O", False, f"{where}: no valid reading ({inputs.reason})",
                     "check the I/O module's address, power and network (modbus.host/port/unit_id)")
    return Check("safety I/O", True, f"{where}: E-stop {'OK' if inputs.estop_ok else 'OPEN'}, area cleared "
                 f"{inputs.area_cleared}, AUT key {inputs.aut_permitted}")


async def _scale(cfg: Config) -> Check:
    if cfg.scale is None:
        return Check("scale", None, "no crane scale configured")
    from rgse_daemon.io.scale import CraneScale

    async with CraneScale(cfg.scale) as scale:
        w = await scale.read_frame(timeout_s=10.0)
    return Check("scale", True, f"{cfg.scale.port}: {w!r}"[:200])


async def _broker(cfg: Config) -> Check:
    if not cfg.mqtt.enabled:
        return Check("broker", None, "MQTT disabled")
    import aiomqtt

    from rgse_daemon.io.mqtt_client import Client, enter, tls_context

    where = f"{cfg.mqtt.host}:{cfg.mqtt.port}"
    # the daemon's own TLS context (its CA, host-name check, a socket closed when the handshake fails)
    client = Client(cfg.mqtt.host, cfg.mqtt.port, username=cfg.mqtt.username, password=cfg.mqtt.password,
                    identifier=f"rgse-doctor-{time.time_ns()}", tls_context=tls_context(cfg.mqtt),
                    timeout=BROKER_TIMEOUT_S)
    try:
        # connecting (and the login it carries) is the check; a connect given up (no CONNACK, the check cancelled)
        # is closed, not left connected
        await enter(client, close_s=BROKER_TIMEOUT_S)
        await client.__aexit__(None, None, None)  # DISCONNECT, bounded by the client's timeout
    except aiomqtt.MqttError as exc:
        return Check("broker", False, f"{where}: {exc}", "check mqtt.host/port, the credentials and that the "
                     "broker runs (systemctl status mosquitto)")
    return Check("broker", True, f"{where} accepts the daemon's credentials")


async def _store(cfg: Config) -> Check:
    from rgse_daemon.store import Store

    where = re.sub(r"//[^@/]*@", "//", cfg.store.url) if cfg.store.url else f"SQLite in {cfg.paths.data_dir}"
    try:
        async with await Store.open(cfg.store.url, cfg.paths.data_dir, timeout_s=5.0):
            pass  # opening (connect, migrations current) is the check
    except RgseError as exc:
        return Check("store", False, f"{where}: {exc}", "check store.url (server running, database and user "
                     "exist) or that paths.data_dir is writable")
    return Check("store", True, f"{where} opens, schema current")

