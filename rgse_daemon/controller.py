"""The KR C4 over TCP: the implementation of :class:`~rgse_daemon.krc.KrcController` (a state snapshot, guarded
writes, files and program control) that the daemon runs with.

It sits on :class:`~rgse_daemon.link.pool.LinkPool` and hides which server runs on the controller:

* **C3 Bridge**: a snapshot is one multi-read (#6); files go through #20–#30 (KUKA's own file interface: list,
  read, write, delete, copy, move, create, attributes, names); programs are selected/started/stopped with #10.
* **plain KUKAVARPROXY**: a snapshot is concurrent single reads (#0) over the pool; files (read, write, list,
  delete, copy, move) go through the controller's ``roboter`` share mounted locally
  (``ControllerConfig.share_dir``); program control, create, attributes and name conversion are not available
  (:class:`~rgse_daemon.link.errors.NotSupportedError`).

Writes are limited to the safety policy's allow-list (:mod:`rgse_daemon.safety.allowlist`);
anything else raises :class:`~rgse_daemon.errors.NotAllowedError` before a byte is sent.

Usage::

    async with Controller.connect(cfg.controller) as krc:
        snap = await krc.snapshot()             # Snapshot: mode_op "T1", axes_deg, torques_nm, ...
        await krc.write("$OV_PRO", 30)          # Python values are formatted as KRL (str → "quoted")
        await krc.put_file("KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC", data)
        await krc.select_program("KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC")
        await krc.delete_file("C:\\KRC\\ROBOTER\\TRACE\\run_01_KRCIpo.dat")
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import re
import shutil
import time
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from rgse_daemon.config import ControllerConfig, Protocol
from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import ConfigError, LinkError, LinkTimeout, NotAllowedError, ProtocolError, VariableError
from rgse_daemon.filelayout import TRACE_DIR_CANDIDATES, FileLayout, is_trace_name
from rgse_daemon.krc import AXES, SNAPSHOT_VARIABLES, DirEntry, LoadData, Pose, Snapshot
from rgse_daemon.link import frames as fr
from rgse_daemon.link.connection import ConnectionState, ServerLoad
from rgse_daemon.link.errors import CommandError, NotSupportedError
from rgse_daemon.link.krlvalue import KrlBits, KrlEnum, KrlStruct, KrlValue, format_value, parse_value
from rgse_daemon.link.pool import LinkPool
from rgse_daemon.safety.allowlist import WRITABLE_PREFIX, WRITABLE_VARIABLES, writable

log = logging.getLogger(__name__)
_T = TypeVar("_T")

#: #29 End copy flag: overwrite an existing file (docs/protocol.md §2, file operation constants).
COPY_OVERWRITE_EXISTS = 64
#: How often a file read starts again from Begin after the connection (and with it the server's buffer) was lost.
FILE_READ_ATTEMPTS = 3


class _Decoder:
    """Turns raw value texts into typed snapshot fields, collecting problems instead of raising."""

    def __init__(self, raw: Mapping[str, str | VariableError]) -> None:
        self.raw = raw
        self.errors: dict[str, str] = {}

    def _get(self, name: str, kind: type | tuple[type, ...]) -> KrlValue | None:
        got = self.raw.get(name)
        if got is None:
            self.errors[name] = "not read"
            return None
        if isinstance(got, VariableError):
            self.errors[name] = str(got)
            return None
        try:
            value = parse_value(got)
        except ProtocolError as exc:
            self.errors[name] = str(exc)
            return None
        if (isinstance(value, bool) and kind is not bool) or not isinstance(value, kind):
            self.errors[name] = f"expected {getattr(kind, '__name__', kind)}, got {got[:60]!r}"
            return None
        return value

    def enum(self, name: str) -> str | None:
        v = self._get(name, KrlEnum)
        return v.name if isinstance(v, KrlEnum) else None

    def boolean(self, name: str) -> bool | None:
        v = self._get(name, bool)
        return v if isinstance(v, bool) else None

    def real(self, name: str) -> float | None:
        v = self._get(name, (int, float))
        return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None

    def integer(self, name: str) -> int | None:
        v = self._get(name, int)
        return v if isinstance(v, int) and not isinstance(v, bool) else None

    def text(self, name: str) -> str | None:
        v = self._get(name, str)
        return v.rstrip() if isinstance(v, str) else None

    def bits(self, name: str) -> str | None:
        v = self._get(name, KrlBits)
        return v.bits if isinstance(v, KrlBits) else None

    def struct(self, name: str, *keys: str) -> KrlStruct | None:
        v = self._get(name, KrlStruct)
        if not isinstance(v, KrlStruct):
            return None
        for path in keys:
            node: object = v
            for part in path.split("."):
                node = node.get(part) if isinstance(node, KrlStruct) else None
            if not isinstance(node, int | float) or isinstance(node, bool):
                self.errors[name] = f"field {path} missing or not a number"
                return None
        return v


def _num(s: KrlStruct, path: str) -> float:
    node: object = s
    for part in path.split("."):
        assert isinstance(node, KrlStruct)
        node = node[part]
    assert isinstance(node, int | float)
    return float(node)


class Controller:
    """The robot controller; construct with :meth:`connect`. See the module docstring."""

    def __init__(self, cfg: ControllerConfig, pool: LinkPool, layout: FileLayout | None = None) -> None:
        self.cfg = cfg
        self.pool = pool
        self.layout = layout
        """The TRACE folder's working path form (``rgse doctor``'s record); probed at first use if ``None``."""

    @classmethod
    @contextlib.asynccontextmanager
    async def connect(
        cls, cfg: ControllerConfig, *, seed: int | None = None, layout: FileLayout | None = None,
        load: ServerLoad | None = None,
    ) -> AsyncIterator[Controller]:
        """Open the link (pool + protocol detection), yield the controller, close the link on exit. ``load``: the
        controller's file work in flight, shared with connections outside the pool (the heartbeat's)."""
        pool = LinkPool(cfg, seed=seed, load=load)
        await pool.start()
        try:
            yield cls(cfg, pool, layout)
        finally:
            await pool.close()

    def busy_until(self) -> float:
        """Monotonic time by which the controller's file work in flight must end (0.0: none): status reads queue
        behind it on the single-threaded server."""
        return self.pool.load.busy_until()

    def file_timeout_s(self, size_bytes: int) -> float:
        """Deadline of one file operation moving ``size_bytes``: the request deadline + bytes at the slowest rate."""
        return self.cfg.request_timeout_s + size_bytes / self.cfg.file_rate_bytes_s

    @property
    def protocol(self) -> Protocol:
        return self.pool.protocol

    def health(self) -> dict[str, object]:
        """Link health for the ``state`` topic: protocol, connection states, counters, latency histogram."""
        return self.pool.health()

    # --- variables ------------------------------------------------------------------------------------------------
    async def snapshot(self) -> Snapshot:
        """Read :data:`SNAPSHOT_VARIABLES` at once (one #6 with C3 Bridge) and decode them.

        Link failures raise (``LinkTimeout``, ``LinkClosed``, ``ProtocolError``); a single unreadable variable
        only leaves its field ``None`` and is named in ``Snapshot.errors``.
        """
        t0 = time.monotonic()
        raw = await self.pool.read_many(SNAPSHOT_VARIABLES)
        duration_s = time.monotonic() - t0
        d = _Decoder(raw)
        axes = d.struct("$AXIS_ACT", *(f"A{i}" for i in AXES))
        pos = d.struct("$POS_ACT", "X", "Y", "Z", "A", "B", "C")
        load = d.struct("$LOAD", "M", "CM.X", "CM.Y", "CM.Z", "J.X", "J.Y", "J.Z")
        pose = None
        if pos is not None:
            s, t = pos.get("S"), pos.get("T")
            pose = Pose(
                *(_num(pos, k) for k in ("X", "Y", "Z", "A", "B", "C")),
                status=s if isinstance(s, int) and not isinstance(s, bool) else None,
                turn=t if isinstance(t, int) and not isinstance(t, bool) else None,
            )
        return Snapshot(
            taken_at_s=time.time(),
            read_duration_s=duration_s,
            mode_op=d.enum("$MODE_OP"),
            pro_state1=d.enum("$PRO_STATE1"),
            pro_name1=d.text("$PRO_NAME1[]"),
            axes_deg=None if axes is None else tuple(_num(axes, f"A{i}") for i in AXES),
            pos_act=pose,
            torques_nm=tuple(d.real(f"$TORQUE_AXIS_ACT[{i}]") for i in AXES),
            motor_temps_k=tuple(d.real(f"$MOT_TEMP[{i}]") for i in AXES),
            trace_state=d.enum("$TRACE.STATE"),
            peri_rdy=d.boolean("$PERI_RDY"),
            user_saf=d.boolean("$USER_SAF"),
            stopmess=d.boolean("$STOPMESS"),
            ov_pro_pct=d.integer("$OV_PRO"),
            load=None
            if load is None
            else LoadData(
                _num(load, "M"),
                (_num(load, "CM.X"), _num(load, "CM.Y"), _num(load, "CM.Z")),
                (_num(load, "J.X"), _num(load, "J.Y"), _num(load, "J.Z")),
            ),
            brake_sig=d.bits("$BRAKE_SIG"),
            vel_act_m_s=d.real("$VEL_ACT"),
            rob_stopped=d.boolean("$ROB_STOPPED"),
            raw={k: v for k, v in raw.items() if isinstance(v, str)},
            errors=d.errors,
        )

    async def read_raw(self, name: str) -> str:
        """The value text of one variable (``VariableError`` if refused or empty)."""
        return await self.pool.read(name)

    async def read(self, name: str) -> KrlValue:
        """One variable, parsed (``ProtocolError`` if the text is not a KRL value)."""
        return parse_value(await self.pool.read(name))

    async def read_many(self, names: Sequence[str]) -> dict[str, str | VariableError]:
        """Many variables' value texts, each name mapped to its text or the ``VariableError`` that refused it: one #6
        per ≤ 255 names with C3 Bridge, concurrent #0 reads over the pool with KUKAVARPROXY. Link failures raise."""
        return await self.pool.read_many(names)

    async def write(self, name: str, value: KrlValue) -> KrlValue:
        """Write a Python value as KRL (``str`` becomes a quoted CHAR[] string); returns ``value``.

        The server's echo is the request's own text (C3 Bridge and KUKAVARPROXY alike), not a read-back of the
        controller's normalised form: read the variable to learn what the controller holds. Raises
        ``NotAllowedError`` for a name outside the allow-list, before anything is sent.
        """
        self._check_writable(name)
        await self.pool.write(name, format_value(value))
        return value

    async def write_raw(self, name: str, text: str) -> str:
        """Write KRL value text as is (e.g. ``#T_START``); same allow-list as :meth:`write`. Returns the echo (the
        request's text on a real server, nothing to rely on)."""
        self._check_writable(name)
        return await self.pool.write(name, text)

    @staticmethod
    def _check_writable(name: str) -> None:
        if not writable(name):
            raise NotAllowedError(
                f"{name}: not on the write allow-list ({', '.join(sorted(WRITABLE_VARIABLES))}, {WRITABLE_PREFIX}*)"
            )

    # --- program control (#10) ------------------------------------------------------------------------------------
    async def _program(self, req: fr.ProgramControl, what: str) -> None:
        if not self.pool.supports(fr.MsgType.PROGRAM_CONTROL):
            raise NotSupportedError(f"{what}: program control needs C3 Bridge (server is {self.protocol.value})")
        rsp = await self.pool.request(req)
        if not rsp.success:
            raise CommandError(what, "refused by the controller", rsp.code)
        if not isinstance(rsp, fr.ProgramControlReply) or rsp.cmd != req.cmd:
            raise ProtocolError(f"{what}: reply does not echo command {req.cmd}")

    async def select_program(self, name: str, params: str = "", *, force: bool = False) -> None:
        """Select ``name`` (e.g. ``KRC:\\R1\\PROGRAM\\RGSE_MEAS.SRC``) in the robot interpreter."""
        await self._program(fr.ProgramControl(fr.ProgCmd.SELECT, 0, name, params, force), f"select {name}")

    async def run_program(self, name: str, params: str = "", *, force: bool = False) -> None:
        """Select and start ``name``; in T1 the controller still needs the enabling switch and start key."""
        await self._program(fr.ProgramControl(fr.ProgCmd.RUN, 0, name, params, force), f"run {name}")

    async def start_program(self, interpreter: int = fr.Interpreter.ROBOT) -> None:
        await self._program(fr.ProgramControl(fr.ProgCmd.START, interpreter), f"start interpreter {interpreter}")

    async def stop_program(self, interpreter: int = fr.Interpreter.ROBOT) -> None:
        await self._program(fr.ProgramControl(fr.ProgCmd.STOP, interpreter), f"stop interpreter {interpreter}")

    async def reset_program(self, interpreter: int = fr.Interpreter.ROBOT) -> None:
        await self._program(fr.ProgramControl(fr.ProgCmd.RESET, interpreter), f"reset interpreter {interpreter}")

    async def cancel_program(self, interpreter: int = fr.Interpreter.ROBOT) -> None:
        await self._program(fr.ProgramControl(fr.ProgCmd.CANCEL, interpreter), f"cancel interpreter {interpreter}")

    async def confirm_all(self) -> None:
        """Acknowledge all acknowledgeable controller messages (#63)."""
        if not self.pool.supports(fr.MsgType.CONFIRM_ALL):
            raise NotSupportedError(f"confirm all needs C3 Bridge (server is {self.protocol.value})")
        rsp = await self.pool.request(fr.ConfirmAll())
        if not rsp.success:
            raise CommandError("confirm all", "refused by the controller", rsp.code)

    # --- files ----------------------------------------------------------------------------------------------------
    def _use_share(self, msg_type: fr.MsgType = fr.MsgType.WRITE_CONTENT) -> bool:
        return not self.pool.supports(msg_type)

    async def _on_share(self, what: str, timeout_s: float, fn: Callable[..., _T], *args: Any) -> _T:
        """``fn(*args)`` on the mounted share in a worker thread, within ``timeout_s``: a hung network mount is a
        :class:`LinkTimeout` like a silent controller (the thread itself cannot be cancelled; it is left to end)."""
        try:
            async with asyncio.timeout(timeout_s):
                return await asyncio.to_thread(fn, *args)
        except TimeoutError as exc:
            raise LinkTimeout(f"{what} on the share: no answer within {timeout_s:.1f} s") from exc

    async def put_file(self, name: str, data: bytes) -> None:
        """Write ``data`` to the controller file ``name`` (overwriting): #29 in chunks ≤ 65525 bytes, or the share."""
        if self._use_share():
            await self._on_share(f"put {name}", self.file_timeout_s(len(data)), _share_write,
                                 self._share_path(name), data)
            return
        name = await self._c3_name(name)
        what = f"put {name}"
        async with self.pool.connection() as conn:  # the write buffer belongs to one connection
            rsp = await conn.request(fr.WriteContentBegin(len(data)))
            _expect(rsp, fr.WriteContentBeginReply, what)
            offset = 0
            while offset < len(data):
                chunk = data[offset : offset + fr.MAX_WRITE_CHUNK]
                rsp = await conn.request(fr.WriteContentData(offset, chunk))
                _expect(rsp, fr.WriteContentDataReply, what)
                assert isinstance(rsp, fr.WriteContentDataReply)
                if rsp.written != len(chunk) or rsp.offset != offset:
                    raise ProtocolError(f"{what}: wrote {rsp.written} of {len(chunk)} bytes at offset {offset}")
                offset += len(chunk)
            # End writes the whole buffer (CopyMem2File) before it answers: a deadline sized by the bytes
            rsp = await conn.request(fr.WriteContentEnd(COPY_OVERWRITE_EXISTS, name),
                                     timeout_s=self.file_timeout_s(len(data)), file_work=True)
            _expect(rsp, fr.WriteContentEndReply, what)

    async def get_file(self, name: str, *, size_bytes: int | None = None) -> bytes:
        """The content of controller file ``name``: #30 in chunks ≤ 64512 bytes, or the share.

        The server loads the whole file before it answers Begin, so Begin's deadline is sized by the file's bytes
        (``size_bytes``, else the size #26 reports). The read buffer lives on the server only as long as the
        connection: if the link drops mid-transfer, the read starts again from Begin on a fresh connection (up to
        :data:`FILE_READ_ATTEMPTS` times). The bytes returned number exactly the size Begin reported, and that
        size must equal ``size_bytes`` when given; anything else is a ``ProtocolError``.
        """
        if self._use_share():
            if size_bytes is None:
                size_bytes = await self.file_size(name)
            return await self._on_share(f"get {name}", self.file_timeout_s(size_bytes), _share_read,
                                        self._share_path(name))
        name = await self._c3_name(name)
        if size_bytes is None:
            size_bytes = await self.file_size(name)
        last: LinkError | None = None
        for attempt in range(1, FILE_READ_ATTEMPTS + 1):
            try:
                return await self._read_once(name, size_bytes)
            except LinkError as exc:  # the buffer is gone with the connection: from Begin again
                last = exc
                log.warning("get %s: attempt %d of %d lost the link (%s); starting again from Begin", name,
                            attempt, FILE_READ_ATTEMPTS, exc)
        assert last is not None
        raise last

    async def _read_once(self, name: str, size_bytes: int) -> bytes:
        what = f"get {name}"
        async with self.pool.connection() as conn:
            rsp = await conn.request(fr.ReadContentBegin(0, name), timeout_s=self.file_timeout_s(size_bytes),
                                     file_work=True)
            _expect(rsp, fr.ReadContentBeginReply, what)
            assert isinstance(rsp, fr.ReadContentBeginReply)
            size = rsp.file_size
            if size != size_bytes:
                raise ProtocolError(f"{what}: the controller loaded {size} bytes, {size_bytes} expected")
            out = bytearray()
            try:
                while len(out) < size:
                    rsp = await conn.request(fr.ReadContentData(len(out), fr.MAX_READ_CHUNK))
                    _expect(rsp, fr.ReadContentDataReply, what)
                    assert isinstance(rsp, fr.ReadContentDataReply)
                    if rsp.offset != len(out) or not rsp.data:
                        raise ProtocolError(f"{what}: got {len(rsp.data)} bytes at {rsp.offset}, expected {len(out)}")
                    out += rsp.data
            finally:
                if conn.state is ConnectionState.CONNECTED:
                    with contextlib.suppress(LinkError):
                        await conn.request(fr.ReadContentEnd())  # free the server's buffer
            if len(out) != size:
                raise ProtocolError(f"{what}: {len(out)} bytes received, file has {size}")
            return bytes(out)

    async def file_size(self, name: str) -> int:
        """The size in bytes of controller file ``name`` (#26, or the share)."""
        if self._use_share(fr.MsgType.GET_PROPERTIES):
            path = self._share_path(name)
            try:
                return (await self._on_share(f"size of {name}", self.cfg.request_timeout_s, path.stat)).st_size
            except OSError as exc:
                raise CommandError(f"size of {name}", exc.strerror or "cannot stat") from exc
        name = await self._c3_name(name)
        rsp = await self._file_command(fr.GetProperties(0xFF, name), fr.GetPropertiesReply, f"properties of {name}")
        assert isinstance(rsp, fr.GetPropertiesReply)
        if rsp.item_type & fr.ItemType.DIR:
            raise CommandError(f"size of {name}", "is a folder")
        return rsp.size_bytes

    async def list_dir(self, path: str) -> list[DirEntry]:
        """Entries of a controller directory or mask (#21), e.g. ``C:\\KRC\\ROBOTER\\TRACE\\``."""
        if self._use_share():
            return await self._on_share(f"list {path}", self.cfg.request_timeout_s, _share_list,
                                        self._share_path(path), path)
        shown = path
        layout = await self.trace_layout() if is_trace_name(path) else None
        if layout is not None:
            path = layout.folder(layout.trace_name(path))
        rsp = await self.pool.request(fr.NameList(0, 0, path))
        _expect(rsp, fr.NameListReply, f"list {path}")
        assert isinstance(rsp, fr.NameListReply)
        infos = list(rsp.infos) + [""] * max(0, len(rsp.items) - len(rsp.infos))
        # a server may list entries by their own name only: make them full names, in the caller's form
        folder = re.sub(r"[\\/][^\\/]*[*?][^\\/]*$", "", shown)  # a mask (…\\*.SRC) lists its folder
        sep = "/" if "/" in folder and "\\" not in folder else "\\"
        folder = folder.rstrip("\\/") + sep
        return [DirEntry(n, i) if re.search(r"[\\/]", n.rstrip("\\/")) else DirEntry(folder + n, i, n)
                for n, i in zip(rsp.items, infos, strict=False)]

    async def delete_file(self, name: str, *, always: bool = False) -> None:
        """Delete controller file (or empty directory) ``name``: #23, or unlink on the share.

        ``always`` is #23's flag (the simulator then deletes a read-only file too). ``CommandError`` if refused
        (with the controller's code over #23, e.g. 3 for a missing file on the simulator).
        """
        if self._use_share(fr.MsgType.DELETE):
            await self._on_share(f"delete {name}", self.cfg.request_timeout_s, _share_delete,
                                 self._share_path(name), name)
            return
        name = await self._c3_name(name)
        await self._file_command(fr.Delete(always, name), fr.DeleteReply, f"delete {name}")

    async def copy_file(self, source: str, destination: str, *, overwrite: bool = False) -> None:
        """Copy ``source`` to ``destination`` (#24, or on the share); an existing destination only if ``overwrite``
        (copy flag OverwriteExists)."""
        if self._use_share(fr.MsgType.COPY):
            src, dst = self._share_path(source), self._share_path(destination)
            await self._on_share(f"copy {source}", await self._copy_timeout_s(source), _share_copy, src, dst,
                                 overwrite, False, f"copy {source}")
            return
        source, destination = await self._c3_name(source), await self._c3_name(destination)
        req = fr.Copy(fr.CopyFlag.OVERWRITE_EXISTS if overwrite else 0, source, destination)
        await self._file_command(req, fr.CopyReply, f"copy {source} to {destination}",
                                 await self._copy_timeout_s(source))

    async def move_file(self, source: str, destination: str, *, overwrite: bool = False) -> None:
        """Move (rename) ``source`` to ``destination`` (#25, or on the share); ``overwrite`` as in :meth:`copy_file`."""
        if self._use_share(fr.MsgType.MOVE):
            src, dst = self._share_path(source), self._share_path(destination)
            await self._on_share(f"move {source}", await self._copy_timeout_s(source), _share_copy, src, dst,
                                 overwrite, True, f"move {source}")
            return
        source, destination = await self._c3_name(source), await self._c3_name(destination)
        req = fr.Move(fr.CopyFlag.OVERWRITE_EXISTS if overwrite else 0, source, destination)
        await self._file_command(req, fr.MoveReply, f"move {source} to {destination}",
                                 await self._copy_timeout_s(source))

    async def create_file(
        self,
        name: str,
        item_type: int = fr.ItemType.MODULE,
        *,
        module_part: int = fr.ModulePart.SRCDAT,
        always: bool = False,
        template: str = "",
    ) -> None:
        """Create ``name`` with #22 (C3 Bridge only): ``item_type`` e.g. ``ItemType.DIR``; ``always`` replaces."""
        self._require(fr.MsgType.CREATE, f"create {name}")
        name = await self._c3_name(name)
        req = fr.Create(item_type, module_part, always, name, template)
        await self._file_command(req, fr.CreateReply, f"create {name}")

    async def set_attribute(self, name: str, attributes: int, mask: int) -> None:
        """Set the ``mask`` bits of ``name``'s attributes to those of ``attributes`` (#20, C3 Bridge only)."""
        self._require(fr.MsgType.SET_ATTRIBUTE, f"set attributes of {name}")
        name = await self._c3_name(name)
        await self._file_command(fr.SetAttribute(attributes, mask, name), fr.SetAttributeReply, f"attributes {name}")

    async def get_full_name(self, path: str) -> str:
        """The controller's full name of ``path`` (#27): ``/R1/TEST.SRC`` → ``KRC:\\R1\\PROGRAM\\TEST.SRC``."""
        self._require(fr.MsgType.GET_FULL_NAME, f"full name of {path}")
        path = await self._c3_name(path)
        rsp = await self._file_command(fr.GetFullName(path), fr.GetFullNameReply, f"full name of {path}")
        assert isinstance(rsp, fr.GetFullNameReply)
        return rsp.path

    async def get_krc_name(self, path: str) -> str:
        """The KRC name of ``path`` (#28): ``KRC:\\R1\\PROGRAM\\TEST.SRC`` → ``/R1/TEST.SRC``."""
        self._require(fr.MsgType.GET_KRC_NAME, f"KRC name of {path}")
        path = await self._c3_name(path)
        rsp = await self._file_command(fr.GetKrcName(path), fr.GetKrcNameReply, f"KRC name of {path}")
        assert isinstance(rsp, fr.GetKrcNameReply)
        return rsp.path

    def _require(self, msg_type: fr.MsgType, what: str) -> None:
        if not self.pool.supports(msg_type):
            raise NotSupportedError(f"{what}: needs C3 Bridge #{int(msg_type)} (server is {self.protocol.value})")

    async def _file_command(
        self, req: fr.Request, kind: type[fr.Reply], what: str, timeout_s: float | None = None
    ) -> fr.Reply:
        if timeout_s is None:
            rsp = await self.pool.request(req)
        else:  # file work that moves bytes: others wait behind it
            async with self.pool.connection() as conn:
                rsp = await conn.request(req, timeout_s=timeout_s, file_work=True)
        _expect(rsp, kind, what)
        return rsp

    async def _copy_timeout_s(self, source: str) -> float:
        try:
            return self.file_timeout_s(await self.file_size(source))
        except CommandError:  # a folder or a missing source: the copy itself says what is wrong
            return self.file_timeout_s(0)

    async def _c3_name(self, name: str) -> str:
        """``name`` with a TRACE-folder prefix in the form this controller accepts (:class:`FileLayout`)."""
        if not is_trace_name(name):
            return name
        layout = await self.trace_layout()
        return name if layout is None else layout.trace_name(name)

    async def trace_layout(self) -> FileLayout | None:
        """The TRACE folder's working form: ``rgse doctor``'s record, else found once by listing each candidate
        (:data:`~rgse_daemon.filelayout.TRACE_DIR_CANDIDATES`, with and without the trailing ``\\``). ``None`` if
        every form is refused (no TRACE folder yet): names are then sent as the caller wrote them."""
        if self.layout is not None:
            return self.layout
        tried = []
        for trace_dir in TRACE_DIR_CANDIDATES:
            for trailing in (True, False):
                layout = FileLayout(trace_dir, trailing)
                folder = layout.folder(trace_dir)
                rsp = await self.pool.request(fr.NameList(0, 0, folder))
                if rsp.success:
                    log.info("controller lists its TRACE folder as %r (no doctor record; probed)", folder)
                    self.layout = layout
                    return layout
                tried.append(f"{folder} (code {rsp.code})")
        log.warning("no form of the TRACE folder could be listed (%s); names go out as written (run rgse doctor)",
                    ", ".join(tried))
        return None

    def _share_path(self, name: str) -> Path:
        if self.cfg.share_dir is None:
            raise ConfigError(
                "controller.share_dir: file operations over plain KUKAVARPROXY need the controller's "
                "'roboter' share mounted locally"
            )
        return share_path(self.cfg.share_dir, name)


def _expect(rsp: fr.Reply, kind: type[fr.Reply], what: str) -> None:
    if not rsp.success:
        raise CommandError(what, "refused by the controller", rsp.code)
    if not isinstance(rsp, kind):
        raise ProtocolError(f"{what}: expected {kind.__name__}, got {type(rsp).__name__}")


_SHARE_PREFIXES = (re.compile(r"^KRC:[\\/]", re.I), re.compile(r"^C:[\\/]KRC[\\/]ROBOTER([\\/]|$)", re.I))


def share_path(root: Path, name: str) -> Path:
    """Map a controller name onto the locally mounted ``roboter`` share (same mapping as C3 Bridge names).

    ``KRC:\\R1\\PROGRAM\\X.SRC`` and ``/R1/X.SRC`` → ``root/R1/PROGRAM/X.SRC``; ``C:\\KRC\\ROBOTER\\TRACE\\x`` →
    ``root/TRACE/x``. ``..``, drives and UNC paths are refused (``NotAllowedError``): nothing leaves the share.
    """
    rest = None
    for p in _SHARE_PREFIXES:
        m = p.match(name)
        if m:
            rest = name[m.end() :]
            break
    if rest is None:
        if name.startswith("/") and not name.startswith("//"):
            rest = name[1:]
        else:
            raise NotAllowedError(f"{name}: not a name on the controller's share")
    parts = [p for p in re.split(r"[\\/]+", rest) if p]
    if any(p in (".", "..") or ":" in p or "\x00" in p for p in parts):
        raise NotAllowedError(f"{name}: path leaves the controller's share")
    if (
        name.startswith("/")
        and len(parts) == 2
        and parts[0].upper() == "R1"
        and not (root / parts[0] / parts[1]).is_dir()
    ):
        parts = ["R1", "PROGRAM", parts[1]]
    return root.joinpath(*parts)


def _share_write(path: Path, data: bytes) -> None:
    write_atomic(path, data)


def _share_read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise CommandError(f"get {path}", exc.strerror or "cannot read") from exc


def _share_delete(path: Path, shown: str) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            path.rmdir()
        else:
            path.unlink()
    except OSError as exc:
        raise CommandError(f"delete {shown}", exc.strerror or "cannot delete") from exc


def _share_copy(src: Path, dst: Path, overwrite: bool, move: bool, what: str) -> None:
    if not src.exists():
        raise CommandError(what, "no such file or directory")
    if dst.exists() and not overwrite:
        raise CommandError(what, f"{dst.name} already exists (overwrite not requested)")
    if src.is_dir() and src.resolve() in (dst.resolve(), *dst.resolve().parents):
        raise CommandError(what, "cannot copy or move a directory into itself")
    try:
        if move:
            os.replace(src, dst)
        elif src.is_dir():
            shutil.copytree(src, dst, dirs_exist_ok=True)
        else:
            shutil.copy2(src, dst)
    except OSError as exc:
        raise CommandError(what, exc.strerror or str(exc)) from exc


def _share_list(path: Path, shown: str) -> list[DirEntry]:
    try:
        entries = sorted(path.iterdir())
    except OSError as exc:
        raise CommandError(f"list {shown}", exc.strerror or "cannot list") from exc
    base = shown if shown.endswith(("\\", "/")) else shown + ("/" if "/" in shown else "\\")
    sep = "/" if "/" in shown and "\\" not in shown else "\\"
    return [DirEntry(base + e.name + (sep if e.is_dir() else "")) for e in entries if not e.name.endswith(".rgse-tmp")]
