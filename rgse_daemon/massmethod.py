"""Where a properties run's mass came from, in the words every surface uses (the console, ``rgse runs``, the HTML
report, the certificate), so that the operator reads the same line wherever he looks.

A properties run's result says which mass it gives (``mass_method``: ``single``, the paper's pose, eq. 21, or
``multipose``, torque differences between the lever poses of one mounting), what was asked for
(``mass_method_requested``: ``single``, ``multipose`` or ``auto``) and both estimates where both were computed
(``mass_methods``: each with its mass, U at k = 2 and robot time). A measurement run's result has none of these: it
is the single pose, and nothing is said.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

#: The methods' names as the operator reads them.
NAMES = {"single": "single pose", "multipose": "multi-pose"}
#: How ``auto`` chooses (procedures.properties, pipeline.multipose.choose_method).
AUTO_RULE = "least predicted U² per robot minute"


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def estimates(result: Mapping[str, Any]) -> list[tuple[str, float, float, float | None]]:
    """(method, mass kg, U kg, robot time s or None) of every estimate the result holds, the chosen one first."""
    methods = result.get("mass_methods")
    if not isinstance(methods, Mapping):
        return []
    out = []
    for name, m in methods.items():
        if name not in NAMES or not isinstance(m, Mapping):
            continue
        mass, u = _number(m.get("mass_kg")), _number(m.get("U_kg"))
        if mass is not None and u is not None:
            out.append((str(name), mass, u, _number(m.get("robot_time_s"))))
    chosen = result.get("mass_method")
    return sorted(out, key=lambda e: e[0] != chosen)


def mass_method_text(result: Mapping[str, Any]) -> str | None:
    """One line: the method the mass comes from, whether ``auto`` chose it, and both estimates with their U when
    both were computed; None for a result without a mass method (a measurement run, a refusal)."""
    chosen = result.get("mass_method")
    if chosen not in NAMES:
        return None
    requested = result.get("mass_method_requested")
    text = NAMES[str(chosen)]
    both = estimates(result)
    if requested == "auto":
        chose = len(both) > 1 or isinstance(result.get("mass_choice"), Mapping)  # (chosen before the run)
        text += f", chosen by auto ({AUTO_RULE})" if chose else ", auto: the multi-pose mass was not available"
    if len(both) > 1:
        text += ": " + "; ".join(
            f"{NAMES[name]} {mass:.3f} ± {u:.3f} kg" + (f" in {t / 60.0:.1f} min" if t is not None else "")
            for name, mass, u, t in both) + " (U at k = 2)"
    return text


def thermal_text(result: Mapping[str, Any]) -> str | None:
    """One line: how the thermal drift of the mass the result gives was treated. The multi-pose mass's note
    (``mass_methods.multipose.thermal``) where that mass is the result's; else the single pose's per axis
    (``thermal_notes``: β with its span applied over the DuT's offset, or why not and the bound U carries; a result
    from before the notes: ``thermal_applied``, applied or not). Then U's ``thermal`` term (standard uncertainty).
    None where nothing was decided (no β in the calibration, no motor temperatures)."""
    methods = result.get("mass_methods")
    multi = methods.get("multipose") if isinstance(methods, Mapping) else None
    text = None
    if result.get("mass_method") == "multipose":
        note = multi.get("thermal") if isinstance(multi, Mapping) else None
        if isinstance(note, str) and note:
            text = f"{NAMES['multipose']} mass: {note}"
    else:
        notes, applied = result.get("thermal_notes"), result.get("thermal_applied")
        if isinstance(notes, Mapping) and notes:
            text = "; ".join(f"{ax} {note}" for ax, note in sorted(notes.items()))
        elif isinstance(applied, Mapping) and applied:
            text = ", ".join(f"{ax} {'applied' if on else 'not applied (U carries the drift)'}"
                             for ax, on in sorted(applied.items()))
    if text is None:
        return None
    budget = result.get("u_components_kg")
    u = _number(budget.get("thermal")) if isinstance(budget, Mapping) else None
    return text + (f"; thermal term of U: u = {u:.3f} kg" if u is not None else "")
