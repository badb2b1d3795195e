"""What the three evolutionary strategies share: state, validation, boundary handling, the runner.

Every strategy searches the unit box ``[0, 1]^d`` (the caller maps to physical units) and
*minimises* a fitness ``f: [0,1]^{P×d} → R^P`` that evaluates a whole population in one call.
Non-finite fitness values are replaced by ``+inf`` (:func:`evaluate`), so a simulation that
blows up in part of the box is simply the worst candidate and NaN never enters a population.

:func:`run` compiles a generation once and loops over generations in Python, so that it can
report progress and record the history of the search.
"""

from __future__ import annotations

import abc
import dataclasses
import time
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from jaxflex._arguments import raised
from jaxflex._progress import Progress
from jaxflex.parallel import gathered, gathered_sharding
from jaxflex.parameters import into_unit_box

FitnessFn = Callable[[Float[Array, "P d"]], Float[Array, " P"]]


# --------------------------------------------------------------------------- validation


def check_integer(owner: str, name: str, value: Any, minimum: int, why: str = "") -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is an integer ``>= minimum``."""
    is_int = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not is_int or value < minimum:
        reason = f" ({why})" if why else ""
        raise ValueError(f"{owner}: {name} must be an integer >= {minimum}{reason}, got {value!r}")


def check_range(
    owner: str,
    name: str,
    value: Any,
    low: float,
    high: float,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a real number in the interval."""
    interval = f"{'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: {name} must be a number in {interval}, got {value!r}") from None
    above = x > low if low_open else x >= low
    below = x < high if high_open else x <= high
    if not (above and below):  # also rejects NaN
        raise ValueError(f"{owner}: {name} must be in {interval}, got {value!r}")


# --------------------------------------------------------------------------- shared operators


def sanitize_fitness(fitness: Float[Array, " P"]) -> Float[Array, " P"]:
    """Replace NaN and ±inf by ``+inf``: a failed evaluation is the worst possible candidate."""
    return jnp.where(jnp.isfinite(fitness), fitness, jnp.inf)


def evaluate(fitness_fn: FitnessFn, population: Float[Array, "P d"]) -> Float[Array, " P"]:
    """Evaluate the whole population in one call of ``fitness_fn`` and sanitise the result."""
    fitness = jnp.asarray(fitness_fn(population))
    if fitness.shape != population.shape[:1]:
        raise ValueError(
            f"fitness_fn must map a ({population.shape[0]}, {population.shape[1]}) population "
            f"to shape ({population.shape[0]},), got shape {fitness.shape}"
        )
    return sanitize_fitness(fitness.astype(population.dtype))


def uniform_blocks(key: PRNGKeyArray, n: int, *widths: int) -> list[Float[Array, "n _"]]:
    """Independent ``U[0, 1)`` blocks of shapes ``(n, w)`` for each ``w`` in ``widths``, cut from
    ONE random draw.

    Every call site of JAX's threefry hash adds XLA compile time of its own (``randint`` more
    than ``uniform``), so a generation draws all its randomness at once.
    """
    u = jax.random.uniform(key, (n, sum(widths)), dtype=jnp.result_type(float))
    return jnp.split(u, np.cumsum(widths)[:-1].tolist(), axis=1)


def uniform_index(u: Float[Array, "..."], m: int | Array) -> Int[Array, "..."]:
    """``⌊u m⌋``: an integer uniform on ``{0, …, m-1}`` from ``u ~ U[0, 1)``."""
    return jnp.minimum(jnp.floor(u * m).astype(int), m - 1)


def gaussian(u1: Float[Array, "..."], u2: Float[Array, "..."]) -> Float[Array, "..."]:
    """Box–Muller: ``√(-2 ln(1 - u1)) cos(2π u2) ~ N(0, 1)`` for independent ``u1, u2 ~ U[0,1)``."""
    return jnp.sqrt(-2.0 * jnp.log1p(-u1)) * jnp.cos(2.0 * jnp.pi * u2)


def repair(
    u: Float[Array, "P d"], candidate: Float[Array, "P d"], anchor: Float[Array, "P d"]
) -> Float[Array, "P d"]:
    """Bring components that left the unit box back, between the anchor and the violated bound.

    With ``u ~ U[0, 1)`` per component::

        x_ij < 0  →  a_ij (1 - u_ij)               (uniform on (0, a_ij])
        x_ij > 1  →  a_ij + u_ij (1 - a_ij)        (uniform on [a_ij, 1))

    where the anchor ``a`` is the in-box point the candidate was derived from (DE's target
    vector, GA's first parent). Unlike clipping this does not pile candidates up on the faces of
    the box, and unlike re-sampling in the whole box it keeps the search local. Non-finite
    components (impossible from finite inputs) fall back to the anchor.
    """
    x = jnp.where(jnp.isfinite(candidate), candidate, anchor)
    x = jnp.where(x < 0.0, anchor * (1.0 - u), x)
    return jnp.where(x > 1.0, anchor + u * (1.0 - anchor), x)


def clip_at_walls(
    position: Float[Array, "P d"], velocity: Float[Array, "P d"]
) -> tuple[Float[Array, "P d"], Float[Array, "P d"]]:
    """Clip positions to the unit box and zero the velocity components that hit a wall.

    Used by PSO ("absorbing walls"): a particle that flies out stops on the face instead of
    carrying its outward momentum into the next generation.
    """
    clipped = jnp.clip(position, 0.0, 1.0)
    return clipped, jnp.where(clipped == position, velocity, 0.0)


def update_best(
    best_x: Float[Array, " d"],
    best_fitness: Float[Array, ""],
    population: Float[Array, "P d"],
    fitness: Float[Array, " P"],
) -> tuple[Float[Array, " d"], Float[Array, ""]]:
    """Running best over all evaluations: replace only on strict improvement (ties keep the old)."""
    i = jnp.argmin(fitness)
    better = fitness[i] < best_fitness
    return jnp.where(better, population[i], best_x), jnp.where(better, fitness[i], best_fitness)


def initial_population(
    key: PRNGKeyArray,
    population: int,
    dim: int,
    init_population: Float[ArrayLike, "k d"] | None = None,
) -> Float[Array, "P d"]:
    """Uniform random points in the unit box; the first ``k`` rows are ``init_population``.

    Seeding lets a caller warm-start the search (e.g. from a previous fit); :func:`run` brings
    the rows into the box (:func:`jaxflex.parameters.into_unit_box`) before they get here.
    """
    x = jax.random.uniform(key, (population, dim), dtype=jnp.result_type(float))
    if init_population is None:
        return x
    seeds = jnp.asarray(init_population, dtype=x.dtype)
    if seeds.ndim != 2 or seeds.shape[1] != dim or seeds.shape[0] > population:
        raise ValueError(
            f"init_population must have shape (k, {dim}) with k <= population={population}, "
            f"got {seeds.shape}"
        )
    return x.at[: seeds.shape[0]].set(jnp.clip(seeds, 0.0, 1.0))


# --------------------------------------------------------------------------- state and strategy


class State(eqx.Module):
    """Search state after a generation; strategies with more memory (PSO) extend it.

    ``best_x``/``best_fitness`` are the best over *all* evaluations so far, so the recorded best
    never increases, whatever the strategy does with its population.
    """

    population: Float[Array, "P d"]
    fitness: Float[Array, " P"]
    best_x: Float[Array, " d"]
    best_fitness: Float[Array, ""]
    generation: Int[Array, ""]


class AbstractStrategy(eqx.Module):
    """An evosax-like strategy: hyper-parameters as fields, pure and jittable ``ask``/``tell``.

    A run is :meth:`initialize` (the first population), :meth:`start` (the state once it is
    evaluated), then per generation :meth:`ask` (the candidates to evaluate, in one batched
    call) and :meth:`tell` (select with their fitness). :meth:`init` and :meth:`step` do the
    same with a fitness function, for a loop inside one program (``lax.scan``).

    Subclasses define ``population`` and ``generations`` (static int fields: the candidates per
    generation, and how many generations a run takes unless told), validate their fields in
    ``__check_init__`` and implement :meth:`ask` and :meth:`tell`.
    """

    name: ClassVar[str] = "strategy"
    population: eqx.AbstractVar[int]
    generations: eqx.AbstractVar[int]

    def initialize(
        self, key: PRNGKeyArray, dim: int, init_population: Float[ArrayLike, "k d"] | None = None
    ) -> Float[Array, "P d"]:
        """The first population: uniform on the unit box, its first rows ``init_population``."""
        return initial_population(key, self.population, dim, init_population)

    def start(self, population: Float[Array, "P d"], fitness: Float[Array, " P"]) -> State:
        """The state after the first population was evaluated."""
        best_x, best_fitness = update_best(
            population[0], jnp.asarray(jnp.inf, population.dtype), population, fitness
        )
        return State(population, fitness, best_x, best_fitness, jnp.zeros((), dtype=int))

    @abc.abstractmethod
    def ask(self, state: State, key: PRNGKeyArray) -> tuple[Float[Array, "P d"], State]:
        """The next ``population`` candidates to evaluate, and the state that remembers what
        :meth:`tell` needs of how they were made."""

    @abc.abstractmethod
    def tell(
        self, state: State, candidates: Float[Array, "P d"], fitness: Float[Array, " P"]
    ) -> State:
        """The state after the asked ``candidates`` scored ``fitness``: selection."""

    def init(
        self,
        key: PRNGKeyArray,
        dim: int,
        fitness_fn: FitnessFn,
        init_population: Float[ArrayLike, "k d"] | None = None,
    ) -> State:
        """Sample (and seed) the first population and evaluate it once."""
        population = self.initialize(key, dim, init_population)
        return self.start(population, evaluate(fitness_fn, population))

    def step(self, state: State, key: PRNGKeyArray, fitness_fn: FitnessFn) -> State:
        """One generation: ask, evaluate the candidates in one call, tell."""
        candidates, state = self.ask(state, key)
        return self.tell(state, candidates, evaluate(fitness_fn, candidates))

    def for_generations(self, generations: int) -> AbstractStrategy:
        """This strategy adapted to a run of ``generations`` (for schedules); default: unchanged."""
        del generations
        return self

    def settings(self) -> dict[str, Any]:
        """The hyper-parameters as a plain dict (field name → value)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def paper(cls, **overrides: Any) -> AbstractStrategy:
        """The settings of the paper, optionally with some fields overridden (a strategy the
        paper did not use: its defaults)."""
        return cls(**overrides)


# --------------------------------------------------------------------------- runner


class EvolutionResult(eqx.Module):
    """Outcome of :func:`run`, in unit-box coordinates.

    ``history_*[g]`` is recorded after generation ``g`` (``g = 0`` is the initial population);
    ``history_best`` is the running best and never increases, ``history_mean`` is the mean of
    the finite fitness values of the current population (``inf`` if there are none).
    ``wall_time`` is the time spent running, ``compile_time`` the time spent compiling the
    initialisation and the generation step (both in seconds). ``final_state`` is the strategy's
    last :class:`State` (for PSO with velocities and personal bests), e.g. to continue a run.
    ``generations`` is the number run: fewer than asked when the population converged first
    (``tol`` of :func:`run`).
    """

    best_x: Float[Array, " d"]
    best_fitness: Float[Array, ""]
    history_best: Float[Array, " G1"]
    history_mean: Float[Array, " G1"]
    history_best_x: Float[Array, "G1 d"]
    final_population: Float[Array, "P d"]
    final_fitness: Float[Array, " P"]
    n_evaluations: int
    generations: int
    wall_time: float
    compile_time: float
    method: str
    settings: dict[str, Any]
    final_state: State


def _summary(state: State) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, " d"]]:
    finite = jnp.isfinite(state.fitness)
    count = jnp.sum(finite)
    total = jnp.sum(jnp.where(finite, state.fitness, 0.0))
    mean = jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.inf)
    return state.best_fitness, mean, state.best_x


def _ask_first(strategy, key, dim, init_population):
    return gathered(strategy.initialize(key, dim, init_population))


def _tell_first(strategy, population, fitness):
    state = gathered(strategy.start(population, sanitize_fitness(fitness)))
    return state, _summary(state)


def _ask(strategy, state, key):
    return gathered(strategy.ask(state, key))


def _tell(strategy, state, candidates, fitness):
    state = gathered(strategy.tell(state, candidates, sanitize_fitness(fitness)))
    return state, _summary(state)


def _evaluate_program(fitness_fn, population):
    return gathered(evaluate(fitness_fn, population))


class StrategyError(ValueError):
    """A strategy's method raised, or returned what the search cannot use; the one-line
    message names the strategy's class, the method and what it returned."""


def _strategy_label(strategy: AbstractStrategy) -> str:
    return f"{type(strategy).__name__} ({strategy.name!r})"


def _traced(strategy: AbstractStrategy, method: str, lower: Callable[[], Any]) -> Any:
    """``lower()``, which traces ``strategy``'s ``method``: an exception from it (often in
    JAX's words) is a :class:`StrategyError` that names the strategy and the method first."""
    try:
        return lower()
    except StrategyError:
        raise
    except Exception as exc:
        raise StrategyError(f"strategy {_strategy_label(strategy)}: {method} raised "
                            f"{raised(exc)}") from exc


def _said(value: Any) -> str:
    """An array as ``shape (7, 3), float64``; anything else by its type."""
    if hasattr(value, "shape") and hasattr(value, "dtype"):
        return f"an array of shape {tuple(value.shape)}, {np.dtype(value.dtype)}"
    return type(value).__name__


def _expect(strategy: AbstractStrategy, method: str, what: str, value: Any,
            shape: tuple[int, ...]) -> None:
    """Refuse ``value`` unless it is a real floating array of ``shape``."""
    if (hasattr(value, "shape") and tuple(value.shape) == shape
            and np.issubdtype(np.dtype(value.dtype), np.floating)):
        return
    raise StrategyError(f"strategy {_strategy_label(strategy)}: {method} returned {what} as "
                        f"{_said(value)}; expected real values of shape {shape} (population "
                        f"{strategy.population} in {shape[-1]} dimensions)")


def _expect_state(strategy: AbstractStrategy, method: str, state: Any, dim: int,
                  like: State | None = None) -> None:
    """Refuse a state that is not a :class:`State` of the population's shapes (or, given
    ``like``, not of the same structure and shapes: the next ask is compiled for those)."""
    if not isinstance(state, State):
        raise StrategyError(f"strategy {_strategy_label(strategy)}: {method} returned "
                            f"{_said(state)} as its state; expected a State")
    size = strategy.population
    _expect(strategy, method, "the state's population", state.population, (size, dim))
    _expect(strategy, method, "the state's fitness", state.fitness, (size,))
    _expect(strategy, method, "the state's best_x", state.best_x, (dim,))
    if like is not None:
        shapes = jax.tree.map(lambda x: (tuple(x.shape), np.dtype(x.dtype)), (like, state))
        if shapes[0] != shapes[1]:
            raise StrategyError(f"strategy {_strategy_label(strategy)}: {method} returned a "
                                f"state unlike the one it was given ({type(state).__name__} "
                                f"of other fields or shapes); the next ask needs the same")


class _Programs(NamedTuple):
    """A run's compiled programs: the first population and its state, the strategy's ask and
    tell of every later generation, and the evaluation of a population, which all share."""

    ask_first: Callable
    tell_first: Callable
    ask: Callable
    tell: Callable
    evaluate: Callable


def _compile(strategy, keys, dim, fitness_fn, init_population) -> _Programs:
    """The programs of a run, compiled before it starts.

    The fitness (the whole simulator) is compiled once, as a program of its own: the first
    generation and the step only propose populations and select from their fitness, so they
    compile in a fraction of the time (evaluating inside each would compile the simulator
    twice per run, and once more for every strategy on the same objective). Later programs are
    lowered for the arrays the earlier ones return, in the layout
    :func:`~jaxflex.parallel.gathered` gives them.
    """
    sharding = gathered_sharding()

    def like(lowered):  # small placeholders (filter_jit lowers for arrays, not shapes)
        shapes = lowered.postprocess(lowered.lowered.out_info)  # without tracing again
        return jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype, device=sharding), shapes)

    size = (strategy.population, dim)
    ask_first = _traced(strategy, "initialize", lambda: eqx.filter_jit(_ask_first).lower(
        strategy, keys[0], dim, init_population))
    population = like(ask_first)
    _expect(strategy, "initialize", "the first population", population, size)
    evaluate_population = eqx.filter_jit(_evaluate_program).lower(fitness_fn, population)
    fitness = like(evaluate_population)
    tell_first = _traced(strategy, "start", lambda: eqx.filter_jit(_tell_first).lower(
        strategy, population, fitness))
    state, _ = like(tell_first)
    _expect_state(strategy, "start", state, dim)
    ask = _traced(strategy, "ask", lambda: eqx.filter_jit(_ask).lower(strategy, state, keys[1]))
    asked = like(ask)
    if not (isinstance(asked, tuple) and len(asked) == 2):
        raise StrategyError(f"strategy {_strategy_label(strategy)}: ask returned "
                            f"{_said(asked)}; expected (candidates, state)")
    candidates, asked_state = asked
    _expect(strategy, "ask", "the candidates", candidates, size)
    _expect_state(strategy, "ask", asked_state, dim)
    tell = _traced(strategy, "tell", lambda: eqx.filter_jit(_tell).lower(
        strategy, asked_state, candidates, fitness))
    _expect_state(strategy, "tell", like(tell)[0], dim, like=state)
    lowered = (ask_first, tell_first, ask, tell, evaluate_population)
    return _Programs(*(program.compile() for program in lowered))


def _converged(fitness: Float[Array, " P"], tol: float) -> bool:
    """Whether a population's costs agree to ``tol``: all finite, spread ≤ tol·|mean|."""
    costs = np.asarray(fitness)
    return bool(np.all(np.isfinite(costs)) and np.std(costs) <= tol * abs(np.mean(costs)))


def _check_init_population(init_population: ArrayLike, population: int, dim: int) -> np.ndarray:
    seeds = np.asarray(init_population, dtype=float)
    if seeds.ndim == 1 and seeds.shape[0] == dim:
        seeds = seeds[None, :]
    if seeds.ndim != 2 or seeds.shape[1] != dim or not 1 <= seeds.shape[0] <= population:
        raise ValueError(
            f"init_population must have shape (k, {dim}) with 1 <= k <= population={population}, "
            f"got {seeds.shape}"
        )
    return into_unit_box(seeds, "init_population")


def run(
    strategy: AbstractStrategy,
    fitness_fn: FitnessFn,
    dim: int,
    *,
    key: PRNGKeyArray | None = None,
    seed: int | None = None,
    generations: int | None = None,
    init_population: Float[ArrayLike, "k d"] | None = None,
    progress: bool = False,
    callback: Callable[[int, State], None] | None = None,
    tol: float | None = None,
) -> EvolutionResult:
    """Minimise ``fitness_fn`` over ``[0, 1]^dim`` for ``generations`` generations (default:
    the strategy's own).

    Pass exactly one of ``key`` (a JAX PRNG key) and ``seed`` (an int); the same key gives a
    bitwise identical result. ``init_population`` (``k ≤ P`` rows in the unit box, or one point
    of shape ``(dim,)``) seeds the first ``k`` members, the rest is uniform random.
    ``fitness_fn`` is called once per generation on the full population, so the run costs
    ``P (generations + 1)`` evaluations. ``callback(g, state)`` is called after every generation
    ``g = 1..generations``; ``progress`` reports the generations on stderr (a bar on a terminal
    or in Jupyter, else a line when the search ends). With ``tol``, the run stops early once the
    population has converged: its costs all finite and their standard deviation at most ``tol``
    times the magnitude of their mean (the test of SciPy's ``differential_evolution``); each
    generation then waits for its costs before the next.
    """
    owner = "run"
    generations = strategy.generations if generations is None else generations
    check_integer(owner, "dim", dim, 1)
    check_integer(owner, "generations", generations, 1)
    if tol is not None and not (isinstance(tol, (int, float)) and 0 < tol < float("inf")):
        raise ValueError(f"run: tol must be a positive number or None, got {tol!r}")
    if (key is None) == (seed is None):
        raise ValueError("run: pass exactly one of key= (a PRNG key) or seed= (an int)")
    if seed is not None:
        check_integer(owner, "seed", seed, 0)
        key = jax.random.key(seed)
    if init_population is not None:
        init_population = jnp.asarray(
            _check_init_population(init_population, strategy.population, dim)
        )
    strategy = strategy.for_generations(generations)
    keys = jax.random.split(key, generations + 1)

    start = time.perf_counter()
    programs = _compile(strategy, keys, dim, fitness_fn, init_population)
    compiled = time.perf_counter()
    population = programs.ask_first(strategy, keys[0], dim, init_population)
    if not bool(jnp.all(jnp.isfinite(population))):
        raise StrategyError(f"strategy {_strategy_label(strategy)}: initialize returned a "
                            "first population with NaN or infinite values")
    fitness = programs.evaluate(fitness_fn, population)
    state, summary = programs.tell_first(strategy, population, fitness)

    summaries = [summary]
    bar = Progress(range(1, generations + 1), label=strategy.name, enabled=progress)
    for g in bar:
        candidates, state = programs.ask(strategy, state, keys[g])
        fitness = programs.evaluate(fitness_fn, candidates)
        state, summary = programs.tell(strategy, state, candidates, fitness)
        summaries.append(summary)
        if progress:
            bar.set_message(f"best {float(summary[0]):.3e}")
        if callback is not None:
            callback(g, state)
        if tol is not None and _converged(state.fitness, tol):
            break
    generations_run = len(summaries) - 1
    best, mean, best_x = (jnp.stack(column) for column in zip(*summaries, strict=True))
    jax.block_until_ready((state, best, mean, best_x))
    wall_time = time.perf_counter() - compiled

    return EvolutionResult(
        best_x=state.best_x,
        best_fitness=state.best_fitness,
        history_best=best,
        history_mean=mean,
        history_best_x=best_x,
        final_population=state.population,
        final_fitness=state.fitness,
        n_evaluations=strategy.population * (generations_run + 1),
        generations=generations_run,
        wall_time=wall_time,
        compile_time=compiled - start,
        method=strategy.name,
        settings=strategy.settings(),
        final_state=state,
    )
