"""A hub torque written as a formula (jaxflex.effects.formula): a motor's cogging torque
``a·sin(6θ)`` against SciPy Radau, identified from Radau records, equal to the library's constant
offset when the formula is one, differentiable, and declared in rig files."""

import json
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference_solver import radau_reference

from jaxflex import FormulaTorque, Model, identify, reference_parameters, simulate
from jaxflex.arm import ArmError, arm_to_toml, load_arm
from jaxflex.discovery import add_effect
from jaxflex.effects import FormulaError, TorqueOffset, library
from jaxflex.fit import build_model, describe_model
from jaxflex.metrics import nrmse
from jaxflex.records import Record
from jaxflex.signals import reference_input
from jaxflex.simulation import simulate_core
from jaxflex.synthetic import make_records

REFERENCE = reference_parameters()
POLES = 6
AMPLITUDE = 0.3 * float(REFERENCE["tau_c"])  # N m: about 0.032
COGGING = FormulaTorque(f"a*sin({POLES}*theta)", {"a": (0.0, -0.05, 0.05)}, name="cogging")
MODEL = Model().with_effects(COGGING)
TRUTH = {**REFERENCE, "a": AMPLITUDE}


def cogging(theta: float, omega: float) -> tuple[float, float, float]:
    """The cogging torque written out for the Radau reference, with its partial derivatives."""
    return (AMPLITUDE * np.sin(POLES * theta), AMPLITUDE * POLES * np.cos(POLES * theta), 0.0)


@pytest.fixture(scope="module")
def radau():
    """The pulse input, and Radau's joint angle and tip acceleration under the cogging torque."""
    _, torque = reference_input("pulse")
    torque = torque[:1201]  # the pulse and the run-out: 1.2 s
    return torque, radau_reference(MODEL, TRUTH, torque, MODEL.testbed.dt, hub_torque=cogging)


def test_the_simulator_matches_radau_with_a_cogging_torque(radau):
    """The same tolerances as the simulator's own Radau tests, and the cogging shows: the
    motion without it differs from Radau's by far more."""
    torque, reference = radau
    out = simulate(MODEL, TRUTH, torque)
    assert nrmse(reference[0], np.asarray(out.joint_angle)) <= 0.05
    assert nrmse(reference[1], np.asarray(out.tip_acceleration)) <= 0.5
    assert nrmse(reference[2], np.asarray(out.joint_velocity)) <= 0.5
    plain = simulate(Model(), REFERENCE, torque)
    assert nrmse(reference[0], np.asarray(plain.joint_angle)) > 1.0
    # the arm still moves, through more than one cogging period
    assert float(np.max(reference[0])) > 2 * np.pi / POLES


def test_identify_recovers_the_cogging_amplitude_from_radau_records(radau):
    """The base parameters held at the truth, the amplitude is found within 5 % from Radau's
    records; the model without the formula, its friction and inertia refitted, fits far
    worse."""
    torque, reference = radau
    dt = MODEL.testbed.dt
    record = Record(time=np.arange(len(torque)) * dt, torque=torque,
                    joint_angle=reference[0], tip_acceleration=reference[1], name="cogging")
    base = {k: float(v) for k, v in REFERENCE.items()}
    fit = identify([record], MODEL, generations=2, population=8, seed=0, intervals=False,
                   fixed=base)
    assert fit.params["a"] == pytest.approx(AMPLITUDE, rel=0.05)
    free = ("J_h", "b_v", "tau_c")
    without = identify([record], Model(), generations=2, population=8, seed=0,
                       intervals=False, fixed={k: v for k, v in base.items() if k not in free},
                       init_population={k: base[k] for k in free})
    assert without.cost > 100 * fit.cost


def test_discovery_refits_a_formula_given_as_a_candidate():
    """A formula effect is a candidate like a library one: added to the reference model and
    refitted on noisy records of the cogging arm (0.8 s of the pulse), its amplitude comes back
    within 1 %."""
    records = make_records(MODEL, TRUTH, inputs=("pulse",), noise=True, seed=1, duration=0.8)
    fit = add_effect(records, SimpleNamespace(params=REFERENCE), COGGING)
    assert fit.model.effect_names == ("cogging",)
    assert float(fit.params["a"]) == pytest.approx(AMPLITUDE, rel=0.01)


def test_a_constant_formula_is_the_torque_offset():
    """``c`` alone joins the drive's torque as the library's constant offset does: the same
    simulation, bit for bit; and the library holds no default formula."""
    torque = reference_input("pulse")[1]
    formula = Model().with_effects(FormulaTorque("c", {"c": (0.0, -0.05, 0.05)}, name="bias"))
    offset = Model().with_effects(TorqueOffset())
    a = simulate(formula, REFERENCE | {"c": 0.02}, torque)
    b = simulate(offset, REFERENCE | {"tau_0": 0.02}, torque)
    np.testing.assert_array_equal(a.joint_angle, b.joint_angle)
    np.testing.assert_array_equal(a.tip_acceleration, b.tip_acceleration)
    assert "torque" not in {e.name for e in library()}


def test_gradients_through_the_formula_match_central_differences():
    """d(mean joint angle)/d(a, b) through a state term (cogging) and an input term (u·b)."""
    effect = FormulaTorque("a*sin(6*theta) + b*u", {"a": (0.0, -0.05, 0.05),
                                                     "b": (0.0, -0.5, 0.5)})
    model = Model().with_effects(effect)
    torque = jnp.asarray(reference_input("pulse")[1][:400])
    params = {k: jnp.asarray(v) for k, v in (REFERENCE | {"a": AMPLITUDE, "b": 0.1}).items()}

    @jax.jit
    def mean_angle(a, b):
        out = simulate_core(model, params | {"a": a, "b": b}, torque, model.testbed.dt)
        return jnp.mean(out.joint_angle)

    grads = jax.jit(jax.grad(mean_angle, argnums=(0, 1)))(params["a"], params["b"])
    for i, step in enumerate((1e-5, 1e-5)):
        shift = [jnp.zeros(()), jnp.zeros(())]
        shift[i] = jnp.asarray(step)
        plus = mean_angle(params["a"] + shift[0], params["b"] + shift[1])
        minus = mean_angle(params["a"] - shift[0], params["b"] - shift[1])
        central = float(plus - minus) / (2 * step)
        assert float(grads[i]) == pytest.approx(central, rel=1e-5), i
        assert abs(central) > 1e-3
    # and the formula's value itself: a·sin(6θ) + b·u
    value = effect.torque({"a": 0.02, "b": 0.1}, jnp.asarray(0.3), jnp.asarray(0.0),
                          jnp.asarray(2.0), jnp.asarray(0.0))
    assert float(value) == pytest.approx(0.02 * np.sin(1.8) + 0.2, rel=1e-14)


RIG = """
[[effects]]
type = "torque"
name = "cogging"
expression = "a*sin(8*theta) + b*omega + c*u*exp(-t)"
a = { reference = 0.0, lower = -0.05, upper = 0.05 }
b = { reference = 0.0, lower = -0.1, upper = 0.1, unit = "N m s/rad" }
c = { reference = 0.5, lower = 0.1, upper = 2.0, log_scale = true }
"""


def rig(tmp_path, effects: str):
    text = arm_to_toml(Model()) + effects
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_a_rig_file_declares_it_and_writes_it_back(tmp_path):
    model = load_arm(rig(tmp_path, RIG))
    (effect,) = model.effects
    assert isinstance(effect, FormulaTorque) and effect.name == "cogging"
    assert model.effect_names == ("cogging",)
    specs = {p.name: p for p in effect.parameters}
    assert specs["b"].unit == "N m s/rad" and specs["c"].log_scale and specs["a"].null == 0.0
    again = tmp_path / "again.toml"
    again.write_text(arm_to_toml(model))
    assert load_arm(again) == model
    # a fit file carries it whole
    assert build_model(json.loads(json.dumps(describe_model(model)))) == model
    # the library's effects still read by name
    assert load_arm(rig(tmp_path, '[[effects]]\nname = "payload"\n')).effect_names == (
        "payload",)


@pytest.mark.parametrize("table, message", [
    ('expression = "a*sin(thta)"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: unknown symbol 'thta' \(variables: theta, omega, u, t; "
     r"parameters: a\)"),
    ('expression = "a*sin(theta)"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }\n'
     'b = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: declared parameter\(s\) b not used"),
    ('expression = "a*sin(theta"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: 'a\*sin\(theta' is not a formula"),
    ('expression = "a*theta"\na = { reference = 2.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.a: bounds \[-1.0, 1.0\] must be increasing and hold the reference 2.0"),
    ('expression = "a*theta"\na = { reference = 0.0, lower = -1.0 }',
     r"effects\[0\]\.a: missing upper"),
    ('expression = "tau_c*theta"\ntau_c = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.tau_c: a reserved name"),
    ('expression = "omega*theta"\nomega = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.omega: a reserved name"),
    ('expression = "a*sqrt(theta)"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: 'a\*sqrt\(theta\)' is not real-valued"),
    ('expression = "a*theta > 0"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: 'a\*theta > 0' is not a real-valued torque"),
    ('expression = "a.__class__"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: '\.' is not allowed"),
    ('expression = "__import__(\'os\')"',
     r"effects\[0\]\.expression: unknown symbol '__import__'"),
    ('expression = "a*theta*u"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: the term a\*theta\*u mixes the state"),
    ('a = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[0\]\.expression: missing"),
    ('expression = "a*theta"\na = { reference = 0.0, lower = -1.0, upper = 1.0 }\n\n'
     '[[effects]]\ntype = "torque"\nname = "other"\nexpression = "a*omega"\n'
     'a = { reference = 0.0, lower = -1.0, upper = 1.0 }',
     r"effects\[1\]\.a: parameter name taken"),
])
def test_bad_declarations_are_named_in_one_line(tmp_path, table, message):
    path = rig(tmp_path, f'[[effects]]\ntype = "torque"\n{table}\n')
    with pytest.raises(ArmError, match=f"^{path}: {message}") as err:
        load_arm(path)
    assert "\n" not in str(err.value)


def test_python_declarations_check_the_same():
    with pytest.raises(FormulaError, match="unknown symbol 'x'"):
        FormulaTorque("a*x", {"a": (0.0, -1.0, 1.0)})
    with pytest.raises(FormulaError, match=r"^name: 'gravity' is a library effect's name"):
        FormulaTorque("a*cos(theta)", {"a": (0.0, -1.0, 1.0)}, name="gravity")
    with pytest.raises(FormulaError, match=r"^name: 'two words'"):
        FormulaTorque("a*theta", {"a": (0.0, -1.0, 1.0)}, name="two words")
    # a formula not vanishing at zero parameters has no null: no score test at zero
    shifted = FormulaTorque("a*cos(theta) + 0.01", {"a": (0.0, -1.0, 1.0)})
    assert shifted.parameters[0].null is None
