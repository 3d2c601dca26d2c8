"""C3 Bridge / KUKAVARPROXY frame codec, both directions (client and simulated server use the same code).

Wire format (``c3bridge-protocol.md`` §1): every integer big-endian; header ``tag u16 | length u16 | type u8``
where ``length`` = total bytes − 4; responses end with the footer ``error_code u16 | success u8`` (success
code is **1**). Strings in #0/#1 are ``u16 byte count + ISO-8859-1``; everywhere else ``wstr`` =
``u16 UTF-16 unit count + UTF-16LE``. Strings carry no terminator.

Public API
----------
``MsgType``, ``ErrorCode``, ``ProgCmd``, ``FileOp``
    Enumerations of message types, footer error codes, #10 commands and #29/#30 operations.
``ItemType``, ``ModulePart``, ``Attribute``, ``CopyFlag``
    The file-operation constants of §3.9 (item types, module parts, attributes, copy flags).
``Request`` subclasses (payload only, the tag travels separately)
    ``ReadVarAscii(name)`` #0, ``WriteVarAscii(name, value)`` #1, ``ReadVar`` #4, ``WriteVar`` #5,
    ``ReadMulti(names)`` #6, ``WriteMulti(items)`` #7, ``ProgramControl(cmd, interpreter, name, params, force)`` #10
    (``name=None`` → subtype I reset/start/stop/cancel, else subtype II select/run), ``ProxyInfo`` #13,
    ``ProxyFeatures`` #14, ``Benchmark`` #17, ``SetAttribute(attributes, mask, name)`` #20, ``NameList`` #21,
    ``Create(item_type, module_part, always, name, template)`` #22, ``Delete(always, name)`` #23,
    ``Copy(copy_flags, source, destination)`` #24, ``Move(copy_flags, source, destination)`` #25,
    ``GetProperties`` #26, ``GetFullName`` #27, ``GetKrcName(path)`` #28,
    ``WriteContentBegin/Data/GetSize/End`` #29, ``ReadContentBegin/Data/GetSize/End`` #30, ``ConfirmAll`` #63.
``Reply`` subclasses (every one carries the footer as keyword fields ``code=1, success=True``)
    ``ReadVarAsciiReply(value)``, ``WriteVarAsciiReply(value)``, ``ReadVarReply``, ``WriteVarReply``,
    ``ReadMultiReply(entries)`` / ``WriteMultiReply(entries)`` with ``MultiEntry(code, value)``,
    ``ProgramControlReply(cmd)``, ``ProxyInfoReply``, ``ProxyFeaturesReply(types)``, ``BenchmarkReply``,
    ``NameListReply(items, infos)``, ``GetPropertiesReply``, ``GetFullNameReply(path)``, ``GetKrcNameReply(path)``,
    the footer-only ``SetAttributeReply``, ``CreateReply``, ``DeleteReply``, ``CopyReply``, ``MoveReply``,
    ``WriteContent{Begin,GetSize,Data,End}Reply``, ``ReadContent{Begin,GetSize,Data,End}Reply``, ``ConfirmAllReply``,
    and ``FailureReply(msg_type, payload)`` for a failed reply (success 0) whose payload has no known layout.
``encode_request(tag, req) -> bytes`` / ``decode_request(frame) -> (tag, req)``
``encode_response(tag, rsp) -> bytes`` / ``decode_response(frame) -> (tag, rsp)``
``encode(tag, msg)``
    Dispatches on the kind of ``msg``.
``FrameReader(responses=...)``, ``split_frames(buffer, responses=...)``, ``await read_frame(stream, responses=...)``
    Cut a byte stream into whole frames. With ``responses=True`` a #0/#1 frame is sized from its value length
    (7 + LVV + 3 bytes) rather than the header's length field, because KUKAVARPROXY's length field is not
    consistent across implementations (``kuka-facts.md`` §3).

Every decoder raises :class:`~rgse_daemon.errors.ProtocolError` on malformed bytes, never ``IndexError``,
``struct.error`` or ``UnicodeDecodeError``. Encoders raise ``ProtocolError`` when a field does not fit the wire
(a string longer than 65535 units, a message longer than 65539 bytes, an integer out of range).
"""

from __future__ import annotations

import asyncio
import dataclasses
import struct
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag
from typing import ClassVar

from rgse_daemon.errors import LinkClosed, ProtocolError

HEADER_SIZE = 5
FOOTER_SIZE = 3
MAX_LENGTH_FIELD = 0xFFFF
MAX_FRAME_SIZE = MAX_LENGTH_FIELD + 4  # 65539 bytes
MAX_MULTI = 255
#: The server caps one #30 data chunk at this many bytes ([src] of c3bridge-server).
MAX_READ_CHUNK = 64512
#: One #29 data chunk: 65535 (length field) − type − op − offset − size = 65525 bytes.
MAX_WRITE_CHUNK = 65525
READ_CHUNK_AS_MUCH_AS_POSSIBLE = 0xFFFFFFFF


class MsgType(IntEnum):
    READ_VAR_ASCII = 0
    WRITE_VAR_ASCII = 1
    READ_VAR = 4
    WRITE_VAR = 5
    READ_MULTI = 6
    WRITE_MULTI = 7
    PROGRAM_CONTROL = 10
    PROXY_INFO = 13
    PROXY_FEATURES = 14
    BENCHMARK = 17
    SET_ATTRIBUTE = 20
    NAME_LIST = 21
    CREATE = 22
    DELETE = 23
    COPY = 24
    MOVE = 25
    GET_PROPERTIES = 26
    GET_FULL_NAME = 27
    GET_KRC_NAME = 28
    WRITE_CONTENT = 29
    READ_CONTENT = 30
    CONFIRM_ALL = 63


class ErrorCode(IntEnum):
    GENERAL = 0
    SUCCESS = 1
    ACCESS = 2
    ARGUMENT = 3
    MEMORY = 4
    POINTER = 5
    UNEXPECTED = 6
    NOT_IMPLEMENTED = 7
    NO_INTERFACE = 8
    PROTOCOL = 9
    LONG_ANSWER = 10


class ProgCmd(IntEnum):
    """#10 commands: 1–4 are subtype I (interpreter only), 5–6 subtype II (name, parameters, force)."""

    RESET = 1
    START = 2
    STOP = 3
    CANCEL = 4
    SELECT = 5
    RUN = 6


class Interpreter(IntEnum):
    SUBMIT = 0
    ROBOT = 1


class FileOp(IntEnum):
    BEGIN = 1
    DATA = 2
    GET_SIZE = 3
    END = 4


class ItemType(IntFlag):
    """#21 / #22 / #26 item types."""

    UNKNOWN = 0
    DIR = 1
    VIRTUAL_DIR = 2
    ARCHIVE = 4
    BINARY = 8
    TEXT = 16
    MODULE = 32
    RAW = 64
    MOTION = 128
    PROTECTED_FILE_CONTAINER = 256


class ModulePart(IntEnum):
    """#22 module parts."""

    UNKNOWN = 0
    SUB = 1
    SRC = 2
    DAT = 4
    SUBDAT = 5
    SRCDAT = 6
    TEMPLATE = 8
    MOTION = 16


class Attribute(IntFlag):
    """#20 / #26 attributes."""

    NONE = 0
    READ_ONLY = 1
    HIDDEN = 2
    SYSTEM = 4
    DIRECTORY = 16
    ARCHIVE = 32
    ENCRYPTED = 16384
    SIGNED = 268435456


class CopyFlag(IntFlag):
    """#24 / #25 / #29 End / #30 Begin copy flags (MODIFY and UPDATE are combinations, as in the spec)."""

    NONE = 0
    ARCHIVE = 1
    MODIFY = 3
    CONTINUE = 4
    RECURSIVE = 8
    REFRESH = 16
    UPDATE = 48
    OVERWRITE_EXISTS = 64
    NO_DIR_ENTRIES = 128
    JUNK_DIR = 256
    FORCE_BINARY = 512
    FORCE_TEXT = 1024
    NO_VERSION_CHECK = 2048
    OVERWRITE_READ = 4096
    NO_KRL_ANALYSIS = 8192


# --- primitive writer / reader ----------------------------------------------------------------------------------
class _Writer:
    __slots__ = ("buf",)

    def __init__(self) -> None:
        self.buf = bytearray()

    def _pack(self, fmt: str, value: int, what: str) -> None:
        try:
            self.buf += struct.pack(fmt, value)
        except struct.error as exc:
            raise ProtocolError(f"{what}={value!r} does not fit the wire field ({fmt})") from exc

    def u8(self, v: int, what: str = "u8") -> None:
        self._pack(">B", v, what)

    def boolean(self, v: bool) -> None:
        self.buf.append(1 if v else 0)

    def u16(self, v: int, what: str = "u16") -> None:
        self._pack(">H", v, what)

    def i16(self, v: int, what: str = "i16") -> None:
        self._pack(">h", v, what)

    def u32(self, v: int, what: str = "u32") -> None:
        self._pack(">I", v, what)

    def i32(self, v: int, what: str = "i32") -> None:
        self._pack(">i", v, what)

    def astr(self, s: str, what: str = "string") -> None:
        """STRING of #0/#1: u16 byte count + ISO-8859-1 bytes."""
        try:
            raw = s.encode("latin-1")
        except UnicodeEncodeError as exc:
            raise ProtocolError(f"{what} {s[:40]!r} is not ISO-8859-1 text") from exc
        if len(raw) > MAX_LENGTH_FIELD:
            raise ProtocolError(f"{what} is {len(raw)} bytes, more than 65535")
        self.u16(len(raw))
        self.buf += raw

    def wstr(self, s: str, what: str = "wstring") -> None:
        """WSTRING: u16 count of UTF-16 units + UTF-16LE bytes."""
        try:
            raw = s.encode("utf-16-le")
        except UnicodeEncodeError as exc:
            raise ProtocolError(f"{what} {s[:40]!r} cannot be encoded as UTF-16") from exc
        units = len(raw) // 2
        if units > MAX_LENGTH_FIELD:
            raise ProtocolError(f"{what} is {units} UTF-16 units, more than 65535")
        self.u16(units)
        self.buf += raw

    def raw(self, b: bytes) -> None:
        self.buf += b


class _Reader:
    __slots__ = ("data", "pos")

    def __init__(self, data: bytes | bytearray | memoryview, pos: int = 0) -> None:
        self.data = bytes(data)
        self.pos = pos

    def take(self, n: int, what: str) -> bytes:
        end = self.pos + n
        if end > len(self.data):
            raise ProtocolError(f"frame too short for {what}: need {end} bytes, have {len(self.data)}")
        out = self.data[self.pos : end]
        self.pos = end
        return out

    def _unpack(self, fmt: str, size: int, what: str) -> int:
        return struct.unpack(fmt, self.take(size, what))[0]

    def u8(self, what: str = "u8") -> int:
        return self._unpack(">B", 1, what)

    def boolean(self, what: str = "bool") -> bool:
        return self._unpack(">B", 1, what) != 0

    def u16(self, what: str = "u16") -> int:
        return self._unpack(">H", 2, what)

    def i16(self, what: str = "i16") -> int:
        return self._unpack(">h", 2, what)

    def u32(self, what: str = "u32") -> int:
        return self._unpack(">I", 4, what)

    def i32(self, what: str = "i32") -> int:
        return self._unpack(">i", 4, what)

    def astr(self, what: str = "string") -> str:
        n = self.u16(f"length of {what}")
        return self.take(n, what).decode("latin-1")

    def wstr(self, what: str = "wstring") -> str:
        n = self.u16(f"length of {what}")
        raw = self.take(2 * n, what)
        try:
            return raw.decode("utf-16-le")
        except UnicodeDecodeError as exc:
            raise ProtocolError(f"{what} is not valid UTF-16LE: {exc.reason}") from exc

    def remaining(self) -> int:
        return len(self.data) - self.pos

    def end(self, what: str) -> None:
        if self.pos != len(self.data):
            raise ProtocolError(f"{what}: {len(self.data) - self.pos} unexpected trailing byte(s)")


# --- messages ---------------------------------------------------------------------------------------------------
class Request:
    """Base of all request payloads. ``TYPE`` is the message type byte."""

    TYPE: ClassVar[MsgType]


@dataclass(frozen=True, kw_only=True)
class Reply:
    """Base of all response payloads; ``code`` and ``success`` are the 3-byte footer."""

    TYPE: ClassVar[MsgType]
    code: int = ErrorCode.SUCCESS
    success: bool = True

    @property
    def ok(self) -> bool:
        return self.success


@dataclass(frozen=True)
class ReadVarAscii(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR_ASCII
    name: str


@dataclass(frozen=True)
class WriteVarAscii(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR_ASCII
    name: str
    value: str


@dataclass(frozen=True)
class ReadVar(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR
    name: str


@dataclass(frozen=True)
class WriteVar(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR
    name: str
    value: str


@dataclass(frozen=True)
class ReadMulti(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_MULTI
    names: tuple[str, ...]


@dataclass(frozen=True)
class WriteMulti(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_MULTI
    items: tuple[tuple[str, str], ...]
    """(name, value) pairs."""


@dataclass(frozen=True)
class ProgramControl(Request):
    """#10. ``name is None`` → subtype I (cmd 1–4: reset/start/stop/cancel an interpreter);
    otherwise subtype II (cmd 5 select / 6 run ``name`` with ``params``, ``force``)."""

    TYPE: ClassVar[MsgType] = MsgType.PROGRAM_CONTROL
    cmd: int
    interpreter: int = Interpreter.ROBOT
    name: str | None = None
    params: str = ""
    force: bool = False


@dataclass(frozen=True)
class ProxyInfo(Request):
    TYPE: ClassVar[MsgType] = MsgType.PROXY_INFO


@dataclass(frozen=True)
class ProxyFeatures(Request):
    TYPE: ClassVar[MsgType] = MsgType.PROXY_FEATURES


@dataclass(frozen=True)
class Benchmark(Request):
    """#17: time ``iterations`` reads (or writes, when ``write``) of ``names`` on the server."""

    TYPE: ClassVar[MsgType] = MsgType.BENCHMARK
    write: bool
    iterations: int
    names: tuple[str, ...]
    values: tuple[str, ...] = ()
    """One value per name, only when ``write``."""


@dataclass(frozen=True)
class SetAttribute(Request):
    """#20: set the bits of ``attributes`` selected by ``mask`` (both INT32) on ``name``."""

    TYPE: ClassVar[MsgType] = MsgType.SET_ATTRIBUTE
    attributes: int
    mask: int
    name: str


@dataclass(frozen=True)
class NameList(Request):
    TYPE: ClassVar[MsgType] = MsgType.NAME_LIST
    item_type: int
    list_flags: int
    path: str


@dataclass(frozen=True)
class Create(Request):
    """#22: create ``name``; ``item_type`` is a UINT16 on the wire (unlike #21's INT32), ``module_part`` a UINT8."""

    TYPE: ClassVar[MsgType] = MsgType.CREATE
    item_type: int
    module_part: int
    always: bool
    name: str
    template: str = ""


@dataclass(frozen=True)
class Delete(Request):
    TYPE: ClassVar[MsgType] = MsgType.DELETE
    always: bool
    name: str


@dataclass(frozen=True)
class Copy(Request):
    TYPE: ClassVar[MsgType] = MsgType.COPY
    copy_flags: int
    source: str
    destination: str


@dataclass(frozen=True)
class Move(Request):
    TYPE: ClassVar[MsgType] = MsgType.MOVE
    copy_flags: int
    source: str
    destination: str


@dataclass(frozen=True)
class GetProperties(Request):
    TYPE: ClassVar[MsgType] = MsgType.GET_PROPERTIES
    flags: int
    name: str


@dataclass(frozen=True)
class GetFullName(Request):
    TYPE: ClassVar[MsgType] = MsgType.GET_FULL_NAME
    path: str


@dataclass(frozen=True)
class GetKrcName(Request):
    TYPE: ClassVar[MsgType] = MsgType.GET_KRC_NAME
    path: str


@dataclass(frozen=True)
class WriteContentBegin(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    total_size: int


@dataclass(frozen=True)
class WriteContentData(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    offset: int
    data: bytes


@dataclass(frozen=True)
class WriteContentGetSize(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT


@dataclass(frozen=True)
class WriteContentEnd(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    copy_flags: int
    file_name: str


@dataclass(frozen=True)
class ReadContentBegin(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    copy_flags: int
    file_name: str


@dataclass(frozen=True)
class ReadContentData(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    offset: int
    max_chunk: int = READ_CHUNK_AS_MUCH_AS_POSSIBLE


@dataclass(frozen=True)
class ReadContentGetSize(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT


@dataclass(frozen=True)
class ReadContentEnd(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT


@dataclass(frozen=True)
class ConfirmAll(Request):
    TYPE: ClassVar[MsgType] = MsgType.CONFIRM_ALL


# --- replies -----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReadVarAsciiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR_ASCII
    value: str


@dataclass(frozen=True)
class WriteVarAsciiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR_ASCII
    value: str


@dataclass(frozen=True)
class ReadVarReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR
    value: str


@dataclass(frozen=True)
class WriteVarReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR
    value: str


@dataclass(frozen=True)
class MultiEntry:
    code: int
    value: str

    @property
    def ok(self) -> bool:
        return self.code == ErrorCode.SUCCESS


@dataclass(frozen=True)
class ReadMultiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_MULTI
    entries: tuple[MultiEntry, ...]


@dataclass(frozen=True)
class WriteMultiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_MULTI
    entries: tuple[MultiEntry, ...]


@dataclass(frozen=True)
class ProgramControlReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.PROGRAM_CONTROL
    cmd: int


@dataclass(frozen=True)
class ProxyInfoReply(Reply):
    """#13. ``utc`` = (year, month, dayOfWeek, day, hour, minute, second, millisecond)."""

    TYPE: ClassVar[MsgType] = MsgType.PROXY_INFO
    major: int
    minor: int
    build_type: int
    utc: tuple[int, int, int, int, int, int, int, int]
    computer_name: str


@dataclass(frozen=True)
class ProxyFeaturesReply(Reply):
    """#14. ``types``: the set of supported message type numbers (0–255)."""

    TYPE: ClassVar[MsgType] = MsgType.PROXY_FEATURES
    types: frozenset[int]


@dataclass(frozen=True)
class BenchmarkReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.BENCHMARK
    write: bool
    count: int
    iterations: int
    start_ms: int
    stop_ms: int
    diff_ms: int


@dataclass(frozen=True)
class NameListReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.NAME_LIST
    items: tuple[str, ...]
    infos: tuple[str, ...] = ()


@dataclass(frozen=True)
class GetPropertiesReply(Reply):
    """#26. Times are Windows FILETIME ticks (100 ns since 1601); biases in minutes.

    On the wire: itemType, sizeLow, sizeHigh, attributes, (low, high, bias) × creation/access/modified,
    editMode — 14 INT32 — then ``wstr`` item name (u16 length at @61, text at @63).
    """

    TYPE: ClassVar[MsgType] = MsgType.GET_PROPERTIES
    item_type: int
    size_bytes: int
    attributes: int
    creation_filetime: int
    creation_bias_min: int
    access_filetime: int
    access_bias_min: int
    modified_filetime: int
    modified_bias_min: int
    edit_mode: int
    name: str


@dataclass(frozen=True)
class GetFullNameReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.GET_FULL_NAME
    path: str


@dataclass(frozen=True)
class GetKrcNameReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.GET_KRC_NAME
    path: str


@dataclass(frozen=True)
class SetAttributeReply(Reply):
    """#20: footer only (Message Length 4)."""

    TYPE: ClassVar[MsgType] = MsgType.SET_ATTRIBUTE


@dataclass(frozen=True)
class CreateReply(Reply):
    """#22: footer only (Message Length 4)."""

    TYPE: ClassVar[MsgType] = MsgType.CREATE


@dataclass(frozen=True)
class DeleteReply(Reply):
    """#23: footer only (Message Length 4)."""

    TYPE: ClassVar[MsgType] = MsgType.DELETE


@dataclass(frozen=True)
class CopyReply(Reply):
    """#24: footer only (Message Length 4)."""

    TYPE: ClassVar[MsgType] = MsgType.COPY


@dataclass(frozen=True)
class MoveReply(Reply):
    """#25: footer only (Message Length 4)."""

    TYPE: ClassVar[MsgType] = MsgType.MOVE


@dataclass(frozen=True)
class WriteContentBeginReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    buffer_size: int


@dataclass(frozen=True)
class WriteContentGetSizeReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    buffer_size: int


@dataclass(frozen=True)
class WriteContentDataReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    offset: int
    written: int


@dataclass(frozen=True)
class WriteContentEndReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT


@dataclass(frozen=True)
class ReadContentBeginReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    file_size: int


@dataclass(frozen=True)
class ReadContentGetSizeReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    size: int


@dataclass(frozen=True)
class ReadContentDataReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    offset: int
    data: bytes


@dataclass(frozen=True)
class ReadContentEndReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT


@dataclass(frozen=True)
class ConfirmAllReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.CONFIRM_ALL


@dataclass(frozen=True)
class FailureReply(Reply):
    """A failed reply (success 0) whose payload does not follow its type's layout; payload kept raw."""

    msg_type: int
    payload: bytes = b""
    success: bool = field(default=False, kw_only=True)
    code: int = field(default=ErrorCode.GENERAL, kw_only=True)


# --- payload encoders -------------------------------------------------------------------------------------------
def _enc_req_payload(w: _Writer, req: Request) -> None:
    match req:
        case ReadVarAscii(name=name):
            w.astr(name, "variable name")
        case WriteVarAscii(name=name, value=value):
            w.astr(name, "variable name")
            w.astr(value, "value")
        case ReadVar(name=name):
            w.wstr(name, "variable name")
        case WriteVar(name=name, value=value):
            w.wstr(name, "variable name")
            w.wstr(value, "value")
        case ReadMulti(names=names):
            w.u8(len(names), "number of names (max 255)")
            for n in names:
                w.wstr(n, "variable name")
        case WriteMulti(items=items):
            w.u8(len(items), "number of items (max 255)")
            for n, v in items:
                w.wstr(n, "variable name")
                w.wstr(v, "value")
        case ProgramControl(cmd=cmd, interpreter=interp, name=name, params=params, force=force):
            w.u8(cmd, "program command")
            w.i16(interp, "interpreter")
            if name is not None:
                w.wstr(name, "program name")
                w.wstr(params, "program parameters")
                w.boolean(force)
        case ProxyInfo() | ProxyFeatures() | ConfirmAll():
            pass  # no payload after the type byte
        case Benchmark(write=write, iterations=iterations, names=names, values=values):
            if write and len(values) != len(names):
                raise ProtocolError(f"benchmark write needs one value per name ({len(names)} names, {len(values)})")
            if not write and values:
                raise ProtocolError("benchmark read carries no values")
            w.boolean(write)
            w.u8(len(names), "number of names (max 255)")
            w.u32(iterations, "iterations")
            for i, n in enumerate(names):
                w.wstr(n, "variable name")
                if write:
                    w.wstr(values[i], "value")
        case SetAttribute(attributes=attrs, mask=mask, name=name):
            w.i32(attrs, "attributes")
            w.i32(mask, "attribute mask")
            w.wstr(name, "file name")
        case NameList(item_type=it, list_flags=lf, path=path):
            w.i32(it, "item type")
            w.i32(lf, "list flags")
            w.wstr(path, "path")
        case Create(item_type=it, module_part=mp, always=always, name=name, template=template):
            w.u16(it, "item type")
            w.u8(mp, "module part")
            w.boolean(always)
            w.wstr(name, "file name")
            w.wstr(template, "template name")
        case Delete(always=always, name=name):
            w.boolean(always)
            w.wstr(name, "file name")
        case Copy(copy_flags=cf, source=src, destination=dst) | Move(copy_flags=cf, source=src, destination=dst):
            w.i32(cf, "copy flags")
            w.wstr(src, "source")
            w.wstr(dst, "destination")
        case GetProperties(flags=flags, name=name):
            w.i32(flags, "property flags")
            w.wstr(name, "file name")
        case GetFullName(path=path) | GetKrcName(path=path):
            w.wstr(path, "path")
        case WriteContentBegin(total_size=size):
            w.u8(FileOp.BEGIN)
            w.u32(size, "total size")
        case WriteContentData(offset=offset, data=data):
            w.u8(FileOp.DATA)
            w.u32(offset, "offset")
            w.u32(len(data), "chunk size")
            w.raw(data)
        case WriteContentGetSize() | ReadContentGetSize():
            w.u8(FileOp.GET_SIZE)
        case WriteContentEnd(copy_flags=cf, file_name=fn) | ReadContentBegin(copy_flags=cf, file_name=fn):
            w.u8(FileOp.END if isinstance(req, WriteContentEnd) else FileOp.BEGIN)
            w.i32(cf, "copy flags")
            # #30 Begin: the spec's table shows a UINT32 name length at @10 (name at @14); the server source
            # reads a UINT16 length at @10 (name at @12), as in #29 End. We follow the source.
            w.wstr(fn, "file name")
        case ReadContentData(offset=offset, max_chunk=mc):
            w.u8(FileOp.DATA)
            w.u32(offset, "offset")
            w.u32(mc, "max chunk")
        case ReadContentEnd():
            w.u8(FileOp.END)
        case _:
            raise ProtocolError(f"not an encodable request: {req!r}")


def _filetime_parts(ft: int, what: str) -> tuple[int, int]:
    if not 0 <= ft < 1 << 64:
        raise ProtocolError(f"{what}={ft} is not a 64-bit FILETIME")
    return ft & 0xFFFFFFFF, ft >> 32


def _enc_rsp_payload(w: _Writer, rsp: Reply) -> None:
    match rsp:
        case ReadVarAsciiReply(value=v) | WriteVarAsciiReply(value=v):
            w.astr(v, "value")
        case ReadVarReply(value=v) | WriteVarReply(value=v):
            w.wstr(v, "value")
        case ReadMultiReply(entries=entries) | WriteMultiReply(entries=entries):
            w.u8(len(entries), "number of entries (max 255)")
            for e in entries:
                w.u8(e.code, "entry code")
                w.wstr(e.value, "value")
        case ProgramControlReply(cmd=cmd):
            w.u8(cmd, "program command")
        case ProxyInfoReply(major=ma, minor=mi, build_type=bt, utc=utc, computer_name=cn):
            w.u8(ma, "major")
            w.u8(mi, "minor")
            w.u8(bt, "build type")
            if len(utc) != 8:
                raise ProtocolError(f"proxy info utc needs 8 fields, got {len(utc)}")
            for x in utc:
                w.u16(x, "utc field")
            w.wstr(cn, "computer name")
        case ProxyFeaturesReply(types=types):
            bitmap = bytearray(32)
            for t in types:
                if not 0 <= t <= 255:
                    raise ProtocolError(f"feature type {t} is not 0..255")
                bitmap[31 - t // 8] |= 1 << (t % 8)
            w.raw(bytes(bitmap))
        case BenchmarkReply(write=wr, count=c, iterations=it, start_ms=s, stop_ms=e, diff_ms=d):
            w.boolean(wr)
            w.u8(c, "count")
            w.u32(it, "iterations")
            w.u32(s, "start ms")
            w.u32(e, "stop ms")
            w.u32(d, "diff ms")
        case NameListReply(items=items, infos=infos):
            w.u16(len(items), "number of items")
            for s in items:
                w.wstr(s, "item")
            w.u16(len(infos), "number of infos")
            for s in infos:
                w.wstr(s, "info")
        case GetPropertiesReply() as p:
            size_lo, size_hi = _filetime_parts(p.size_bytes, "size_bytes")
            w.i32(p.item_type, "item type")
            w.u32(size_lo)
            w.u32(size_hi)
            w.i32(p.attributes, "attributes")
            for ft, bias, what in (
                (p.creation_filetime, p.creation_bias_min, "creation"),
                (p.access_filetime, p.access_bias_min, "access"),
                (p.modified_filetime, p.modified_bias_min, "modified"),
            ):
                lo, hi = _filetime_parts(ft, f"{what} time")
                w.u32(lo)
                w.u32(hi)
                w.i32(bias, f"{what} bias")
            w.i32(p.edit_mode, "edit mode")
            w.wstr(p.name, "item name")
        case GetFullNameReply(path=path) | GetKrcNameReply(path=path):
            w.wstr(path, "path")
        case SetAttributeReply() | CreateReply() | DeleteReply() | CopyReply() | MoveReply():
            pass  # footer only (Message Length 4)
        case WriteContentBeginReply(buffer_size=n):
            w.u8(FileOp.BEGIN)
            w.u32(n, "buffer size")
        case WriteContentGetSizeReply(buffer_size=n):
            w.u8(FileOp.GET_SIZE)
            w.u32(n, "buffer size")
        case WriteContentDataReply(offset=o, written=n):
            w.u8(FileOp.DATA)
            w.u32(o, "offset")
            w.u32(n, "bytes written")
        case WriteContentEndReply() | ReadContentEndReply():
            w.u8(FileOp.END)
        case ReadContentBeginReply(file_size=n):
            w.u8(FileOp.BEGIN)
            w.u32(n, "file size")
        case ReadContentGetSizeReply(size=n):
            w.u8(FileOp.GET_SIZE)
            w.u32(n, "size")
        case ReadContentDataReply(offset=o, data=data):
            w.u8(FileOp.DATA)
            w.u32(o, "offset")
            w.u32(len(data), "chunk size")
            w.raw(data)
        case ConfirmAllReply():
            pass  # footer only
        case FailureReply(payload=payload):
            w.raw(payload)
        case _:
            raise ProtocolError(f"not an encodable reply: {rsp!r}")


def _frame(tag: int, msg_type: int, body: bytes) -> bytes:
    length = 1 + len(body)
    if length > MAX_LENGTH_FIELD:
        raise ProtocolError(f"message type {msg_type} would be {length + 4} bytes, more than {MAX_FRAME_SIZE}")
    if not 0 <= tag <= 0xFFFF:
        raise ProtocolError(f"tag {tag} is not a u16")
    if not 0 <= msg_type <= 0xFF:
        raise ProtocolError(f"message type {msg_type} is not a u8")
    return struct.pack(">HHB", tag, length, msg_type) + body


def encode_request(tag: int, req: Request) -> bytes:
    """Encode a whole request frame (header + payload; requests carry no footer)."""
    w = _Writer()
    _enc_req_payload(w, req)
    return _frame(tag, req.TYPE, bytes(w.buf))


def encode_response(tag: int, rsp: Reply) -> bytes:
    """Encode a whole response frame (header + payload + footer)."""
    w = _Writer()
    _enc_rsp_payload(w, rsp)
    w.u16(int(rsp.code), "error code")
    w.boolean(rsp.success)
    msg_type = rsp.msg_type if isinstance(rsp, FailureReply) else rsp.TYPE
    return _frame(tag, msg_type, bytes(w.buf))


def encode(tag: int, msg: Request | Reply) -> bytes:
    """Encode a request or a response, whichever ``msg`` is."""
    if isinstance(msg, Reply):
        return encode_response(tag, msg)
    if isinstance(msg, Request):
        return encode_request(tag, msg)
    raise ProtocolError(f"not a message: {msg!r}")


# --- decoders ---------------------------------------------------------------------------------------------------
def _header(frame: bytes | bytearray | memoryview, *, ascii_reply: bool = False) -> tuple[int, int, _Reader]:
    r = _Reader(frame)
    tag = r.u16("tag")
    length = r.u16("length")
    msg_type = r.u8("message type")
    if length == 0 and not ascii_reply:
        raise ProtocolError("message length 0")
    if not ascii_reply and length + 4 != len(r.data):
        raise ProtocolError(f"header length {length} does not match frame of {len(r.data)} bytes")
    return tag, msg_type, r


def _dec_file_req(r: _Reader, msg_type: int) -> Request:
    op = r.u8("file operation")
    if msg_type == MsgType.WRITE_CONTENT:
        if op == FileOp.BEGIN:
            return WriteContentBegin(r.u32("total size"))
        if op == FileOp.DATA:
            offset = r.u32("offset")
            size = r.u32("chunk size")
            return WriteContentData(offset, r.take(size, "chunk data"))
        if op == FileOp.GET_SIZE:
            return WriteContentGetSize()
        if op == FileOp.END:
            return WriteContentEnd(r.i32("copy flags"), r.wstr("file name"))
    else:
        if op == FileOp.BEGIN:
            return ReadContentBegin(r.i32("copy flags"), r.wstr("file name"))
        if op == FileOp.DATA:
            return ReadContentData(r.u32("offset"), r.u32("max chunk"))
        if op == FileOp.GET_SIZE:
            return ReadContentGetSize()
        if op == FileOp.END:
            return ReadContentEnd()
    raise ProtocolError(f"message type {msg_type}: unknown file operation {op}")


def _dec_req_payload(r: _Reader, msg_type: int) -> Request:
    match msg_type:
        case MsgType.READ_VAR_ASCII:
            return ReadVarAscii(r.astr("variable name"))
        case MsgType.WRITE_VAR_ASCII:
            return WriteVarAscii(r.astr("variable name"), r.astr("value"))
        case MsgType.READ_VAR:
            return ReadVar(r.wstr("variable name"))
        case MsgType.WRITE_VAR:
            return WriteVar(r.wstr("variable name"), r.wstr("value"))
        case MsgType.READ_MULTI:
            n = r.u8("number of names")
            return ReadMulti(tuple(r.wstr("variable name") for _ in range(n)))
        case MsgType.WRITE_MULTI:
            n = r.u8("number of items")
            return WriteMulti(tuple((r.wstr("variable name"), r.wstr("value")) for _ in range(n)))
        case MsgType.PROGRAM_CONTROL:
            cmd = r.u8("program command")
            interp = r.i16("interpreter")
            if r.remaining() == 0:
                return ProgramControl(cmd, interp)
            return ProgramControl(cmd, interp, r.wstr("program name"), r.wstr("program parameters"), r.boolean())
        case MsgType.PROXY_INFO:
            return ProxyInfo()
        case MsgType.PROXY_FEATURES:
            return ProxyFeatures()
        case MsgType.BENCHMARK:
            write = r.boolean()
            n = r.u8("count")
            iterations = r.u32("iterations")
            names: list[str] = []
            values: list[str] = []
            for _ in range(n):
                names.append(r.wstr("variable name"))
                if write:
                    values.append(r.wstr("value"))
            return Benchmark(write, iterations, tuple(names), tuple(values))
        case MsgType.SET_ATTRIBUTE:
            return SetAttribute(r.i32("attributes"), r.i32("attribute mask"), r.wstr("file name"))
        case MsgType.NAME_LIST:
            return NameList(r.i32("item type"), r.i32("list flags"), r.wstr("path"))
        case MsgType.CREATE:
            return Create(
                r.u16("item type"), r.u8("module part"), r.boolean("always"), r.wstr("file name"), r.wstr("template")
            )
        case MsgType.DELETE:
            return Delete(r.boolean("always"), r.wstr("file name"))
        case MsgType.COPY:
            return Copy(r.i32("copy flags"), r.wstr("source"), r.wstr("destination"))
        case MsgType.MOVE:
            return Move(r.i32("copy flags"), r.wstr("source"), r.wstr("destination"))
        case MsgType.GET_PROPERTIES:
            return GetProperties(r.i32("property flags"), r.wstr("file name"))
        case MsgType.GET_FULL_NAME:
            return GetFullName(r.wstr("path"))
        case MsgType.GET_KRC_NAME:
            return GetKrcName(r.wstr("path"))
        case MsgType.WRITE_CONTENT | MsgType.READ_CONTENT:
            return _dec_file_req(r, msg_type)
        case MsgType.CONFIRM_ALL:
            return ConfirmAll()
    raise ProtocolError(f"unknown request message type {msg_type}")


def decode_request(frame: bytes | bytearray | memoryview) -> tuple[int, Request]:
    """Decode one whole request frame into ``(tag, request)``; ``ProtocolError`` if malformed or unknown type."""
    tag, msg_type, r = _header(frame)
    req = _dec_req_payload(r, msg_type)
    r.end(f"request type {msg_type}")
    return tag, req


def _dec_file_rsp(r: _Reader, msg_type: int) -> Reply:
    op = r.u8("file operation")
    if msg_type == MsgType.WRITE_CONTENT:
        if op == FileOp.BEGIN:
            return WriteContentBeginReply(r.u32("buffer size"))
        if op == FileOp.GET_SIZE:
            return WriteContentGetSizeReply(r.u32("buffer size"))
        if op == FileOp.DATA:
            return WriteContentDataReply(r.u32("offset"), r.u32("bytes written"))
        if op == FileOp.END:
            return WriteContentEndReply()
    else:
        if op == FileOp.BEGIN:
            return ReadContentBeginReply(r.u32("file size"))
        if op == FileOp.GET_SIZE:
            return ReadContentGetSizeReply(r.u32("size"))
        if op == FileOp.DATA:
            offset = r.u32("offset")
            n = r.u32("chunk size")
            return ReadContentDataReply(offset, r.take(n, "chunk data"))
        if op == FileOp.END:
            return ReadContentEndReply()
    raise ProtocolError(f"message type {msg_type}: unknown file operation {op} in reply")


def _dec_properties(r: _Reader) -> GetPropertiesReply:
    item_type = r.i32("item type")
    size = r.u32("size low") | (r.u32("size high") << 32)
    attributes = r.i32("attributes")
    times: list[int] = []
    for what in ("creation", "access", "modified"):
        times.append(r.u32(f"{what} low") | (r.u32(f"{what} high") << 32))
        times.append(r.i32(f"{what} bias"))
    edit_mode = r.i32("edit mode")
    return GetPropertiesReply(item_type, size, attributes, *times, edit_mode, r.wstr("item name"))


def _features(bitmap: bytes) -> frozenset[int]:
    return frozenset((31 - i) * 8 + bit for i, byte in enumerate(bitmap) for bit in range(8) if byte & (1 << bit))


def _dec_rsp_payload(r: _Reader, msg_type: int) -> Reply:
    match msg_type:
        case MsgType.READ_VAR_ASCII:
            return ReadVarAsciiReply(r.astr("value"))
        case MsgType.WRITE_VAR_ASCII:
            return WriteVarAsciiReply(r.astr("value"))
        case MsgType.READ_VAR:
            return ReadVarReply(r.wstr("value"))
        case MsgType.WRITE_VAR:
            return WriteVarReply(r.wstr("value"))
        case MsgType.READ_MULTI | MsgType.WRITE_MULTI:
            n = r.u8("number of entries")
            entries = tuple(MultiEntry(r.u8("entry code"), r.wstr("value")) for _ in range(n))
            return ReadMultiReply(entries) if msg_type == MsgType.READ_MULTI else WriteMultiReply(entries)
        case MsgType.PROGRAM_CONTROL:
            return ProgramControlReply(r.u8("program command"))
        case MsgType.PROXY_INFO:
            ma, mi, bt = r.u8("major"), r.u8("minor"), r.u8("build type")
            utc = tuple(r.u16("utc field") for _ in range(8))
            return ProxyInfoReply(ma, mi, bt, utc, r.wstr("computer name"))  # type: ignore[arg-type]
        case MsgType.PROXY_FEATURES:
            return ProxyFeaturesReply(_features(r.take(32, "feature bitmap")))
        case MsgType.BENCHMARK:
            return BenchmarkReply(
                r.boolean(), r.u8("count"), r.u32("iterations"), r.u32("start ms"), r.u32("stop ms"), r.u32("diff ms")
            )
        case MsgType.NAME_LIST:
            items = tuple(r.wstr("item") for _ in range(r.u16("number of items")))
            infos = tuple(r.wstr("info") for _ in range(r.u16("number of infos")))
            return NameListReply(items, infos)
        case MsgType.GET_PROPERTIES:
            return _dec_properties(r)
        case MsgType.GET_FULL_NAME:
            return GetFullNameReply(r.wstr("path"))
        case MsgType.GET_KRC_NAME:
            return GetKrcNameReply(r.wstr("path"))
        case MsgType.SET_ATTRIBUTE:
            return SetAttributeReply()
        case MsgType.CREATE:
            return CreateReply()
        case MsgType.DELETE:
            return DeleteReply()
        case MsgType.COPY:
            return CopyReply()
        case MsgType.MOVE:
            return MoveReply()
        case MsgType.WRITE_CONTENT | MsgType.READ_CONTENT:
            return _dec_file_rsp(r, msg_type)
        case MsgType.CONFIRM_ALL:
            return ConfirmAllReply()
    raise ProtocolError(f"unknown response message type {msg_type}")


def decode_response(frame: bytes | bytearray | memoryview) -> tuple[int, Reply]:
    """Decode one whole response frame into ``(tag, reply)``.

    #0/#1 replies are parsed from their value length (7 + LVV + 3 bytes) and the header's length field is not
    checked (KUKAVARPROXY quirk). A failed reply (success 0) whose payload does not follow its layout becomes a
    :class:`FailureReply`; a successful one that does not follow it raises ``ProtocolError``.
    """
    raw = bytes(frame)
    ascii_reply = len(raw) >= HEADER_SIZE and raw[4] in (MsgType.READ_VAR_ASCII, MsgType.WRITE_VAR_ASCII)
    tag, msg_type, _ = _header(raw, ascii_reply=ascii_reply)
    if len(raw) < HEADER_SIZE + FOOTER_SIZE:
        raise ProtocolError(f"response of {len(raw)} bytes has no room for the footer")
    code, success_byte = struct.unpack(">HB", raw[-FOOTER_SIZE:])
    success = success_byte != 0
    body = _Reader(raw[: len(raw) - FOOTER_SIZE], HEADER_SIZE)
    try:
        rsp = _dec_rsp_payload(body, msg_type)
        body.end(f"response type {msg_type}")
    except ProtocolError:
        if success or msg_type not in _KNOWN_TYPES:
            raise
        return tag, FailureReply(msg_type, raw[HEADER_SIZE:-FOOTER_SIZE], code=code, success=False)
    return tag, _with_footer(rsp, code, success)


_KNOWN_TYPES = frozenset(int(t) for t in MsgType)


def _with_footer(rsp: Reply, code: int, success: bool) -> Reply:
    if rsp.code == code and rsp.success == success:
        return rsp
    return dataclasses.replace(rsp, code=code, success=success)


# --- stream splitting -------------------------------------------------------------------------------------------
def frame_size(prefix: bytes | bytearray | memoryview, *, responses: bool, max_length: int = MAX_LENGTH_FIELD) -> int:
    """Total size of the frame starting at ``prefix`` or 0 if more bytes are needed to tell.

    For responses of type #0/#1 the size is 7 + LVV + 3 (from the value length at @5), else length + 4.
    Raises ``ProtocolError`` on a zero or oversized length field.
    """
    if len(prefix) < (HEADER_SIZE if responses else 4):
        return 0
    if responses and prefix[4] in (MsgType.READ_VAR_ASCII, MsgType.WRITE_VAR_ASCII):
        # KVP quirk: the header's length field is not trusted; the value length is.
        if len(prefix) < 7:
            return 0
        return 7 + ((prefix[5] << 8) | prefix[6]) + FOOTER_SIZE
    length = (prefix[2] << 8) | prefix[3]
    if length == 0:
        raise ProtocolError("message length 0")
    if length > max_length:
        raise ProtocolError(f"message length {length} exceeds the limit {max_length}")
    return length + 4


def split_frames(buffer: bytearray, *, responses: bool, max_length: int = MAX_LENGTH_FIELD) -> list[bytes]:
    """Remove every whole frame from the front of ``buffer`` and return them; a partial frame stays."""
    out: list[bytes] = []
    while True:
        size = frame_size(buffer, responses=responses, max_length=max_length)
        if size == 0 or len(buffer) < size:
            return out
        out.append(bytes(buffer[:size]))
        del buffer[:size]


class FrameReader:
    """Incremental splitter: ``feed(bytes) -> list[frame]``. After a ``ProtocolError`` the stream is unusable."""

    def __init__(self, *, responses: bool, max_length: int = MAX_LENGTH_FIELD) -> None:
        self._buf = bytearray()
        self._responses = responses
        self._max_length = max_length

    def feed(self, data: bytes) -> list[bytes]:
        self._buf += data
        return split_frames(self._buf, responses=self._responses, max_length=self._max_length)

    @property
    def pending(self) -> int:
        """Bytes held back as the start of an incomplete frame."""
        return len(self._buf)


async def read_frame(stream: asyncio.StreamReader, *, responses: bool, max_length: int = MAX_LENGTH_FIELD) -> bytes:
    """Read exactly one frame from ``stream`` (no deadline here: wrap the call in ``asyncio.timeout``).

    Raises ``LinkClosed`` if the peer closes the stream, ``ProtocolError`` on a bad length.
    """
    try:
        head = await stream.readexactly(HEADER_SIZE)
        size = frame_size(head, responses=responses, max_length=max_length)
        if size == 0:  # #0/#1 reply: two more bytes give the value length
            head += await stream.readexactly(2)
            size = frame_size(head, responses=responses, max_length=max_length)
        if size < len(head):
            raise ProtocolError(f"frame size {size} is shorter than its header")
        rest = await stream.readexactly(size - len(head))
    except asyncio.IncompleteReadError as exc:
        raise LinkClosed(f"peer closed the stream mid-frame ({len(exc.partial)} bytes read)") from exc
    return head + rest
