"""File operations of the simulated KR C4 (C3 Bridge messages #20–#30) on a local share directory.

``root`` stands for the controller's ``roboter`` share (``C:\\KRC\\ROBOTER``, shared as ``\\\\<krc>\\roboter``).
Controller names map below it:

=====================================  ==============================  ==========================
name the client sends                   file on disk                    full name (#27)
=====================================  ==============================  ==========================
``KRC:\\R1\\PROGRAM\\TEST.SRC``          ``root/R1/PROGRAM/TEST.SRC``    ``KRC:\\R1\\PROGRAM\\TEST.SRC``
``/R1/TEST.SRC`` (KRC name, #28)        ``root/R1/PROGRAM/TEST.SRC``    ``KRC:\\R1\\PROGRAM\\TEST.SRC``
``/R1/PROGRAM/TEST.SRC``                ``root/R1/PROGRAM/TEST.SRC``    ``KRC:\\R1\\PROGRAM\\TEST.SRC``
``C:\\KRC\\ROBOTER\\TRACE\\x.dat``       ``root/TRACE/x.dat``            ``C:\\KRC\\ROBOTER\\TRACE\\x.dat``
``/TRACE/x.dat``, ``KRC:\\TRACE\\x``     ``root/TRACE/...``              ``C:\\KRC\\ROBOTER\\TRACE\\...``
=====================================  ==============================  ==========================

**Decision** (the spec's only examples are #27 ``/R1/TEST.SRC`` → ``KRC:\\R1\\PROGRAM\\TEST.SRC`` and #28 back):
a KRC name ``/R1/<X>`` with a single component means the module ``X`` in ``R1\\PROGRAM`` unless ``root/R1/X`` is
an existing directory. Separators may be ``\\`` or ``/``; prefixes and components are case-insensitive as on
Windows (an existing entry that matches case-insensitively is used with its real spelling). ``..``, ``.``, other
drives, UNC paths and symlinks leading out of ``root`` are refused with code 3: nothing escapes the share.

Read and write buffers (#29/#30) belong to one connection: each connection owns one :class:`FileSession`.

**#20 #22–#25 semantics** (Cross3 ``IKSyncFile`` passes the flags on without documenting them; these follow the
Win32 calls they resemble). Refusals: a missing name or a missing target directory → code 3, an existing or
read-only target, a non-empty directory or the share itself → code 2.

* #20 SetAttribute: only ReadOnly (1) has an effect, and only on files (Windows ignores it on folders).
* #22 Create: an empty file, or a directory for item type Dir; ``always`` is ``CREATE_ALWAYS``: an existing
  writable file is truncated (without it an existing entry is refused). Module part and template are ignored.
* #23 Delete: a file or an empty directory; ``always`` also deletes a read-only file.
* #24 Copy / #25 Move: a file or a directory tree; an existing destination is replaced only with copy flag
  OverwriteExists (64), a read-only one only with OverwriteRead (4096) too. Nothing is copied or moved into itself.
"""

from __future__ import annotations

import fnmatch
import os
import re
import shutil
import stat
import time
from dataclasses import dataclass
from pathlib import Path

from rgse_daemon.durable import write_atomic
from rgse_daemon.errors import RgseError

# C3 Bridge error codes (docs/protocol.md §1).
CODE_GENERAL = 0
CODE_ACCESS = 2
CODE_ARGUMENT = 3
CODE_MEMORY = 4
CODE_NOT_IMPLEMENTED = 7
CODE_LONG_ANSWER = 10

# Attributes, item types, list and copy flags (docs/protocol.md §2, file operation constants).
ATTR_READONLY = 1
ATTR_DIRECTORY = 16
ATTR_ARCHIVE = 32
ITEM_DIR = 1
ITEM_BINARY = 8
ITEM_TEXT = 16
ITEM_MODULE = 32
LIST_RECURSIVE = 1
COPY_OVERWRITE_EXISTS = 64
COPY_OVERWRITE_READ = 4096
EDIT_FULL = 0

#: [src] file-read chunks and name lists are capped at this many bytes.
MAX_CHUNK_BYTES = 64512
#: Largest file a #29 Begin may allocate in this simulator (answers code 4 above it, as a failed allocation).
MAX_BUFFER_BYTES = 64 * 1024 * 1024

#: #21 answer formats the simulator can give (the real info text is not known, docs/protocol.md §3):
#: ``fields``: full names, info ``<itemType>;<sizeBytes>;<attributes>;<modifiedFILETIME>``;
#: ``bare``: names without their folder, no info strings at all;
#: ``text``: full names, info as free text ``<sizeBytes> <dd.mm.yyyy hh:mm:ss> <attribute letters>``.
LISTING_VARIANTS = ("fields", "bare", "text")
#: Path forms the file messages accept (the real Cross3's are not known):
#: ``any``: ``KRC:\...``, ``C:\KRC\ROBOTER\...`` and KRC names ``/R1/...``, a folder with or without a trailing ``\``;
#: ``disk``: outside ``R1`` only ``C:\KRC\ROBOTER\...``, and a folder to list must end with ``\``;
#: ``krc``: only ``KRC:\...`` and ``/R1/...`` (the TRACE folder is ``KRC:\TRACE``), a folder to list must not end
#: with ``\``.
PATH_FORM_VARIANTS = ("any", "disk", "krc")

_MODULE_SUFFIXES = {".SRC", ".DAT", ".SUB"}
_TEXT_SUFFIXES = {".TXT", ".XML", ".INI", ".CONFIG", ".LOG", ".CSV"}
_FILETIME_UNIX_EPOCH = 116_444_736_000_000_000  # 100 ns ticks from 1601-01-01 to 1970-01-01


class FileOpError(RgseError):
    """A file operation the simulated controller refuses; ``code`` is the C3 Bridge error code on the wire."""

    def __init__(self, name: str, message: str, code: int = CODE_GENERAL) -> None:
        super().__init__(f"{name}: {message}")
        self.name = name
        self.code = code


def filetime(unix_ns: int) -> int:
    """Windows FILETIME (100 ns ticks since 1601-01-01 UTC) of a POSIX time in nanoseconds."""
    return unix_ns // 100 + _FILETIME_UNIX_EPOCH


@dataclass(frozen=True)
class FileProperties:
    """Answer of #26: item type, size (bytes), attributes, FILETIMEs (UTC, bias 0 min) and edit mode."""

    item_type: int
    size_bytes: int
    attributes: int
    creation_ft: int
    access_ft: int
    modified_ft: int
    bias_min: int = 0
    edit_mode: int = EDIT_FULL


_DRIVE_PREFIXES = (  # both land at root
    re.compile(r"^krc:[\\/]*", re.IGNORECASE),
    re.compile(r"^c:[\\/]+krc[\\/]+roboter(?:[\\/]+|$)", re.IGNORECASE),
)


class ShareFiles:
    """The share directory and the name mapping; stateless file operations (#20–#28).

    Parameters
    ----------
    root:
        The local directory standing for the ``roboter`` share; created if missing.
    """

    def __init__(self, root: Path, *, listing: str = "fields", path_forms: str = "any") -> None:
        root.mkdir(parents=True, exist_ok=True)
        self.root = root.resolve()
        self.listing = listing
        self.path_forms = path_forms

    def check_form(self, name: str, *, folder: bool = False) -> None:
        """Refuse (code 3) a name whose form this controller variant does not accept (``path_forms``)."""
        if self.path_forms == "any":
            return
        upper = name.upper().replace("/", "\\")
        is_krc_name = name.startswith("/") and not name.startswith("//")
        in_r1 = upper.startswith("KRC:\\R1") or (is_krc_name and upper[1:3] == "R1")
        if self.path_forms == "disk":
            if (upper.startswith("KRC:") or is_krc_name) and not in_r1:
                raise FileOpError(name, "this controller wants C:\\KRC\\ROBOTER\\... outside R1", CODE_ARGUMENT)
            if folder and not name.endswith(("\\", "/")) and not any(c in name for c in "*?"):
                raise FileOpError(name, "a folder to list must end with \\", CODE_ARGUMENT)
        elif self.path_forms == "krc":
            if upper.startswith("C:"):
                raise FileOpError(name, "this controller wants KRC:\\... names", CODE_ARGUMENT)
            if folder and name.endswith(("\\", "/")):
                raise FileOpError(name, "a folder to list must not end with \\", CODE_ARGUMENT)

    def size_or_zero(self, name: str) -> int:
        """The size of file ``name`` in bytes, 0 if it is no readable file (the operation then fails anyway)."""
        try:
            path = self.resolve(name)
            return path.stat().st_size if path.is_file() else 0
        except (FileOpError, OSError):
            return 0

    # --- names ---------------------------------------------------------------------------------------------------
    def _parts(self, name: str) -> list[str]:
        """The components below root that ``name`` designates, before case matching."""
        if not name or "\x00" in name:
            raise FileOpError(repr(name), "empty or malformed name", CODE_ARGUMENT)
        rest: str | None = None
        krc_name = False
        for pattern in _DRIVE_PREFIXES:
            m = pattern.match(name)
            if m:
                rest = name[m.end() :]
                break
        if rest is None:
            if name.startswith("/") and not name.startswith("//"):
                rest, krc_name = name[1:], True
            else:
                raise FileOpError(
                    name, "not on the controller's share (KRC:\\, C:\\KRC\\ROBOTER\\, /R1/)", CODE_ARGUMENT
                )
        parts = [p for p in re.split(r"[\\/]+", rest) if p]
        for p in parts:
            if p in (".", "..") or ":" in p:
                raise FileOpError(name, "path leaves the share", CODE_ARGUMENT)
        if krc_name and len(parts) == 2 and parts[0].upper() == "R1":
            if not self._match_case(["R1", parts[1]]).is_dir():
                parts = ["R1", "PROGRAM", parts[1]]  # spec #27: /R1/TEST.SRC is KRC:\R1\PROGRAM\TEST.SRC
        return parts

    def _match_case(self, parts: list[str]) -> Path:
        path = self.root
        for part in parts:
            candidate = path / part
            if not candidate.exists() and path.is_dir():
                for entry in path.iterdir():
                    if entry.name.upper() == part.upper():
                        candidate = entry
                        break
            path = candidate
        return path

    def resolve(self, name: str) -> Path:
        """The local path of a controller name; refuses anything outside the share (code 3)."""
        path = self._match_case(self._parts(name))
        real = path.resolve()
        if real != self.root and self.root not in real.parents:
            raise FileOpError(name, "path leaves the share", CODE_ARGUMENT)
        return path

    def full_name(self, name: str) -> str:
        """#27: the controller's full name, e.g. ``/R1/TEST.SRC`` → ``KRC:\\R1\\PROGRAM\\TEST.SRC``."""
        return self._display(self.resolve(name))

    def krc_name(self, name: str) -> str:
        """#28: the KRC name, e.g. ``KRC:\\R1\\PROGRAM\\TEST.SRC`` → ``/R1/TEST.SRC``."""
        parts = list(self.resolve(name).relative_to(self.root).parts)
        if len(parts) == 3 and parts[0].upper() == "R1" and parts[1].upper() == "PROGRAM":
            parts = [parts[0], parts[2]]
        return "/" + "/".join(parts)

    def _display(self, path: Path) -> str:
        parts = path.relative_to(self.root).parts
        if parts and parts[0].upper() == "R1":
            return "KRC:\\" + "\\".join(parts)
        return "C:\\KRC\\ROBOTER" + "".join("\\" + p for p in parts)

    def exists(self, name: str) -> bool:
        """Whether ``name`` designates an existing entry (a bad name counts as missing)."""
        try:
            return self.resolve(name).exists()
        except FileOpError:
            return False

    # --- #21 name list -------------------------------------------------------------------------------------------
    def name_list(self, path: str, item_type: int = 0, list_flags: int = 0) -> tuple[list[str], list[str]]:
        """Entries of a directory (or matching a mask like ``KRC:\\R1\\PROGRAM\\*.SRC``).

        Returns the names (directories end with ``\\``) and the info strings, in the ``listing`` variant's format
        (:data:`LISTING_VARIANTS`; the spec leaves the info format open).
        ``item_type`` 0 lists everything, otherwise entries whose type shares a bit with it.
        """
        mask = "*"
        target = self.resolve(path)
        if not target.exists() and any(c in target.name for c in "*?"):
            mask, target = target.name, target.parent
        if not target.is_dir():
            raise FileOpError(path, "no such directory", CODE_ARGUMENT)
        entries = target.rglob("*") if list_flags & LIST_RECURSIVE else target.iterdir()
        walker = sorted(entries, key=lambda p: str(p).upper())  # Windows order: case-insensitive
        items: list[str] = []
        infos: list[str] = []
        for entry in walker:
            if not fnmatch.fnmatch(entry.name.upper(), mask.upper()):
                continue
            try:
                props = self._properties(entry)
            except FileNotFoundError:  # removed or renamed between listing and stat (e.g. a trace being written)
                continue
            if item_type and not props.item_type & item_type:
                continue
            shown = entry.name if self.listing == "bare" else self._display(entry)
            items.append(shown + ("\\" if entry.is_dir() else ""))
            if self.listing == "fields":
                infos.append(f"{props.item_type};{props.size_bytes};{props.attributes};{props.modified_ft}")
            elif self.listing == "text":
                when = time.strftime("%d.%m.%Y %H:%M:%S", time.gmtime(entry.stat().st_mtime))
                letters = ("D" if entry.is_dir() else "A") + ("R" if props.attributes & ATTR_READONLY else "")
                infos.append(f"{props.size_bytes} {when} {letters}")
        total = sum(2 + 2 * len(s) for s in items + infos)
        if total > MAX_CHUNK_BYTES or len(items) > 65535:
            raise FileOpError(path, f"list of {len(items)} entries does not fit one reply", CODE_LONG_ANSWER)
        return items, infos

    # --- #26 properties ------------------------------------------------------------------------------------------
    def properties(self, name: str) -> FileProperties:
        path = self.resolve(name)
        if not path.exists():
            raise FileOpError(name, "no such file or directory", CODE_ARGUMENT)
        return self._properties(path)

    @staticmethod
    def _properties(path: Path) -> FileProperties:
        st = path.stat()
        if stat.S_ISDIR(st.st_mode):
            item, attrs, size = ITEM_DIR, ATTR_DIRECTORY, 0
        else:
            suffix = path.suffix.upper()
            item = (
                ITEM_MODULE | ITEM_TEXT
                if suffix in _MODULE_SUFFIXES
                else (ITEM_TEXT if suffix in _TEXT_SUFFIXES else ITEM_BINARY)
            )
            attrs, size = ATTR_ARCHIVE, st.st_size
        if not st.st_mode & stat.S_IWUSR:
            attrs |= ATTR_READONLY
        ctime_ns = getattr(st, "st_birthtime_ns", st.st_ctime_ns)
        return FileProperties(item, size, attrs, filetime(ctime_ns), filetime(st.st_atime_ns), filetime(st.st_mtime_ns))

    # --- #20 #22 #23 #24 #25 -------------------------------------------------------------------------------------
    def set_attribute(self, name: str, attributes: int, mask: int) -> None:
        """#20: set the masked bits; only ReadOnly on a file has an effect on this simulator."""
        path = self._existing(name)
        if not mask & ATTR_READONLY or path.is_dir():
            return
        try:
            mode = path.stat().st_mode
            path.chmod(mode & ~0o222 if attributes & ATTR_READONLY else mode | stat.S_IWUSR)
        except OSError as exc:
            raise FileOpError(name, f"cannot set attributes: {exc.strerror}", CODE_ACCESS) from exc

    def create(self, name: str, item_type: int, always: bool) -> None:
        """#22: an empty directory (item type Dir) or an empty file; ``always`` truncates an existing file."""
        path = self.resolve(name)
        self._parent_exists(name, path)
        is_dir = bool(item_type & ITEM_DIR)
        if path.exists():
            if not always:
                raise FileOpError(name, "already exists", CODE_ACCESS)
            if path.is_dir() != is_dir:
                raise FileOpError(name, "exists as a " + ("directory" if path.is_dir() else "file"), CODE_ACCESS)
            if not is_dir and _read_only(path):
                raise FileOpError(name, "is read-only", CODE_ACCESS)
        try:
            if is_dir:
                path.mkdir(exist_ok=True)
            else:
                path.write_bytes(b"")
        except OSError as exc:
            raise FileOpError(name, f"cannot create: {exc.strerror}", CODE_ACCESS) from exc

    def delete(self, name: str, always: bool) -> None:
        """#23: delete a file or an empty directory; a read-only file only if ``always``."""
        path = self._existing(name)
        if path.resolve() == self.root:
            raise FileOpError(name, "refusing to delete the share itself", CODE_ACCESS)
        try:
            if path.is_dir() and not path.is_symlink():
                path.rmdir()
                return
            if _read_only(path):
                if not always:
                    raise FileOpError(name, "is read-only", CODE_ACCESS)
                path.chmod(path.stat().st_mode | stat.S_IWUSR)
            path.unlink()
        except OSError as exc:
            raise FileOpError(name, f"cannot delete: {exc.strerror}", CODE_ACCESS) from exc

    def copy(self, source: str, destination: str, copy_flags: int, *, move: bool = False) -> None:
        """#24 / #25: copy or move one file (or a directory tree); OverwriteExists (64) allows replacing."""
        what = "move" if move else "copy"
        src = self._existing(source)
        dst = self.resolve(destination)
        self._parent_exists(destination, dst)
        src_real, dst_real = src.resolve(), dst.resolve()
        if src_real == self.root:
            raise FileOpError(source, f"refusing to {what} the share itself", CODE_ACCESS)
        if src.is_dir() and (dst_real == src_real or src_real in dst_real.parents):
            raise FileOpError(destination, f"cannot {what} a directory into itself", CODE_ARGUMENT)
        if dst.exists():
            if not copy_flags & COPY_OVERWRITE_EXISTS:
                raise FileOpError(destination, "already exists (copy flag OverwriteExists not set)", CODE_ACCESS)
            if dst_real == src_real:
                raise FileOpError(destination, f"cannot {what} a file onto itself", CODE_ACCESS)
            if dst.is_dir() != src.is_dir():
                raise FileOpError(destination, "exists as a " + ("directory" if dst.is_dir() else "file"), CODE_ACCESS)
            if not dst.is_dir() and _read_only(dst) and not copy_flags & COPY_OVERWRITE_READ:
                raise FileOpError(destination, "is read-only (copy flag OverwriteRead not set)", CODE_ACCESS)
        try:
            if move:
                if dst.is_file() and _read_only(dst):
                    dst.chmod(dst.stat().st_mode | stat.S_IWUSR)
                os.replace(src, dst)
            elif src.is_dir():
                shutil.copytree(src, dst, dirs_exist_ok=True)
            else:
                if dst.exists() and _read_only(dst):
                    dst.chmod(dst.stat().st_mode | stat.S_IWUSR)
                shutil.copy2(src, dst)
        except OSError as exc:
            raise FileOpError(source, f"cannot {what}: {exc.strerror}", CODE_ACCESS) from exc

    def _parent_exists(self, name: str, path: Path) -> None:
        if path.resolve() != self.root and not path.parent.is_dir():
            raise FileOpError(name, "no such directory", CODE_ARGUMENT)

    def _existing(self, name: str) -> Path:
        path = self.resolve(name)
        if not path.exists():
            raise FileOpError(name, "no such file or directory", CODE_ARGUMENT)
        return path

    # --- content, used by FileSession ----------------------------------------------------------------------------
    def load(self, name: str) -> bytes:
        path = self.resolve(name)
        if not path.is_file():
            raise FileOpError(name, "no such file", CODE_ARGUMENT)
        return path.read_bytes()

    def store_atomically(self, name: str, content: bytes) -> None:
        """Write ``content`` to ``name`` via a temp file in the same directory and a rename: never half a file."""
        path = self.resolve(name)
        if path.is_dir():
            raise FileOpError(name, "is a directory", CODE_ACCESS)
        if path.exists() and not path.stat().st_mode & stat.S_IWUSR:
            raise FileOpError(name, "is read-only", CODE_ACCESS)
        write_atomic(path, content)


def _read_only(path: Path) -> bool:
    return not path.stat().st_mode & stat.S_IWUSR


class FileSession:
    """One connection's #29 write buffer and #30 read buffer (freed when the connection ends).

    Offsets and sizes are bytes; the protocol's UINT32 fields bound them.
    """

    def __init__(self, files: ShareFiles, max_buffer_bytes: int = MAX_BUFFER_BYTES) -> None:
        self.files = files
        self.max_buffer_bytes = max_buffer_bytes
        self._write: bytearray | None = None
        self._read: bytes | None = None

    # #29 WRITE CONTENT
    def write_begin(self, total_bytes: int) -> int:
        """Allocate a zero-filled buffer of ``total_bytes`` (discarding an earlier one); returns its size."""
        self._write = None
        if total_bytes > self.max_buffer_bytes:
            raise FileOpError("<write buffer>", f"{total_bytes} bytes is more than this controller allocates", 4)
        self._write = bytearray(total_bytes)
        return total_bytes

    def write_data(self, offset: int, data: bytes) -> int:
        """Copy ``data`` into the buffer at ``offset``, clipped at its end; returns the bytes written."""
        if self._write is None:
            raise FileOpError("<write buffer>", "no write in progress (Begin first)", CODE_GENERAL)
        if offset >= len(self._write) or not data:
            return 0
        n = min(len(data), len(self._write) - offset)
        self._write[offset : offset + n] = data[:n]
        return n

    def write_size(self) -> int:
        return 0 if self._write is None else len(self._write)

    def write_end(self, name: str) -> None:
        """Write the buffer to ``name`` atomically; the buffer is freed only if that succeeds."""
        if self._write is None:
            raise FileOpError(name, "no write in progress (Begin first)", CODE_GENERAL)
        self.files.store_atomically(name, bytes(self._write))
        self._write = None

    # #30 READ CONTENT
    def read_begin(self, name: str) -> int:
        """Load ``name`` into the read buffer; returns its size in bytes."""
        self._read = None
        content = self.files.load(name)
        if len(content) > 0xFFFFFFFF:
            raise FileOpError(name, "too large for the protocol", CODE_MEMORY)
        self._read = content
        return len(content)

    def read_data(self, offset: int, max_chunk: int) -> bytes:
        """At most ``min(max_chunk, remaining, 64512)`` bytes from ``offset``; empty at or past the end."""
        if self._read is None:
            raise FileOpError("<read buffer>", "no read in progress (Begin first)", CODE_GENERAL)
        n = min(max_chunk, MAX_CHUNK_BYTES)
        return self._read[offset : offset + n]

    def read_size(self) -> int:
        return 0 if self._read is None else len(self._read)

    def read_end(self) -> None:
        self._read = None

    def close(self) -> None:
        """The connection ended: free both buffers."""
        self._write = None
        self._read = None
