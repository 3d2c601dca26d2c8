"""The KUKA Trace configuration XML that ``$TRACE.CONFIG[]`` names (docs/controller.md §5.2).

Format, as kept in the controller's ``TRACE`` folder::

    <Trace><Time>600</Time><PreTrigger>0</PreTrigger><Basename>12_ms_v2</Basename>
      <Modules>
        <Module><Name>KRCIpo</Name><Rate>12000</Rate><Channel>500</Channel></Module>
        <Module><Name>NextGenDrive#3</Name><Rate>12000</Rate><Channel>1</Channel><Channel>202</Channel></Module>
      </Modules>
      <Trigger><ModuleName>KRCIpo</ModuleName><ID>1</ID></Trigger></Trace>

``Time`` and ``PreTrigger`` are in s, ``Rate`` in µs. Channel IDs are opaque integers (their mapping to names
is not public). The parser is strict: unknown elements, missing elements, rates the controller does not
offer, and a recording longer than the controller's buffer are refused with DataError. Documents with a DTD
or entity declarations are refused before parsing (the files come from our own controller; still, no
entity expansion).

Public API::

    cfg = parse_trace_config(xml_text, source="12_ms_v2.xml")    # -> TraceConfig
    text = render_trace_config(cfg)                              # parse_trace_config(text) == cfg
    buffer_limit_s(0.004)                                        # -> 200.0
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from rgse_daemon.errors import DataError

__all__ = [
    "BUFFER_SAMPLES",
    "PERIOD_MAX_S",
    "PERIOD_MIN_S",
    "SUPPORTED_RATES_US",
    "TraceConfig",
    "TraceModule",
    "TraceTrigger",
    "buffer_limit_s",
    "parse_trace_config",
    "render_trace_config",
]

#: Sample periods the KR C4 trace offers, in µs (docs/controller.md §5.3: 1, 4 and 12 ms).
SUPPORTED_RATES_US: frozenset[int] = frozenset({1000, 4000, 12000})

#: Plausible sample periods of a KUKA trace, s, around those offered: a header period (code 241) outside this range
#: is a corrupt or foreign file, and so is such a period in a calibration file (CAL.json ``fit.sample_period_s``).
PERIOD_MIN_S = 0.0005
PERIOD_MAX_S = 1.0

#: Samples per channel the controller's trace buffer holds. docs/controller.md §5.3 gives 600 s at 12 ms and 200 s at
#: 4 ms, both exactly 50 000 samples; the ~50 s at 1 ms follows from the same buffer (an extrapolation).
BUFFER_SAMPLES = 50_000

_INT_RE = re.compile(r"[+-]?[0-9]{1,9}")


def buffer_limit_s(period_s: float) -> float:
    """Longest recording in s that the controller's buffer holds at sample period ``period_s`` (s)."""
    if not (math.isfinite(period_s) and period_s > 0.0):
        raise ValueError(f"period_s must be finite and positive, got {period_s}")
    return BUFFER_SAMPLES * period_s


@dataclass(frozen=True)
class TraceModule:
    """One recorded module: its name (e.g. ``NextGenDrive#3``), sample period in µs and channel IDs."""

    name: str
    rate_us: int
    channels: tuple[int, ...]

    @property
    def period_s(self) -> float:
        return self.rate_us * 1e-6


@dataclass(frozen=True)
class TraceTrigger:
    """Start condition: trigger ``id`` of module ``module_name``."""

    module_name: str
    id: int


@dataclass(frozen=True)
class TraceConfig:
    """A trace configuration. ``time_s`` is the recording length, ``pretrigger_s`` the part before the trigger."""

    time_s: float
    pretrigger_s: float
    basename: str
    modules: tuple[TraceModule, ...]
    trigger: TraceTrigger | None = None

    def validate(self, source: str = "<trace config>") -> TraceConfig:
        """Check every bound; DataError naming ``source`` and the problem. Returns ``self``."""
        if not (math.isfinite(self.time_s) and self.time_s > 0.0):
            raise DataError(f"{source}: Time must be a positive number of seconds, got {self.time_s}")
        if not (math.isfinite(self.pretrigger_s) and 0.0 <= self.pretrigger_s <= self.time_s):
            raise DataError(
                f"{source}: PreTrigger must be between 0 and Time ({self.time_s} s), got {self.pretrigger_s}"
            )
        if not self.basename or any(c in self.basename for c in '\\/:*?"<>|') or self.basename.strip() != self.basename:
            raise DataError(f"{source}: Basename {self.basename!r} is empty or not usable as a file name")
        if not self.modules:
            raise DataError(f"{source}: no Module")
        names = [m.name for m in self.modules]
        if len(set(names)) != len(names):
            raise DataError(f"{source}: a Module is listed twice: {names}")
        for m in self.modules:
            if not m.name or m.name.strip() != m.name:
                raise DataError(f"{source}: Module name {m.name!r} is empty or padded")
            if m.rate_us not in SUPPORTED_RATES_US:
                raise DataError(
                    f"{source}: Module {m.name}: Rate {m.rate_us} µs is not offered "
                    f"(one of {sorted(SUPPORTED_RATES_US)})"
                )
            if not m.channels:
                raise DataError(f"{source}: Module {m.name}: no Channel")
            if len(set(m.channels)) != len(m.channels) or min(m.channels) < 0:
                raise DataError(f"{source}: Module {m.name}: Channel IDs must be distinct and >= 0: {m.channels}")
        fastest_s = min(m.period_s for m in self.modules)
        limit_s = buffer_limit_s(fastest_s)
        if self.time_s > limit_s:
            raise DataError(
                f"{source}: Time {self.time_s} s exceeds the controller's trace buffer "
                f"({limit_s:g} s at {fastest_s * 1e3:g} ms)"
            )
        if self.trigger is not None:
            if self.trigger.module_name not in names:
                raise DataError(f"{source}: Trigger names module {self.trigger.module_name!r}, not in Modules")
            if self.trigger.id < 0:
                raise DataError(f"{source}: Trigger ID must be >= 0, got {self.trigger.id}")
        return self


# --- parsing -----------------------------------------------------------------------------------------------------
def _children(elem: ET.Element, allowed: set[str], source: str) -> None:
    for child in elem:
        if child.tag not in allowed:
            raise DataError(f"{source}: unexpected element <{child.tag}> in <{elem.tag}>")


def _text(parent: ET.Element, tag: str, source: str) -> str:
    found = parent.findall(tag)
    if len(found) != 1:
        raise DataError(f"{source}: <{parent.tag}> must have exactly one <{tag}>, has {len(found)}")
    return (found[0].text or "").strip()


def _number(text: str, what: str, source: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DataError(f"{source}: {what} is not a number: {text[:40]!r}") from None
    if not math.isfinite(value):
        raise DataError(f"{source}: {what} is not finite: {text[:40]!r}")
    return value


def _integer(text: str, what: str, source: str) -> int:
    if not _INT_RE.fullmatch(text):
        raise DataError(f"{source}: {what} is not an integer: {text[:40]!r}")
    return int(text)


def parse_trace_config(text: str, source: str = "<trace config>") -> TraceConfig:
    """Parse and validate a trace configuration XML document; DataError naming ``source`` on any problem."""
    upper = text.upper()
    if "<!DOCTYPE" in upper or "<!ENTITY" in upper:
        raise DataError(f"{source}: DTD or entity declarations are refused in a trace configuration")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise DataError(f"{source}: not well-formed XML: {exc}") from exc
    if root.tag != "Trace":
        raise DataError(f"{source}: root element must be <Trace>, found <{root.tag}>")
    _children(root, {"Time", "PreTrigger", "Basename", "Modules", "Trigger"}, source)
    modules_elems = root.findall("Modules")
    if len(modules_elems) != 1:
        raise DataError(f"{source}: <Trace> must have exactly one <Modules>")
    _children(modules_elems[0], {"Module"}, source)
    modules = []
    for elem in modules_elems[0]:
        _children(elem, {"Name", "Rate", "Channel"}, source)
        name = _text(elem, "Name", source)
        modules.append(
            TraceModule(
                name=name,
                rate_us=_integer(_text(elem, "Rate", source), f"Module {name}: Rate", source),
                channels=tuple(
                    _integer((c.text or "").strip(), f"Module {name}: Channel", source) for c in elem.findall("Channel")
                ),
            )
        )
    trigger = None
    triggers = root.findall("Trigger")
    if len(triggers) > 1:
        raise DataError(f"{source}: more than one <Trigger>")
    if triggers:
        _children(triggers[0], {"ModuleName", "ID"}, source)
        trigger = TraceTrigger(
            module_name=_text(triggers[0], "ModuleName", source),
            id=_integer(_text(triggers[0], "ID", source), "Trigger ID", source),
        )
    pretrigger = root.findall("PreTrigger")
    return TraceConfig(
        time_s=_number(_text(root, "Time", source), "Time", source),
        pretrigger_s=_number(_text(root, "PreTrigger", source), "PreTrigger", source) if pretrigger else 0.0,
        basename=_text(root, "Basename", source),
        modules=tuple(modules),
        trigger=trigger,
    ).validate(source)


# --- rendering ---------------------------------------------------------------------------------------------------
def _num_text(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def render_trace_config(cfg: TraceConfig) -> str:
    """The XML text of ``cfg`` (validated first), in the controller's layout; UTF-8 declaration included."""
    cfg.validate()
    root = ET.Element("Trace")
    ET.SubElement(root, "Time").text = _num_text(cfg.time_s)
    ET.SubElement(root, "PreTrigger").text = _num_text(cfg.pretrigger_s)
    ET.SubElement(root, "Basename").text = cfg.basename
    modules = ET.SubElement(root, "Modules")
    for m in cfg.modules:
        elem = ET.SubElement(modules, "Module")
        ET.SubElement(elem, "Name").text = m.name
        ET.SubElement(elem, "Rate").text = str(m.rate_us)
        for channel in m.channels:
            ET.SubElement(elem, "Channel").text = str(channel)
    if cfg.trigger is not None:
        trigger = ET.SubElement(root, "Trigger")
        ET.SubElement(trigger, "ModuleName").text = cfg.trigger.module_name
        ET.SubElement(trigger, "ID").text = str(cfg.trigger.id)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
