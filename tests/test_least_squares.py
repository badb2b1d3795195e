"""The secant curvature of the bounded Levenberg–Marquardt (:mod:`jaxflex.least_squares`)."""

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize as so
from threadpoolctl import threadpool_info

from jaxflex import least_squares
from jaxflex.least_squares import (
    bounded_least_squares,
    bounded_least_squares_of,
    secant_curvature,
)


def _quadratic_residuals(rng, n=12, d=4):
    """``rᵢ(x) = aᵢ + bᵢᵀx + ½ xᵀCᵢx`` and its Jacobian: ``Σ rᵢ∇²rᵢ = Σ rᵢCᵢ`` exactly."""
    a, b = 5.0 * rng.normal(size=n), rng.normal(size=(n, d))  # large: H indefinite
    c = rng.normal(size=(n, d, d))
    c = c + np.transpose(c, (0, 2, 1))

    def system(x):
        return a + b @ x + 0.5 * np.einsum("i,nij,j->n", x, c, x), b + np.einsum("nij,j->ni", c, x)

    return system


def test_the_secant_update_meets_the_secant_condition_and_keeps_s_where_curvature_is_negative():
    """Over a step ``s`` with ``yᵀs > 0`` the updated ``S`` is symmetric and maps ``s`` to
    ``y♯ = (J₊ − J₀)ᵀr₊`` (for quadratic residuals: ``Σ r₊ᵢCᵢ s``) to round-off; where
    ``yᵀs ≤ 0`` the update leaves ``S`` as it was."""
    rng = np.random.default_rng(3)
    system = _quadratic_residuals(rng)
    d = 4
    curvature = rng.normal(size=(d, d))
    curvature = curvature + curvature.T
    updated = 0
    for _ in range(20):
        x0, step = rng.normal(size=d), 0.3 * rng.normal(size=d)
        (r0, j0), (r1, j1) = system(x0), system(x0 + step)
        new = np.asarray(secant_curvature(jnp.asarray(curvature), jnp.asarray(step),
                                          jnp.asarray(j1), jnp.asarray(r1),
                                          jnp.asarray(j0), jnp.asarray(r0)))
        change = j1.T @ r1 - j0.T @ r0
        if change @ step > 0:
            updated += 1
            sharp = (j1 - j0).T @ r1
            np.testing.assert_allclose(new @ step, sharp, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(new, new.T, rtol=0, atol=1e-12)
        else:
            np.testing.assert_array_equal(new, curvature)
    assert 0 < updated < 20  # both branches met


def _dennis_schnabel(p, steepness):
    """The large-residual problem ``r(x) = (x + 1, λx² + x − 1)``: minimum ``x = 0`` with cost 2,
    where Gauss–Newton converges only linearly, at the rate ``|λ|``."""
    x = p[0]
    return jnp.stack([x + 1.0, steepness * x**2 + x - 1.0])


@pytest.mark.parametrize("marquardt", [False, True])
def test_with_the_secant_curvature_a_large_residual_fit_converges_in_fewer_steps(marquardt):
    """On the large-residual example (λ = 0.7), Gauss–Newton's linear convergence takes dozens
    of steps; with the secant curvature the solve reaches the same minimum in fewer than half
    as many, also when the residuals and Jacobian come from the host (discovery's way)."""
    tight = dict(rtol=1e-12, atol=1e-12, ftol=1e-14, max_steps=200, marquardt=marquardt)
    box = (np.array([1.0]), np.array([-3.0]), np.array([3.0]))
    plain = bounded_least_squares(_dennis_schnabel, jnp.asarray(0.7), *box, **tight)
    curved = bounded_least_squares(_dennis_schnabel, jnp.asarray(0.7), *box, secant=True,
                                   **tight)
    for fit in (plain, curved):
        assert fit.result == "successful"
        assert abs(fit.value[0]) < 1e-6
        assert fit.cost == pytest.approx(2.0, rel=1e-12)
    assert plain.steps >= 30
    assert 2 * curved.steps < plain.steps

    def system(p):
        x = p[0]
        return np.array([x + 1.0, 0.7 * x**2 + x - 1.0]), np.array([[1.0], [1.4 * x + 1.0]])

    host = bounded_least_squares_of(system, 2, *box, secant=True, **tight)
    assert host.result == "successful" and 2 * host.steps < plain.steps
    np.testing.assert_allclose(host.value, curved.value, rtol=0, atol=1e-12)


def test_with_the_secant_curvature_a_box_problem_ends_where_scipy_bvls_does():
    """Linear residuals have no curvature of their own: with the secant estimate and its
    Cholesky step, parameters held on their bounds still end where SciPy's BVLS puts them."""
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(40, 5)), 3.0 * rng.normal(size=40)
    lower, upper = -0.2 * np.ones(5), 0.3 * np.ones(5)
    fit = bounded_least_squares_of(lambda p: (a @ p - b, a), 40, np.zeros(5), lower, upper,
                                   rtol=1e-12, atol=1e-14, ftol=1e-15, max_steps=100,
                                   marquardt=True, secant=True)
    ref = so.lsq_linear(a, b, (lower, upper), method="bvls", tol=1e-14)
    assert np.sum(ref.active_mask != 0) >= 2  # the bounds matter
    np.testing.assert_allclose(fit.value, ref.x, rtol=0, atol=1e-7)
    assert fit.cost == pytest.approx(2 * ref.cost, rel=1e-12)


def test_a_host_stepped_solve_compiles_its_step_once_and_keeps_blas_on_one_thread(monkeypatch):
    """The solve is stepped from the host: its step is traced once however many steps it takes
    (the first step's inputs are typed as every later step's), and while the caller computes
    its residuals the BLAS libraries run on one thread (their idle threads would otherwise spin
    on the cores the caller's program needs); afterwards they have their threads back."""
    traced = []
    advance = least_squares._advance
    monkeypatch.setattr(least_squares, "_advance",
                        lambda *args: traced.append(1) or advance(*args))
    system = _quadratic_residuals(np.random.default_rng(11), n=13, d=4)  # a size of its own
    threads = []

    def counted(x):
        threads.append(max((lib["num_threads"] for lib in threadpool_info()
                            if lib["user_api"] == "blas"), default=1))
        return system(x)

    before = [lib["num_threads"] for lib in threadpool_info()]
    fit = bounded_least_squares_of(counted, 13, np.zeros(4), -np.ones(4), np.ones(4),
                                   rtol=1e-12, atol=1e-12, ftol=1e-14, max_steps=50,
                                   marquardt=True, secant=True)
    assert fit.steps >= 4 and len(threads) == fit.steps
    assert len(traced) == 1
    assert set(threads) == {1}
    assert [lib["num_threads"] for lib in threadpool_info()] == before
