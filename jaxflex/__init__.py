"""jaxflex: identify flexible-link manipulators by differentiable simulation.

Importing jaxflex switches JAX to float64 (structural dynamics with stiff FEM modes needs it),
exposes one JAX CPU device per usable core so that populations run on all of them (see
:mod:`jaxflex.parallel`; ``JAXFLEX_HOST_DEVICES=1`` turns it off) and, unless ``XLA_FLAGS``
already says otherwise, turns off XLA's multi-threaded Eigen on the CPU, whose thread pool can
wedge on vmapped programs on small machines, and XLA's rewriting of large reductions into
library kernels (YNNPACK), which sum in another order than XLA's own loops and are chosen by
array size: with them a candidate's cost would depend on how many candidates share its device,
so on the number of host devices.
"""

import os

for _flag, _value in (
    ("xla_cpu_multi_thread_eigen", "false"),
    ("xla_disable_hlo_passes", "dot-library-rewriter"),
):
    if _flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --{_flag}={_value}".strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from jaxflex.parallel import configure_host_devices  # noqa: E402

configure_host_devices()

from jaxflex import datasets  # noqa: E402
from jaxflex.arm import ArmError, arm_to_toml, load_arm  # noqa: E402
from jaxflex.comparison import Comparison, compare, fit_and_validate, noise_floor  # noqa: E402
from jaxflex.data import Dataset, Record, load_dataset, load_record, save_record  # noqa: E402
from jaxflex.design import DesignResult, design_input, predicted_intervals  # noqa: E402
from jaxflex.diagnosis import Diagnosis, diagnose  # noqa: E402
from jaxflex.discovery import (  # noqa: E402
    DiscoveryReport,
    add_effect,
    discover,
    load_example,
    refit,
    score_tests,
)
from jaxflex.drives import (  # noqa: E402
    DRIVES,
    CommandDrive,
    CurrentDrive,
    Drive,
    TorqueDrive,
    VoltageDrive,
)
from jaxflex.effects import EFFECTS, Effect, get_effect, library  # noqa: E402
from jaxflex.frequency_response import frf, mode_shapes, natural_frequencies  # noqa: E402
from jaxflex.identification import Fit, identify, load_fit  # noqa: E402
from jaxflex.model import Model  # noqa: E402
from jaxflex.parameters import (  # noqa: E402
    BASE_PARAMETERS,
    ParameterSpace,
    ParameterSpec,
    base_space,
    reference_parameters,
)
from jaxflex.rigid import RigidEstimate, estimate_rigid, warm_start  # noqa: E402
from jaxflex.signals import reference_input  # noqa: E402
from jaxflex.simulation import Outputs, simulate, simulate_batch  # noqa: E402
from jaxflex.synthetic import make_records  # noqa: E402
from jaxflex.testbed import Testbed  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "BASE_PARAMETERS",
    "DRIVES",
    "EFFECTS",
    "ArmError",
    "CommandDrive",
    "Comparison",
    "CurrentDrive",
    "Dataset",
    "DesignResult",
    "Diagnosis",
    "DiscoveryReport",
    "Drive",
    "Effect",
    "Fit",
    "Model",
    "Outputs",
    "ParameterSpace",
    "ParameterSpec",
    "Record",
    "RigidEstimate",
    "Testbed",
    "TorqueDrive",
    "VoltageDrive",
    "add_effect",
    "arm_to_toml",
    "base_space",
    "compare",
    "datasets",
    "design_input",
    "diagnose",
    "discover",
    "estimate_rigid",
    "fit_and_validate",
    "frf",
    "get_effect",
    "identify",
    "library",
    "load_arm",
    "load_dataset",
    "load_example",
    "load_fit",
    "load_record",
    "make_records",
    "mode_shapes",
    "natural_frequencies",
    "noise_floor",
    "predicted_intervals",
    "reference_input",
    "reference_parameters",
    "refit",
    "save_record",
    "score_tests",
    "simulate",
    "simulate_batch",
    "warm_start",
]
