"""``jaxflex simulate``: simulate one input and write a record (and optionally a figure).

With ``--arm``, the arm's model under its drive, written in the arm's columns
(:func:`jaxflex.measured.logged_record`).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from jaxflex.cli import UsageError
from jaxflex.cli._arm import add_arm_arguments, arm_inputs, rig_of
from jaxflex.cli._checks import (
    FIGURE_SUFFIXES,
    RECORD_SUFFIXES,
    add_max_samples,
    check_outputs,
    check_size,
    max_samples,
    positive_float,
    seed,
)
from jaxflex.cli._options import add_effect_option, add_renamed_option, finite_number
from jaxflex.signals import EXCITATION_BREAKAWAY_MULTIPLE, INPUT_NAMES

TIMING_SETTINGS = ("dt", "duration")
"""Testbed settings that have their own options (--dt, --duration), not --set."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="simulate the arm under a named torque input and write a record CSV",
        description="Simulate the arm under a named torque input and write the record format "
        "of the testbed (time, torque, joint_angle, tip_acceleration, plus joint_velocity and "
        "tip_deflection); with --arm, the arm's model under its drive, written as the rig logs "
        "it (time, the drive's input column, every sensor's channel).",
    )
    parser.add_argument("--input", required=True, choices=INPUT_NAMES, help="torque input shape")
    parser.add_argument("--amplitude", type=float,
                        help="N m, or the drive's unit with --arm (default: a reference "
                             "input's own torque, an excitation's "
                             f"{EXCITATION_BREAKAWAY_MULTIPLE:g} times the rig's breakaway "
                             "friction torque, through the drive's gain)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a parameter (E, J_h, …, or an effect's) or a testbed setting (length, …)",
    )
    add_effect_option(parser)
    add_renamed_option(parser, "--effects", "--effect NAME (repeatable)")
    parser.add_argument("--duration", type=positive_float,
                        help="seconds (default 2.0, or the arm's sampling.duration)")
    parser.add_argument("--dt", type=positive_float,
                        help="sample step, s (default 1e-3, or the arm's sampling.dt)")
    parser.add_argument("--add-noise", action="store_true",
                        help="add the testbed's sensor noise (with --arm: each sensor's noise "
                             "and quantisation)")
    add_renamed_option(parser, "--noise", "--add-noise")
    parser.add_argument("--seed", type=seed, default=0, help="noise seed (default 0)")
    add_max_samples(parser)
    parser.add_argument("--out", required=True, help="record CSV (or .npz) to write")
    parser.add_argument("--plot", help="figure of joint angle and tip acceleration (PNG/PDF)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing files")
    add_arm_arguments(parser, window=False)
    parser.add_argument("--rest", type=float, default=0.0, metavar="S",
                        help="with --arm: seconds at rest before the input, as a rig's log "
                             "starts (default 0)")
    parser.set_defaults(func=run)


def parse_assignments(items: list[str]) -> dict[str, float]:
    """``["E=6e10", "n_elements=12"]`` → ``{"E": 6e10, "n_elements": 12.0}`` with clear errors."""
    values: dict[str, float] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise UsageError(f"--set expects NAME=VALUE, got {item!r}")
        values[name] = finite_number(text, f"--set {name}")
    return values


def build_model_and_params(assignments: dict[str, float], effects: list[str], dt: float,
                           duration: float, rig=None):
    """The model (the rig, default the reference, with testbed settings and effects applied)
    and its full parameter set."""
    from jaxflex.cli._arm import with_effects
    from jaxflex.model import Model
    from jaxflex.testbed import TESTBED_SETTINGS

    rig = Model() if rig is None else rig
    model = with_effects(rig, effects, "--effect")
    for name in TIMING_SETTINGS:
        if name in assignments:
            raise UsageError(f"--set {name}: use --{name} instead")
    settings = {k: v for k, v in assignments.items() if k in TESTBED_SETTINGS}
    params = {k: v for k, v in assignments.items() if k not in TESTBED_SETTINGS}
    unknown = sorted(set(params) - set(model.space.names))
    if unknown:
        known = list(model.space.names) + [s for s in TESTBED_SETTINGS if s not in TIMING_SETTINGS]
        raise UsageError(f"--set: unknown name(s) {unknown}; known names: {known}")
    if "n_elements" in settings:
        if settings["n_elements"] != int(settings["n_elements"]):
            raise UsageError(
                f"--set n_elements must be a whole number, got {settings['n_elements']}"
            )
        settings["n_elements"] = int(settings["n_elements"])
    model = model.replace(testbed=model.testbed.replace(**settings, dt=dt, duration=duration))
    values = {k: float(v) for k, v in model.space.reference().items()} | params
    model.space.validate(values)
    return model, values


def run(args: argparse.Namespace) -> int:
    from jaxflex._io import all_or_nothing
    from jaxflex.data import save_record
    from jaxflex.signals import reference_input
    from jaxflex.synthetic import add_noise, rig_amplitude, simulated_record, warn_if_held

    rig, source = rig_of(args)
    if not rig.sensors and args.rest:
        raise UsageError(f"--rest: rig {rig.name!r} has no sensors; records of the simulator's "
                         "outputs start at rest at t = 0 (give --arm a rig with sensors)")
    sampling = rig.testbed
    args.dt = sampling.dt if args.dt is None else args.dt
    args.duration = sampling.duration if args.duration is None else args.duration
    if args.duration < 2 * args.dt:
        raise UsageError(f"--duration {args.duration} s is shorter than two samples of {args.dt} s")
    out, *plot = check_outputs(
        [("--out", args.out, RECORD_SUFFIXES), ("--plot", args.plot, FIGURE_SUFFIXES)],
        overwrite=args.overwrite, inputs=arm_inputs(source),
    )
    if rig.sensors:
        return simulate_logged(args, rig, out, plot)
    assignments = parse_assignments(args.set)
    n_elements = assignments.get("n_elements", 10)
    check_size(args.duration / args.dt + 1, f"--duration {args.duration:g} s at --dt {args.dt:g} s",
               n_elements=int(n_elements), limit=max_samples(args.max_samples))
    model, params = build_model_and_params(assignments, args.effect, args.dt, args.duration,
                                           rig)
    amplitude = args.amplitude
    if amplitude is None:
        amplitude = rig_amplitude(args.input, model, params)
    time, torque = reference_input(args.input, amplitude, args.duration, args.dt)
    warn_if_held(args.input, model, params, torque, args.dt)
    metadata = {
        "generator": "jaxflex simulate",
        "input": args.input,
        "parameters": ", ".join(f"{k}={v!r}" for k, v in params.items()),
        "effects": ", ".join(model.effect_names) or "none",
        "noise": f"testbed sensor noise, seed {args.seed}" if args.add_noise else "none",
    }
    record = simulated_record(
        model, params, args.input, time, torque, args.dt,
        extras=("joint_velocity", "tip_deflection"), metadata=metadata,
    )
    if args.add_noise:
        record = add_noise(record, args.seed)
    with all_or_nothing():
        save_record(record, out, overwrite=args.overwrite)
        if plot:
            from jaxflex.plots._style import save_figure
            from jaxflex.plots.simulate import plot_record

            save_figure(plot_record(record), plot[0], overwrite=args.overwrite)
    print(
        f"wrote {out}: {record.n_samples} samples, final joint angle "
        f"{np.degrees(record.joint_angle[-1]):.2f} deg, peak |tip acceleration| "
        f"{np.max(np.abs(record.tip_acceleration)):.3g} m/s^2"
    )
    for path in plot:
        print(f"wrote {path}")
    return 0


def simulate_logged(args: argparse.Namespace, arm, out, plot) -> int:
    """``simulate`` on a rig with sensors: its model under its drive, written as the rig would
    log it (the drive's input column and every sensor's channel)."""
    from jaxflex._io import all_or_nothing
    from jaxflex.cli._arm import with_effects
    from jaxflex.data import save_record
    from jaxflex.measured import logged_record, logged_units
    from jaxflex.rest import REST_KEY, rest_note
    from jaxflex.signals import reference_input
    from jaxflex.synthetic import rig_amplitude, warn_if_held
    from jaxflex.testbed import TESTBED_SETTINGS

    if not (math.isfinite(args.rest) and args.rest >= 0):
        raise UsageError(f"--rest {args.rest!r}: must be a finite number of seconds >= 0")
    assignments = parse_assignments(args.set)
    settings = sorted(set(assignments) & set(TESTBED_SETTINGS))
    if settings:
        raise UsageError(f"--set {settings[0]}: with --arm the arm file sets the link; edit it")
    n_rest = int(round(args.rest / args.dt))
    check_size(n_rest + args.duration / args.dt + 1,
               f"--rest {args.rest:g} s and --duration {args.duration:g} s at --dt {args.dt:g} s",
               n_elements=arm.testbed.n_elements, limit=max_samples(args.max_samples))
    model = with_effects(arm, args.effect, "--effect")
    space = model.space
    unknown = sorted(set(assignments) - set(space.names))
    if unknown:
        raise UsageError(f"--set: unknown name(s) {unknown}; known names: {list(space.names)}")
    params = space.reference() | assignments
    try:
        space.validate(params)
    except ValueError as err:
        raise UsageError(f"--set: {err}") from None
    amplitude = args.amplitude
    if amplitude is None:  # the input's own torque, or one that moves the hub, in the drive's unit
        amplitude = rig_amplitude(args.input, model, params)
    _, signal = reference_input(args.input, amplitude, args.duration, args.dt)
    warn_if_held(args.input, model, params, signal, args.dt)
    signal = np.concatenate([np.zeros(n_rest), signal])
    time = np.arange(signal.size) * args.dt
    metadata = {
        "generator": "jaxflex simulate --arm",
        "rig": arm.name,
        "input": f"{args.input}, {arm.drive.name} ({arm.drive.unit}), after "
                 f"{n_rest * args.dt:g} s at rest",
        "parameters": ", ".join(f"{k}={float(v)!r}" for k, v in params.items()),
        REST_KEY: rest_note(float(time[0]), float(time[n_rest])),
        "effects": ", ".join(model.effect_names) or "none",
        "noise": f"each sensor's noise and quantisation, seed {args.seed}" if args.add_noise
        else "none",
    }
    record = logged_record(model, params, time, signal,
                           seed=args.seed if args.add_noise else None, name=args.input,
                           metadata=metadata)
    from jaxflex.comparison import channel_units

    units = channel_units(model, record.columns)
    with all_or_nothing():
        save_record(record, out, overwrite=args.overwrite, units=logged_units(model))
        if plot:
            from jaxflex.plots._style import save_figure
            from jaxflex.plots.simulate import plot_record

            save_figure(plot_record(record, units=units), plot[0], overwrite=args.overwrite)
    print(f"wrote {out}: {record.n_samples} samples of {', '.join(record.columns[1:])} "
          f"(rig {arm.name!r})")
    for path in plot:
        print(f"wrote {path}")
    return 0
