"""``rgse krl check`` and ``rgse krl render`` (interfaces §1): the interlock's static check and the template renderer.

``rgse krl check FILE.src [--config FILE]`` reads ``FILE.dat`` beside it if there is one and checks the program in the
*default context* (:func:`default_context`), which stands for the situation the daemon pushes programs in:

* mode T1, hazard area not cleared, key switch not confirmed (so only T1 passes);
* start pose: the measurement pose (``kinematics.measurement_pose()``), where every RGSE procedure starts and ends;
* payload: the heaviest the limits allow (``limits.max_payload_kg``) with its CoG on the flange axis as far in front
  of the flange as the A5 torque limit allows with 10 % margin (load diagram, paper Fig. 16);
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
from pathlib import Path

from rgse_daemon import robots
from rgse_daemon.config import Config, LimitsConfig, load_config
from rgse_daemon.errors import ConfigError, DataError
from rgse_daemon.kinematics import G_PAPER_M_S2, measurement_pose
from rgse_daemon.krl.render import (
    GLOBALS_DAT,
    TEMPLATES,
    TemplateDefaults,
    cube_corners,
    default_params,
    globals_dat_text,
    render,
)
from rgse_daemon.safety.static import CheckContext, check_program

EXIT_OK = 0
EXIT_REFUSED = 3

#: The config keys a template's parameters come from (named when a template has no safe parameters).
CONFIG_KEYS: dict[str, tuple[str, ...]] = {
    "rgse_warmup": ("measurement.warmup_amplitude_deg", "measurement.warmup_cycles"),
    "rgse_brake_release": ("measurement.brake_release_deg",),
    "rgse_resident": ("measurement.warmup_amplitude_deg", "measurement.warmup_cycles", "measurement.brake_release_deg"),
}

#: Margin below the A5 torque limit for the default payload's CoG.
A5_TORQUE_MARGIN = 0.9


def default_payload(limits: LimitsConfig) -> tuple[float, tuple[float, float, float]]:
    """Mass (kg) and CoG (flange frame, m) of the conservative default payload (see the module docstring)."""
    mass_kg = limits.max_payload_kg
    lever_m = A5_TORQUE_MARGIN * limits.max_a5_torque_nm / (mass_kg * G_PAPER_M_S2)
    return mass_kg, (0.0, 0.0, max(0.0, lever_m - robots.active().dh[5].d_m))


def default_context(cfg: Config) -> CheckContext:
    """The context ``rgse krl check`` and ``rgse krl render`` check in (see the module docstring)."""
    mass_kg, cog = default_payload(cfg.limits)
    return CheckContext(
        limits=cfg.limits,
        mode="T1",
        area_cleared=False,
        key_confirmed=False,
        payload_mass_kg=mass_kg,
        payload_cog_flange_m=cog,
        payload_points_flange_m=tuple(cube_corners(cfg.measurement.payload_lever_max_m)),
        start_axes_deg=tuple(float(v) for v in measurement_pose()),
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
    try:
        return path.read_bytes().decode("latin-1")  # as stored: no newline translation (a lone CR is refused)
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror or exc}") from exc


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
    violations = check_program(src, dat, default_context(cfg), file=str(src_path))
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


def run(args: argparse.Namespace) -> int:
    if args.krl_command == "check":
        return check(args)
    return render_all(args)
