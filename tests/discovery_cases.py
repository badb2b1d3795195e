"""Synthetic discovery scenarios shared by the discovery tests: records of an arm whose base
parameters lie away from the reference values, with hidden effects and the spec's noise, and
where the loop starts (near, not at, the true base parameters)."""

from __future__ import annotations

import functools

from helpers import ARMS, REAL_DATA_DIR, or_skip

from jaxflex.diagnosis import NoiseLevel
from jaxflex.effects import get_effect
from jaxflex.model import Model
from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP, make_records

#: Base parameters of the "real" arm: every one away from the paper's value.
TRUTH = {"E": 5.2e10, "J_h": 0.0062, "b_v": 1.2e-3, "tau_c": 0.09, "alpha": 1.3, "beta": 9e-5}
#: Where the loop starts: 3 % off the truth (a fit of the base model would be near there).
START = {k: v * (1.03 if i % 2 else 0.97) for i, (k, v) in enumerate(TRUTH.items())}
NOISE = {"joint_angle": NoiseLevel.quantised(ENCODER_STEP),
         "tip_acceleration": NoiseLevel(ACCELEROMETER_SIGMA)}


def hidden(effects: dict, seed: int = 0, inputs=("triangular", "pulse", "half_sine"),
           amplitudes=None):
    """Noisy records of the truth with ``effects`` (effect or name → {param: value}), the true
    model and parameters."""
    instances = [get_effect(e) if isinstance(e, str) else e for e in effects]
    model = Model().with_effects(*instances)
    # a shape parameter (a Stribeck velocity) where the effect instance puts it
    params = {**{s.name: s.reference for s in model.space.specs if s.null is None}, **TRUTH}
    for values in effects.values():
        params.update(values)
    records = make_records(model, params, inputs=inputs, seed=seed, amplitudes=amplitudes)
    return records, model, params


def one(name: str, value: float, **kwargs):
    """:func:`hidden` with one library effect, its first parameter at ``value``."""
    effect = get_effect(name)
    return hidden({effect: {effect.parameters[0].name: value}}, **kwargs)


@functools.cache
def rotflex_report():
    """``discover`` on the real ROTFLEX square wave, held out on run 985, through the rig's
    sensors (DE 10 × 20, one step); computed once per process (the test skips without data)."""
    from jaxflex import datasets
    from jaxflex.arm import load_arm
    from jaxflex.discovery import discover
    from jaxflex.measured import fit_noise, model_record

    runs = or_skip(datasets.load, "quanser_rotflex", REAL_DATA_DIR)
    arm = load_arm(ARMS / "quanser_rotflex.toml")
    square = runs["square_wave"]
    return discover(
        [model_record(arm, square)], holdout=[model_record(arm, runs["random_985"])],
        model=arm, noise=fit_noise(arm, square), t_end=None, budget=(10, 20), max_steps=1,
        seed=0,
    )
