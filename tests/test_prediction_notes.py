"""The filter never predicts worse than the simulation without saying why, and a noise-level
search that does not converge says so."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.optimize

from jaxflex import Model, make_records, reference_parameters
from jaxflex.kalman import Prediction, fit_noise
from jaxflex.prediction_report import PredictionComparison, prediction_notes, prediction_table

T = np.arange(200) * 1e-2
MEASURED = np.sin(2 * np.pi * T)


def _row(simulated_error: float, predicted_error: float, innovation: float,
         sigma: float, floor: float) -> PredictionComparison:
    """A record whose simulation and 0.5 s prediction miss a sine by the given amplitudes."""
    wobble = np.cos(7 * T)
    prediction = Prediction(
        name="run", channels=("acc",), measured=MEASURED[None], one_step=MEASURED[None],
        innovations=np.full((1, T.size), innovation), variance=np.ones((1, T.size)),
        predicted={0.5: (MEASURED + predicted_error * wobble)[None]}, sigma_y={"acc": sigma},
        disturbance=0.02, log_likelihood=0.0)
    return PredictionComparison(name="run", role="held-out", time=T,
                                simulated=(MEASURED + simulated_error * wobble)[None],
                                prediction=prediction, floors={"acc": floor})


def test_a_horizon_worse_than_the_simulation_is_said_with_the_innovations_against_the_noise():
    row = _row(simulated_error=0.1, predicted_error=0.3, innovation=0.6, sigma=0.2, floor=0.2)
    scores = row.scores()
    assert scores["0.5 s"]["acc"] == pytest.approx(3 * scores["simulation"]["acc"], rel=1e-12)
    note, = prediction_notes([row], {"acc": "m/s^2"})
    assert note.startswith(f"run acc: the prediction 0.5 s ahead ({scores['0.5 s']['acc']:.3g} "
                           f"%) is worse than the free simulation "
                           f"({scores['simulation']['acc']:.3g} %)")
    assert "innovations are 3x the noise it assumes (0.2 m/s^2, held at the sensor's own level)" \
        in note
    assert "σ_τ = 0.02 N m" in note
    assert "worse than the free simulation" in " ".join(prediction_table([row]).split())
    # a prediction that beats the simulation needs no word; nor is a level above its floor held
    assert prediction_notes([_row(0.3, 0.1, 0.6, 0.2, 0.2)]) == []
    assert "held at" not in prediction_notes([_row(0.1, 0.3, 0.6, 0.4, 0.2)])[0]


def test_a_noise_search_that_does_not_converge_says_where_it_ended(monkeypatch):
    record = make_records(inputs=("pulse",), seed=1)[0]
    model, params = Model(), reference_parameters()
    levels = {"joint_angle": 1e-3, "tip_acceleration": 0.05}
    channels = ["joint_angle", "tip_acceleration"]
    minimize = scipy.optimize.minimize

    def stopped(fun, x0, **kwargs):  # Nelder–Mead stopped after its first iterations
        result = minimize(fun, x0, **(kwargs | {"options": kwargs["options"] | {"maxiter": 3}}))
        assert not result.success
        return result

    monkeypatch.setattr(scipy.optimize, "minimize", stopped)
    with pytest.warns(UserWarning, match=r"^the noise levels' maximum-likelihood search did not "
                                          r"converge \(Maximum number of iterations has been "
                                          r"exceeded\.\); the filter uses where it ended: σ_τ "):
        found, tau = fit_noise([record], model, params, channels, levels, ["tip_acceleration"])
    assert found["tip_acceleration"] >= 0.05 and tau > 0
    monkeypatch.setattr(scipy.optimize, "minimize", minimize)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit_noise([record], model, params, channels, levels, ["tip_acceleration"])
