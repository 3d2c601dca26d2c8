"""``rgse krl check`` and ``rgse krl render`` (interfaces §1): the interlock's static check and the template renderer.

``rgse krl check FILE.src [--config FILE]`` reads ``FILE.dat`` beside it if there is one and checks the program in the
*default context* (:func:`default_context`), which stands for the situation the daemon pushes programs in:

* mode T1, hazard area not cleared, key switch not confirmed (so only T1 passes);
* start pose: the measurement pose (``kinematics.measurement_pose()``), where every RGSE procedure starts and ends;
* payload: the fixture plus the DuT (:func:`~rgse_daemon.safety.static.mounted_payload`): ``--payload KG`` and
  ``--cog X Y Z`` (flange frame, m) if given, else ``cell.dut_mass_kg``/``cell.dut_cog_flange_m``, else the worst
  credible: the heaviest the limits allow with its CoG on the flange axis as far in front of the flange as the A5
  torque limit allows with 10 % margin (load diagram, paper Fig. 16);
* the cell (``cell``: floor, walls, keep-out boxes, the DuT's box) for the workspace rule;
* payload points whose speed matters: the corners of a cube of half side ``measurement.payload_lever_max_m`` around
  the flange, i.e. every point of a fixture + DuT reaching that far (speed is convex in the point);
* override: 100 % can be in force (the operator can raise it on the smartPAD).

Exit status: 0 allowed, 3 refused (each violation on its own line on stdout, ``FILE:line:column: RULE: message``),
2 on bad input (missing file, syntax error, bad config).

``rgse krl render --out DIR [--config FILE]`` renders every template with the configured defaults
(:func:`template_defaults`) into DIR, copies ``rgse_globals.dat`` beside them, and checks each rendered program in the
default context; a refused rendering is a bug and exits 3.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from rgse_daemon.config import Config, load_config
from rgse_daemon.errors import ConfigError, DataError
from rgse_daemon.kinematics import measurement_pose
from rgse_daemon.krl.render import (
    GLOBALS_DAT,
    TEMPLATES,
    TemplateDefaults,
    cube_corners,
    default_params,
    globals_dat_text,
    render,
)
from rgse_daemon.safety.static import MAX_PROGRAM_BYTES, CheckContext, check_program, mounted_payload

EXIT_OK = 0
EXIT_REFUSED = 3

#: The config keys a template's parameters come from (named when a template has no safe parameters).
CONFIG_KEYS: dict[str, tuple[str, ...]] = {
    "rgse_warmup": ("measurement.warmup_amplitude_deg", "measurement.warmup_cycles"),
    "rgse_brake_release": ("measurement.brake_release_deg",),
    "rgse_resident": ("measurement.warmup_amplitude_deg", "measurement.warmup_cycles", "measurement.brake_release_deg"),
}

def default_context(cfg: Config, payload_kg: float | None = None,
                    cog_flange_m: tuple[float, float, float] | None = None) -> CheckContext:
    """The context ``rgse krl check`` and ``rgse krl render`` check in (see the module docstring)."""
    mass_kg, cog = mounted_payload(cfg, payload_kg, cog_flange_m)
    return CheckContext(
        limits=cfg.limits,
        mode="T1",
        area_cleared=False,
        key_confirmed=False,
        payload_mass_kg=mass_kg,
        payload_cog_flange_m=cog,
        payload_points_flange_m=tuple(cube_corners(cfg.measurement.payload_lever_max_m)),
        start_axes_deg=tuple(float(v) for v in measurement_pose()),
        require_watchdog=cfg.controller.watchdog_required,
        cell=cfg.cell,
    )


def template_defaults(cfg: Config) -> TemplateDefaults:
    """Template parameters from the config: T1 limit, payload reach, warm-up and brake-release settings."""
    ctx = default_context(cfg)
    m = cfg.measurement
    return TemplateDefaults(
        limit_mm_s=cfg.limits.t1_speed_mm_s,
        payload_points_flange_m=(*ctx.payload_points_flange_m, ctx.payload_cog_flange_m),
        start_deg=ctx.start_axes_deg or tuple(float(v) for v in measurement_pose()),
        override_pct=ctx.override_max_pct,
        warmup_amplitude_deg=m.warmup_amplitude_deg,
        warmup_cycles=m.warmup_cycles,
        brake_angle_deg=m.brake_release_deg,
    )


def _read_text(path: Path) -> str:
    """The file as stored (ISO-8859-1, no newline translation: a lone CR is refused); a file above the check's size
    limit is refused after reading at most one byte more than the limit."""
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_PROGRAM_BYTES + 1)
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if len(raw) > MAX_PROGRAM_BYTES:
        raise DataError(f"{path}: more than {MAX_PROGRAM_BYTES} bytes, above what the interlock's check reads: "
                        "refused unread")
    return raw.decode("latin-1")


def _dat_beside(src: Path) -> Path | None:
    for suffix in (".dat", ".DAT", ".Dat"):
        candidate = src.with_suffix(suffix)
        if candidate.is_file():
            return candidate
    return None


def check(args: argparse.Namespace) -> int:
    src_path: Path = args.file
    src = _read_text(src_path)
    dat_path = _dat_beside(src_path)
    dat = _read_text(dat_path) if dat_path is not None else None
    if "{{" in src or (dat is not None and "{{" in dat):
        raise DataError(f"{src_path}: an unrendered template (it holds {{{{...}}}} placeholders), not a program: "
                        f"render it with rgse krl render --out DIR [--config FILE], then check DIR/{src_path.name}")
    cfg = load_config(args.config)
    payload_kg: float | None = getattr(args, "payload", None)
    cog = getattr(args, "cog", None)
    if payload_kg is not None and not (math.isfinite(payload_kg) and payload_kg >= 0.0):
        raise DataError(f"--payload {payload_kg:g}: the DuT's mass must be a finite number of kg >= 0")
    if cog is not None and not all(math.isfinite(c) and abs(c) <= 3.0 for c in cog):
        raise DataError(f"--cog {' '.join(f'{c:g}' for c in cog)}: the CoG must be finite, within 3 m of the flange")
    ctx = default_context(cfg, payload_kg, tuple(cog) if cog is not None else None)
    violations = check_program(src, dat, ctx, file=str(src_path))
    for v in violations:
        print(f"{src_path}:{v}")
    if violations:
        return EXIT_REFUSED
    print(f"{src_path}: allowed")
    return EXIT_OK


def render_all(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    out: Path = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{out}: cannot create the output directory: {exc.strerror or exc}") from exc
    defaults = template_defaults(cfg)
    ctx = default_context(cfg)
    refused = 0

    def write(name: str, text: str) -> None:
        try:
            # KRL files on the controller are ISO-8859-1 with CRLF line ends (as WorkVisual writes them)
            (out / name).write_bytes(text.replace("\r\n", "\n").replace("\n", "\r\n").encode("latin-1"))
        except OSError as exc:
            raise DataError(f"{out / name}: cannot write: {exc.strerror or exc}") from exc

    write(GLOBALS_DAT, globals_dat_text())
    for name in TEMPLATES:
        try:
            params = default_params(name, defaults)
        except ConfigError as exc:
            source = args.config or "the defaults"
            keys = ", ".join(f"{k} = {getattr(cfg.measurement, k.split('.')[1]):g}" for k in CONFIG_KEYS.get(name, ()))
            raise ConfigError(f"{exc} (from {keys} in {source})" if keys else str(exc)) from exc
        program = render(name, params)
        write(f"{name}.src", program.src_text)
        if program.dat_text is not None:
            write(f"{name}.dat", program.dat_text)
        violations = check_program(program.src_text, program.dat_text, ctx, file=f"{name}.src")
        for v in violations:
            print(f"{out / name}.src:{v}")
        refused += bool(violations)
        if not violations:
            print(f"{out / name}.src: rendered, allowed ($VEL_AXIS {program.params.vel_axis_pct:g} %)")
    return EXIT_REFUSED if refused else EXIT_OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rgse krl``."""
    krl_sub = p.add_subparsers(dest="krl_command", required=True, metavar="ACTION")
    c = krl_sub.add_parser("check", help="the interlock's static check (exit 3 if refused)")
    c.add_argument("file", type=Path, metavar="FILE.src")
    c.add_argument("--config", type=Path, metavar="FILE")
    c.add_argument("--payload", type=float, metavar="KG",
                   help="the DuT's mass mounted (kg; default: cell.dut_mass_kg, else the worst credible)")
    c.add_argument("--cog", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="the DuT's CoG in the flange frame (m; default: cell.dut_cog_flange_m, else worst credible)")
    r = krl_sub.add_parser("render", help="render every template in krl/ with the configured defaults")
    r.add_argument("--out", type=Path, required=True, metavar="DIR")
    r.add_argument("--config", type=Path, metavar="FILE")


def run(args: argparse.Namespace) -> int:
    if args.krl_command == "check":
        return check(args)
    return render_all(args)
