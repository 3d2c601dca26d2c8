"""KUKA Trace: the configuration XML (:mod:`.config`), the DIAdem ``.dat``/``.r64`` reader (:mod:`.diadem`), the
module/channel names and units (:mod:`.channels`) and the rule that a trace name is a plain name (:mod:`.names`). See
docs/controller.md §5."""

from rgse_daemon.trace.diadem import Channel, TraceFile, TraceSet, read_trace_file, read_trace_set

__all__ = ["Channel", "TraceFile", "TraceSet", "read_trace_file", "read_trace_set"]
