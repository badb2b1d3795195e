"""Link sensors away from the tip: their output maps against an independent reference, and
single-channel records (a tip laser alone, a strain gauge alone) identified.

The reference is SciPy Radau on the full FEM equations in physical coordinates
(``reference_solver.radau_states``); the deflection, curvature and acceleration at a point are
computed here from the textbook cubic Hermite polynomials, not from ``jaxflex.stations``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from reference_solver import designed_torque, radau_states

import jaxflex
from jaxflex import Model, identify, simulate
from jaxflex.measured import logged_record, model_record
from jaxflex.objective import fitted_channels
from jaxflex.parameters import BASE_PARAMETERS
from jaxflex.sensors import Accelerometer, DeflectionSensor, StrainGauge
from jaxflex.signals import reference_input
from jaxflex.testbed import Testbed

Testbed.__test__ = False  # not a test class

REFERENCE = jaxflex.reference_parameters()
LENGTH = Model().testbed.length
NEAR, FAR = 0.3 * LENGTH, 0.9 * LENGTH

ANGLE_TARGET = 0.05
"""NRMSE (percent) of the joint angle against Radau: tests/test_simulate.py's target."""
LINK_TARGET = 0.5
"""NRMSE (percent) of a link output against Radau: tests/test_simulate.py's target for the tip
acceleration (and the joint velocity), here asked of every station reading and the tip laser."""


def nrmse(y, y_hat):
    """Percent, normalised by the reference's RMS (as in tests/test_simulate.py)."""
    y, y_hat = np.asarray(y), np.asarray(y_hat)
    return 100.0 * np.sqrt(np.mean((y - y_hat) ** 2)) / np.sqrt(np.mean(y**2))


def hermite_rows(length: float, n_elements: int, x: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows over ``q = [θ, w_1, w'_1, …, w_n, w'_n]`` (node 0 clamped) giving ``w(x)`` and
    ``w''(x)``, from the cubic Hermite polynomials of the element holding ``x``.

    With ``ξ = (x − x_e)/l_e`` on element ``e`` (nodes ``e`` and ``e + 1``):
    ``w = H1 w_e + l_e H2 w'_e + H3 w_{e+1} + l_e H4 w'_{e+1}``, ``H1 = (1 − ξ)²(1 + 2ξ)``,
    ``H2 = ξ(1 − ξ)²``, ``H3 = ξ²(3 − 2ξ)``, ``H4 = ξ²(ξ − 1)``, and ``w'' = d²w/dξ² / l_e²``.
    The curvature of cubic elements jumps at a node: a node inside the link is read on the
    element outboard of it (ξ = 0), as the simulator reads it, the tip on the last element
    (ξ = 1). The jump is discretisation, not simulator error: at 0.9 L on the pulse the inboard
    element's curvature differs from the outboard one's by about 3 % NRMSE (0.04 % at 0.3 L).
    """
    le = length / n_elements
    s = x / le
    if abs(s - round(s)) < 1e-9:  # on a node
        s = float(round(s))
    e = min(int(np.floor(s)), n_elements - 1)
    xi = s - e
    values = [(1 - xi) ** 2 * (1 + 2 * xi), le * xi * (1 - xi) ** 2,
              xi**2 * (3 - 2 * xi), le * xi**2 * (xi - 1)]
    # d²/dξ² of the four: 12ξ − 6, l_e(6ξ − 4), 6 − 12ξ, l_e(6ξ − 2); then / l_e²
    bends = [(12 * xi - 6) / le**2, (6 * xi - 4) / le, (6 - 12 * xi) / le**2, (6 * xi - 2) / le]
    deflection, curvature = np.zeros(1 + 2 * n_elements), np.zeros(1 + 2 * n_elements)
    nodal = (2 * e - 1, 2 * e, 2 * e + 1, 2 * e + 2)  # w_e, w'_e, w_{e+1}, w'_{e+1}
    for column, value, bend in zip(nodal, values, bends, strict=True):
        if column >= 1:  # node 0 is clamped: no columns
            deflection[column], curvature[column] = value, bend
    return deflection, curvature


def test_own_hermite_rows_give_the_static_cantilever():
    """The test's own rows read the exact static tip-load shape of the clamped link
    (``w = P x²(3L − x)/(6EI)``, ``w'' = P(L − x)/EI``, exact for cubic elements)."""
    model = Model()
    bed = model.testbed
    stiffness = np.asarray(model.structure(REFERENCE).stiffness)
    load = np.zeros(stiffness.shape[0])
    load[-2] = 0.8  # N at the tip
    q = np.zeros_like(load)
    q[1:] = np.linalg.solve(stiffness[1:, 1:], load[1:])
    ei = float(REFERENCE["E"]) * bed.second_moment
    for x in (0.0, 0.0123, NEAR, 0.3333, FAR, LENGTH):
        deflection, curvature = hermite_rows(LENGTH, bed.n_elements, x)
        assert deflection @ q == pytest.approx(0.8 * x**2 * (3 * LENGTH - x) / (6 * ei),
                                               rel=1e-9, abs=1e-15)
        assert curvature @ q == pytest.approx(0.8 * (LENGTH - x) / ei, rel=1e-9)


RIG = Model(
    sensors=(
        Accelerometer(channel="acc_03", x=NEAR),
        Accelerometer(channel="acc_09", x=FAR),
        StrainGauge(channel="sg_03", x=NEAR),
        StrainGauge(channel="sg_09", x=FAR),
        DeflectionSensor(channel="laser", x=LENGTH),
    )
)


def _input(name: str) -> np.ndarray:
    if name == "designed":  # tests/test_simulate.py's designed input (torque changes each step)
        return designed_torque()
    return reference_input(name)[1]  # the paper's pulse: a torque step on and off


@pytest.fixture(scope="module", params=["pulse", "designed"])
def rig_run(request):
    """One simulation of the rig per input: the input's name, its torque and the outputs."""
    torque = _input(request.param)
    return request.param, torque, simulate(RIG, REFERENCE, torque, RIG.testbed.dt)


@pytest.fixture(scope="module")
def against_radau(rig_run):
    """:func:`rig_run` and one Radau solution (q, q', q'') of the same input."""
    name, torque, out = rig_run
    return name, torque, radau_states(Model(), REFERENCE, torque, RIG.testbed.dt), out


def test_station_readings_match_radau_through_own_shape_functions(against_radau):
    """Deflection, strain ``(h/2)·w''`` and acceleration ``x·θ'' + ẅ`` at 0.3 L and 0.9 L and
    the tip laser ``w(L)``, from the Radau state through the test's own Hermite rows: every
    reading within the tip acceleration's target of tests/test_simulate.py."""
    name, _, (q, _, acc), out = against_radau
    bed = RIG.testbed
    errors = {"joint_angle": nrmse(q[:, 0], out.joint_angle)}
    for x, tag in ((NEAR, "03"), (FAR, "09")):
        deflection, curvature = hermite_rows(bed.length, bed.n_elements, x)
        k = RIG.stations.index(x)
        errors[f"w_{tag}"] = nrmse(q @ deflection, out.station_deflection[:, k])
        errors[f"sg_{tag}"] = nrmse(0.5 * bed.thickness * (q @ curvature),
                                    out.channel(f"sg_{tag}"))
        errors[f"acc_{tag}"] = nrmse(x * acc[:, 0] + acc @ deflection, out.channel(f"acc_{tag}"))
    tip, _ = hermite_rows(bed.length, bed.n_elements, bed.length)
    errors["laser"] = nrmse(q @ tip, out.channel("laser"))
    assert errors.pop("joint_angle") <= ANGLE_TARGET, (name, errors)
    assert max(errors.values()) <= LINK_TARGET, (name, errors)


def test_sensors_at_the_tip_read_the_tip_outputs_bit_for_bit(rig_run):
    """The laser at x = L is the simulator's own tip deflection, and adding the rig's sensors
    (and their stations) leaves that output as the sensorless model gives it."""
    _, torque, out = rig_run
    plain = simulate(Model(), REFERENCE, torque, RIG.testbed.dt)
    np.testing.assert_array_equal(out.channel("laser"), out.tip_deflection)
    np.testing.assert_array_equal(out.channel("laser"), plain.tip_deflection)
    tip = RIG.stations.index(LENGTH)
    np.testing.assert_array_equal(out.station_deflection[:, tip], out.tip_deflection)
    np.testing.assert_array_equal(out.joint_angle, plain.joint_angle)


# --- single-channel records identified --------------------------------------------------------

STEEL = Testbed(length=0.35, width=0.02, thickness=0.001, density=7850.0, n_elements=6)
"""An invented rig: a 0.35 m steel strip, 20 mm × 1 mm, six elements, a torque drive."""
TRUTH = {"E": 1.95e11, "J_h": 0.002, "b_v": 1e-3, "tau_c": 0.01, "alpha": 0.5, "beta": 2e-5}
STEEL_BOUNDS = {"E": (1e11, 3e11), "J_h": (3e-4, 1e-2)}
STEEL_SPECS = tuple(
    dataclasses.replace(spec, reference=TRUTH[spec.name])
    if spec.name not in STEEL_BOUNDS
    else dataclasses.replace(spec, reference=TRUTH[spec.name], lower=STEEL_BOUNDS[spec.name][0],
                             upper=STEEL_BOUNDS[spec.name][1])
    for spec in BASE_PARAMETERS
)
"""The base parameters with the truth as reference (what the rig's ``fixed`` holds) and search
bounds around a steel strip's E and a small hub."""


def steel_rig(sensor, fixed: tuple[str, ...]) -> Model:
    """The steel strip logging one sensor only (no encoder), ``fixed`` held at the truth."""
    return Model(STEEL, base=STEEL_SPECS, sensors=(sensor,), fixed=fixed, name="steel_strip")


def doublet_log(rig: Model, seed: int):
    """0.1 s at rest, then ±0.05 N m for 0.1 s each, then 0.3 s of free motion (1 kHz)."""
    dt = rig.testbed.dt
    t = np.arange(601) * dt
    torque = 0.05 * (((t >= 0.1) & (t < 0.2)).astype(float) - ((t >= 0.2) & (t < 0.3)))
    return logged_record(rig, rig.space.reference(), t, torque, seed=seed, name="doublet")


def _check_fit(fit, rig: Model, channel: str, free: tuple[str, ...], rel: float) -> None:
    assert fit.settings["channels"] == [channel], fit.settings["channels"]
    assert fit.names == free
    assert fit.fixed == {n: TRUTH[n] for n in rig.fixed}
    assert not fit.poorly_identifiable and not fit.warnings, fit.summary()
    for name in free:
        lower, upper = fit.intervals[name]
        assert lower <= TRUTH[name] <= upper, (name, fit.summary())
        assert fit.params[name] == pytest.approx(TRUTH[name], rel=rel), (name, fit.summary())


def test_a_tip_laser_alone_identifies_stiffness_hub_and_viscous_friction():
    """A tip laser (2 µm noise, 10 µm steps) and no encoder: E, J_h and b_v come back within
    their intervals and 2 % (the damping and the Coulomb level held at the truth)."""
    laser = DeflectionSensor(channel="laser", x=STEEL.length, noise=2e-6, resolution=1e-5)
    rig = steel_rig(laser, fixed=("tau_c", "alpha", "beta"))
    log = doublet_log(rig, seed=1)
    assert set(log.columns) == {"time", "torque", "laser"}
    assert np.ptp(log.channel("laser")) > 100 * laser.resolution  # far above the steps
    ready = model_record(rig, log)
    assert fitted_channels([ready], rig) == ("laser",)
    fit = identify(ready, rig, generations=15, population=24, seed=0)
    _check_fit(fit, rig, "laser", ("E", "J_h", "b_v"), rel=0.02)


def test_a_strain_gauge_alone_identifies_stiffness_and_hub():
    """A strain gauge 5 cm from the clamp (1 µε noise) and no encoder: E and J_h come back
    within their intervals and 2 %; friction and damping are held at the truth (b_v shows only
    weakly in the strain: left free, its interval spans about ±30 %)."""
    gauge = StrainGauge(channel="strain", x=0.05, noise=1e-6)
    rig = steel_rig(gauge, fixed=("b_v", "tau_c", "alpha", "beta"))
    log = doublet_log(rig, seed=2)
    assert set(log.columns) == {"time", "torque", "strain"}
    ready = model_record(rig, log)
    assert fitted_channels([ready], rig) == ("strain",)
    fit = identify(ready, rig, generations=15, population=24, seed=0)
    _check_fit(fit, rig, "strain", ("E", "J_h"), rel=0.02)
