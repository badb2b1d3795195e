"""The library of physical effects: null exactness, physics against independent references,
gradients at the null, composition, the registry and the extension point."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import ellipk

from jaxflex.effects import (
    EFFECTS,
    AbstractEffect,
    Delay,
    Gravity,
    MotorLag,
    Payload,
    RootCompliance,
    Stribeck,
    Structure,
    get_effect,
    library,
)
from jaxflex.effects.gravity import GRAVITY
from jaxflex.modal import free_hub_modes
from jaxflex.model import Model
from jaxflex.parameters import ParameterSpec, reference_parameters
from jaxflex.sensors import calibrated
from jaxflex.signals import reference_input
from jaxflex.simulation import (
    OUTPUT_NAMES,
    simulate,
    simulate_batch,
    simulate_core,
    simulate_readings,
)

NAMES = (
    "delay",
    "drive_gain",
    "gravity",
    "motor_lag",
    "payload",
    "root_compliance",
    "sensor_gain",
    "sensor_offset",
    "stribeck",
    "torque",
    "torque_offset",
)
CHANNEL_EFFECTS = tuple(f"{k}:{c}" for k in ("sensor_gain", "sensor_offset")
                        for c in ("joint_angle", "tip_acceleration", "root_strain"))
LIBRARY = NAMES[:6] + CHANNEL_EFFECTS + tuple(n for n in NAMES[8:] if n != "torque")
# (a formula torque exists only as declared: the library holds no default one)
TESTBED = Model().testbed
DT = TESTBED.dt


@pytest.fixture(scope="module")
def pulse():
    return reference_input("pulse")[1]


@pytest.fixture(scope="module")
def base_outputs(pulse):
    return simulate(Model(), reference_parameters(), pulse)


def _with(model: Model, **values) -> dict:
    """Reference base parameters, every effect parameter at its null (a shape parameter
    without one, the Stribeck velocity, at its reference), then ``values``."""
    return {**model.space.reference(), **reference_parameters(), **model.space.nulls(),
            **values}


def _assert_same_outputs(a, b, rtol):
    for name in OUTPUT_NAMES:
        x, y = np.asarray(a.channel(name)), np.asarray(b.channel(name))
        assert np.all(np.isfinite(x)), name
        np.testing.assert_allclose(x, y, rtol=0, atol=rtol * np.abs(y).max(), err_msg=name)


# --- registry ---------------------------------------------------------------------------------
def test_registry_holds_the_six_effects_with_documented_parameters():
    assert tuple(sorted(EFFECTS)) == NAMES
    assert [e.name for e in library()] == list(LIBRARY)
    for cls in EFFECTS.values():
        assert cls.description and cls.signature, cls.name
        for spec in cls.parameters:
            gain = cls.name in ("sensor_gain", "drive_gain")
            null = 1.0 if gain else 0.0  # a gain vanishes at its reference, 1 by default
            null = None if spec.name == "v_s" else null  # a shape: the law vanishes without it
            assert spec.null == null and spec.lower <= spec.reference <= spec.upper, spec.name
    assert [s.name for s in Payload().parameters] == ["m_p"]
    assert [s.name for s in Payload(rotary=True).parameters] == ["m_p", "J_p"]
    assert isinstance(get_effect("payload", rotary=True), Payload)
    assert [e.v_s for e in Stribeck.grid()] == [0.03, 0.1, 0.3]
    # the Stribeck velocity is fitted from where the instance puts it
    assert [(s.name, s.reference) for s in Stribeck(v_s=0.2).parameters] == [
        ("delta_tau_s", 0.03), ("v_s", 0.2)]


def test_get_effect_names_the_unknown_effect_and_lists_the_known_ones():
    with pytest.raises(ValueError, match="'backlash'") as info:
        get_effect("backlash")
    for name in NAMES:
        assert name in str(info.value)
    with pytest.raises(ValueError, match="v_s"):
        Stribeck(v_s=0.0)


# --- null exactness ---------------------------------------------------------------------------
@pytest.mark.parametrize("effect", [*library(), Payload(rotary=True)], ids=lambda e: e.name)
def test_every_hook_is_the_identity_at_the_null(effect):
    model = Model().with_effects(effect)
    velocity = jnp.linspace(-3.0, 3.0, 61)
    torque = jnp.asarray(np.random.default_rng(0).normal(size=50))

    @eqx.filter_jit
    def hooks(model, params):
        return (
            model.structure(params),
            model.friction(params, velocity),
            model.load_amplitudes(params, jnp.asarray(0.7), jnp.asarray(0.2)),
            model.input_torque(params, torque, 5e-4),
            model.readings(params, {"joint_angle": torque, "root_strain": -torque}),
        )

    params = _with(model)
    structure, friction, amplitudes, applied, read = hooks(model, params)
    base_structure, base_friction, _, _, _ = hooks(Model(), reference_parameters())
    for field in ("mass", "stiffness", "first_moment", "tip", "root_curvature"):
        assert np.array_equal(getattr(structure, field), getattr(base_structure, field)), field
    assert np.array_equal(friction, base_friction)
    assert amplitudes.shape == (len(effect.loads(structure, params)),)
    assert np.all(amplitudes == 0.0)
    assert np.array_equal(applied, torque)
    assert np.array_equal(read["joint_angle"], torque)
    assert np.array_equal(read["root_strain"], -torque)


def test_all_six_at_their_nulls_simulate_exactly_the_base_model(pulse, base_outputs):
    model = Model().with_effects(*library())
    out = calibrated(model, _with(model), simulate(model, _with(model), pulse))
    _assert_same_outputs(out, base_outputs, rtol=1e-12)


def test_composed_effects_vmap_and_reduce_to_the_base_row(pulse, base_outputs):
    model = Model().with_effects(Payload(), RootCompliance(), Stribeck(), Delay(), Gravity(),
                                 MotorLag())
    assert model.space.names[6:] == ("m_p", "c_r", "delta_tau_s", "v_s", "d", "phi", "T_m")
    null, reference = _with(model), {**_with(model), **model.space.reference()}
    batch = {k: jnp.stack([null[k], reference[k]]) for k in model.space.names}
    out = simulate_batch(model, batch, pulse)
    # against the batched base model: the friction solve is converged to round-off in every
    # sample, stick phases included, so the rows agree to round-off amplified by the stiff
    # friction law (a stuck joint's torque is ~10 N m s/rad times its velocity error)
    base = {k: v for k, v in batch.items() if k in reference_parameters()}
    base_row = jax.tree.map(lambda x: x[0], simulate_batch(Model(), base, pulse))
    _assert_same_outputs(jax.tree.map(lambda x: x[0], out), base_row, 1e-9)
    # and a single run of the base model (another compiled program) to the same tolerance
    _assert_same_outputs(base_row, base_outputs, 1e-9)
    moved = jax.tree.map(lambda x: x[1], out)
    assert np.all(np.isfinite(np.asarray(moved.tip_acceleration)))
    # a heavier, softer, stickier arm turns less far under the same pulse
    assert moved.joint_angle[-1] < 0.9 * base_outputs.joint_angle[-1]


# --- payload and root compliance: frequencies against the continuous beam ---------------------
def _first_beam_root(determinant) -> float:
    """Smallest positive root βL of a frequency determinant, bracketed on a grid."""
    grid = np.linspace(0.3, 4.0, 371)
    values = [determinant(b) for b in grid]
    for a, b, fa, fb in zip(grid[:-1], grid[1:], values[:-1], values[1:], strict=True):
        if np.sign(fa) != np.sign(fb):
            return brentq(determinant, a, b, xtol=1e-14)
    raise AssertionError("no root bracketed")


def _beam_frequency(ei, rho_a, length, root_compliance=0.0, tip_mass=0.0, tip_inertia=0.0):
    """First natural frequency (Hz) of a Euler–Bernoulli beam with w(0) = 0, a rotational root
    spring EI w''(0) = w'(0)/c and a tip body: EI w''(L) = J ω² w'(L), EI w'''(L) = −m ω² w(L)."""

    def determinant(beta_l):
        beta = beta_l / length
        omega2 = beta**4 * ei / rho_a

        def basis(order, x):  # derivatives of [cos, sin, cosh, sinh](βx)
            c, s, ch, sh = np.cos(beta * x), np.sin(beta * x), np.cosh(beta * x), np.sinh(beta * x)
            rows = ([c, s, ch, sh], [-s, c, sh, ch], [-c, -s, ch, sh], [s, -c, sh, ch])
            return beta**order * np.array(rows[order])

        rows = [
            basis(0, 0.0),
            root_compliance * ei * basis(2, 0.0) - basis(1, 0.0),
            (ei * basis(2, length) - tip_inertia * omega2 * basis(1, length)) / ei * length**2,
            (ei * basis(3, length) + tip_mass * omega2 * basis(0, length)) / ei * length**3,
        ]
        rows[1] = rows[1] * length
        return np.linalg.det(np.array(rows))

    beta_l = _first_beam_root(determinant)
    return (beta_l / length) ** 2 * np.sqrt(ei / rho_a) / (2 * np.pi)


def _first_frequency(model: Model, **values) -> float:
    params = _with(model, J_h=1e4, **values)  # a hub too heavy to move: the clamped beam
    return float(free_hub_modes(model.structure(params)).frequencies_hz[0])


EI = float(reference_parameters()["E"]) * TESTBED.second_moment
BEAM = (EI, TESTBED.mass_per_length, TESTBED.length)


@pytest.mark.parametrize("tip_mass, tip_inertia", [(0.02, 0.0), (0.1, 0.0), (0.05, 5e-5)])
def test_payload_frequency_matches_the_beam_with_a_tip_body(tip_mass, tip_inertia):
    model = Model().with_effects(Payload(rotary=True))
    got = _first_frequency(model, m_p=tip_mass, J_p=tip_inertia)
    want = _beam_frequency(*BEAM, tip_mass=tip_mass, tip_inertia=tip_inertia)
    clamped = _beam_frequency(*BEAM)
    assert got == pytest.approx(want, rel=1e-3)
    assert got < 0.8 * clamped


@pytest.mark.parametrize("compliance", [3e-3, 0.03, 0.4])
def test_root_compliance_frequency_matches_the_beam_on_a_rotational_spring(compliance):
    model = Model().with_effects(RootCompliance())
    got = _first_frequency(model, c_r=compliance)
    assert got == pytest.approx(_beam_frequency(*BEAM, root_compliance=compliance), rel=1e-3)
    assert got < _first_frequency(model)


def test_root_compliance_bounds_move_the_free_hub_resonance_by_1_to_50_percent():
    model = Model().with_effects(RootCompliance())
    spec = model.space["c_r"]

    def first(c):
        return float(free_hub_modes(model.structure(_with(model, c_r=c))).frequencies_hz[0])

    drop_low, drop_high = 1 - first(spec.lower) / first(0.0), 1 - first(spec.upper) / first(0.0)
    assert 0.005 < drop_low < 0.02 and 0.4 < drop_high < 0.55


def test_payload_adds_its_weight_to_the_first_moment():
    model = Model().with_effects(Payload())
    base = Model().structure(_with(model))
    moved = model.structure(_with(model, m_p=0.1))
    extra = np.asarray(moved.first_moment - base.first_moment)
    assert extra[0] == pytest.approx(0.1 * TESTBED.length) and extra[-2] == pytest.approx(0.1)
    assert np.count_nonzero(extra) == 2


# --- input effects ----------------------------------------------------------------------------
def test_delay_by_whole_samples_shifts_the_outputs_exactly(pulse, base_outputs):
    model = Model().with_effects(Delay())
    shifted = simulate(model, _with(model, d=5 * DT), pulse)
    for name in OUTPUT_NAMES:
        got, want = np.asarray(shifted.channel(name)), np.asarray(base_outputs.channel(name))
        np.testing.assert_allclose(got[5:], want[:-5], rtol=0, atol=1e-12 * np.abs(want).max())
        assert np.all(got[:5] == 0.0), name
    # half a sample more lies between five and six samples (the joint angle, which is monotone
    # over a step) and is close to their average
    angle = [
        np.asarray(simulate(model, _with(model, d=k * DT), pulse).joint_angle) for k in (5.5, 6)
    ]
    five, half, six = np.asarray(shifted.joint_angle), angle[0], angle[1]
    spread = np.abs(five - six).max()
    assert spread > 1e-3 * np.abs(five).max()
    assert np.all(half >= np.minimum(five, six) - 1e-5 * spread)
    assert np.all(half <= np.maximum(five, six) + 1e-5 * spread)
    assert np.abs(half - 0.5 * (five + six)).max() < 0.01 * spread


def test_delay_hook_interpolates_and_its_null_gradient_is_the_backward_difference():
    h = 5e-4
    torque = jnp.asarray(np.random.default_rng(1).normal(size=40))
    effect = Delay()

    def delayed(d):
        return effect.input_torque({"d": d}, torque, h)

    padded = np.concatenate([np.zeros(4), np.asarray(torque)])
    np.testing.assert_allclose(delayed(3.25 * h), 0.75 * padded[1:-3] + 0.25 * padded[:-4])
    slope = jax.jacfwd(delayed)(jnp.asarray(0.0))
    np.testing.assert_allclose(slope, -np.diff(padded[3:]) / h, rtol=1e-12)


def test_motor_lag_step_response_is_one_minus_exponential():
    h, lag = 5e-4, 0.01
    step = jnp.ones(200)
    got = MotorLag().input_torque({"T_m": jnp.asarray(lag)}, step, h)
    t = np.arange(200) * h
    # per-step average of 1 − exp(−t/T) over [t_i, t_i + h]
    want = 1.0 - lag / h * (np.exp(-t / lag) - np.exp(-(t + h) / lag))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)


def test_motor_lag_gradient_is_finite_from_zero_to_underflow():
    h = 5e-4
    torque = jnp.asarray(np.random.default_rng(2).normal(size=30))

    def lagged(lag):
        return MotorLag().input_torque({"T_m": lag}, torque, h)

    padded = np.concatenate([[0.0], np.asarray(torque)])
    np.testing.assert_allclose(jax.jacfwd(lagged)(jnp.asarray(0.0)), -np.diff(padded) / h)
    for lag in (1e-300, 1e-8, h / 700, 1e-2):
        value, slope = lagged(jnp.asarray(lag)), jax.jacfwd(lagged)(jnp.asarray(lag))
        assert np.all(np.isfinite(value)) and np.all(np.isfinite(slope)), lag


# --- friction ---------------------------------------------------------------------------------
@eqx.filter_jit
def _friction_and_slope(model: Model, params, velocity):
    return jax.vmap(jax.value_and_grad(lambda v: model.friction(params, v)))(velocity)


def test_stribeck_friction_breaks_away_at_tau_s_and_slides_at_tau_c():
    tau_c, excess, omega_s = 0.1, 0.05, TESTBED.omega_s
    params = {**reference_parameters(), "tau_c": tau_c, "b_v": 1e-5, "delta_tau_s": excess}
    v = jnp.arange(-2000, 2001) / 1000.0  # rad/s, 0 included exactly
    for effect in (*Stribeck.grid(), *(Stribeck(delta=d) for d in (0.5, 1.0, 3.0))):
        total, slope = _friction_and_slope(Model().with_effects(effect), params, v)
        assert np.array_equal(np.sign(total), np.sign(v)) and float(total[2000]) == 0.0
        assert np.all(np.isfinite(slope)), effect
        extra = effect.friction({"delta_tau_s": jnp.asarray(excess)}, v, omega_s)
        assert np.all(extra * v >= 0.0) and np.all(extra[2001:2100] > 0.0)
        if effect.delta == 2.0:  # at 5 v_s the friction is back to the Coulomb law
            sliding = 2000 + round(5000 * effect.v_s)
            assert float(total[sliding]) == pytest.approx(tau_c + 1e-5 * float(v[sliding]))
        if effect.delta == 2.0 and effect.v_s >= 10 * omega_s:
            # (for v_s ~ omega_s the Coulomb smoothing hides part of the peak)
            breakaway = float(jnp.max(total))
            assert breakaway == pytest.approx(tau_c + excess, rel=0.04)


# --- gravity ----------------------------------------------------------------------------------
TILT = 0.5
#: m g sin(phi) L/2, the link weight moment about the joint in the tilted plane
LINK_WEIGHT_TORQUE = (
    TESTBED.mass_per_length * TESTBED.length * GRAVITY * np.sin(TILT) * TESTBED.length / 2
)


@pytest.fixture(scope="module")
def gravity_run():
    model = Model().with_effects(Gravity())
    torque = np.zeros(2201)  # past the second crossing of the bottom

    def run(**values):
        return simulate(model, _with(model, phi=TILT, **values), torque)

    return run


def test_gravity_holding_torque_is_the_link_weight_moment(gravity_run):
    # with strong Coulomb friction the arm only creeps at the speed where friction balances
    # m g sin(phi) L/2 cos(theta): b_v v + tau_c tanh(v/omega_s) = torque
    out = gravity_run(tau_c=0.2, b_v=1e-5)
    angle, velocity = float(out.joint_angle[-1]), float(out.joint_velocity[-1])
    holding = LINK_WEIGHT_TORQUE * np.cos(angle)
    assert abs(angle) < 0.02
    assert float(out.joint_torque[-1]) == pytest.approx(holding, rel=2e-3)
    creep = brentq(lambda v: 1e-5 * v + 0.2 * np.tanh(v / TESTBED.omega_s) - holding, 0.0, 1.0)
    assert -velocity == pytest.approx(creep, rel=2e-3)


def test_gravity_swings_the_free_arm_like_a_compound_pendulum(gravity_run):
    # released from horizontal, the arm swings ±90° about straight down the slope:
    # period 4 sqrt(J/(m g' L/2)) K(sin²(π/4)) (the complete elliptic integral, exact amplitude)
    out = gravity_run(tau_c=1e-6, b_v=1e-7)
    below = np.asarray(out.joint_angle) + np.pi / 2
    i = np.flatnonzero(np.sign(below[:-1]) != np.sign(below[1:]))
    crossings = (i + below[i] / (below[i] - below[i + 1])) * DT
    assert len(crossings) == 2
    inertia = float(reference_parameters()["J_h"]) + TESTBED.link_inertia
    period = 4 * np.sqrt(inertia / LINK_WEIGHT_TORQUE) * ellipk(0.5)
    assert 2 * (crossings[1] - crossings[0]) == pytest.approx(period, rel=0.01)
    assert below.max() == pytest.approx(np.pi / 2, abs=0.01)


# --- gradients at the null --------------------------------------------------------------------
def _loss(outputs) -> jnp.ndarray:
    return (jnp.mean(outputs.joint_angle**2) + 1e-3 * jnp.mean(outputs.tip_acceleration**2)
            + 1e3 * jnp.mean(outputs.root_strain**2))


def test_gradients_at_the_null_are_finite_nonzero_and_match_finite_differences():
    model = Model().with_effects(
        *(Payload(rotary=True) if e.name == "payload" else e for e in library())
    )
    # steps at 0 and 0.3 s; 0.5 s keeps the joint sliding, where the loss is smooth enough for
    # one-sided differences (after a stop, round-off in the stuck joint makes them noisy)
    torque = jnp.asarray(reference_input("pulse", duration=0.5)[1])
    nulls = model.space.nulls()
    base = {k: v for k, v in _with(model).items() if k not in nulls}

    @eqx.filter_jit
    @jax.value_and_grad
    def loss(effect_params):
        params = {**base, **effect_params}
        return _loss(calibrated(model, params, simulate_core(model, params, torque, DT)))

    value, grads = loss(nulls)
    calibrations = {f"{k}_{c}" for k in ("gain", "offset")
                    for c in ("joint_angle", "tip_acceleration", "root_strain")}
    assert set(grads) == {"d", "phi", "T_m", "m_p", "J_p", "c_r", "delta_tau_s", "tau_0",
                          "torque_per_unit", *calibrations}
    for name, grad in grads.items():
        step = 1e-3 * model.space[name].lower
        moved = jnp.asarray(nulls[name] + step, dtype=jnp.float64)
        difference = (loss({**nulls, name: moved})[0] - value) / step
        assert np.isfinite(grad) and abs(grad) > 0, name
        assert float(grad) == pytest.approx(float(difference), rel=0.02), name


# --- the extension point ----------------------------------------------------------------------
class TorqueOffset(AbstractEffect):
    """A constant torque on the joint (e.g. an uncompensated amplifier offset), as a load."""

    name: ClassVar[str] = "torque_offset"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec("tau_0", "N m", 0.0, 0.05, 0.01, log_scale=False, null=0.0),
    )
    description: ClassVar[str] = "A constant joint torque added to the commanded one."
    signature: ClassVar[str] = "a drift of the joint angle growing with t² while it slides"

    def loads(self, structure: Structure, params) -> jnp.ndarray:
        return jnp.zeros((1, structure.mass.shape[0])).at[0, 0].set(1.0)

    def load_amplitudes(self, params, angle, velocity) -> jnp.ndarray:
        return jnp.broadcast_to(params["tau_0"], (1,))


def test_a_user_defined_effect_plugs_in_through_the_same_hooks(pulse, base_outputs):
    model = Model().with_effects(TorqueOffset())
    assert model.space.names[-1] == "tau_0"
    offset = 0.03
    got = simulate(model, _with(model, tau_0=offset), pulse)
    want = simulate(Model(), reference_parameters(), pulse + offset)
    for name in ("joint_angle", "tip_acceleration", "joint_velocity", "tip_deflection"):
        # same physics, different rounding: equal up to the friction solve's tolerance
        scale = np.abs(np.asarray(want.channel(name))).max()
        np.testing.assert_allclose(got.channel(name), want.channel(name), atol=1e-5 * scale)
    assert np.abs(np.asarray(got.joint_angle - base_outputs.joint_angle)).max() > 0.05


class _Misbehaving(AbstractEffect):
    """A user's effect whose hook ``fault`` goes wrong in one of the ways a new effect does."""

    name: ClassVar[str] = "misbehaving"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec("k_m", "N m", 0.0, 1.0, 0.1, log_scale=False, null=0.0),
    )
    fault: str = eqx.field(static=True, default="friction")

    def friction(self, params, velocity, omega_s):
        if self.fault == "friction":  # one torque per mode, not per velocity
            return params["k_m"] * jnp.ones(3)
        return jnp.zeros_like(velocity)

    def structure(self, structure, params):
        if self.fault == "structure":  # the hub's row and column dropped
            return eqx.tree_at(lambda s: s.mass, structure, structure.mass[1:, 1:])
        return structure

    def input_torque(self, params, torque, h):
        if self.fault == "input_torque":
            return torque + params["k_missing"]
        return torque

    def readings(self, params, readings):
        if self.fault == "readings":
            return {c: v for c, v in readings.items() if c != "tip_acceleration"}
        return dict(readings)


@pytest.mark.parametrize(("fault", "message"), [
    ("friction", r"friction returned an array of shape \(3,\), float64; expected real values "
                 r"of shape \(\) \(a torque per velocity\)"),
    ("structure", r"structure returned an array of shape \(\d+, \d+\), float64; expected real "
                  r"values of shape \(\d+, \d+\) \(its mass matrix\)"),
    ("input_torque", r"input_torque raised KeyError: 'k_missing'"),
    ("readings", r"readings returned without \['tip_acceleration'\]; expected every channel it "
                 r"was given: \["),
])
def test_a_user_effect_that_goes_wrong_is_named_with_what_it_returned(pulse, fault, message):
    """Said in the effect's terms, not in JAX's from deep inside the simulator's trace."""
    from jaxflex.effects import EffectError

    model = Model().with_effects(_Misbehaving(fault=fault))
    with pytest.raises(EffectError, match=r"^effect _Misbehaving \('misbehaving'\): " + message):
        simulate_readings(model, _with(model, k_m=0.1), pulse[:50])
