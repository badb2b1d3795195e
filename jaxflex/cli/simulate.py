"""``jaxflex simulate``: simulate one input and write a record (and optionally a figure)."""

from __future__ import annotations

import argparse
import math

import numpy as np

from jaxflex.cli import UsageError
from jaxflex.signals import INPUT_NAMES


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="simulate the arm under a named torque input and write a record CSV",
        description="Simulate the arm under a named torque input and write the record format "
        "of the testbed (time, torque, joint_angle, tip_acceleration, plus joint_velocity and "
        "tip_deflection).",
    )
    parser.add_argument("--input", required=True, choices=INPUT_NAMES, help="torque input shape")
    parser.add_argument("--amplitude", type=float, help="N m (default: the input's own)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a parameter (E, J_h, …, or an effect's) or a testbed setting (length, …)",
    )
    parser.add_argument(
        "--effects", default="", help="comma-separated physical effects to add (e.g. payload)"
    )
    parser.add_argument("--duration", type=float, default=2.0, help="seconds (default 2.0)")
    parser.add_argument("--dt", type=float, default=1e-3, help="sample step, s (default 1e-3)")
    parser.add_argument("--noise", action="store_true", help="add the testbed's sensor noise")
    parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    parser.add_argument("--out", required=True, help="record CSV (or .npz) to write")
    parser.add_argument("--plot", help="figure of joint angle and tip acceleration (PNG/PDF)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing files")
    parser.set_defaults(func=run)


def parse_assignments(items: list[str]) -> dict[str, float]:
    """``["E=6e10", "n_elements=12"]`` → ``{"E": 6e10, "n_elements": 12.0}`` with clear errors."""
    values: dict[str, float] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise UsageError(f"--set expects NAME=VALUE, got {item!r}")
        try:
            value = float(text)
        except ValueError:
            raise UsageError(f"--set {name}: {text!r} is not a number") from None
        if not math.isfinite(value):
            raise UsageError(f"--set {name}: value must be finite, got {text!r}")
        values[name] = value
    return values


def build_model_and_params(assignments: dict[str, float], effects: str, dt: float, duration: float):
    """The model (testbed settings and effects applied) and its full parameter set."""
    from jaxflex.effects import get_effect
    from jaxflex.model import Model
    from jaxflex.testbed import TESTBED_SETTINGS, Testbed

    names = [e.strip() for e in effects.split(",") if e.strip()]
    model = Model(effects=tuple(get_effect(n) for n in names))
    settings = {k: v for k, v in assignments.items() if k in TESTBED_SETTINGS}
    params = {k: v for k, v in assignments.items() if k not in TESTBED_SETTINGS}
    unknown = sorted(set(params) - set(model.space.names))
    if unknown:
        known = list(model.space.names) + list(TESTBED_SETTINGS)
        raise UsageError(f"--set: unknown name(s) {unknown}; known names: {known}")
    if "n_elements" in settings:
        if settings["n_elements"] != int(settings["n_elements"]):
            raise UsageError(
                f"--set n_elements must be a whole number, got {settings['n_elements']}"
            )
        settings["n_elements"] = int(settings["n_elements"])
    testbed = Testbed().replace(**settings, dt=dt, duration=duration)
    model = Model(testbed, model.effects)
    values = {k: float(v) for k, v in model.space.reference().items()} | params
    model.space.validate(values)
    return model, values


def run(args: argparse.Namespace) -> int:
    from jaxflex._io import check_writable
    from jaxflex.data import save_record
    from jaxflex.signals import reference_input
    from jaxflex.synthetic import add_measurement_noise, simulated_record

    for label, value in (("--dt", args.dt), ("--duration", args.duration)):
        if not (math.isfinite(value) and value > 0):
            raise UsageError(f"{label} must be a positive number, got {value}")
    if args.duration < 2 * args.dt:
        raise UsageError(f"--duration {args.duration} s is shorter than two samples of {args.dt} s")
    check_writable(args.out, args.overwrite)
    if args.plot:
        check_writable(args.plot, args.overwrite)
    model, params = build_model_and_params(
        parse_assignments(args.set), args.effects, args.dt, args.duration
    )
    time, torque = reference_input(args.input, args.amplitude, args.duration, args.dt)
    metadata = {
        "generator": "jaxflex simulate",
        "input": args.input,
        "parameters": ", ".join(f"{k}={v!r}" for k, v in params.items()),
        "effects": ", ".join(model.effect_names) or "none",
        "noise": f"testbed sensor noise, seed {args.seed}" if args.noise else "none",
    }
    record = simulated_record(
        model, params, args.input, time, torque, args.dt,
        extras=("joint_velocity", "tip_deflection"), metadata=metadata,
    )
    if args.noise:
        record = add_measurement_noise(record, args.seed)
    path = save_record(record, args.out, overwrite=args.overwrite)
    print(
        f"wrote {path}: {record.n_samples} samples, final joint angle "
        f"{np.degrees(record.joint_angle[-1]):.2f} deg, peak |tip acceleration| "
        f"{np.max(np.abs(record.tip_acceleration)):.3g} m/s^2"
    )
    if args.plot:
        from jaxflex.plots._style import save_figure
        from jaxflex.plots.simulate import plot_record

        print(f"wrote {save_figure(plot_record(record), args.plot, overwrite=args.overwrite)}")
    return 0
