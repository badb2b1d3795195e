"""An independent reference for the simulator: SciPy Radau on the full FEM equations of motion.

Nothing here uses the modal basis or the stepping scheme of ``jaxflex.simulation``: it integrates
``M q'' + D q' + K q = e_θ(τ − τ_f(θ')) − g sin(φ) cos(θ) F`` (a tilted plane, when the model has
gravity; ``τ_f`` with Stribeck friction, when it has that) in physical coordinates, restarting
wherever the torque sample changes so the zero-order hold is exact, with tight tolerances and
the analytic Jacobian.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from jaxflex.design import fourier_basis
from jaxflex.effects.gravity import GRAVITY
from jaxflex.model import Model


def radau_reference(model: Model, params, torque, dt, rtol=1e-9, atol=1e-11):
    """Joint angle, tip acceleration and joint velocity at the samples (right-hand limits)."""
    q, velocity, acc = radau_states(model, params, torque, dt, rtol=rtol, atol=atol)
    tip = np.asarray(model.structure(params).tip)
    return np.array([q[:, 0], model.testbed.length * acc[:, 0] + acc @ tip, velocity[:, 0]])


def radau_states(model: Model, params, torque, dt, rtol=1e-9, atol=1e-11, hub_torque=None):
    """The physical state at the samples (right-hand limits): ``q``, ``q'`` and ``q''``, each
    ``(samples, 1 + 2n)`` over ``q = [θ, w_1, w'_1, …, w_n, w'_n]`` (node 0 clamped).

    ``hub_torque(θ, θ')``, where given, is a further torque on the hub, returned with its
    slopes in ``θ`` and ``θ'`` (for the Jacobian)."""
    structure = model.structure(params)
    mass = np.asarray(structure.mass)
    stiffness = np.asarray(structure.stiffness)
    n = mass.shape[0]
    projector = np.eye(n)
    projector[0, 0] = 0.0
    damping = float(params["alpha"]) * projector @ mass @ projector + float(
        params["beta"]
    ) * stiffness
    inv_mass = np.linalg.inv(mass)
    mk, md, me = inv_mass @ stiffness, inv_mass @ damping, inv_mass[:, 0]
    b_v, tau_c = float(params["b_v"]), float(params["tau_c"])
    omega_s = model.testbed.omega_s
    # Stribeck friction: delta_tau_s exp(-(|v|/v_s)^delta) tanh(v/omega_s) (jaxflex.effects)
    stribeck = next((e for e in model.effects if e.name == "stribeck"), None)
    excess = float(params["delta_tau_s"]) if stribeck is not None else 0.0
    v_s = float(params.get("v_s", stribeck.v_s)) if stribeck is not None else 1.0
    delta = stribeck.delta if stribeck is not None else 2.0
    # a tilted plane: the load -g sin(phi) cos(theta) on the first moment (jaxflex.effects.Gravity)
    tilt = GRAVITY * math.sin(float(params["phi"])) if "gravity" in model.effect_names else 0.0
    moment = inv_mass @ np.asarray(structure.first_moment)

    def friction(v):
        fade = excess * np.exp(-((np.abs(v) / v_s) ** delta))
        return b_v * v + (tau_c + fade) * np.tanh(v / omega_s)

    def friction_slope(v):
        fade = excess * np.exp(-((np.abs(v) / v_s) ** delta))
        fade_slope = -fade * delta * (np.abs(v) / v_s) ** (delta - 1.0) * np.sign(v) / v_s
        return (b_v + (tau_c + fade) / omega_s * (1.0 - np.tanh(v / omega_s) ** 2)
                + fade_slope * np.tanh(v / omega_s))

    def added(x):
        return (0.0, 0.0, 0.0) if hub_torque is None else hub_torque(x[0], x[n])

    def acceleration(x, tau):
        q, v = x[:n], x[n:]
        return (me * (tau + added(x)[0] - friction(v[0])) - md @ v - mk @ q
                - tilt * math.cos(q[0]) * moment)

    def jacobian(x):
        _, by_angle, by_velocity = added(x)
        slope = friction_slope(x[n]) - by_velocity
        lower_right = -md.copy()
        lower_right[:, 0] -= me * slope
        lower_left = -mk.copy()
        lower_left[:, 0] += tilt * math.sin(x[0]) * moment + me * by_angle
        return np.block([[np.zeros((n, n)), np.eye(n)], [lower_left, lower_right]])

    # Integrate each run of equal torque samples in one go (restarting where the torque steps).
    torque = np.asarray(torque, dtype=np.float64)
    steps = np.flatnonzero(np.diff(torque) != 0.0) + 1
    starts = np.concatenate([[0], steps])
    ends = np.concatenate([steps, [len(torque) - 1]])
    x = np.zeros(2 * n)  # at rest, the hub held at 0 and the beam deflected by any tilt
    load = -tilt * np.asarray(structure.first_moment)
    x[1:n] = np.linalg.solve(stiffness[1:, 1:], load[1:])
    states = np.zeros((len(torque), 2 * n))
    for start, end in zip(starts, ends, strict=True):
        tau = torque[start]
        states[start] = x
        if end == start:
            continue
        times = np.arange(start, end + 1) * dt
        sol = solve_ivp(
            lambda _, y, tau=tau: np.concatenate([y[n:], acceleration(y, tau)]),
            (times[0], times[-1]),
            x,
            method="Radau",
            t_eval=times,
            rtol=rtol,
            atol=atol,
            jac=lambda _, y: jacobian(y),
        )
        states[start : end + 1] = sol.y.T
        x = sol.y[:, -1]
    acc = np.array([acceleration(s, tau) for s, tau in zip(states, torque, strict=True)])
    return states[:, :n], states[:, n:], acc


def designed_torque() -> np.ndarray:
    """The designed input the accuracy tests check: jaxflex.design's Fourier basis up to 20 Hz
    (1 s at 1 kHz, 0.1 s ramps), seeded coefficients, 0.3 N m peak; the torque changes at every
    sample, unlike the paper's three inputs."""
    basis = fourier_basis(1.0, 1e-3, harmonics=20, ramp=0.1)
    shape = np.random.default_rng(0).standard_normal(basis.shape[0]) @ basis
    return 0.3 * shape / np.max(np.abs(shape))


def logged_mid_run(model: Model, params, torque, dt, start: int):
    """A record logged from sample ``start`` of a run from rest (a moving, deflected arm):
    joint angle and tip acceleration from there on, and the state at ``start`` in the
    coordinates of :mod:`jaxflex.initial` (angle, velocity, then every flexible mode's
    coordinates and velocities, mass-normalised: ``η = Φᵀ M q``)."""
    from jaxflex.modal import free_hub_modes

    q, velocity, acc = radau_states(model, params, torque, dt)
    structure = model.structure(params)
    tip = np.asarray(structure.tip)
    mass, shapes = np.asarray(structure.mass), np.asarray(free_hub_modes(structure).shapes)
    outputs = np.array([q[start:, 0], model.testbed.length * acc[start:, 0] + acc[start:] @ tip])
    state = (q[start, 0], velocity[start, 0], shapes.T @ mass @ q[start],
             shapes.T @ mass @ velocity[start])
    return outputs, state
