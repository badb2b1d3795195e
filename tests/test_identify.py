"""Identification: evolutionary search + Levenberg–Marquardt refinement + honest intervals.

Budgets are reduced (a box of ±50 % around the truth, small populations) so the default suite
stays fast; the paper-setting run over the full box is marked slow. All tests that fit the
three 2 s reference records share the same search bounds, so they share compiled code
(compilation, not running, is what these tests mostly pay for).
"""

import json
import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize as so

import jaxflex  # noqa: F401  (float64)
from jaxflex._io import OutputExistsError
from jaxflex.data import RecordError
from jaxflex.effects import AbstractEffect
from jaxflex.evolve import get_strategy
from jaxflex.identification import Fit, identify, load_fit
from jaxflex.model import Model
from jaxflex.objective import build_objective
from jaxflex.parameters import ParameterSpec
from jaxflex.refine import bounded_least_squares, bounded_least_squares_of, refine, uncertainty
from jaxflex.synthetic import make_records

TRUTH = {k: float(v) for k, v in Model().space.reference().items()}
BOUNDS = {k: (v / 1.5, v * 1.5) for k, v in TRUTH.items()}
FACTORS = (1.04, 0.96, 1.2, 0.97, 1.1, 0.9)
START = {k: v * f for (k, v), f in zip(TRUTH.items(), FACTORS, strict=True)}


@pytest.fixture(scope="module")
def clean():
    return make_records(noise=False)


def test_noise_free_identification(clean, tmp_path):
    """DE + refinement on noise-free records: recovery, record keeping, JSON, figures.

    One test, because the identification (search, refinement, intervals) is what costs.
    """
    fit = identify(clean, method="de", seed=0, generations=12, population=20, bounds=BOUNDS)

    # every parameter recovered within 0.5 %, or honestly reported as poorly identifiable
    for name, true in TRUTH.items():
        error = abs(fit.params[name] / true - 1)
        assert error < 0.005 or name in fit.poorly_identifiable, (name, error)
        if name in fit.poorly_identifiable:
            lo, hi = fit.intervals[name]
            assert hi / lo > 2.0 and lo <= true <= hi
    # noise-free: refinement drives the residual far below the search result
    assert fit.refinement.accepted and fit.refinement.result == "successful"
    assert fit.cost < 1e-10 < fit.cost_search

    # how it was found
    assert fit.names == tuple(TRUTH) and fit.method == "de" and fit.seed == 0
    assert fit.record_names == ("triangular", "pulse", "half_sine")
    best = fit.history.best
    assert best.shape == (13,) and np.all(np.diff(best) <= 0)  # running best never rises
    assert np.all(fit.history.mean >= best)
    assert fit.history.best_params["E"].shape == (13,)
    assert fit.settings["strategy"]["population"] == 20 and fit.settings["n_evaluations"] == 260
    assert fit.settings["bounds"]["J_h"] == pytest.approx(list(BOUNDS["J_h"]))
    assert {"search", "search_compile", "refine", "uncertainty", "total"} <= set(fit.timing)
    assert fit.provenance["versions"]["jax"]
    assert fit.model == Model() and fit.search == get_strategy("de", population=20, generations=12)
    assert "E" in fit.summary() and "refinement: successful" in fit.summary()

    # JSON round trip, no silent overwrite
    path = tmp_path / "fit.json"
    fit.to_json(path)
    with pytest.raises(OutputExistsError):
        fit.to_json(path)
    loaded = load_fit(path)
    assert isinstance(loaded, Fit)
    assert loaded.params == fit.params and loaded.intervals == fit.intervals
    np.testing.assert_array_equal(loaded.correlation, fit.correlation)
    np.testing.assert_array_equal(loaded.history.best, fit.history.best)
    assert loaded.refinement == fit.refinement
    np.testing.assert_array_equal(
        loaded.identifiability["eigenvectors"], fit.identifiability["eigenvectors"]
    )
    assert loaded.settings == json.loads(json.dumps(fit.to_dict()["settings"]))
    assert loaded.model == fit.model and loaded.search == fit.search
    (tmp_path / "bad.json").write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match="bad.json: not a jaxflex fit"):
        load_fit(tmp_path / "bad.json")

    # figures
    from jaxflex.plots._style import save_figure
    from jaxflex.plots.identify import plot_convergence, plot_fit

    figure = plot_fit(fit, TRUTH)
    assert len(figure.axes) == 2 and "generation" in figure.axes[0].get_xlabel()
    labels = [t.get_text() for t in figure.axes[1].get_yticklabels()]
    assert [t.split("\n")[0] for t in labels] == list(TRUTH)  # name, then its spread
    assert save_figure(figure, tmp_path / "fit.png").stat().st_size > 1000
    curves = plot_convergence({"de": [fit.history.best, fit.history.best[::-1]]})
    assert curves.axes[0].get_yscale() == "log"


def test_same_seed_same_run_different_seed_different_run(clean):
    kwargs = dict(generations=3, population=20, bounds=BOUNDS, refine=False, intervals=False)
    a = identify(clean, seed=5, **kwargs)
    b = identify(clean, seed=5, **kwargs)
    c = identify(clean, seed=6, **kwargs)
    assert a.params == b.params
    np.testing.assert_array_equal(a.history.best, b.history.best)
    assert a.params != c.params
    assert not np.array_equal(a.history.mean, c.history.mean)
    assert a.refinement is None and a.intervals == {} and a.cost == a.cost_search


def test_init_population_seeds_the_search(clean):
    fit = identify(
        clean, seed=1, generations=1, population=20, bounds=BOUNDS, refine=False,
        intervals=False, init_population=TRUTH,
    )
    assert fit.history.best[0] < 1e-10  # the seeded truth is the best of the first generation


# ------------------------------------------------------------------------------ intervals


def _coverage(seeds):
    """Refine from START on noisy records of each seed; interval hits and the costs."""
    hits, z_scores = [], []
    for seed in seeds:
        objective = build_objective(make_records(noise=True, seed=seed), bounds=BOUNDS)
        result = refine(objective, START)
        assert result.accepted and result.cost < result.cost_start
        again = refine(objective, result.params)  # already optimal: never made worse
        assert again.cost <= again.cost_start and again.cost <= result.cost * (1 + 1e-9)
        assert again.accepted == (again.cost_end < again.cost_start)
        unc = uncertainty(objective, result.params)
        # inside the box, the refinement's own Jacobian (unit box, its last step) gives the
        # same intervals
        assert all(lo < result.params[n] < hi for n, (lo, hi) in BOUNDS.items())
        reused = uncertainty(objective, result.params, linearization=result.linearization)
        for a, b in ((unc.std, reused.std), (unc.lower, reused.lower), (unc.upper, reused.upper)):
            np.testing.assert_allclose(b, a, rtol=1e-8, atol=0)
        hits.append(list(unc.contains(TRUTH).values()))
        std_log = np.log(unc.upper / unc.lower) / (2 * 1.959964)
        z_scores.append((np.log(unc.estimate) - np.log(list(TRUTH.values()))) / std_log)
        assert unc.poorly_identifiable == () and unc.unidentifiable == ()
        # the right model: the robust (HAC) intervals agree with the nominal ones, so they are
        # not labelled conditional on the model
        widening = np.array(list(unc.residual_checks["widening"].values()))
        assert np.all((0.8 < widening) & (widening < 1.25)), widening
        assert not unc.model_conditional
        # the per-channel noise estimates find the spec's sensors
        assert unc.noise["tip_acceleration"] == pytest.approx(0.05, rel=0.1)
        encoder_rms = 2 * math.pi / 4096 / math.sqrt(12)  # uniform quantisation error
        assert unc.noise["joint_angle"] == pytest.approx(encoder_rms, rel=0.2)
    return np.asarray(hits), np.asarray(z_scores)


def test_intervals_contain_the_truth_at_about_the_stated_rate():
    hits, z = _coverage(range(4))
    assert hits.mean() >= 0.7, hits
    # neither overconfident nor uselessly wide: the spread of the errors matches the stds
    assert 0.15 < np.mean(z**2) < 2.5, z


def test_a_refinement_ended_on_a_bound_gives_the_intervals_a_fresh_jacobian_gives(monkeypatch):
    """The true E lies above the box: the refinement ends on E's upper bound, and its last
    linearisation (the box map without its clip) is the Jacobian the intervals compute."""
    import jaxflex.intervals

    bounds = BOUNDS | {"E": (TRUTH["E"] / 1.5, TRUTH["E"] / 1.1)}
    objective = build_objective(make_records(noise=True, seed=3), bounds=bounds)
    result = refine(objective, START | {"E": TRUTH["E"] / 1.2})
    assert result.accepted and result.params["E"] == pytest.approx(TRUTH["E"] / 1.1, rel=1e-12)
    fresh = uncertainty(objective, result.params)
    monkeypatch.setattr(jaxflex.intervals, "_jacobian_jit", None)  # reused, not evaluated
    reused = uncertainty(objective, result.params, linearization=result.linearization)
    for a, b in ((fresh.std, reused.std), (fresh.lower, reused.lower)):
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=0)


@pytest.mark.slow
def test_interval_coverage_over_ten_noise_seeds():
    hits, z = _coverage(range(10, 20))
    assert hits.mean() >= 0.85, hits.mean(axis=0)
    assert hits.mean(axis=0).min() >= 0.6, hits.mean(axis=0)
    assert 0.3 < np.mean(z**2) < 2.0


def test_encoder_only_data_cannot_pin_the_stiffness_damping():
    """Without the accelerometer, beta is reported as poorly identifiable — and it is."""
    records = make_records(noise=True, seed=3, duration=1.0)
    objective = build_objective(records, weights={"tip_acceleration": 0.0}, bounds=BOUNDS)
    result = refine(objective, START, max_steps=30)
    assert result.accepted
    unc = uncertainty(objective, result.params)
    assert "beta" in unc.poorly_identifiable
    assert unc.unidentifiable == ("beta",)  # its interval spans six decades
    assert any("beta is not identifiable from these records" in w for w in unc.warnings)
    assert any("beta" in w and "direction" in w for w in unc.warnings)
    lo, hi = unc.intervals["beta"]
    assert hi / lo > 10 and lo <= TRUTH["beta"] <= hi
    assert "J_h" not in unc.poorly_identifiable and "tau_c" not in unc.poorly_identifiable

    # It is true: moving beta by 40 % along the reported direction changes the fit by less
    # than the noise can resolve (chi-square change below the 95 % threshold 3.84), while a
    # 1 % change of J_h changes it by orders of magnitude more.
    cost_jit = eqx.filter_jit(lambda o, p: o.cost(p))  # the values traced: compiled once

    def cost(y):
        return float(cost_jit(objective, dict(zip(objective.names, y, strict=True))))

    x = np.array([result.params[n] for n in objective.names])
    base = cost(x)
    per_sample = base / objective.size  # noise variance of one normalised residual

    def delta_chi2(y):
        return (cost(y) - base) / per_sample

    direction = unc.eigenvectors[:, 0]  # the weakest direction, in log-parameters
    beta = objective.names.index("beta")
    assert abs(direction[beta]) > 0.9
    moved = x * np.exp(np.log(1.4) / direction[beta] * direction)
    assert moved[beta] == pytest.approx(1.4 * x[beta])
    assert delta_chi2(moved) < 3.84
    j_h = objective.names.index("J_h")
    assert delta_chi2(np.where(np.arange(x.size) == j_h, 1.01 * x, x)) > 1e3


@pytest.mark.slow
def test_paper_setting_de_over_the_full_box_recovers_the_truth(clean):
    fit = identify(clean, method="de", seed=0, generations=100)
    for name, true in TRUTH.items():
        assert abs(fit.params[name] / true - 1) < 0.005 or name in fit.poorly_identifiable
    assert fit.cost <= fit.cost_search


# ------------------------------------------------------------------------ the refinement engine


def _linear(p, args):
    a, b = args
    return a @ p - b


def _decay(p, t):
    return p[0] * jnp.exp(-p[1] * t) + p[2] - jnp.exp(-3.0 * t) * (1 + 0.1 * jnp.sin(7 * t))


def test_bounded_least_squares_solves_box_problems_as_scipy_does():
    """Against SciPy's bounded solvers: a linear problem with active bounds (BVLS; also with
    the Jacobian computed on the host), the same with one parameter held at its start, and a
    nonlinear decay fit whose rate ends on its upper bound (trust-region reflective). The
    costs agree to round-off; the parameters to about √ε of their scale, as far as a cost at
    round-off resolves them."""
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(40, 5)), 3.0 * rng.normal(size=40)
    lower, upper = -0.2 * np.ones(5), 0.3 * np.ones(5)
    start = np.zeros(5)
    tight = dict(rtol=1e-12, atol=1e-14, max_steps=100)
    fit = bounded_least_squares(_linear, (jnp.asarray(a), jnp.asarray(b)), start, lower, upper,
                                **tight)
    ref = so.lsq_linear(a, b, (lower, upper), method="bvls", tol=1e-14)
    assert np.sum(ref.active_mask != 0) >= 2  # the bounds matter
    assert fit.result == "successful" and fit.steps < 100
    np.testing.assert_allclose(fit.value, ref.x, rtol=0, atol=1e-7)
    assert fit.cost == pytest.approx(2 * ref.cost, rel=1e-12)
    assert fit.cost_start == pytest.approx(float(b @ b), rel=1e-14)
    # the same solve with the residuals and Jacobian computed on the host (discovery's way)
    host = bounded_least_squares_of(lambda p: (a @ p - b, a), 40, start, lower, upper, **tight)
    np.testing.assert_allclose(host.value, fit.value, rtol=0, atol=1e-12)
    assert host.cost == pytest.approx(fit.cost, rel=1e-14)

    free = np.array([True, True, False, True, True])
    start[2] = 0.25
    held = bounded_least_squares(_linear, (jnp.asarray(a), jnp.asarray(b)), start, lower, upper,
                                 free=free, **tight)
    ref = so.lsq_linear(a[:, free], b - 0.25 * a[:, 2], (lower[free], upper[free]),
                        method="bvls", tol=1e-14)
    assert held.value[2] == 0.25
    np.testing.assert_allclose(held.value[free], ref.x, rtol=0, atol=1e-7)
    assert held.cost == pytest.approx(2 * ref.cost, rel=1e-12)

    t = jnp.linspace(0.0, 2.0, 60)
    lower, upper = np.array([0.1, 0.5, -1.0]), np.array([5.0, 2.5, 1.0])
    fit = bounded_least_squares(_decay, t, np.array([1.0, 1.0, 0.0]), lower, upper, **tight)
    ref = so.least_squares(lambda p: np.asarray(_decay(jnp.asarray(p), t)), [1.0, 1.0, 0.0],
                           bounds=(lower, upper), method="trf", xtol=1e-15, ftol=1e-15,
                           gtol=1e-15)
    assert fit.value[1] == 2.5 and ref.x[1] == pytest.approx(2.5, abs=1e-9)  # on the bound
    np.testing.assert_allclose(fit.value, ref.x, rtol=0, atol=1e-7)
    assert fit.cost <= 2 * ref.cost * (1 + 1e-9)


# ------------------------------------------------------------------------------ bad input



ONE_CORE_SOLVE = """
import json, sys
import jax, jax.numpy as jnp, numpy as np
from jaxflex.refine import bounded_least_squares_of

t = jnp.linspace(0.0, 2.0, 60)

def decay(p):  # the fit's model, stepped in time as a simulator is (a loop in the program)
    step = jnp.exp(-p[1] * (t[1] - t[0]))
    def advance(y, _):
        return y * step, y
    _, y = jax.lax.scan(advance, p[0], None, length=t.shape[0])
    return y + p[2] - jnp.exp(-3.0 * t) * (1 + 0.1 * jnp.sin(7 * t))

@jax.jit
def system(p):  # compiled code, called between the solve's compiled steps
    return decay(p), jax.jacfwd(decay)(p)

fit = bounded_least_squares_of(system, 60, np.array([1.0, 1.0, 0.0]), np.array([0.1, 0.5, -1.0]),
                               np.array([5.0, 2.5, 1.0]), rtol=1e-12, atol=1e-14, max_steps=100)
print(json.dumps({"value": fit.value.tolist(), "cost": fit.cost}))
"""


def test_on_one_core_a_host_stepped_solve_ends_where_it_ends_on_several():
    """On a single usable core XLA's CPU runtime has one worker: a compiled solve that called
    the system back held it while the system's compiled code waited for it (discovery's refit
    of the 2 s example record hung there). Stepped from the host, the solve ends on one core
    where it ends on several."""
    import os
    import subprocess
    import sys

    runs = {}
    for cores in ({0}, os.sched_getaffinity(0)):
        done = subprocess.run(
            [sys.executable, "-c", ONE_CORE_SOLVE], capture_output=True, text=True, timeout=120,
            preexec_fn=lambda cores=cores: os.sched_setaffinity(0, cores),
        )
        assert done.returncode == 0, done.stderr[-2000:]
        runs[len(cores)] = json.loads(done.stdout.strip().splitlines()[-1])
    one, several = runs[1], runs[max(runs)]
    assert max(runs) > 1  # the machine has more than one core to compare with
    np.testing.assert_allclose(one["value"], several["value"], rtol=0, atol=1e-9)
    assert one["cost"] == pytest.approx(several["cost"], rel=1e-12)


def test_bad_input_gets_a_clear_error(clean):
    with pytest.raises(ValueError, match="bounds for J_h: lower bound 0.1 must be below upper"):
        identify(clean, bounds={"J_h": (0.1, 0.01)})
    pulse = clean["pulse"]
    with pytest.raises(RecordError, match="different sampling intervals"):
        identify([pulse, pulse.replace(time=0.5 * pulse.time, name="fast")])
    with pytest.raises(ValueError, match="DE: population must be an integer >= 4"):
        identify(clean, method="de", population=3)
    with pytest.raises(ValueError, match="GA: population must be an integer >= 2"):
        identify(clean, method="ga", population=1)
    with pytest.raises(ValueError, match="PSO: population must be an integer >= 2"):
        identify(clean, method="pso", population=1)
    with pytest.raises(ValueError, match="unknown method 'cmaes'; choose one of de, ga, pso"):
        identify(clean, method="cmaes")
    with pytest.raises(ValueError, match="generations must be an integer >= 1"):
        identify(clean, generations=0, population=20)
    with pytest.raises(ValueError, match="seed must be an integer >= 0"):
        identify(clean, seed=-1, population=20)
    with pytest.raises(ValueError, match="init_population: E=1.0 lies outside its search bounds"):
        identify(clean, init_population={**TRUTH, "E": 1.0})
    with pytest.raises(ValueError, match="refine_starts"):
        identify(clean, population=20, refine_starts=0)
    assert get_strategy("de").population == 100  # the paper's preset is the default


# ------------------------------------------------------------------------------ study, CLI, figures


def _bound_options():
    return [f"--bound={k}={lo!r}:{hi!r}" for k, (lo, hi) in BOUNDS.items()]


def test_cli_identify_writes_the_fit_and_refuses_to_overwrite(clean, tmp_path, capsys):
    from jaxflex.cli import main
    from jaxflex.data import save_record

    paths = [str(save_record(r, tmp_path / f"{r.name}.csv")) for r in clean]
    out, figure = tmp_path / "fit.json", tmp_path / "fit.png"
    argv = ["identify", *paths, "--method", "pso", "--seed", "2", "--generations", "3",
            "--population", "20", "--no-refine", *_bound_options(), "--quiet", "--tol", "1e-12",
            "--out", str(out), "--plot", str(figure)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "PSO seed 2" in printed and f"wrote {out}" in printed
    fit = load_fit(out)
    assert fit.seed == 2 and fit.method == "pso" and fit.refinement is None
    assert fit.record_names == ("triangular", "pulse", "half_sine")
    assert fit.settings["generations"] == 3 and fit.settings["strategy"]["population"] == 20
    assert fit.settings["tol"] == 1e-12 and fit.settings["generations_run"] == 3  # not reached
    assert fit.settings["bounds"]["E"] == pytest.approx(list(BOUNDS["E"]))
    assert set(fit.intervals) == set(TRUTH)
    assert any("only indicative" in w for w in fit.warnings)
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(argv) == 2  # exists: refused, one clear line
    assert "file exists" in capsys.readouterr().err
    assert main(["identify", paths[0], "--bound", "E=5:1", "--out", str(tmp_path / "x.json")]) == 2
    assert "lower bound 5.0 must be below upper" in capsys.readouterr().err
    assert main(["identify", paths[0], "--population", "3", "--out", str(tmp_path / "y.json")]) == 2
    assert "population must be an integer >= 4" in capsys.readouterr().err
    assert main(["identify", paths[0], "--tol", "0", "--out", str(tmp_path / "z.json")]) == 2
    assert "--tol" in capsys.readouterr().err


def test_study_table_and_cli(clean, tmp_path, capsys):
    from jaxflex.cli import main
    from jaxflex.cli.study import parse_seeds
    from jaxflex.data import save_record
    from jaxflex.study import run_study

    assert parse_seeds("0-3,7") == [0, 1, 2, 3, 7]
    study = run_study(clean, methods=("de",), seeds=(0, 1), generations=2, population=20,
                      bounds=BOUNDS, refine=False)
    assert [r.seed for r in study.runs] == [0, 1] and study.methods == ("de",)
    assert study.runs[0].params != study.runs[1].params
    summary = study.summary()["de"]
    values = [r.params["E"] for r in study.runs]
    assert summary["E"]["mean"] == pytest.approx(np.mean(values))
    assert summary["E"]["std"] == pytest.approx(np.std(values, ddof=1))
    table = study.table(truth=TRUTH)
    assert "DE (2 seeds)" in table and "objective" in table and "wall time" in table

    paths = [str(save_record(r, tmp_path / f"{r.name}.csv")) for r in clean]
    out = tmp_path / "study.json"
    argv = ["study", *paths, "--methods", "de", "--seeds", "0-1", "--generations", "2",
            "--population", "20", "--no-refine", *_bound_options(), "--quiet",
            "--out", str(out), "--plot", str(tmp_path / "curves.png")]
    assert main(argv) == 0
    assert "DE (2 seeds)" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["format"] == "jaxflex-study/2" and len(data["runs"]) == 2
    assert data["runs"][0]["params"] == pytest.approx(study.runs[0].params)  # same seed, same run
    assert (tmp_path / "curves.png").stat().st_size > 1000


def test_a_search_object_is_the_method_shorthand_spelled_out(clean):
    """``search=DE(population=12, generations=3)`` is ``method="de", population=12,
    generations=3`` bit for bit; mixing the two ways is refused in one line."""
    from jaxflex.evolve import DE

    shorthand = identify(clean[:1], method="de", population=12, generations=3, seed=2,
                         refine=False, intervals=False)
    spelled = identify(clean[:1], search=DE.paper(population=12, generations=3), seed=2,
                       refine=False, intervals=False)
    assert spelled.params == shorthand.params
    assert spelled.method == "de" and spelled.settings["generations"] == 3
    with pytest.raises(ValueError, match="search= holds the whole search; drop population"):
        identify(clean[:1], search=DE(), population=12)
    with pytest.raises(TypeError, match="search must be a strategy .* got 'de' \\(str\\)"):
        identify(clean[:1], search="de")


def test_a_refinement_object_is_the_refine_shorthand_spelled_out(clean):
    """``refine=LevenbergMarquardt(starts=2)`` is ``refine=True, refine_starts=2`` bit for bit,
    and the fit records how it was refined."""
    from jaxflex.refine import LevenbergMarquardt

    kwargs = dict(method="de", population=8, generations=2, seed=1, bounds=BOUNDS,
                  intervals=False)
    shorthand = identify(clean[:1], refine=True, refine_starts=2, **kwargs)
    spelled = identify(clean[:1], refine=LevenbergMarquardt(starts=2), **kwargs)
    assert spelled.params == shorthand.params
    assert spelled.settings["refinement"] == {"method": "LevenbergMarquardt", "starts": 2,
                                              "rtol": 1e-6, "atol": 1e-8, "max_steps": 100}
    with pytest.raises(TypeError, match="refine must be True, False or a refinement"):
        identify(clean[:1], refine="lm", **kwargs)


class _Seizing(AbstractEffect):
    """A joint law of one's own with a fault: its friction is NaN at any speed."""

    name: ClassVar[str] = "seizing"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec("k_seize", "N m s/rad", 1e-3, 1e-1, 1e-2, "seizing coefficient"),
    )

    def friction(self, params, velocity, omega_s):
        return params["k_seize"] * velocity * jnp.log(-1.0 - jnp.abs(velocity))  # NaN


def test_a_fit_whose_every_simulation_is_nan_raises_instead_of_returning_a_fit():
    """Every candidate non-finite: no parameters at all, said at once, as the command line
    refuses it (not a Fit with cost inf and arbitrary values)."""
    from jaxflex.identification import FitError

    records = make_records(inputs=("pulse",), noise=False, duration=0.2)
    model = Model(effects=(_Seizing(),))
    with pytest.raises(FitError, match=r"^identify: the fit failed: no candidate of 16 gave a "
                                       r"finite simulation \(cost inf\), so there are no "
                                       r"parameters to return; check the effects \['seizing'\]"
                       ) as info:
        identify(records, model, generations=1, population=8, refine=False, intervals=False)
    assert info.value.cost == math.inf and isinstance(info.value, ValueError)


@pytest.mark.parametrize("command", ["identify", "study"])
def test_the_command_line_words_a_failed_fit_as_before(monkeypatch, tmp_path, capsys, command):
    from jaxflex import identification
    from jaxflex.cli import main
    from jaxflex.identification import FitError
    from jaxflex.synthetic import make_records as records_of

    def failed(*args, **kwargs):
        raise FitError("identify: the fit failed", math.inf)

    monkeypatch.setattr(identification, "identify", failed)
    monkeypatch.setattr("jaxflex.study.identify", failed)
    data = tmp_path / "pulse.csv"
    from jaxflex.data import save_record

    save_record(records_of(inputs=("pulse",), noise=False)[0], data)
    out = tmp_path / "out.json"
    assert main([command, str(data), "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().err == (
        f"jaxflex {command}: error: the fit failed: its cost is inf (the simulation diverged for "
        "every candidate); check the records and --effect; nothing was written\n")
    assert not out.exists()
