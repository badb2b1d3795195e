"""jaxflex: identify flexible-link manipulators by differentiable simulation.

Importing jaxflex switches JAX to float64: structural dynamics with stiff FEM modes needs it.
"""

import jax

jax.config.update("jax_enable_x64", True)

from jaxflex.parameters import (  # noqa: E402
    BASE_PARAMETERS,
    ParameterSpace,
    ParameterSpec,
    base_space,
    reference_parameters,
)
from jaxflex.testbed import Testbed  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "BASE_PARAMETERS",
    "ParameterSpace",
    "ParameterSpec",
    "Testbed",
    "base_space",
    "reference_parameters",
]
