"""The simulator: exact modal stepping of the linear dynamics, implicit joint friction.

Each step of length ``h`` (``dt / n_substeps``) holds the applied torque constant (zero-order
hold) and does three things:

1. advances every flexible mode with the *exact* solution of
   ``η'' + c η' + ω² η = g`` for constant ``g`` (closed form, robust from undamped to heavily
   overdamped modes) and the rigid rotation with the exact double integrator — so stiff FEM modes
   cost nothing in accuracy or stability;
2. solves the joint torque ``u = τ − f(θ'_{k+1})`` implicitly (a θ-method in the friction
   only) by a scalar Newton iteration converged to round-off in every step (stick phases
   included, with a convergence test, not a fixed count): the end-of-step joint velocity is
   affine in ``u``, so the stiff smooth-Coulomb law near zero velocity stays stable at any step,
   and the result does not depend on how a compiler rounds the iterations. It starts from a
   Newton step off the previous step's velocity with the friction and slope carried there,
   takes two plain Newton steps as straight-line code, and only where the round-off test then
   fails (breakaway, stops: a small share of the steps) solves again with a safeguarded loop;
   it hands on the friction it evaluated at the root (no further evaluation of the law;
   :mod:`jaxflex.friction_solve`);
3. applies the weak rank-one mass-damping coupling (folded into the step's coefficients) and
   position-dependent loads (gravity) explicitly from the start of the step.

With ``Model(n_modes=m)`` only the ``m`` lowest flexible modes are advanced; the others add
their quasi-static response (residual flexibility: ``η_j = g_j/ω_j²``) to the joint angle,
deflections and curvatures, and nothing to the accelerations (the mode-acceleration method).
Measured against SciPy Radau this keeps joint angle, velocity and strain, but the truncated modes
ring after every torque step wherever they are lightly damped, and the samples see that ringing
in the accelerations: so every mode is advanced by default.

Outputs are taken at the sample instants with the new torque sample (the right-hand limit).
Gradients of the friction solve use the implicit-function theorem (:func:`jax.lax.custom_root`),
so reverse mode does not store the iterations.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Scalar

from jaxflex.friction_solve import friction_at_root, joint_velocity_solve, warm_start
from jaxflex.modal import Modes, free_hub_modes
from jaxflex.model import Model
from jaxflex.parallel import population_vmap
from jaxflex.parameters import Params
from jaxflex.sensors import calibrated

SCAN_UNROLL = 1
#: Weight of the end-of-step friction (θ-method): 0.5 is trapezoidal, 1 backward Euler.
FRICTION_THETA = 0.55


class Outputs(eqx.Module):
    """Simulated signals at the sample instants (leading axes: population, if batched)."""

    joint_angle: Float[Array, "*batch n"]  # rad
    tip_acceleration: Float[Array, "*batch n"]  # m/s², L·θ'' + w''(L)
    joint_velocity: Float[Array, "*batch n"]  # rad/s
    tip_deflection: Float[Array, "*batch n"]  # m, w(L) in the hub frame
    root_strain: Float[Array, "*batch n"]  # bending strain at the clamp surface
    joint_torque: Float[Array, "*batch n"]  # torque at the joint after friction, N m
    # at the model's stations x_k (sensor positions, from the clamp); None without stations
    station_deflection: Float[Array, "*batch n k"] | None = None  # w(x_k), m
    station_curvature: Float[Array, "*batch n k"] | None = None  # w''(x_k), 1/m
    station_acceleration: Float[Array, "*batch n k"] | None = None  # (r + x_k)θ'' + ẅ(x_k)
    # the model's sensors' readings relative to rest, by channel; None for a model without
    readings: dict[str, Float[Array, "*batch n"]] | None = None

    def channel(self, name: str) -> Array:
        """One output or sensor reading by name (a reading first: a sensor may log a channel
        named as an output); a ValueError lists the valid names."""
        if self.readings is not None and name in self.readings:
            return self.readings[name]
        if name not in OUTPUT_NAMES:
            own = [] if self.readings is None else list(self.readings)
            raise ValueError(f"unknown output {name!r}; outputs are {list(OUTPUT_NAMES)}"
                             + (f", sensor channels {own}" if own else ""))
        return getattr(self, name)


OUTPUT_NAMES = (
    "joint_angle",
    "tip_acceleration",
    "joint_velocity",
    "tip_deflection",
    "root_strain",
    "joint_torque",
)


class _StepMaps(eqx.Module):
    """Exact one-step maps of the modal oscillators for constant forcing."""

    p11: Array
    p12: Array
    p21: Array
    p22: Array
    gx: Array  # position response to a unit force held for one step
    gv: Array  # velocity response to a unit force held for one step


def oscillator_step(omega: Array, damping: Array, h: float) -> _StepMaps:
    """Exact map over ``h`` of ``x'' + c x' + ω² x = g`` (``g`` constant), elementwise.

    With ``σ = c/2`` and ``d² = σ² − ω²``: ``e^{Ah} = e^{−σh}[cosh(dh) I + sinh(dh)/d (A + σI)]``.
    Three numerically safe forms: a power series in ``s = d²h²`` near critical damping, the
    trigonometric form when underdamped, and the two real exponentials (slow pole written as
    ``−ω²/(σ + d)``) when overdamped, which never overflows.
    """
    sigma = 0.5 * damping
    d2 = sigma**2 - omega**2
    s = d2 * h**2
    decay = jnp.exp(-sigma * h)

    # near critical: cosh(√s) and sinh(√s)/√s as series in s
    s_c = jnp.clip(s, -1.0, 1.0)
    cosh_s, sinhc_s, term_c, term_s = 1.0, 1.0, 1.0, 1.0
    for k in range(1, 12):
        term_c = term_c * s_c / ((2 * k - 1) * (2 * k))
        term_s = term_s * s_c / ((2 * k) * (2 * k + 1))
        cosh_s, sinhc_s = cosh_s + term_c, sinhc_s + term_s
    ec_series, es_series = decay * cosh_s, decay * h * sinhc_s

    # underdamped
    nu = jnp.sqrt(jnp.maximum(-d2, 1e-300))
    ec_under, es_under = decay * jnp.cos(nu * h), decay * jnp.sin(nu * h) / nu

    # overdamped: e^{−σh}cosh(dh) = (E1 + E2)/2, e^{−σh}sinh(dh)/d = (E1 − E2)/(2d)
    d = jnp.sqrt(jnp.maximum(d2, 1e-300))
    slow, fast = -(omega**2) / (sigma + d), -(sigma + d)
    e1, e2 = jnp.exp(slow * h), jnp.exp(fast * h)
    es_over = (e1 - e2) / (2.0 * d)
    p11_over = (-fast * e1 + slow * e2) / (2.0 * d)
    p22_over = (slow * e1 - fast * e2) / (2.0 * d)

    near = jnp.abs(s) <= 1.0
    under = s < 0.0
    ec = jnp.where(near, ec_series, ec_under)
    es = jnp.where(near, es_series, jnp.where(under, es_under, es_over))
    p11 = jnp.where(near | under, ec + sigma * es, p11_over)
    p22 = jnp.where(near | under, ec - sigma * es, p22_over)
    return _StepMaps(
        p11=p11,
        p12=es,
        p21=-(omega**2) * es,
        p22=p22,
        gx=(1.0 - p11) / omega**2,
        gv=es,
    )


class _StaticResponse(eqx.Module):
    """Quasi-static response of the truncated modes (residual flexibility), per output row.

    Each array maps the forcing ``g = [u − αJ·pᵀη', a_1, …, a_k]`` (joint torque less the
    mass-damping coupling, then the load amplitudes) to an output: a truncated mode ``j`` sits at
    ``η_j = (p_j g_0 + Σ_i f_ij g_i)/ω_j²``, its inertia and damping neglected.
    """

    angle: Array  # (1 + k,) joint angle
    tip: Array  # (1 + k,) w(L)
    root_curvature: Array  # (1 + k,) w''(0)
    stations: tuple[Array, ...]  # (k_s, 1 + k) each: w(x_k), w''(x_k)
    shapes: Array  # (n, 1 + k) generalised coordinates


class _ModalSystem(eqx.Module):
    """Everything the time loop needs for one parameter set, precomputed once.

    Modal arrays hold the advanced modes only (``Model.n_modes``); ``static`` holds the
    quasi-static response of the truncated ones, or is None when every mode is advanced.
    """

    maps: _StepMaps
    damping: Array  # diagonal modal damping c
    omega2: Array
    hub: Array  # p
    inertia: Scalar
    coupling: Scalar  # α·J, the rank-one mass-damping coefficient
    load_hub: Array  # (k,) hub torque of each load shape
    load_modal: Array  # (k, m) modal force of each load shape
    tip: Array  # (m,) w(L) per mode
    root_curvature: Array  # (m,) w''(0) per mode
    stations: tuple[Array, ...]  # w(x_k) per mode, w''(x_k) per mode: (k, m) each
    station_radius: Array  # (k,) each station's distance from the axis (an input of a kernel)
    shapes: Array  # (n, m) mode shapes, to map back to physical coordinates
    initial: tuple[Array, Array]  # (θ_r, η) at rest under the loads
    static: _StaticResponse | None  # the truncated modes' share of each output; None: none


def _modal_system(model: Model, params: Params, h: float) -> _ModalSystem:
    structure = model.structure(params)
    modes = free_hub_modes(structure)
    damping = modes.modal_damping(params["alpha"], params["beta"])
    loads = model.loads(structure, params)
    load_modal = modes.project(loads)
    tip = modes.project(structure.tip)
    root_curvature = modes.project(structure.root_curvature)
    stations = tuple(modes.project(jnp.asarray(rows)) for rows in model.station_rows())
    initial = _rest_under_loads(model, params, structure, modes, loads)
    kept = model.advanced_modes
    static = None
    if kept < modes.omega.shape[0]:
        # columns: truncated modal displacement per unit forcing g (joint torque, then loads)
        forcing = jnp.concatenate([modes.hub[None, kept:], load_modal[:, kept:]], axis=0)
        per_unit = (forcing / modes.omega[kept:] ** 2).T  # (m_truncated, 1 + k)

        def rows(projected):  # row by row, as the outputs: equal rows give equal responses
            responses = [row[kept:] @ per_unit for row in projected]
            return jnp.asarray(responses).reshape(len(responses), per_unit.shape[1])

        static = _StaticResponse(
            angle=modes.hub[kept:] @ per_unit,
            tip=tip[kept:] @ per_unit,
            root_curvature=root_curvature[kept:] @ per_unit,
            stations=tuple(rows(projected) for projected in stations),
            shapes=modes.shapes[:, kept:] @ per_unit,
        )
        initial = (initial[0], initial[1][:kept])
    return _ModalSystem(
        maps=oscillator_step(modes.omega[:kept], damping[:kept], h),
        damping=damping[:kept],
        omega2=modes.omega[:kept] ** 2,
        hub=modes.hub[:kept],
        inertia=modes.inertia,
        coupling=params["alpha"] * modes.inertia,
        load_hub=loads[:, 0],
        load_modal=load_modal[:, :kept],
        tip=tip[:kept],
        root_curvature=root_curvature[:kept],
        stations=tuple(projected[:, :kept] for projected in stations),
        station_radius=jnp.asarray([model.testbed.clamp_offset + x for x in model.stations]),
        shapes=modes.shapes[:, :kept],
        initial=initial,
        static=static,
    )


def _rest_under_loads(model: Model, params: Params, structure, modes: Modes, loads):
    """Modal coordinates of rest at θ = 0 with the beam deflected statically by the loads.

    With the hub held, ``K_qq q = f_q``; since ``Φ_qᵀ K_qq Φ_q = diag ω²`` with ``Φ_q`` square,
    ``K_qq⁻¹ = Φ_q diag(ω⁻²) Φ_qᵀ`` and no further factorisation is needed.
    """
    amplitude = model.load_amplitudes(params, jnp.zeros(()), jnp.zeros(()))
    force = amplitude @ loads
    elastic_shapes = modes.shapes[1:]
    q_elastic = elastic_shapes @ ((elastic_shapes.T @ force[1:]) / modes.omega**2)
    q0 = jnp.concatenate([jnp.zeros(1), q_elastic])
    eta = modes.project(structure.mass @ q0)
    return -modes.hub @ eta, eta


class InitialState(eqx.Module):
    """A start away from rest: deviations of the hub angle and velocity and of the lowest
    modes' coordinates from rest under the loads (modes not given start at rest).

    ``modal`` and ``modal_velocity`` hold the ``k`` lowest flexible modes' coordinates
    (mass-normalised, as :func:`jaxflex.modal.free_hub_modes` gives them), ``k`` at most the
    advanced modes. The hub angle is the joint angle ``θ = θ_r + pᵀη``, so a deflection given
    here leaves it where ``angle`` puts it.
    """

    angle: Scalar
    velocity: Scalar
    modal: Float[Array, " k"]
    modal_velocity: Float[Array, " k"]

    def __init__(self, angle=0.0, velocity=0.0, modal=(), modal_velocity=None):
        self.angle = jnp.asarray(angle, dtype=float)
        self.velocity = jnp.asarray(velocity, dtype=float)
        self.modal = jnp.asarray(modal, dtype=float).reshape(-1)
        self.modal_velocity = (
            jnp.zeros_like(self.modal)
            if modal_velocity is None
            else jnp.asarray(modal_velocity, dtype=float).reshape(-1)
        )
        if self.modal.shape != self.modal_velocity.shape:
            raise ValueError(
                f"InitialState: modal has {self.modal.shape[0]} coordinates but "
                f"modal_velocity {self.modal_velocity.shape[0]}"
            )

    @property
    def n_modes(self) -> int:
        """How many of the lowest flexible modes it sets."""
        return int(self.modal.shape[0])


State = tuple[Array, Array, Array, Array, Array, Array, Array]
"""The time loop's state at a sample instant: rigid angle and velocity ``θ_r, θ'_r``, modal
coordinates and velocities ``η, η'`` (advanced modes), the joint velocity ``θ'`` and the
friction and its slope there."""


class Dynamics(NamedTuple):
    """One parameter set's sampled dynamics, as functions of the time loop's :data:`State`.

    ``advance(state, taus)`` takes one sample interval under the ``n_substeps`` fine torques
    ``taus`` (from :attr:`fine_torque`), ``observe(state, tau)`` gives the outputs at a sample
    instant (a tuple in :class:`Outputs` order), ``start(initial)`` the state at the first
    sample, and ``to_vector`` / ``from_vector`` map a state to the flat vector
    ``[θ_r, θ'_r, η, η']`` and back (the joint velocity and friction recomputed from it).
    """

    system: _ModalSystem
    start: Callable[[InitialState | None], State]
    advance: Callable[[State, Array], State]
    observe: Callable[[State, Array], tuple[Array, ...]]
    physical: Callable[[State, Array], tuple[Array, Array]]
    fine_torque: Callable[[Array], Array]
    to_vector: Callable[[State], Array]
    from_vector: Callable[[Array], State]


def simulate_core(
    model: Model,
    params: Params,
    torque: Float[Array, " n"],
    dt: float,
    *,
    initial: InitialState | None = None,
    return_states: bool = False,
) -> Outputs | tuple[Outputs, tuple[Array, Array]]:
    """Simulate one parameter set; pure and traceable (no input checks). See :func:`simulate`.

    ``initial`` starts it away from rest (default: at rest under the loads). With
    ``return_states`` also returns the generalised coordinates and velocities
    ``(q, q')``, each ``(n_samples, 1 + 2·n_elements)``, at the sample instants.
    """
    dynamics = model_dynamics(model, params, dt)

    def sample(state, taus):
        out = dynamics.observe(state, taus[0])
        if return_states:
            out = (out, dynamics.physical(state, taus[0]))
        return dynamics.advance(state, taus), out

    state0 = dynamics.start(initial)
    fine = dynamics.fine_torque(torque)
    _, out = jax.lax.scan(sample, state0, fine, unroll=SCAN_UNROLL)
    if return_states:
        out, states = out
        return with_readings(model, Outputs(*out)), states
    return with_readings(model, Outputs(*out))


def sum_matmul(a: Array, b: Array) -> Array:
    """``a @ b`` for vectors and matrices, written as products and sums (a Triton kernel lowers
    these in float64, not a matrix product)."""
    if b.ndim == 1:
        return jnp.sum(a * b, axis=-1)
    return jnp.sum(a[..., :, None] * b, axis=-2)


class StepCoefficients(eqx.Module):
    """One parameter set's time-loop coefficients, formed once outside the loop: the modal
    system and the step's per-candidate factors (what a fused kernel loads per lane)."""

    system: _ModalSystem
    gain: Scalar  # d θ'_{k+1} / d u over one step
    inv_j: Scalar
    h_inv_j: Scalar
    half_h2_inv_j: Scalar
    gx_p: Array
    gv_p: Array
    p2: Array
    a12: Array  # the free step's coefficients with the rank-one mass damping folded in
    a22: Array
    bx: Array
    bv: Array


def step_coefficients(model: Model, params: Params, dt: float) -> StepCoefficients:
    """The coefficients of :func:`model_dynamics`' time loop for ``params``."""
    h = dt / model.n_substeps
    system = _modal_system(model, params, h)
    maps, p = system.maps, system.hub
    # per-candidate factors formed once, outside the time loop: left inside, the compiler
    # re-associates ``h·u/J`` differently in a one-device and a multi-device program
    inv_j = 1.0 / system.inertia
    h_inv_j = h * inv_j
    gx_p, gv_p = maps.gx * p, maps.gv * p
    p2 = p**2
    # the free step with the mass-damping coupling ``αJ·(p²η' − p·pᵀη')`` folded into its
    # coefficients, formed once rather than applied as a force each step (fewer operations in
    # the time loop): η_free = p11·η + a12·η' + bx·pᵀη' (+ gx·loads), likewise η'
    coupled = system.coupling * p2
    return StepCoefficients(
        system=system,
        gain=h_inv_j + jnp.sum(p2 * maps.gv),
        inv_j=inv_j,
        h_inv_j=h_inv_j,
        half_h2_inv_j=0.5 * h * h_inv_j,
        gx_p=gx_p,
        gv_p=gv_p,
        p2=p2,
        a12=maps.p12 + coupled * maps.gx,
        a22=maps.p22 + coupled * maps.gv,
        bx=-system.coupling * gx_p,
        bv=-system.coupling * gv_p,
    )


def model_dynamics(
    model: Model,
    params: Params,
    dt: float,
    coefficients: StepCoefficients | None = None,
    *,
    fused: bool = False,
) -> Dynamics:
    """The sampled dynamics of ``model`` with ``params`` at sample interval ``dt``: what
    :func:`simulate_core` scans, and what a state estimator steps and linearises.

    ``coefficients`` (default: :func:`step_coefficients`) may come precomputed. ``fused``
    writes the step for the lanes of a GPU kernel (:mod:`jaxflex.fused`): its products as sums
    (Triton has no float64 matrix units), the friction solve's loop shared by the lanes."""
    n_sub = model.n_substeps
    h = dt / n_sub
    c = step_coefficients(model, params, dt) if coefficients is None else coefficients
    matmul = sum_matmul if fused else jnp.matmul
    system = c.system
    maps = system.maps
    p = system.hub
    length = model.testbed.clamp_offset + model.testbed.length  # tip radius from the axis
    thickness = model.testbed.thickness
    w = FRICTION_THETA
    inv_j, h_inv_j, half_h2_inv_j, gain = c.inv_j, c.h_inv_j, c.half_h2_inv_j, c.gain
    gx_p, gv_p, p2 = c.gx_p, c.gv_p, c.p2
    a12, a22, bx, bv = c.a12, c.a22, c.bx, c.bv
    has_loads = system.load_modal.shape[0] > 0

    def friction(v):
        return model.friction(params, v)

    def law_and_slope(params, v):
        return jax.jvp(lambda v: model.friction(params, v), (v,), (jnp.ones_like(v),))

    def load_forces(theta, vel):
        """Rigid acceleration and modal force of the position-dependent loads, and their
        amplitudes (None without loads: a kernel holds no empty arrays)."""
        if not has_loads:  # (0·J⁻¹ as the empty sum gave: the same rounding downstream)
            return 0.0 * inv_j, jnp.zeros_like(p), None
        amp = model.load_amplitudes(params, theta, vel)
        return matmul(amp, system.load_hub) * inv_j, matmul(amp, system.load_modal), amp

    def explicit_forces(theta, vel, vel_r, deta):
        """Rigid acceleration, modal force (loads and the off-diagonal mass damping) and the
        forcing ``[u − αJ·pᵀη', loads]`` of the truncated modes without its ``u``."""
        rigid, loads, amp = load_forces(theta, vel)
        flex_velocity = vel - vel_r  # pᵀη'
        modal = loads - system.coupling * (p * flex_velocity - p2 * deta)
        return rigid, modal, (-system.coupling * flex_velocity, amp)

    def substep(state, tau):
        theta_r, vel_r, eta, deta, vel, f_vel, df_vel = state
        flex_velocity = vel - vel_r  # pᵀη'
        eta_free = maps.p11 * eta + a12 * deta + bx * flex_velocity
        deta_free = maps.p21 * eta + a22 * deta + bv * flex_velocity
        theta_r_free, vel_r_free = theta_r + h * vel_r, vel_r
        if has_loads:
            rigid, loads, _ = load_forces(theta_r + matmul(p, eta), vel)
            eta_free, deta_free = eta_free + maps.gx * loads, deta_free + maps.gv * loads
            vel_r_free = vel_r + h * rigid
            theta_r_free = theta_r_free + 0.5 * h**2 * rigid
        target = vel_r_free + matmul(p, deta_free) + gain * (tau - (1.0 - w) * f_vel)
        v_end, evaluated = joint_velocity_solve(
            friction, target, w * gain, warm_start(vel, f_vel, df_vel, target, w * gain), fused
        )
        f_end, df_end = friction_at_root(law_and_slope, params, v_end, evaluated)
        u = tau - w * f_end - (1.0 - w) * f_vel
        return (
            theta_r_free + half_h2_inv_j * u,
            vel_r_free + h_inv_j * u,
            eta_free + gx_p * u,
            deta_free + gv_p * u,
            v_end,
            f_end,
            df_end,
        )

    def static_forcing(u, rest):
        """``[u − αJ·pᵀη', load amplitudes]``: what drives the truncated modes."""
        coupling, amp = rest
        return jnp.concatenate([(u + coupling)[None]] + ([] if amp is None else [amp]))

    def read(rows, static_rows, modal, forcing):
        """Output rows applied to the modal state, plus the truncated modes' static share."""
        if static_rows is None:
            return matmul(rows, modal)
        return matmul(rows, modal) + matmul(static_rows, forcing)

    def outputs(state, tau):
        theta_r, vel_r, eta, deta, vel, f_vel, _ = state
        u = tau - f_vel
        rigid, modal, rest = explicit_forces(theta_r + matmul(p, eta), vel, vel_r, deta)
        static = system.static
        forcing = None if static is None else static_forcing(u, rest)

        def share(name):
            return None if static is None else getattr(static, name)

        theta = theta_r + read(p, share("angle"), eta, forcing)
        ddeta = p * u + modal - system.damping * deta - system.omega2 * eta
        acc = rigid + u * inv_j + matmul(p, ddeta)
        signals = (
            theta,
            length * acc + matmul(system.tip, ddeta),
            vel,
            read(system.tip, share("tip"), eta, forcing),
            0.5 * thickness * read(system.root_curvature, share("root_curvature"), eta, forcing),
            u,
        )
        if not model.stations:
            return signals
        deflection, curvature = system.stations
        static_rows = (None, None) if static is None else static.stations

        def at(rows, static_rows, modal, forcing=None):
            """Row by row, so a station at the tip or clamp rounds as they do (a kernel's sums
            round every row as a vector anyway, and it has no slices)."""
            if fused:
                return read(rows, static_rows, modal, forcing)
            if static_rows is None:
                return jnp.stack([read(row, None, modal, forcing) for row in rows])
            return jnp.stack(
                [read(row, s, modal, forcing) for row, s in zip(rows, static_rows, strict=True)]
            )

        acceleration = system.station_radius * acc + at(deflection, None, ddeta)
        return signals + (
            at(deflection, static_rows[0], eta, forcing),
            at(curvature, static_rows[1], eta, forcing),
            acceleration,
        )

    def fine_torque(torque):
        fine = jnp.repeat(torque, n_sub)
        return model.input_torque(params, fine, h).reshape(torque.shape[0], n_sub)

    def physical(state, tau):
        theta_r, vel_r, eta, deta, vel, f_vel, _ = state
        e_theta = jnp.zeros(system.shapes.shape[0]).at[0].set(1.0)
        q = e_theta * theta_r + matmul(system.shapes, eta)
        if system.static is not None:
            _, _, rest = explicit_forces(theta_r + matmul(p, eta), vel, vel_r, deta)
            q = q + matmul(system.static.shapes, static_forcing(tau - f_vel, rest))
        return q, e_theta * vel_r + matmul(system.shapes, deta)

    def advance(state, taus):
        for j in range(n_sub):
            state = substep(state, taus[j])
        return state

    def from_vector(x):
        m = p.shape[0]
        theta_r, vel_r, eta, deta = x[0], x[1], x[2 : 2 + m], x[2 + m :]
        vel = vel_r + matmul(p, deta)
        return (theta_r, vel_r, eta, deta, vel, *law_and_slope(params, vel))

    def to_vector(state):
        theta_r, vel_r, eta, deta = state[:4]
        return jnp.concatenate([theta_r[None], vel_r[None], eta, deta])

    def start(initial):
        theta_r0, eta0 = system.initial
        vel0 = jnp.zeros_like(theta_r0)
        if initial is None:
            deta0 = jnp.zeros_like(eta0)
            return (theta_r0, vel0, eta0, deta0, vel0, *law_and_slope(params, vel0))
        k = initial.n_modes
        if k > eta0.shape[0]:
            raise ValueError(
                f"InitialState sets {k} modes but the model advances {eta0.shape[0]}"
            )
        eta = eta0.at[:k].add(initial.modal)
        deta = jnp.zeros_like(eta0).at[:k].set(initial.modal_velocity)
        theta_r = theta_r0 + initial.angle - matmul(p[:k], initial.modal)
        vel_r = initial.velocity - matmul(p[:k], initial.modal_velocity)
        return from_vector(jnp.concatenate([theta_r[None], vel_r[None], eta, deta]))

    return Dynamics(system, start, advance, outputs, physical, fine_torque, to_vector,
                    from_vector)


def read_channels(
    model: Model, params: Params, outputs: Outputs, channels: Sequence[str]
) -> Float[Array, " C *n"]:
    """The named channels (outputs or sensor channels) as the rig logs them, the model's
    effects on the readings applied, stacked in ``channels`` order; pure and traceable: what
    the objective, the Kalman filter and the experiment design all compare with data."""
    read = model.readings(params, {c: outputs.channel(c) for c in channels})
    return jnp.stack([read[c] for c in channels])


def with_readings(model: Model, outputs: Outputs) -> Outputs:
    """``outputs`` with each of the model's sensors' readings (none without sensors)."""
    if not model.sensors:
        return outputs
    readings = {s.channel: s.reading(model, outputs) for s in model.sensors}
    return eqx.tree_at(lambda o: o.readings, outputs, readings, is_leaf=lambda x: x is None)


BUCKETS_PER_OCTAVE = 4
"""Record lengths are padded up to one of this many lengths per doubling (:func:`bucket_length`),
so one compiled program serves every record and window of similar length."""
MIN_BUCKET = 64


def bucket_length(n: int) -> int:
    """The compiled length that serves ``n`` samples: the smallest ``⌈2^(j/4)·64⌉`` (rounded up
    to a multiple of 16) not below ``n``. Padding adds under 25 % to a run; the time loop is
    causal, so the first ``n`` samples are those of an unpadded run."""
    length, j = MIN_BUCKET, 0
    while length < n:
        j += 1
        length = 16 * math.ceil(MIN_BUCKET * 2.0 ** (j / BUCKETS_PER_OCTAVE) / 16)
    return length


def _padded(torque: Array) -> Array:
    """``torque`` held at its last sample up to its bucket length."""
    n = torque.shape[0]
    return jnp.pad(torque, (0, bucket_length(n) - n), mode="edge")


def _first(outputs: Outputs, n: int, axis: int) -> Outputs:
    """The first ``n`` samples of every output (time along ``axis``)."""
    return jax.tree_util.tree_map(lambda a: jax.lax.slice_in_dim(a, 0, n, axis=axis), outputs)


@eqx.filter_jit
def _simulate_jit(model: Model, params: Params, torque: Array, dt: float) -> Outputs:
    return simulate_core(model, params, torque, dt)


@eqx.filter_jit
def _simulate_batch_jit(model: Model, params: Params, torque: Array, dt: float) -> Outputs:
    from jaxflex import fused  # the kernel is built on this module

    if fused.preferred(model):
        return fused.simulate_fused(model, params, torque, dt)
    return population_vmap(lambda p, t: simulate_core(model, p, t, dt), params, torque)


def check_dt(dt) -> float:
    """``dt`` as a float, or a ValueError unless it is a positive finite number of seconds."""
    if not (isinstance(dt, (int, float)) and np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    return float(dt)


def check_torque(torque: ArrayLike) -> Float[np.ndarray, " n"]:
    """``torque`` as float64, or a ValueError naming the shape or the first non-finite sample."""
    torque = np.asarray(torque, dtype=np.float64)
    if torque.ndim != 1 or torque.shape[0] < 2:
        raise ValueError(
            f"torque must be a 1-D array of at least 2 samples, got shape {torque.shape}"
        )
    if not np.all(np.isfinite(torque)):
        bad = int(np.flatnonzero(~np.isfinite(torque))[0])
        raise ValueError(f"torque is not finite at sample {bad}")
    return torque


def _check_inputs(model: Model, params: Mapping[str, ArrayLike], torque, dt, batched: bool):
    dt = check_dt(model.testbed.dt if dt is None else dt)
    torque = check_torque(torque)
    model.space.validate(params)
    values = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}
    shapes = {k: v.shape for k, v in values.items()}
    if batched:
        sizes = {s[0] if len(s) == 1 else None for s in shapes.values()}
        if len(sizes) != 1 or None in sizes:
            raise ValueError(f"batched parameters must all be 1-D of one length, got {shapes}")
    elif any(s != () for s in shapes.values()):
        raise ValueError(
            f"parameters must be scalars (use simulate_batch for arrays), got {shapes}"
        )
    return values, jnp.asarray(torque), float(dt)


def simulate(
    model: Model,
    params: Mapping[str, ArrayLike],
    torque: Float[ArrayLike, " n"],
    dt: float | None = None,
) -> Outputs:
    """Simulate the arm for one parameter set under a sampled torque (zero-order hold).

    ``params`` names every parameter of ``model.space``; ``torque`` (N m) is sampled every ``dt``
    seconds (default: the testbed's). Returns :class:`Outputs` with one value per torque sample.
    """
    values, torque, dt = _check_inputs(model, params, torque, dt, batched=False)
    return _first(_simulate_jit(model, values, _padded(torque), dt), torque.shape[0], axis=0)


def simulate_batch(
    model: Model,
    params: Mapping[str, ArrayLike],
    torque: Float[ArrayLike, " n"],
    dt: float | None = None,
) -> Outputs:
    """Simulate a population at once: each parameter is a 1-D array of ``P`` candidates.

    The whole population is one vmapped, JIT-compiled call, split across the host's cores
    (:mod:`jaxflex.parallel`), or on a GPU one kernel for the whole time loop where the model
    allows it (:mod:`jaxflex.fused`); outputs have shape ``(P, n)``.
    """
    values, torque, dt = _check_inputs(model, params, torque, dt, batched=True)
    outputs = _simulate_batch_jit(model, values, _padded(torque), dt)
    return _first(outputs, torque.shape[0], axis=1)


def simulate_readings(
    model: Model,
    params: Mapping[str, ArrayLike],
    torque: Float[ArrayLike, " n"],
    dt: float | None = None,
) -> Outputs:
    """:func:`simulate`, then the model's effects on the readings (a sensor's gain or offset,
    :func:`jaxflex.sensors.calibrated`): what the rig's sensors would log, relative to rest.
    The one way every comparison with measurements predicts them."""
    return calibrated(model, dict(params), simulate(model, params, torque, dt))
