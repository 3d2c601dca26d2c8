"""Done-when of issue 32: outside the robot files no module defines a robot's geometry, limit, pose or load figure.

Every numeric literal in the code of ``rgse_daemon`` (but ``rgse_daemon/robots``), ``simulators`` and the tests'
support is compared with the figures of every robot file (DH lengths, axis ranges and speeds, reach, Δr, payload,
load diagram, the calibration load set); docstrings are prose and not scanned. A figure too common to be a robot's
(0.1 m, 0.5 kg ...) is left out by name below, so that a new robot's distinctive numbers are caught without editing
this test; whole numbers (angles, speeds) are too common alone and are caught as tables: any six-number literal equal
to a robot's pose or speed table, any six pairs equal to its axis ranges, and its nested tables (torsional points,
torque levers, CoG poses).
"""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

from rgse_daemon import robots

ROOT = Path(__file__).resolve().parents[2]
SCANNED = [ROOT / "rgse_daemon", ROOT / "simulators", ROOT / "tests" / "support"]
ROBOT_DIR = ROOT / "rgse_daemon" / "robots"
#: Numbers a robot file holds that are too common in other code to stand for the robot (angles of the usual poses,
#: counts, the envelope the paper uses for its own settings too).
COMMON = {0.0, 1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 30.0, 35.0, 45.0, 55.0, 90.0, 100.0, 120.0, 0.1, 0.2, 0.5, 0.6,
          1.5, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.3, 0.4, 0.45, 0.004, 0.008, 0.002, 0.015, 0.12, 0.13,
          0.14, 0.15, 0.16, 0.18, 0.22, 0.25, 0.35, 3.0, 7900.0, 9.81,
          1.3,  # 1.3: the simulator's Stribeck ratio, not the KR 500's a2
          0.7}  # 0.7: a plot's alpha, a test's ratio; also the KR 500's frame half-width (its default cell)


def _numbers(value: object) -> list[float]:
    if isinstance(value, bool):
        return []
    if isinstance(value, int | float):
        return [float(value)]
    if isinstance(value, tuple):
        return [v for item in value for v in _numbers(item)]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return [v for f in dataclasses.fields(value) for v in _numbers(getattr(value, f.name))]
    return []


def robot_figures() -> set[float]:
    """The distinctive single numbers: every non-integer figure (lengths, masses, levers) and the load diagram's."""
    figures = {abs(v) for r in robots.ROBOTS.values() for v in _numbers(r) if not float(v).is_integer()}
    figures |= {r.max_payload_kg for r in robots.ROBOTS.values()} | {r.max_a5_torque_nm for r in robots.ROBOTS.values()}
    return {round(v, 9) for v in figures} - {round(v, 9) for v in COMMON}


def six_tuples() -> set[tuple[float, ...]]:
    """The tables: poses, axis speeds, and the axis ranges (flattened)."""
    out = set()
    for r in robots.ROBOTS.values():
        for t in (r.home_deg, r.candle_deg, r.operator_pose_deg, r.max_axis_speed_deg_s, *r.calibration_poses_deg[1:]):
            out.add(tuple(float(v) for v in t))
        out.add(tuple(float(v) for pair in r.axis_range_deg for v in pair))
    return out


def nested_tables() -> list[object]:
    """Tables of several levels (the torsional points, the torque levers, the CoG poses) as Python values."""
    out: list[object] = []
    for r in robots.ROBOTS.values():
        c = r.calibration
        out += [c.torsional_points, c.torque_levers_a5_m, r.calibration_poses_deg, r.axis_range_deg]
    return out


def _same(a: object, b: object) -> bool:
    if isinstance(a, tuple | list) and isinstance(b, tuple | list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return isinstance(a, int | float) and isinstance(b, int | float) and float(a) == float(b)


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and body:
            first = body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
        # attribute docstrings (a string after an assignment) are prose too
        if isinstance(node, ast.Module | ast.ClassDef) and body:
            for stmt in body:
                if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant):
                    out.add(id(stmt.value))
    return out


def _literal(node: ast.AST) -> float | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float) and not isinstance(node.value, bool):
        return float(node.value)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        inner = _literal(node.operand)
        return None if inner is None else -inner
    return None


def scan(directories: list[Path], figures: set[float], tuples: set[tuple[float, ...]]) -> list[str]:
    found = []
    for base in directories:
        for path in sorted(base.rglob("*.py")):
            if ROBOT_DIR in path.parents:
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
            prose = _docstrings(tree)
            where = path.relative_to(base.parent)
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and id(node) not in prose:
                    v = _literal(node)
                    if v is not None and round(abs(v), 9) in figures:
                        found.append(f"{where}:{node.lineno}: {node.value!r}")
                if isinstance(node, ast.Tuple | ast.List) and len(node.elts) >= 3:
                    try:
                        value = ast.literal_eval(node)
                    except ValueError:
                        value = None
                    if value is not None and any(_same(value, t) for t in nested_tables()):
                        found.append(f"{where}:{node.lineno}: the table literal {value}")
                        continue
                if isinstance(node, ast.Tuple | ast.List) and len(node.elts) == 6:
                    elts = node.elts
                    if all(isinstance(e, ast.Tuple | ast.List) and len(e.elts) == 2 for e in elts):
                        elts = [x for e in elts for x in e.elts]  # type: ignore[attr-defined]
                    values = [_literal(e) for e in elts]
                    if None not in values and tuple(values) in tuples:  # type: ignore[arg-type]
                        found.append(f"{where}:{node.lineno}: the table literal {tuple(values)}")
    return found


def test_no_module_outside_the_robot_files_holds_a_robot_figure() -> None:
    found = scan(SCANNED, robot_figures(), six_tuples())
    assert not found, "robot figures outside rgse_daemon/robots/ (take them from the RobotModel):\n" + "\n".join(found)


def test_the_scan_finds_a_planted_figure(tmp_path: Path) -> None:
    # the check itself: the KR 500's d1, its A5 torque limit and its home pose planted in a module; prose is not code
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "planted.py").write_text(
        '"""Docstring: d4 = 1.025 m is prose."""\nD1 = 1.045\nCAP = -3330\nHOME = (0, -90, 90, 0, 0, 0)\n'
        "LEVERS = (0.761, 1.011, 1.261)\n",
        encoding="utf-8")
    found = sorted(line.split(": ", 1)[1] for line in scan([tmp_path / "pkg"], robot_figures(), six_tuples()))
    assert found == sorted(["1.045", "3330", "the table literal (0.0, -90.0, 90.0, 0.0, 0.0, 0.0)",
                            "0.761", "1.011", "1.261", "the table literal (0.761, 1.011, 1.261)"])
