"""The simulator against independent references: beam theory, SciPy Radau, energy, gradients."""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference_solver import designed_torque, radau_reference
from scipy.optimize import brentq

import jaxflex
from jaxflex.frequency_response import frf, natural_frequencies
from jaxflex.model import Model
from jaxflex.signals import reference_input
from jaxflex.simulation import simulate, simulate_batch, simulate_core
from jaxflex.testbed import Testbed

Testbed.__test__ = False  # not a test class

REFERENCE = jaxflex.reference_parameters()
CLAMPED_FREE_BETA_L = (1.8751040687, 4.6940911330, 7.8547574382)


def nrmse(y, y_hat):
    return 100.0 * np.sqrt(np.mean((y - y_hat) ** 2)) / np.sqrt(np.mean(y**2))


def with_values(**changes):
    return {**REFERENCE, **{k: jnp.asarray(v, dtype=jnp.float64) for k, v in changes.items()}}


def clamped_free_hz(testbed: Testbed, youngs: float, beta_l: float) -> float:
    ei = youngs * testbed.second_moment
    return beta_l**2 * np.sqrt(ei / (testbed.mass_per_length * testbed.length**4)) / (2 * np.pi)


@pytest.mark.parametrize("n_elements", [10])
def test_huge_hub_gives_clamped_free_frequencies(n_elements):
    model = Model(Testbed(n_elements=n_elements))
    freqs = natural_frequencies(model, with_values(J_h=1e6))
    for k, beta_l in enumerate(CLAMPED_FREE_BETA_L):
        exact = clamped_free_hz(model.testbed, float(REFERENCE["E"]), beta_l)
        assert abs(freqs[k] / exact - 1.0) < 0.005, (k, freqs[k], exact)


def test_frequencies_converge_with_mesh():
    errors = []
    for n in (3, 5, 10, 20):
        model = Model(Testbed(n_elements=n))
        freqs = natural_frequencies(model, with_values(J_h=1e6))
        exact = clamped_free_hz(model.testbed, float(REFERENCE["E"]), CLAMPED_FREE_BETA_L[2])
        errors.append(abs(freqs[2] / exact - 1.0))
    assert all(later < earlier for earlier, later in zip(errors, errors[1:], strict=False)), errors
    assert errors[-1] < 1e-4


def hub_beam_betas(testbed: Testbed, hub_inertia: float, count: int) -> list[float]:
    """Roots β of the free-hub beam frequency equation (hub: J_h θ'' = EI w''(0), free tip)."""
    rho_a, length = testbed.mass_per_length, testbed.length

    def determinant(beta):
        kappa = hub_inertia * beta**3 / (2.0 * rho_a)
        bl = beta * length
        ch, sh, c, s = np.cosh(bl), np.sinh(bl), np.cos(bl), np.sin(bl)
        # A = −κ(B + D); rows: W''(L) = 0 and W'''(L) = 0 in the unknowns (B, D).
        a11, a12 = -kappa * (ch + c) + sh, -kappa * (ch + c) - s
        a21, a22 = -kappa * (sh - s) + ch, -kappa * (sh - s) - c
        return (a11 * a22 - a12 * a21) / np.cosh(bl) ** 2

    grid = np.linspace(0.5, 12.0, 4000) / length
    values = [determinant(b) for b in grid]
    roots = [
        brentq(determinant, grid[i], grid[i + 1])
        for i in range(len(grid) - 1)
        if np.sign(values[i]) != np.sign(values[i + 1])
    ]
    return roots[:count]


@pytest.mark.parametrize("hub_inertia", [1e-3, 0.0053, 0.05])
def test_free_hub_frequencies_match_frequency_equation(hub_inertia):
    model = Model(Testbed(n_elements=20))
    freqs = natural_frequencies(model, with_values(J_h=hub_inertia))
    ei = float(REFERENCE["E"]) * model.testbed.second_moment
    for k, beta in enumerate(hub_beam_betas(model.testbed, hub_inertia, 3)):
        exact = beta**2 * np.sqrt(ei / model.testbed.mass_per_length) / (2 * np.pi)
        assert abs(freqs[k] / exact - 1.0) < 1e-3, (k, freqs[k], exact)


def test_analytic_frf_peaks_at_the_natural_frequencies():
    model = Model()
    params = with_values(alpha=1e-3, beta=1e-7)
    first = natural_frequencies(model, params)[0]
    freqs = np.linspace(0.5 * first, 1.5 * first, 2001)
    peak = freqs[np.argmax(np.abs(frf(model, params, freqs)))]
    assert abs(peak / first - 1.0) < 2e-3


@pytest.mark.parametrize("name", ["triangular", "pulse", "half_sine"])
def test_accuracy_against_radau(name):
    """Every mode advanced, and eight advanced plus the others' static response (residual
    flexibility): the same tolerances against one Radau reference."""
    _, torque = reference_input(name)
    reference = radau_reference(Model(), REFERENCE, torque, Model().testbed.dt)
    for model in (Model(), Model(n_modes=8)):
        out = simulate(model, REFERENCE, torque)
        assert nrmse(reference[0], np.asarray(out.joint_angle)) <= 0.05, model.n_modes
        assert nrmse(reference[1], np.asarray(out.tip_acceleration)) <= 0.5, model.n_modes
        assert nrmse(reference[2], np.asarray(out.joint_velocity)) <= 0.5, model.n_modes
        # the paper's test condition: each reference input moves the joint to about 80 degrees
        assert 70.0 < np.degrees(float(out.joint_angle[-1])) < 90.0


def test_accuracy_against_radau_on_a_designed_input():
    """A designed input (jaxflex.design's Fourier basis up to 20 Hz, seeded coefficients) changes
    the torque at every sample, unlike the paper's three: the same tolerances hold."""
    model = Model()
    torque = designed_torque()
    reference = radau_reference(model, REFERENCE, torque, 1e-3)
    out = simulate(model, REFERENCE, torque)
    assert nrmse(reference[0], np.asarray(out.joint_angle)) <= 0.05
    assert nrmse(reference[1], np.asarray(out.tip_acceleration)) <= 0.5
    assert nrmse(reference[2], np.asarray(out.joint_velocity)) <= 0.5


def test_a_tilted_plane_against_radau():
    """Gravity's load on the first moment and the beam's static deflection at rest, integrated
    by Radau in physical coordinates: the same tolerances, and the tilt shows (the motion
    differs from the level plane's by far more than the tolerance)."""
    from jaxflex.effects import get_effect

    model = Model().with_effects(get_effect("gravity"))
    params = {**REFERENCE, "phi": 0.06}
    _, torque = reference_input("pulse")
    reference = radau_reference(model, params, torque, model.testbed.dt)
    out = simulate(model, params, torque)
    assert nrmse(reference[0], np.asarray(out.joint_angle)) <= 0.05
    assert nrmse(reference[1], np.asarray(out.tip_acceleration)) <= 0.5
    assert nrmse(reference[2], np.asarray(out.joint_velocity)) <= 0.5
    level = simulate(Model(), REFERENCE, torque)
    assert nrmse(reference[0], np.asarray(level.joint_angle)) > 1.0


def test_energy_balance_without_dissipation():
    model = Model()
    params = with_values(alpha=0.0, beta=0.0, b_v=0.0, tau_c=0.0)
    _, torque = reference_input("half_sine")
    out, (q, qdot) = simulate_core(model, params, jnp.asarray(torque), 1e-3, return_states=True)
    structure = model.structure(params)
    mass, stiffness = np.asarray(structure.mass), np.asarray(structure.stiffness)
    q, qdot = np.asarray(q), np.asarray(qdot)
    theta = np.asarray(out.joint_angle)
    work = np.concatenate([[0.0], np.cumsum(torque[:-1] * np.diff(theta))])  # ZOH: τ_k·Δθ
    kinetic = 0.5 * np.einsum("ti,ij,tj->t", qdot, mass, qdot)
    potential = 0.5 * np.einsum("ti,ij,tj->t", q, stiffness, q)
    assert np.max(np.abs(kinetic + potential - work)) <= 1e-3 * np.max(work)
    assert np.allclose(q[:, 0], theta)


@pytest.mark.parametrize("name", ["triangular", "pulse", "half_sine"])
def test_finite_everywhere_in_the_bounds(name):
    model = Model()
    u = np.random.default_rng(42).uniform(size=(1000, len(model.space)))
    params = model.space.from_unit(u)  # log-uniform for log-scale parameters
    _, torque = reference_input(name)
    out = simulate_batch(model, params, torque)
    for field in ("joint_angle", "tip_acceleration", "joint_velocity", "tip_deflection"):
        assert np.all(np.isfinite(np.asarray(getattr(out, field)))), field


def test_batch_matches_single_runs():
    model = Model()
    u = np.random.default_rng(3).uniform(size=(4, 6))
    params = model.space.from_unit(u)
    _, torque = reference_input("pulse")
    batch = simulate_batch(model, params, torque)
    for i in range(4):
        single = simulate(model, {k: v[i] for k, v in params.items()}, torque)
        # Vectorised and scalar code round differently; a joint creeping under the smooth
        # Coulomb law after it stops amplifies that to ~1e-7, so compare at 1e-6.
        np.testing.assert_allclose(batch.joint_angle[i], single.joint_angle, rtol=1e-6, atol=1e-9)


def test_gradients_match_central_differences():
    model = Model()
    _, torque = reference_input("half_sine", duration=0.5)  # the joint slides throughout
    torque = jnp.asarray(torque)
    names = model.space.names

    def loss(log_values):
        params = {n: jnp.exp(log_values[i]) for i, n in enumerate(names)}
        out = simulate_core(model, params, torque, 1e-3)
        return jnp.mean(out.tip_acceleration**2) + 100.0 * jnp.mean(out.joint_angle**2)

    x0 = jnp.log(model.space.to_vector(REFERENCE))
    grad = np.asarray(jax.jit(jax.grad(loss))(x0))
    loss_jit = jax.jit(loss)
    scale = np.max(np.abs(grad))
    for i, name in enumerate(names):
        # Median over three steps guards against one unlucky step (truncation or round-off).
        estimates = []
        for step in (1e-3, 1e-4, 1e-5):
            e = jnp.zeros_like(x0).at[i].set(step)
            estimates.append((float(loss_jit(x0 + e)) - float(loss_jit(x0 - e))) / (2 * step))
        fd = float(np.median(estimates))
        if abs(fd) < 1e-6 * scale:
            continue  # the derivative is tiny: relative error is meaningless
        assert abs(grad[i] - fd) <= 1e-4 * abs(fd), (name, grad[i], estimates)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"E": -1.0}, "parameter E must be positive"),
        ({"J_h": float("nan")}, "parameter J_h must be finite"),
        ({"tau_c": 0.0}, "parameter tau_c must be positive"),
    ],
)
def test_bad_parameters_are_named(changes, message):
    _, torque = reference_input("pulse")
    with pytest.raises(ValueError, match=message):
        simulate(Model(), {**REFERENCE, **changes}, torque)


def test_bad_inputs_are_named():
    model = Model()
    _, torque = reference_input("pulse")
    with pytest.raises(ValueError, match="dt must be a positive"):
        simulate(model, REFERENCE, torque, dt=0.0)
    with pytest.raises(ValueError, match="dt must be a positive"):
        simulate(model, REFERENCE, torque, dt=-1e-3)
    with pytest.raises(ValueError, match="torque must be a 1-D array"):
        simulate(model, REFERENCE, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="torque is not finite at sample 5"):
        simulate(model, REFERENCE, np.where(np.arange(10) == 5, np.nan, 0.1))
    with pytest.raises(ValueError, match="missing"):
        simulate(model, {k: v for k, v in REFERENCE.items() if k != "beta"}, torque)
    with pytest.raises(ValueError, match="unknown parameter"):
        simulate(model, {**REFERENCE, "mass": 1.0}, torque)
    with pytest.raises(ValueError, match="1-D of one length"):
        ragged = {k: jnp.full((2,), v) for k, v in REFERENCE.items()} | {"E": 1e10}
        simulate_batch(model, ragged, torque)
    with pytest.raises(ValueError, match="unknown input 'sawtooth'"):
        reference_input("sawtooth")
    with pytest.raises(ValueError, match="unknown testbed setting"):
        Testbed().replace(lenght=0.4)
    with pytest.raises(ValueError, match="n_substeps"):
        Model(n_substeps=0)


def _base_friction(v):
    return float(REFERENCE["b_v"]) * v + float(REFERENCE["tau_c"]) * jnp.tanh(v / 0.01)


def _friction_residual(target, gain=0.05):
    """``v + gain·f(v) − target`` as the friction solve evaluates it: with its slope, the size
    of its terms and the law's friction and slope there."""

    def residual(v):
        f, df = jax.jvp(_base_friction, (v,), (1.0,))
        scale = abs(v) + abs(gain * f) + abs(target)
        return v + gain * f - target, 1.0 + gain * df, scale, (f, df)

    return residual


@pytest.mark.parametrize("target", [1e-9, -3e-4, 0.004, 0.02, 0.5, -2.0])
@pytest.mark.parametrize("guess_share", [0.0, 0.5, 1.0])
def test_friction_solve_converges_to_round_off(target, guess_share):
    """Stuck (|v| ≪ ω_s) to sliding: the root equals SciPy's brentq at full precision, from any
    start in the bracket, alone and vmapped, with the implicit-function derivative."""
    gain = 0.05
    solver = sys.modules["jaxflex.friction_solve"]

    def solve(target, guess):
        return solver.joint_velocity_solve(_base_friction, target, gain, guess)[0]

    root = float(solve(jnp.float64(target), jnp.float64(guess_share * target)))
    expected = brentq(
        lambda v: v + gain * float(_base_friction(v)) - target,
        min(0.0, target), max(0.0, target), xtol=1e-300, rtol=4 * np.finfo(float).eps,
    )
    assert root == pytest.approx(expected, rel=1e-14, abs=0)
    targets = jnp.asarray([target, 0.1, -1e-5, target])
    batched = jax.vmap(solve)(targets, guess_share * targets)
    assert float(batched[0]) == pytest.approx(root, rel=1e-14, abs=0)
    assert float(batched[3]) == pytest.approx(root, rel=1e-14, abs=0)
    slope = 1.0 + gain * float(jax.grad(_base_friction)(root))
    assert float(jax.grad(solve)(jnp.float64(target), 0.0)) == pytest.approx(1 / slope, rel=1e-12)


def test_friction_solve_stops_well_before_its_limit():
    """Few iterations from a start near the root; never the safety limit from a poor one."""
    solver = sys.modules["jaxflex.friction_solve"]
    for target in (1e-9, 3e-4, 0.02, 0.5, 5.0):
        residual = _friction_residual(target)
        for guess in (0.0, target):
            _, count, _ = solver.bracketed_newton(residual, 0.0, target, guess)
            assert int(count) < solver.MAX_FRICTION_ITERATIONS // 2, (target, guess, count)
        _, count, _ = solver.bracketed_newton(residual, 0.0, target, 0.999 * target)
        assert int(count) <= 12, (target, count)


@pytest.mark.parametrize("target, guess", [(0.02, 0.0), (0.02, 0.01), (0.004, 0.0)])
def test_safeguarded_loop_solves_what_the_plain_newton_steps_leave(target, guess):
    """A start on the far side of the smooth-Coulomb knee: the plain Newton steps overshoot, the
    round-off test fails and the bracketed loop takes over, ending on brentq's root with the
    law's friction and slope there."""
    solver = sys.modules["jaxflex.friction_solve"]
    gain = 0.05
    root, count, (f_root, slope_root) = solver.bracketed_newton(
        _friction_residual(target, gain), 0.0, target, jnp.float64(guess)
    )
    assert solver.NEWTON_STEPS + 1 < int(count) < solver.MAX_FRICTION_ITERATIONS // 2
    expected = brentq(
        lambda v: v + gain * float(_base_friction(v)) - target,
        0.0, target, xtol=1e-300, rtol=4 * np.finfo(float).eps,
    )
    assert float(root) == pytest.approx(expected, rel=1e-14, abs=0)
    f_law, slope_law = jax.jvp(_base_friction, (root,), (1.0,))
    assert float(f_root) == pytest.approx(float(f_law), rel=1e-14, abs=0)
    assert float(slope_root) == pytest.approx(float(slope_law), rel=1e-14, abs=0)


def test_static_response_of_truncated_modes():
    """One advanced mode: the others' quasi-static share keeps the deflection and the strain of
    the full model (to 0.5 %); stations at the tip and clamp read those outputs."""
    _, torque = reference_input("triangular")
    full = simulate(Model(), REFERENCE, torque)
    length = Model().testbed.length
    truncated = simulate(Model(n_modes=1, stations=(0.0, length)), REFERENCE, torque)
    for name in ("tip_deflection", "root_strain", "joint_angle"):
        full_value, value = np.asarray(getattr(full, name)), np.asarray(getattr(truncated, name))
        assert nrmse(full_value, value) <= 0.5, name
    half_thickness = 0.5 * Model().testbed.thickness
    for station, output in (
        (truncated.station_deflection[:, 1], truncated.tip_deflection),
        (truncated.station_acceleration[:, 1], truncated.tip_acceleration),
        (half_thickness * truncated.station_curvature[:, 0], truncated.root_strain),
    ):  # equal up to round-off (the rows are summed in other orders)
        scale = float(np.max(np.abs(output)))
        np.testing.assert_allclose(station, output, rtol=0, atol=1e-12 * scale)
    with pytest.raises(ValueError, match="n_modes must be None or an int from 1 to 20"):
        Model(n_modes=21)


def test_warm_start_lands_on_the_root_while_sliding():
    """From the previous step's velocity, friction and slope, one Newton step (no evaluation)
    starts the solve within round-off of the root while sliding, so the plain Newton steps end
    converged; near zero velocity it still converges to brentq's root."""
    solver = sys.modules["jaxflex.friction_solve"]
    gain = 0.05
    for previous, change in ((0.5, 1e-4), (-2.0, -3e-3), (0.3, -1e-3), (2e-3, -3e-3)):
        target = previous + gain * float(_base_friction(previous)) + change
        f, slope = jax.jvp(_base_friction, (jnp.float64(previous),), (1.0,))
        guess = solver.warm_start(jnp.float64(previous), f, slope, target, gain)
        residual = _friction_residual(target, gain)
        lo, hi = min(0.0, target), max(0.0, target)
        root, count, (f_root, slope_root) = solver.bracketed_newton(residual, lo, hi, guess)
        expected = brentq(
            lambda v, target=target: v + gain * float(_base_friction(v)) - target,
            lo, hi, xtol=1e-300, rtol=4 * np.finfo(float).eps,
        )
        assert float(root) == pytest.approx(expected, rel=1e-14, abs=0)
        # the friction and slope the solve hands on are the law's at the root it returns
        f_law, slope_law = jax.jvp(_base_friction, (root,), (1.0,))
        assert float(f_root) == pytest.approx(float(f_law), rel=1e-14, abs=0)
        assert float(slope_root) == pytest.approx(float(slope_law), rel=1e-14, abs=0)
        if abs(previous) >= 30 * 0.01:  # far from the smooth-Coulomb knee (ω_s = 0.01)
            r, _, scale, _ = residual(guess)
            eps = np.finfo(float).eps
            assert abs(float(r)) <= solver.RESIDUAL_ULPS * eps * float(scale), (previous, r)
            # so the plain Newton steps end converged and the safeguarded loop never runs
            assert int(count) == solver.NEWTON_STEPS + 1, (previous, change, count)


def test_length_buckets_share_a_program_and_leave_the_samples_unchanged():
    """Records of similar length run through one padded program; their samples are those of an
    unpadded run, bit for bit (the time loop is causal)."""
    from jaxflex.simulation import _simulate_jit, bucket_length

    lengths = range(2, 5000)
    buckets = [bucket_length(n) for n in lengths]
    assert all(b >= n for b, n in zip(buckets, lengths, strict=True))
    assert np.all(np.diff(buckets) >= 0)
    assert max(b / n for b, n in zip(buckets, lengths, strict=True) if n > 64) < 1.25
    assert len(set(buckets)) < 30  # a few programs, not one per length

    model = Model()
    params = model.space.reference()
    torque = jnp.asarray(reference_input("pulse", duration=1.0)[1][:900])
    assert bucket_length(900) == bucket_length(1000)
    unpadded = _simulate_jit(model, {k: jnp.asarray(v) for k, v in params.items()}, torque,
                             model.testbed.dt)
    padded = simulate(model, params, torque)
    for name in ("joint_angle", "tip_acceleration", "root_strain"):
        assert np.array_equal(getattr(padded, name), getattr(unpadded, name))
