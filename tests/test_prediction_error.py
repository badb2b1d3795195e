"""Prediction-error identification: the Kalman filter's innovations as the fitted residuals."""

from __future__ import annotations

import numpy as np
import pytest
from test_kalman import SIGMA, _record

from jaxflex import Model, identify
from jaxflex.kalman import predict
from jaxflex.objective import build_objective
from jaxflex.prediction_error import noise_settings, prediction_objective
from jaxflex.testbed import Testbed


@pytest.mark.slow
def test_prediction_error_recovers_the_parameters_of_a_drifting_record():
    """A record of the model under a white torque disturbance drifts away from any free
    simulation; prediction error recovers the stiffness to 1 % and the hub inertia within
    three of its standard deviations, and the disturbance level by maximum likelihood."""
    model = Model(testbed=Testbed(n_elements=3))
    truth = model.space.reference()
    record = _record(model, truth, 600, 0.01, seed=4)
    held = {k: float(v) for k, v in truth.items() if k not in ("E", "J_h")}
    fit = identify(record, model, population=16, generations=6, seed=0, fixed=held,
                   criterion="prediction", noise=SIGMA)
    assert fit.settings["criterion"] == "prediction"
    assert fit.settings["disturbance"] == pytest.approx(0.01, rel=0.3)
    assert fit.params["E"] == pytest.approx(float(truth["E"]), rel=0.01)
    assert abs(fit.params["J_h"] - float(truth["J_h"])) < 3 * fit.std["J_h"] < 0.6 * fit.params[
        "J_h"]


def test_prediction_error_residuals_are_the_filters_innovations():
    """The objective's residuals are the filter's innovations (one-step predictions less the
    record) times the output-error scales; the noise levels given are the filter's."""
    model = Model(testbed=Testbed(n_elements=2))
    truth = model.space.reference()
    record = _record(model, truth, 120, 0.01, seed=5)
    objective = prediction_objective(build_objective(record, model), [record], truth,
                                     noise=SIGMA, disturbance=0.01)
    [run] = predict(record, model, truth, noise=SIGMA, disturbance=0.01)
    free = {n: truth[n] for n in objective.names}
    scale = np.asarray(objective.scale[0])[0][:, None]
    np.testing.assert_allclose(np.asarray(objective.residuals(free)),
                               (-scale * run.innovations).reshape(-1), rtol=1e-9, atol=1e-15)
    assert noise_settings(objective) == {"disturbance": 0.01, "measurement_noise": SIGMA}


def test_an_unknown_criterion_is_refused():
    model = Model(testbed=Testbed(n_elements=2))
    record = _record(model, model.space.reference(), 50, 0.0, seed=3)
    with pytest.raises(ValueError, match="unknown criterion 'innovation'; criteria: "):
        identify(record, model, criterion="innovation")
