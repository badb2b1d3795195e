"""The NumPy alternative a user would write: one candidate, one record at a time.

Same model as :mod:`jaxflex.simulation` (hub + Hermite FEM beam from
:class:`jaxflex.fem.BeamPatterns`, Rayleigh damping on the elastic coordinates, smooth Coulomb +
viscous joint friction) and the same scheme, so the same accuracy at the same step:

* free-hub modal decomposition (Cholesky + ``eigh``), the rigid rotation decoupled;
* each flexible mode advanced over a sub-step ``h = dt/2`` by its exact zero-order-hold map,
  taken from ``scipy.linalg.expm`` of the augmented 3×3 matrix ``[[0, 1, 0], [−ω², −c, 1],
  [0, 0, 0]]·h`` (an independent route to the closed forms jaxflex uses);
* the rank-one mass-damping coupling applied explicitly from the start of the step;
* the joint torque ``u = τ − f`` with the friction taken implicitly (θ-method, weight 0.55 on
  the end-of-step velocity), solved by a bracketed Newton iteration to round-off.

The time loop is plain Python over samples and sub-steps with NumPy vectors over the modes:
what one writes without a JIT compiler, and the cost the benchmark compares against.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy.linalg import expm

from jaxflex.fem import BeamPatterns
from jaxflex.testbed import Testbed

FRICTION_THETA = 0.55
N_SUBSTEPS = 2


TESTBED = Testbed()


def modal_system(params: Mapping[str, float], testbed: Testbed = TESTBED):
    """Modes, hub participation, inertia and the tip row of the reference arm."""
    pat = BeamPatterns(testbed.length, testbed.n_elements)
    mass = testbed.mass_per_length * pat.mass
    mass[0, 0] += params["J_h"]
    stiffness = params["E"] * testbed.second_moment * pat.stiffness
    inertia = mass[0, 0]
    coupling = mass[1:, 0]
    condensed = mass[1:, 1:] - np.outer(coupling, coupling) / inertia
    chol = np.linalg.cholesky(condensed)
    left = np.linalg.solve(chol, stiffness[1:, 1:])
    sym = np.linalg.solve(chol, left.T).T
    eigval, eigvec = np.linalg.eigh(0.5 * (sym + sym.T))
    elastic = np.linalg.solve(chol.T, eigvec)
    hub = -(coupling @ elastic) / inertia
    omega = np.sqrt(np.maximum(eigval, 0.0))
    tip = elastic[-2]  # w(L) of each mode (the second-to-last DOF)
    return omega, hub, inertia, tip


def step_maps(omega: np.ndarray, damping: np.ndarray, h: float) -> np.ndarray:
    """``(6, m)``: p11, p12, p21, p22, gx, gv of every mode over one step, by ``expm``."""
    maps = np.empty((6, omega.size))
    for j, (w, c) in enumerate(zip(omega, damping, strict=True)):
        a = np.array([[0.0, 1.0, 0.0], [-(w**2), -c, 1.0], [0.0, 0.0, 0.0]]) * h
        e = expm(a)
        maps[:, j] = e[0, 0], e[0, 1], e[1, 0], e[1, 1], e[0, 2], e[1, 2]
    return maps


def simulate(
    params: Mapping[str, float],
    torque: np.ndarray,
    dt: float,
    testbed: Testbed = TESTBED,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint angle and tip acceleration at the samples of ``torque`` (zero-order hold)."""
    omega, p, inertia, tip = modal_system(params, testbed)
    alpha, beta = params["alpha"], params["beta"]
    b_v, tau_c, omega_s = params["b_v"], params["tau_c"], testbed.omega_s
    damping = alpha * (1.0 + inertia * p**2) + beta * omega**2
    h = dt / N_SUBSTEPS
    p11, p12, p21, p22, gx, gv = step_maps(omega, damping, h)
    omega2, p2, coupling, length = omega**2, p**2, alpha * inertia, testbed.length
    gain = h / inertia + float(np.sum(p2 * gv))
    w = FRICTION_THETA

    def friction(v: float) -> float:
        return b_v * v + tau_c * math.tanh(v / omega_s)

    def solve_velocity(target: float, g: float, guess: float) -> float:
        """``v + g f(v) = target``; the root lies between 0 and target (bracketed Newton)."""
        lo, hi = min(0.0, target), max(0.0, target)
        v = min(max(guess, lo), hi)
        for _ in range(60):
            th = math.tanh(v / omega_s)
            r = v + g * (b_v * v + tau_c * th) - target
            if r == 0.0:
                break
            if r < 0.0:
                lo = v
            else:
                hi = v
            slope = 1.0 + g * (b_v + tau_c * (1.0 - th * th) / omega_s)
            new = v - r / slope
            if not lo < new < hi:
                new = 0.5 * (lo + hi)
            if abs(new - v) <= 1e-15 * max(abs(v), 1e-300) or hi - lo <= 1e-16 * abs(hi):
                v = new
                break
            v = new
        return v

    n = torque.shape[0]
    angle = np.empty(n)
    accel = np.empty(n)
    theta_r = vel_r = 0.0
    eta = np.zeros(omega.size)
    deta = np.zeros(omega.size)
    for k in range(n):
        tau = float(torque[k])
        # outputs at the sample, with the new torque (right-hand limit)
        pd = float(p @ deta)
        vel = vel_r + pd
        u = tau - friction(vel)
        ddeta = p * u - coupling * (p * pd - p2 * deta) - damping * deta - omega2 * eta
        angle[k] = theta_r + float(p @ eta)
        accel[k] = length * (u / inertia + float(p @ ddeta)) + float(tip @ ddeta)
        for _ in range(N_SUBSTEPS):
            pd = float(p @ deta)
            vel = vel_r + pd
            modal = -coupling * (p * pd - p2 * deta)
            eta_free = p11 * eta + p12 * deta + gx * modal
            deta_free = p21 * eta + p22 * deta + gv * modal
            f_start = friction(vel)
            target = vel_r + float(p @ deta_free) + gain * (tau - (1.0 - w) * f_start)
            v_end = solve_velocity(target, w * gain, vel)
            u = tau - w * friction(v_end) - (1.0 - w) * f_start
            theta_r += h * vel_r + 0.5 * h**2 * u / inertia
            vel_r += h * u / inertia
            eta = eta_free + gx * p * u
            deta = deta_free + gv * p * u
    return angle, accel


def cost(params: Mapping[str, float], records, weights=(1.0, 1.0)) -> float:
    """The objective of :mod:`jaxflex.objective` (weighted mean squared NRMSE), in NumPy."""
    total, n_records = sum(weights), len(records)
    value = 0.0
    for record in records:
        angle, accel = simulate(params, record.torque, record.dt)
        for w, y, y_hat in zip(
            weights, (record.joint_angle, record.tip_acceleration), (angle, accel), strict=True
        ):
            value += w / (total * n_records) * np.mean((y_hat - y) ** 2) / np.mean(y**2)
    return value if math.isfinite(value) else math.inf
