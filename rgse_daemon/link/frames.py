"""C3 Bridge / KUKAVARPROXY frame codec, both directions (client and simulated server use the same code).

Wire format (``docs/protocol.md`` §1): every integer big-endian; header ``tag u16 | length u16 | type u8``
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
    consistent across implementations (``docs/protocol.md`` §3).

Layouts are declared once
-------------------------
Each message is a frozen dataclass whose fields are declared with :func:`wire` (the field's codec and the name
errors give it) in wire order; ``TYPE`` is its message type and ``OP`` its #29/#30 operation byte. One generic
walker (:class:`_Record`) encodes and decodes every such layout; the codecs (``U8`` … ``WSTR``, ``BLOB``,
``_List``, ``_Array`` …) each write and read one kind of field. Only #17's request, whose count stands apart from
its names, has a hand-written layout (:class:`_BenchmarkLayout`).

Every decoder raises :class:`~rgse_daemon.errors.ProtocolError` on malformed bytes, never ``IndexError``,
``struct.error`` or ``UnicodeDecodeError``. Encoders raise ``ProtocolError`` when a field does not fit the wire
(a string longer than 65535 units, a message longer than 65539 bytes, an integer out of range).
"""

from __future__ import annotations

import asyncio
import dataclasses
import operator
import struct
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag
from typing import Any, ClassVar, Protocol

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


# --- wire codecs: each one writes and reads one kind of field --------------------------------------------------
class _Reader:
    """A cursor over one frame; every read that runs past the end raises ``ProtocolError`` naming the field."""

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

    def remaining(self) -> int:
        return len(self.data) - self.pos

    def end(self, what: str) -> None:
        if self.pos != len(self.data):
            raise ProtocolError(f"{what}: {len(self.data) - self.pos} unexpected trailing byte(s)")


class _Codec(Protocol):
    """One kind of wire field. ``what`` names the field in every error."""

    def put(self, out: bytearray, value: Any, what: str) -> None: ...

    def get(self, r: _Reader, what: str) -> Any: ...


class _Int:
    def __init__(self, fmt: str) -> None:
        self.struct = struct.Struct(fmt)
        bits = 8 * self.struct.size
        self.lo, self.hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if fmt.islower() else (0, (1 << bits) - 1)

    def put(self, out: bytearray, value: Any, what: str) -> None:
        try:
            fits = self.lo <= operator.index(value) <= self.hi
        except TypeError:
            fits = False
        if not fits:
            raise ProtocolError(f"{what}={value!r} does not fit the wire field (an integer {self.lo}..{self.hi})")
        out += self.struct.pack(value)

    def get(self, r: _Reader, what: str) -> int:
        value: int = self.struct.unpack(r.take(self.struct.size, what))[0]
        return value


class _Bool:
    """Senders write 0 or 1; any non-zero byte reads as true (§1)."""

    def put(self, out: bytearray, value: Any, what: str) -> None:
        out.append(1 if value else 0)

    def get(self, r: _Reader, what: str) -> bool:
        return r.take(1, what)[0] != 0


class _Text:
    """A u16 length followed by the text, no terminator; the length counts units of ``unit`` bytes."""

    def __init__(self, encoding: str, unit: int, kind: str) -> None:
        self.encoding, self.unit, self.kind = encoding, unit, kind

    def put(self, out: bytearray, value: Any, what: str) -> None:
        if not isinstance(value, str):
            raise ProtocolError(f"{what}={value!r} is not text")
        try:
            raw = value.encode(self.encoding)
        except UnicodeEncodeError as exc:
            raise ProtocolError(f"{what} {value[:40]!r} is not {self.kind} text") from exc
        units = len(raw) // self.unit
        if units > MAX_LENGTH_FIELD:
            raise ProtocolError(f"{what} is {units} {self.kind} units long, more than 65535")
        U16.put(out, units, f"length of {what}")
        out += raw

    def get(self, r: _Reader, what: str) -> str:
        raw = r.take(self.unit * U16.get(r, f"length of {what}"), what)
        try:
            return raw.decode(self.encoding)
        except UnicodeDecodeError as exc:
            raise ProtocolError(f"{what} is not valid {self.kind}: {exc.reason}") from exc


class _Blob:
    """A u32 byte count followed by raw bytes (the data chunks of #29 / #30)."""

    def put(self, out: bytearray, value: Any, what: str) -> None:
        if not isinstance(value, bytes | bytearray | memoryview):
            raise ProtocolError(f"{what}={value!r} is not bytes")
        U32.put(out, len(value), f"size of {what}")
        out += value

    def get(self, r: _Reader, what: str) -> bytes:
        return r.take(U32.get(r, f"size of {what}"), what)


class _LowHigh64:
    """A 64-bit unsigned number sent as two u32, low word first (#26 sizes and FILETIMEs)."""

    def put(self, out: bytearray, value: Any, what: str) -> None:
        if not isinstance(value, int) or not 0 <= value < 1 << 64:
            raise ProtocolError(f"{what}={value!r} is not a 64-bit unsigned number")
        U32.put(out, value & 0xFFFFFFFF, f"{what} low")
        U32.put(out, value >> 32, f"{what} high")

    def get(self, r: _Reader, what: str) -> int:
        return U32.get(r, f"{what} low") | (U32.get(r, f"{what} high") << 32)


class _TypeBitmap:
    """#14: 32 bytes, the first covers types 255..248 and the last 7..0, the MSB being the higher type."""

    def put(self, out: bytearray, value: Any, what: str) -> None:
        bitmap = bytearray(32)
        for t in value:
            if not isinstance(t, int) or not 0 <= t <= 255:
                raise ProtocolError(f"{what}: type {t!r} is not 0..255")
            bitmap[31 - t // 8] |= 1 << (t % 8)
        out += bitmap

    def get(self, r: _Reader, what: str) -> frozenset[int]:
        bitmap = r.take(32, what)
        return frozenset((31 - i) * 8 + bit for i, byte in enumerate(bitmap) for bit in range(8) if byte & (1 << bit))


class _Array:
    """Exactly ``n`` items of one codec, no count on the wire."""

    def __init__(self, item: _Codec, n: int) -> None:
        self.item, self.n = item, n

    def put(self, out: bytearray, value: Any, what: str) -> None:
        if len(value) != self.n:
            raise ProtocolError(f"{what} needs {self.n} fields, got {len(value)}")
        for i, v in enumerate(value):
            self.item.put(out, v, f"{what}[{i}]")

    def get(self, r: _Reader, what: str) -> tuple[Any, ...]:
        return tuple(self.item.get(r, f"{what}[{i}]") for i in range(self.n))


class _List:
    """A count (``count`` codec) followed by that many items."""

    def __init__(self, count: _Int, item: _Codec) -> None:
        self.count, self.item = count, item

    def put(self, out: bytearray, value: Any, what: str) -> None:
        self.count.put(out, len(value), f"number of {what}")
        _Array(self.item, len(value)).put(out, value, what)

    def get(self, r: _Reader, what: str) -> tuple[Any, ...]:
        return _Array(self.item, self.count.get(r, f"number of {what}")).get(r, what)


class _Pair:
    """Two fields in a row, held as a plain tuple (#7's name and value)."""

    def __init__(self, first: tuple[_Codec, str], second: tuple[_Codec, str]) -> None:
        self.parts = (first, second)

    def put(self, out: bytearray, value: Any, what: str) -> None:
        if not isinstance(value, tuple | list) or len(value) != 2:
            raise ProtocolError(f"{what}={value!r} is not a pair")
        for (codec, name), v in zip(self.parts, value, strict=True):
            codec.put(out, v, f"{name} of {what}")

    def get(self, r: _Reader, what: str) -> tuple[Any, Any]:
        (c1, n1), (c2, n2) = self.parts
        return c1.get(r, f"{n1} of {what}"), c2.get(r, f"{n2} of {what}")


U8, U16, I16, U32, I32 = _Int(">B"), _Int(">H"), _Int(">h"), _Int(">I"), _Int(">i")
BOOL = _Bool()
ASTR = _Text("latin-1", 1, "ISO-8859-1")
WSTR = _Text("utf-16-le", 2, "UTF-16")
BLOB = _Blob()
U64 = _LowHigh64()
_NAME_VALUE = _Pair((WSTR, "variable name"), (WSTR, "value"))


def wire(codec: _Codec, what: str, *, optional: bool = False, **kw: Any) -> Any:
    """Declare a message field: its wire ``codec`` and the name errors give it; ``kw`` as for ``dataclasses.field``.

    Fields go on the wire in the order the dataclass declares them. ``optional=True`` opens an optional tail: this
    field and every later one are sent only when this one is not ``None``, and read only when bytes remain.
    """
    return field(metadata={"wire": (codec, what, optional)}, **kw)


class _Record:
    """The wire layout of a dataclass, read from its :func:`wire` fields; the generic encode and decode walkers.

    ``what`` is empty for a whole message; for a record inside one (a #6 entry) it prefixes its fields' names.
    """

    def __init__(self, cls: type) -> None:
        self.cls = cls
        self.fields = tuple((f.name, *f.metadata["wire"]) for f in dataclasses.fields(cls) if "wire" in f.metadata)
        positional = [f.name for f in dataclasses.fields(cls) if not f.kw_only]
        assert [name for name, *_ in self.fields] == positional, f"{cls.__name__}: every positional field is wired"

    def put(self, out: bytearray, value: Any, what: str) -> None:
        for name, codec, field_what, optional in self.fields:
            v = getattr(value, name)
            if optional and v is None:
                return
            codec.put(out, v, f"{what} {field_what}" if what else field_what)

    def get(self, r: _Reader, what: str) -> Any:
        values = []
        for _, codec, field_what, optional in self.fields:
            if optional and r.remaining() == 0:
                break  # the later fields keep their defaults
            values.append(codec.get(r, f"{what} {field_what}" if what else field_what))
        return self.cls(*values)


# --- messages ---------------------------------------------------------------------------------------------------
class Request:
    """Base of all request payloads. ``TYPE`` is the message type byte; ``OP`` the #29/#30 operation byte."""

    TYPE: ClassVar[MsgType]
    OP: ClassVar[FileOp | None] = None


@dataclass(frozen=True, kw_only=True)
class Reply:
    """Base of all response payloads; ``code`` and ``success`` are the 3-byte footer."""

    TYPE: ClassVar[MsgType]
    OP: ClassVar[FileOp | None] = None
    code: int = ErrorCode.SUCCESS
    success: bool = True

    @property
    def ok(self) -> bool:
        return self.success


@dataclass(frozen=True)
class ReadVarAscii(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR_ASCII
    name: str = wire(ASTR, "variable name")


@dataclass(frozen=True)
class WriteVarAscii(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR_ASCII
    name: str = wire(ASTR, "variable name")
    value: str = wire(ASTR, "value")


@dataclass(frozen=True)
class ReadVar(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR
    name: str = wire(WSTR, "variable name")


@dataclass(frozen=True)
class WriteVar(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR
    name: str = wire(WSTR, "variable name")
    value: str = wire(WSTR, "value")


@dataclass(frozen=True)
class ReadMulti(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_MULTI
    names: tuple[str, ...] = wire(_List(U8, WSTR), "variable names")


@dataclass(frozen=True)
class WriteMulti(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_MULTI
    items: tuple[tuple[str, str], ...] = wire(_List(U8, _NAME_VALUE), "items")
    """(name, value) pairs."""


@dataclass(frozen=True)
class ProgramControl(Request):
    """#10. ``name is None`` → subtype I (cmd 1–4: reset/start/stop/cancel an interpreter);
    otherwise subtype II (cmd 5 select / 6 run ``name`` with ``params``, ``force``)."""

    TYPE: ClassVar[MsgType] = MsgType.PROGRAM_CONTROL
    cmd: int = wire(U8, "program command")
    interpreter: int = wire(I16, "interpreter", default=Interpreter.ROBOT)
    name: str | None = wire(WSTR, "program name", optional=True, default=None)
    params: str = wire(WSTR, "program parameters", default="")
    force: bool = wire(BOOL, "force", default=False)


@dataclass(frozen=True)
class ProxyInfo(Request):
    TYPE: ClassVar[MsgType] = MsgType.PROXY_INFO


@dataclass(frozen=True)
class ProxyFeatures(Request):
    TYPE: ClassVar[MsgType] = MsgType.PROXY_FEATURES


@dataclass(frozen=True)
class Benchmark(Request):
    """#17: time ``iterations`` reads (or writes, when ``write``) of ``names`` on the server.

    Its layout is the one :func:`wire` cannot declare (the name count stands before ``iterations``, and a value
    follows each name only when ``write``): :class:`_BenchmarkLayout` writes and reads it.
    """

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
    attributes: int = wire(I32, "attributes")
    mask: int = wire(I32, "attribute mask")
    name: str = wire(WSTR, "file name")


@dataclass(frozen=True)
class NameList(Request):
    TYPE: ClassVar[MsgType] = MsgType.NAME_LIST
    item_type: int = wire(I32, "item type")
    list_flags: int = wire(I32, "list flags")
    path: str = wire(WSTR, "path")


@dataclass(frozen=True)
class Create(Request):
    """#22: create ``name``; ``item_type`` is a UINT16 on the wire (unlike #21's INT32), ``module_part`` a UINT8."""

    TYPE: ClassVar[MsgType] = MsgType.CREATE
    item_type: int = wire(U16, "item type")
    module_part: int = wire(U8, "module part")
    always: bool = wire(BOOL, "always")
    name: str = wire(WSTR, "file name")
    template: str = wire(WSTR, "template name", default="")


@dataclass(frozen=True)
class Delete(Request):
    TYPE: ClassVar[MsgType] = MsgType.DELETE
    always: bool = wire(BOOL, "always")
    name: str = wire(WSTR, "file name")


@dataclass(frozen=True)
class Copy(Request):
    TYPE: ClassVar[MsgType] = MsgType.COPY
    copy_flags: int = wire(I32, "copy flags")
    source: str = wire(WSTR, "source")
    destination: str = wire(WSTR, "destination")


@dataclass(frozen=True)
class Move(Request):
    TYPE: ClassVar[MsgType] = MsgType.MOVE
    copy_flags: int = wire(I32, "copy flags")
    source: str = wire(WSTR, "source")
    destination: str = wire(WSTR, "destination")


@dataclass(frozen=True)
class GetProperties(Request):
    TYPE: ClassVar[MsgType] = MsgType.GET_PROPERTIES
    flags: int = wire(I32, "property flags")
    name: str = wire(WSTR, "file name")


@dataclass(frozen=True)
class GetFullName(Request):
    TYPE: ClassVar[MsgType] = MsgType.GET_FULL_NAME
    path: str = wire(WSTR, "path")


@dataclass(frozen=True)
class GetKrcName(Request):
    TYPE: ClassVar[MsgType] = MsgType.GET_KRC_NAME
    path: str = wire(WSTR, "path")


@dataclass(frozen=True)
class WriteContentBegin(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    OP: ClassVar[FileOp] = FileOp.BEGIN
    total_size: int = wire(U32, "total size")


@dataclass(frozen=True)
class WriteContentData(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    OP: ClassVar[FileOp] = FileOp.DATA
    offset: int = wire(U32, "offset")
    data: bytes = wire(BLOB, "chunk data")


@dataclass(frozen=True)
class WriteContentGetSize(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    OP: ClassVar[FileOp] = FileOp.GET_SIZE


@dataclass(frozen=True)
class WriteContentEnd(Request):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    OP: ClassVar[FileOp] = FileOp.END
    copy_flags: int = wire(I32, "copy flags")
    file_name: str = wire(WSTR, "file name")


@dataclass(frozen=True)
class ReadContentBegin(Request):
    """#30 Begin. The spec's table shows a UINT32 name length at @10 (name at @14); the server source reads a UINT16
    length at @10 (name at @12), as in #29 End. We follow the source."""

    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.BEGIN
    copy_flags: int = wire(I32, "copy flags")
    file_name: str = wire(WSTR, "file name")


@dataclass(frozen=True)
class ReadContentData(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.DATA
    offset: int = wire(U32, "offset")
    max_chunk: int = wire(U32, "max chunk", default=READ_CHUNK_AS_MUCH_AS_POSSIBLE)


@dataclass(frozen=True)
class ReadContentGetSize(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.GET_SIZE


@dataclass(frozen=True)
class ReadContentEnd(Request):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.END


@dataclass(frozen=True)
class ConfirmAll(Request):
    TYPE: ClassVar[MsgType] = MsgType.CONFIRM_ALL


# --- replies -----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReadVarAsciiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR_ASCII
    value: str = wire(ASTR, "value")


@dataclass(frozen=True)
class WriteVarAsciiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR_ASCII
    value: str = wire(ASTR, "value")


@dataclass(frozen=True)
class ReadVarReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_VAR
    value: str = wire(WSTR, "value")


@dataclass(frozen=True)
class WriteVarReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_VAR
    value: str = wire(WSTR, "value")


@dataclass(frozen=True)
class MultiEntry:
    code: int = wire(U8, "entry code")
    value: str = wire(WSTR, "value")

    @property
    def ok(self) -> bool:
        return self.code == ErrorCode.SUCCESS


_ENTRIES = _List(U8, _Record(MultiEntry))


@dataclass(frozen=True)
class ReadMultiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_MULTI
    entries: tuple[MultiEntry, ...] = wire(_ENTRIES, "entries")


@dataclass(frozen=True)
class WriteMultiReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_MULTI
    entries: tuple[MultiEntry, ...] = wire(_ENTRIES, "entries")


@dataclass(frozen=True)
class ProgramControlReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.PROGRAM_CONTROL
    cmd: int = wire(U8, "program command")


@dataclass(frozen=True)
class ProxyInfoReply(Reply):
    """#13. ``utc`` = (year, month, dayOfWeek, day, hour, minute, second, millisecond)."""

    TYPE: ClassVar[MsgType] = MsgType.PROXY_INFO
    major: int = wire(U8, "major")
    minor: int = wire(U8, "minor")
    build_type: int = wire(U8, "build type")
    utc: tuple[int, int, int, int, int, int, int, int] = wire(_Array(U16, 8), "utc")
    computer_name: str = wire(WSTR, "computer name")


@dataclass(frozen=True)
class ProxyFeaturesReply(Reply):
    """#14. ``types``: the set of supported message type numbers (0–255)."""

    TYPE: ClassVar[MsgType] = MsgType.PROXY_FEATURES
    types: frozenset[int] = wire(_TypeBitmap(), "feature bitmap")


@dataclass(frozen=True)
class BenchmarkReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.BENCHMARK
    write: bool = wire(BOOL, "write")
    count: int = wire(U8, "count")
    iterations: int = wire(U32, "iterations")
    start_ms: int = wire(U32, "start ms")
    stop_ms: int = wire(U32, "stop ms")
    diff_ms: int = wire(U32, "diff ms")


@dataclass(frozen=True)
class NameListReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.NAME_LIST
    items: tuple[str, ...] = wire(_List(U16, WSTR), "items")
    infos: tuple[str, ...] = wire(_List(U16, WSTR), "infos", default=())


@dataclass(frozen=True)
class GetPropertiesReply(Reply):
    """#26. Times are Windows FILETIME ticks (100 ns since 1601); biases in minutes.

    On the wire: itemType, sizeLow, sizeHigh, attributes, (low, high, bias) × creation/access/modified,
    editMode — 14 INT32 — then ``wstr`` item name (u16 length at @61, text at @63).
    """

    TYPE: ClassVar[MsgType] = MsgType.GET_PROPERTIES
    item_type: int = wire(I32, "item type")
    size_bytes: int = wire(U64, "size")
    attributes: int = wire(I32, "attributes")
    creation_filetime: int = wire(U64, "creation time")
    creation_bias_min: int = wire(I32, "creation bias")
    access_filetime: int = wire(U64, "access time")
    access_bias_min: int = wire(I32, "access bias")
    modified_filetime: int = wire(U64, "modified time")
    modified_bias_min: int = wire(I32, "modified bias")
    edit_mode: int = wire(I32, "edit mode")
    name: str = wire(WSTR, "item name")


@dataclass(frozen=True)
class GetFullNameReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.GET_FULL_NAME
    path: str = wire(WSTR, "path")


@dataclass(frozen=True)
class GetKrcNameReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.GET_KRC_NAME
    path: str = wire(WSTR, "path")


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
    OP: ClassVar[FileOp] = FileOp.BEGIN
    buffer_size: int = wire(U32, "buffer size")


@dataclass(frozen=True)
class WriteContentGetSizeReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    OP: ClassVar[FileOp] = FileOp.GET_SIZE
    buffer_size: int = wire(U32, "buffer size")


@dataclass(frozen=True)
class WriteContentDataReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    OP: ClassVar[FileOp] = FileOp.DATA
    offset: int = wire(U32, "offset")
    written: int = wire(U32, "bytes written")


@dataclass(frozen=True)
class WriteContentEndReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.WRITE_CONTENT
    OP: ClassVar[FileOp] = FileOp.END


@dataclass(frozen=True)
class ReadContentBeginReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.BEGIN
    file_size: int = wire(U32, "file size")


@dataclass(frozen=True)
class ReadContentGetSizeReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.GET_SIZE
    size: int = wire(U32, "size")


@dataclass(frozen=True)
class ReadContentDataReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.DATA
    offset: int = wire(U32, "offset")
    data: bytes = wire(BLOB, "chunk data")


@dataclass(frozen=True)
class ReadContentEndReply(Reply):
    TYPE: ClassVar[MsgType] = MsgType.READ_CONTENT
    OP: ClassVar[FileOp] = FileOp.END


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


# --- layouts by message class and by (type, op) -------------------------------------------------------------------


class _BenchmarkLayout:
    """#17 request: BOOL write, UINT8 count, UINT32 iterations, then count × (wstr name [, wstr value if write])."""

    def put(self, out: bytearray, value: Any, what: str) -> None:
        if value.write and len(value.values) != len(value.names):
            n_names, n_values = len(value.names), len(value.values)
            raise ProtocolError(f"benchmark write needs one value per name ({n_names} names, {n_values} values)")
        if not value.write and value.values:
            raise ProtocolError("benchmark read carries no values")
        items = tuple(zip(value.names, value.values, strict=True)) if value.write else value.names
        BOOL.put(out, value.write, "write")
        U8.put(out, len(items), "number of variables")
        U32.put(out, value.iterations, "iterations")
        _Array(_NAME_VALUE if value.write else WSTR, len(items)).put(out, items, "variables")

    def get(self, r: _Reader, what: str) -> Benchmark:
        write, n = BOOL.get(r, "write"), U8.get(r, "number of variables")
        iterations = U32.get(r, "iterations")
        items = _Array(_NAME_VALUE if write else WSTR, n).get(r, "variables")
        if write:
            return Benchmark(write, iterations, tuple(k for k, _ in items), tuple(v for _, v in items))
        return Benchmark(write, iterations, items)


class _Catalogue:
    """The message classes of one direction (each a direct subclass of ``base``) and the layout of each."""

    def __init__(self, base: type, kind: str) -> None:
        self.kind = kind
        self.layouts: dict[type, _Codec] = {
            cls: _BenchmarkLayout() if cls is Benchmark else _Record(cls)
            for cls in base.__subclasses__()
            if "TYPE" in vars(cls)  # FailureReply has no layout of its own
        }
        self.classes = {(cls.TYPE, cls.OP): cls for cls in self.layouts}
        assert len(self.classes) == len(self.layouts), f"two {kind} classes share a message type and operation"

    def put(self, out: bytearray, msg: Request | Reply) -> None:
        layout = self.layouts.get(type(msg))
        if layout is None:
            raise ProtocolError(f"not an encodable {self.kind}: {msg!r}")
        if msg.OP is not None:
            U8.put(out, msg.OP, "file operation")
        layout.put(out, msg, "")

    def get(self, r: _Reader, msg_type: int) -> Any:
        op = U8.get(r, "file operation") if msg_type in _FILE_TYPES else None
        cls = self.classes.get((msg_type, op))
        if cls is None and op is None:
            raise ProtocolError(f"unknown {self.kind} message type {msg_type}")
        if cls is None:
            raise ProtocolError(f"message type {msg_type}: unknown file operation {op} in a {self.kind}")
        msg = self.layouts[cls].get(r, "")
        r.end(f"{self.kind} type {msg_type}")
        return msg


_FILE_TYPES = frozenset((MsgType.WRITE_CONTENT, MsgType.READ_CONTENT))
_KNOWN_TYPES = frozenset(int(t) for t in MsgType)
_REQUESTS = _Catalogue(Request, "request")
_REPLIES = _Catalogue(Reply, "reply")


# --- frames -------------------------------------------------------------------------------------------------------
def _frame(tag: int, msg_type: int, body: bytes | bytearray) -> bytes:
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
    out = bytearray()
    _REQUESTS.put(out, req)
    return _frame(tag, req.TYPE, out)


def encode_response(tag: int, rsp: Reply) -> bytes:
    """Encode a whole response frame (header + payload + footer)."""
    out = bytearray()
    if isinstance(rsp, FailureReply):
        out += rsp.payload
        msg_type = rsp.msg_type
    else:
        _REPLIES.put(out, rsp)
        msg_type = rsp.TYPE
    U16.put(out, rsp.code, "error code")
    BOOL.put(out, rsp.success, "success")
    return _frame(tag, msg_type, out)


def encode(tag: int, msg: Request | Reply) -> bytes:
    """Encode a request or a response, whichever ``msg`` is."""
    if isinstance(msg, Reply):
        return encode_response(tag, msg)
    if isinstance(msg, Request):
        return encode_request(tag, msg)
    raise ProtocolError(f"not a message: {msg!r}")


def _header(frame: bytes | bytearray | memoryview, *, ascii_reply: bool = False) -> tuple[int, int, _Reader]:
    r = _Reader(frame)
    tag = U16.get(r, "tag")
    length = U16.get(r, "length")
    msg_type = U8.get(r, "message type")
    if length == 0 and not ascii_reply:
        raise ProtocolError("message length 0")
    if not ascii_reply and length + 4 != len(r.data):
        raise ProtocolError(f"header length {length} does not match frame of {len(r.data)} bytes")
    return tag, msg_type, r


def decode_request(frame: bytes | bytearray | memoryview) -> tuple[int, Request]:
    """Decode one whole request frame into ``(tag, request)``; ``ProtocolError`` if malformed or unknown type."""
    tag, msg_type, r = _header(frame)
    return tag, _REQUESTS.get(r, msg_type)


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
    try:
        rsp = _REPLIES.get(_Reader(raw[: len(raw) - FOOTER_SIZE], HEADER_SIZE), msg_type)
    except ProtocolError:
        if success or msg_type not in _KNOWN_TYPES:
            raise
        return tag, FailureReply(msg_type, raw[HEADER_SIZE:-FOOTER_SIZE], code=code, success=False)
    if (rsp.code, rsp.success) != (code, success):
        rsp = dataclasses.replace(rsp, code=code, success=success)
    return tag, rsp


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
