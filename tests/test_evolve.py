"""Evolutionary strategies on the unit box: convergence, robustness, determinism, validation."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402

from jaxflex.evolve import (  # noqa: E402
    DE,
    GA,
    PSO,
    AbstractStrategy,
    EvolutionResult,
    State,
    get_strategy,
    run,
    update_best,
)
from jaxflex.evolve._base import initial_population  # noqa: E402
from jaxflex.evolve.de import _distinct_others  # noqa: E402

DIM = 6
OPT = jnp.linspace(0.3, 0.7, DIM)
NAMES = ("de", "ga", "pso")
# Tolerance on f(best) = |best_x - OPT|² after 100 generations of the paper preset (seed 0).
# Over 20 seeds the worst values were 1e-8 (DE), 2e-4 (GA, fixed mutation width) and 2e-5 (PSO).
SPHERE_TOL = {"de": 1e-6, "ga": 1e-3, "pso": 1e-4}


def sphere(x):
    return jnp.sum((x - OPT) ** 2, axis=1)


@pytest.fixture(scope="module")
def paper_runs() -> dict[str, EvolutionResult]:
    return {name: run(get_strategy(name), sphere, DIM, seed=0) for name in NAMES}


def _assert_in_box(x) -> None:
    x = np.asarray(x)
    assert np.all(np.isfinite(x))
    assert np.all((x >= 0.0) & (x <= 1.0))


# --------------------------------------------------------------------------- convergence


@pytest.mark.parametrize("name", NAMES)
def test_paper_preset_finds_shifted_sphere(paper_runs, name):
    result = paper_runs[name]
    tol = SPHERE_TOL[name]
    assert float(result.best_fitness) < tol
    assert np.max(np.abs(np.asarray(result.best_x) - np.asarray(OPT))) < np.sqrt(tol)
    # re-evaluating in another batch may round differently in the last bit
    np.testing.assert_allclose(sphere(result.best_x[None])[0], result.best_fitness, rtol=1e-12)


def test_default_pso_constriction_converges_tightly():
    result = run(PSO(), sphere, DIM, seed=0)
    assert float(result.best_fitness) < 1e-8


def test_de_best1bin_finds_shifted_sphere():
    result = run(DE.paper(variant="best1bin"), sphere, DIM, seed=0)
    assert float(result.best_fitness) < 1e-10


def test_a_converged_population_stops_the_run_early_and_changes_nothing_before():
    """With ``tol`` the run stops at the first generation whose costs agree to it (SciPy's
    test: std ≤ tol·|mean|); up to there it is the run without ``tol``, bit for bit."""

    def lifted(x):  # minimum 1, so that the relative spread can fall below tol
        return 1.0 + sphere(x)

    full = run(DE.paper(population=20), lifted, DIM, seed=4, generations=150)
    early = run(DE.paper(population=20), lifted, DIM, seed=4, generations=150, tol=1e-6)
    g = early.generations
    assert 0 < g < 150 and full.generations == 150
    assert early.n_evaluations == 20 * (g + 1) and early.history_best.shape == (g + 1,)
    np.testing.assert_array_equal(early.history_best, full.history_best[: g + 1])
    np.testing.assert_array_equal(early.history_best_x, full.history_best_x[: g + 1])
    costs = np.asarray(early.final_fitness)
    assert np.std(costs) <= 1e-6 * abs(np.mean(costs))
    # the population has gathered at the optimum (within tol), not short of it; the full run
    # only polishes it further
    assert float(early.best_fitness) - 1.0 < 1e-6
    assert float(full.best_fitness) <= float(early.best_fitness)
    with pytest.raises(ValueError, match="tol must be a positive number or None, got 0"):
        run(DE.paper(population=20), lifted, DIM, seed=4, tol=0)


def test_de_finds_shifted_rosenbrock():
    """Rosenbrock on y = 4u - 1 ∈ [-1, 3]^4, minimum 0 at y = 1, i.e. u = 0.5 (banana valley)."""

    def rosenbrock(u):
        y = 4.0 * u - 1.0
        return jnp.sum(100.0 * (y[:, 1:] - y[:, :-1] ** 2) ** 2 + (1.0 - y[:, :-1]) ** 2, axis=1)

    result = run(DE.paper(), rosenbrock, 4, seed=0, generations=200)
    assert float(result.best_fitness) < 1e-4  # worst of 20 seeds: 8e-6
    np.testing.assert_allclose(result.best_x, 0.5, atol=5e-3)


# --------------------------------------------------------------------------- result invariants


@pytest.mark.parametrize("name", NAMES)
def test_history_shapes_elitism_and_bounds(paper_runs, name):
    result = paper_runs[name]
    g1 = 101
    assert result.history_best.shape == result.history_mean.shape == (g1,)
    assert result.history_best_x.shape == (g1, DIM)
    assert result.final_population.shape == (100, DIM)
    assert result.final_fitness.shape == (100,)
    assert result.n_evaluations == 100 * g1
    assert result.method == name.upper()
    assert result.settings == get_strategy(name).for_generations(100).settings()
    assert result.wall_time > 0 and result.compile_time > 0

    best = np.asarray(result.history_best)
    assert np.all(np.diff(best) <= 0.0), "the recorded best must never increase"
    assert best[-1] == float(result.best_fitness)
    np.testing.assert_array_equal(result.history_best_x[-1], result.best_x)
    np.testing.assert_allclose(sphere(result.history_best_x), best, rtol=1e-12)
    assert np.all(np.asarray(result.history_mean) >= best)
    _assert_in_box(result.final_population)
    _assert_in_box(result.history_best_x)
    np.testing.assert_allclose(sphere(result.final_population), result.final_fitness, rtol=1e-12)

    # elitism: the best point is still held by the population (PSO: by the personal bests)
    held = result.final_state.personal_best_fitness if name == "pso" else result.final_fitness
    assert float(jnp.min(held)) == float(result.best_fitness)


def test_pso_paper_inertia_schedule():
    pso = PSO.paper().for_generations(50)
    assert pso.horizon == 50 and pso.v_max == 0.2
    assert float(pso.inertia(0)) == pytest.approx(1.4)
    assert float(pso.inertia(49)) == pytest.approx(0.4)
    assert float(pso.inertia(80)) == pytest.approx(0.4)
    assert float(PSO().inertia(49)) == pytest.approx(0.7298)


# --------------------------------------------------------------------------- non-finite fitness


# Optimum of the box-constrained problem sits on two walls: c is outside the box in x0 and x2.
CENTRE = jnp.array([-0.2, 0.3, 1.3, 0.5, 0.6, 0.7])
BOX_OPT = jnp.clip(CENTRE, 0.0, 1.0)
BOX_MIN = float(jnp.sum((BOX_OPT - CENTRE) ** 2))  # 0.13


@pytest.mark.parametrize("name", NAMES)
def test_walls_nan_and_inf_regions_and_one_call_per_generation(name):
    """NaN for x3 > 0.8, +inf for x4 < 0.15: the search goes on, no NaN in population/history."""
    shapes: list[tuple[int, ...]] = []
    traces: list[int] = []
    called: list[int] = []

    def fitness(x):
        traces.append(1)  # Python side effect: runs once per trace, not per call
        jax.debug.callback(lambda v: shapes.append(v.shape), x)
        f = jnp.sum((x - CENTRE) ** 2, axis=1)
        f = jnp.where(x[:, 3] > 0.8, jnp.nan, f)
        return jnp.where(x[:, 4] < 0.15, jnp.inf, f)

    generations = 60
    result = run(
        get_strategy(name), fitness, DIM, seed=3, generations=generations,
        callback=lambda g, state: called.append(g),
    )
    jax.effects_barrier()
    assert shapes == [(100, DIM)] * (generations + 1), "one full-population call per generation"
    assert result.n_evaluations == 100 * (generations + 1)
    assert len(traces) == 1, "the fitness is traced (compiled) once, for every generation"
    assert called == list(range(1, generations + 1))

    assert np.all(np.isfinite(result.history_best))
    assert np.all(np.isfinite(result.history_mean))
    assert not np.any(np.isnan(result.final_fitness))
    _assert_in_box(result.final_population)
    assert float(result.best_fitness) - BOX_MIN < 1e-3
    np.testing.assert_allclose(result.best_x, BOX_OPT, atol=0.05)


def test_all_nan_fitness_does_not_crash():
    result = run(DE.paper(population=8), lambda x: jnp.full(x.shape[0], jnp.nan), 3, seed=0,
                 generations=5)
    assert np.all(np.isinf(result.history_best)) and np.all(np.isinf(result.history_mean))
    assert np.all(np.isposinf(result.final_fitness))
    _assert_in_box(result.final_population)


def test_fitness_of_wrong_shape_is_rejected():
    with pytest.raises(ValueError, match="fitness_fn"):
        run(DE.paper(population=8), lambda x: x, 3, seed=0, generations=2)


# --------------------------------------------------------------------------- determinism, seeding


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_identical_different_seed_different(paper_runs, name):
    again = run(get_strategy(name), sphere, DIM, key=jax.random.key(0), progress=True)
    first = paper_runs[name]
    for field in ("best_x", "best_fitness", "history_best", "history_mean", "history_best_x",
                  "final_population", "final_fitness"):
        np.testing.assert_array_equal(getattr(again, field), getattr(first, field), err_msg=field)
    other = run(get_strategy(name), sphere, DIM, seed=1)
    assert not np.array_equal(other.final_population, first.final_population)
    assert not np.array_equal(other.history_best_x, first.history_best_x)


def test_init_population_warm_starts_the_search():
    result = run(DE.paper(), sphere, DIM, seed=0, generations=3, init_population=OPT)
    assert float(result.history_best[0]) == 0.0
    np.testing.assert_array_equal(result.history_best_x[0], OPT)

    seeds = jnp.stack([OPT, 0.5 * OPT, jnp.ones(DIM)])
    x = initial_population(jax.random.key(0), 10, DIM, seeds)
    np.testing.assert_array_equal(x[:3], seeds)
    _assert_in_box(x)
    assert np.unique(np.asarray(x), axis=0).shape[0] == 10


def test_de_donors_are_distinct_uniform_and_differ_from_target():
    u = jax.random.uniform(jax.random.key(1), (4000, 5, 3))
    picks = np.asarray(jax.jit(jax.vmap(_distinct_others))(u))  # 4000 draws for n=5, k=3
    rows = np.arange(5)[None, :, None]
    assert np.all(picks != rows)
    assert np.all(np.sort(picks, axis=2)[..., 1:] != np.sort(picks, axis=2)[..., :-1])
    # each of the 4 other members is equally likely in every slot: p = 1/4 ± 4σ (σ ≈ 0.007)
    for slot in range(3):
        freq = np.bincount(picks[:, 0, slot], minlength=5) / 4000
        np.testing.assert_allclose(freq, [0, 0.25, 0.25, 0.25, 0.25], atol=0.03)


# --------------------------------------------------------------------------- validation


BAD_SETTINGS = [
    (lambda: DE(population=3), "population"),
    (lambda: DE(population=2, variant="best1bin"), "population"),
    (lambda: DE(population=10.5), "population"),
    (lambda: DE(F=0.0), "F"),
    (lambda: DE(F=2.5), "F"),
    (lambda: DE(F=float("nan")), "F"),
    (lambda: DE(CR=1.1), "CR"),
    (lambda: DE(CR=-0.1), "CR"),
    (lambda: DE(variant="rand2exp"), "variant"),
    (lambda: GA(population=1), "population"),
    (lambda: GA(selection_rate=0.0), "selection_rate"),
    (lambda: GA(selection_rate=1.5), "selection_rate"),
    (lambda: GA(crossover=-0.1), "crossover"),
    (lambda: GA(mutation=1.2), "mutation"),
    (lambda: GA(mutation_scale=0.0), "mutation_scale"),
    (lambda: GA(n_elite=101), "n_elite"),
    (lambda: PSO(population=1), "population"),
    (lambda: PSO(w=-0.5), "w"),
    (lambda: PSO(c1=-1.0), "c1"),
    (lambda: PSO(c2=float("inf")), "c2"),
    (lambda: PSO(v_max=0.0), "v_max"),
    (lambda: PSO(w_final=-0.1), "w_final"),
    (lambda: run(DE(), sphere, DIM, seed=0, generations=0), "generations"),
    (lambda: run(DE(), sphere, DIM, seed=0, generations=-5), "generations"),
    (lambda: run(DE(), sphere, 0, seed=0), "dim"),
    (lambda: run(DE(), sphere, DIM), "seed"),
    (lambda: run(DE(), sphere, DIM, seed=-1), "seed"),
    (lambda: run(DE(), sphere, DIM, seed=0, init_population=jnp.ones((2, 5))), "init_population"),
    (lambda: run(DE(), sphere, DIM, seed=0, init_population=jnp.ones((101, 6))),
     "init_population"),
    (lambda: run(DE(), sphere, DIM, seed=0, init_population=1.5 * OPT), "init_population"),
    (lambda: get_strategy("de", preset="fast"), "preset"),
    (lambda: get_strategy("ga", mutation_rate=0.1), "mutation_rate"),
]


@pytest.mark.parametrize(("make", "setting"), BAD_SETTINGS)
def test_bad_setting_raises_value_error_naming_it(make, setting):
    with pytest.raises(ValueError) as info:
        make()
    assert re.search(rf"(?<![\w.]){re.escape(setting)}\b", str(info.value)), str(info.value)


# --------------------------------------------------------------------------- get_strategy


def test_get_strategy_names_presets_and_overrides():
    assert get_strategy("DE") == DE(population=100, F=0.5, CR=0.8, variant="rand1bin")
    assert get_strategy("Ga") == GA(population=100, selection_rate=0.5, crossover=0.8,
                                    mutation=0.2)
    paper = get_strategy("pso")
    assert (paper.population, paper.w, paper.c1, paper.c2) == (100, 1.4, 1.5, 2.5)
    default = get_strategy("PSO", preset="default")
    assert (default.w, default.c1, default.c2, default.v_max) == (0.7298, 1.49618, 1.49618, None)
    assert get_strategy("de", variant="best1bin", population=3).variant == "best1bin"


def test_get_strategy_rejects_unknown_name():
    with pytest.raises(ValueError, match="cmaes") as info:
        get_strategy("cmaes")
    for name in NAMES:
        assert name in str(info.value)


class _RandomSearch(AbstractStrategy):
    """A strategy written outside the library: fresh uniform candidates, keep the better."""

    population: int = eqx.field(static=True, default=16)
    generations: int = eqx.field(static=True, default=30)

    def ask(self, state, key):
        return jax.random.uniform(key, state.population.shape), state

    def tell(self, state, candidates, fitness):
        better = fitness < state.fitness
        x = jnp.where(better[:, None], candidates, state.population)
        f = jnp.where(better, fitness, state.fitness)
        best_x, best_f = update_best(state.best_x, state.best_fitness, x, f)
        return State(x, f, best_x, best_f, state.generation + 1)


def test_a_strategy_of_ones_own_runs_through_ask_and_tell():
    """``run`` drives any subclass by its ask/tell; ``step`` (ask, evaluate, tell) agrees."""
    def sphere(x):
        return jnp.sum((x - 0.25) ** 2, axis=1)

    result = run(_RandomSearch(), sphere, 2, seed=0)  # its own 30 generations
    assert result.generations == 30
    assert result.best_fitness < 0.01
    assert np.all(np.diff(np.asarray(result.history_best)) <= 0)
    strategy, key = _RandomSearch(), jax.random.key(1)
    state = strategy.init(key, 2, sphere)
    stepped = strategy.step(state, key, sphere)
    candidates, asked = strategy.ask(state, key)
    told = strategy.tell(asked, candidates, sphere(candidates))
    assert np.array_equal(stepped.population, told.population)


def test_a_strategy_without_ask_and_tell_cannot_be_made():
    class Incomplete(AbstractStrategy):
        population: int = 4
        generations: int = 10

    with pytest.raises(TypeError, match="abstract"):
        Incomplete()


class _Faulty(_RandomSearch):
    """The user's strategy with one fault: ``fault`` says which."""

    fault: str = eqx.field(static=True, default="ask_shape")

    def ask(self, state, key):
        candidates, state = super().ask(state, key)
        if self.fault == "ask_shape":  # one candidate short
            return candidates[1:], state
        if self.fault == "ask_pair":
            return candidates
        if self.fault == "ask_raises":
            return candidates @ jnp.ones((3, 3)), state  # (16, 2) @ (3, 3)
        return candidates, state

    def tell(self, state, candidates, fitness):
        if self.fault == "tell_fitness":  # forgot to keep one fitness per member
            told = super().tell(state, candidates, fitness)
            return State(told.population, told.fitness[:1], told.best_x, told.best_fitness,
                         told.generation)
        return super().tell(state, candidates, fitness)

    def initialize(self, key, dim, init_population=None):
        population = super().initialize(key, dim, init_population)
        return population * jnp.nan if self.fault == "nan" else population


@pytest.mark.parametrize(("fault", "message"), [
    ("ask_shape", "ask returned the candidates as an array of shape (15, 2), float64; expected "
                  "real values of shape (16, 2) (population 16 in 2 dimensions)"),
    ("ask_pair", "ask returned an array of shape (16, 2), float64; expected (candidates, state)"),
    ("ask_raises", "ask raised TypeError: "),  # then JAX's words on the shapes
    ("tell_fitness", "tell returned the state's fitness as an array of shape (1,), float64; "
                     "expected real values of shape (16,)"),
    ("nan", "initialize returned a first population with NaN or infinite values"),
])
def test_a_strategy_that_goes_wrong_is_named_with_what_it_returned(fault, message):
    """Said in the strategy's terms, before the search, not in JAX's from a compiled call."""
    from jaxflex.evolve import StrategyError

    def sphere(x):
        return jnp.sum((x - 0.25) ** 2, axis=1)

    with pytest.raises(StrategyError) as info:
        run(_Faulty(fault=fault), sphere, 2, seed=0, generations=2)
    assert str(info.value).startswith(f"strategy _Faulty ('strategy'): {message}"), info.value
