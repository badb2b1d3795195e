"""jaxflex: identify flexible-link manipulators by differentiable simulation.

Once jaxflex is imported, JAX is set up for it the moment JAX itself is imported (by jaxflex
or by anyone; at once if JAX was imported first): float64 (structural dynamics with stiff FEM
modes needs it) and one JAX CPU device per usable core so that populations run on all of them
(see :mod:`jaxflex.parallel`; ``JAXFLEX_HOST_DEVICES=1`` turns it off). Importing jaxflex also,
before JAX starts and unless ``XLA_FLAGS`` already says otherwise, turns off XLA's
multi-threaded Eigen on the CPU, whose thread pool can wedge on vmapped programs on small
machines, and XLA's rewriting of large reductions into library kernels (YNNPACK), which sum in
another order than XLA's own loops and are chosen by array size: with them a candidate's cost
would depend on how many candidates share its device, so on the number of host devices.

The names below are imported on first use (``jaxflex.identify`` imports
:mod:`jaxflex.identification`), so that ``import jaxflex`` alone, and the command line's
``--help``, do not load JAX.
"""

import os
import sys
from typing import TYPE_CHECKING

for _flag, _value in (
    ("xla_cpu_multi_thread_eigen", "false"),
    ("xla_disable_hlo_passes", "dot-library-rewriter"),
):
    if _flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --{_flag}={_value}".strip()


def _configure_jax() -> None:
    """float64 and the host devices; JAX must be imported, and nothing computed yet."""
    import jax

    jax.config.update("jax_enable_x64", True)

    from jaxflex._host import configure_host_devices

    configure_host_devices()


class _ConfigureJaxOnImport:
    """A meta-path finder that runs :func:`_configure_jax` right after ``jax`` is first
    imported, whoever imports it, then leaves ``sys.meta_path``."""

    def find_spec(self, name, path=None, target=None):
        if name != "jax" or self not in sys.meta_path:
            return None
        sys.meta_path.remove(self)
        from importlib.util import find_spec

        spec = find_spec(name)
        if spec is not None and spec.loader is not None:
            load = spec.loader.exec_module

            def exec_module(module) -> None:
                load(module)
                _configure_jax()

            spec.loader.exec_module = exec_module
        return spec


if "jax" in sys.modules:
    _configure_jax()
else:
    sys.meta_path.insert(0, _ConfigureJaxOnImport())

if TYPE_CHECKING:  # what static tools see; at run time __getattr__ imports each on first use
    from jaxflex import datasets
    from jaxflex.arm import ArmError, arm_to_toml, load_arm
    from jaxflex.comparison import Comparison, FRFSettings, compare, fit_and_validate, noise_floor
    from jaxflex.data import Dataset, Record, load_dataset, load_record, save_record
    from jaxflex.design import (
        DesignResult,
        compare_inputs,
        design_input,
        interval_table,
        paper_inputs,
        predicted_intervals,
    )
    from jaxflex.diagnosis import Diagnosis, diagnose
    from jaxflex.discovery import (
        DiscoveryReport,
        add_effect,
        discover,
        load_example,
        refit,
        score_tests,
    )
    from jaxflex.discovery.explain import explain
    from jaxflex.drives import (
        DRIVES,
        AbstractDrive,
        CommandDrive,
        CurrentDrive,
        TorqueDrive,
        VoltageDrive,
    )
    from jaxflex.effects import (
        EFFECTS,
        AbstractEffect,
        FormulaTorque,
        get_effect,
        library,
        register_effect,
    )
    from jaxflex.frequency_response import frf, mode_shapes, natural_frequencies
    from jaxflex.identification import Fit, identify, load_fit
    from jaxflex.intervals import uncertainty
    from jaxflex.measured import fit_noise, load_records, validate
    from jaxflex.metrics import nrmse
    from jaxflex.missing_torque import MissingTorque, estimate_missing_torque
    from jaxflex.model import Model
    from jaxflex.objective import build_objective, fitted_channels
    from jaxflex.parameters import (
        BASE_PARAMETERS,
        ParameterSpace,
        ParameterSpec,
        base_space,
        reference_parameters,
    )
    from jaxflex.prediction_report import compare_predictions, prediction_table
    from jaxflex.rigid import RigidEstimate, estimate_rigid, rigid_simulate, warm_start
    from jaxflex.signals import reference_input
    from jaxflex.simulation import Outputs, simulate, simulate_batch
    from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP, make_records
    from jaxflex.testbed import Testbed
    from jaxflex.torque_regression import TorqueMap, torque_map

_SOURCES: dict[str, tuple[str, ...]] = {
    "jaxflex.arm": ("ArmError", "arm_to_toml", "load_arm"),
    "jaxflex.comparison": (
        "Comparison", "FRFSettings", "compare", "fit_and_validate", "noise_floor",
    ),
    "jaxflex.data": ("Dataset", "Record", "load_dataset", "load_record", "save_record"),
    "jaxflex.design": (
        "DesignResult", "compare_inputs", "design_input", "interval_table", "paper_inputs",
        "predicted_intervals",
    ),
    "jaxflex.diagnosis": ("Diagnosis", "diagnose"),
    "jaxflex.discovery": (
        "DiscoveryReport", "add_effect", "discover", "load_example", "refit", "score_tests",
    ),
    "jaxflex.discovery.explain": ("explain",),
    "jaxflex.drives": (
        "DRIVES", "CommandDrive", "CurrentDrive", "AbstractDrive", "TorqueDrive", "VoltageDrive",
    ),
    "jaxflex.effects": (
        "EFFECTS", "AbstractEffect", "FormulaTorque", "get_effect", "library", "register_effect",
    ),
    "jaxflex.frequency_response": ("frf", "mode_shapes", "natural_frequencies"),
    "jaxflex.identification": ("Fit", "identify", "load_fit"),
    "jaxflex.intervals": ("uncertainty",),
    "jaxflex.measured": ("fit_noise", "load_records", "validate"),
    "jaxflex.metrics": ("nrmse",),
    "jaxflex.missing_torque": ("MissingTorque", "estimate_missing_torque"),
    "jaxflex.model": ("Model",),
    "jaxflex.objective": ("build_objective", "fitted_channels"),
    "jaxflex.parameters": (
        "BASE_PARAMETERS", "ParameterSpace", "ParameterSpec", "base_space",
        "reference_parameters",
    ),
    "jaxflex.prediction_report": ("compare_predictions", "prediction_table"),
    "jaxflex.rigid": ("RigidEstimate", "estimate_rigid", "rigid_simulate", "warm_start"),
    "jaxflex.signals": ("reference_input",),
    "jaxflex.simulation": ("Outputs", "simulate", "simulate_batch"),
    "jaxflex.synthetic": ("ACCELEROMETER_SIGMA", "ENCODER_STEP", "make_records"),
    "jaxflex.testbed": ("Testbed",),
    "jaxflex.torque_regression": ("TorqueMap", "torque_map"),
}
"""Where each top-level name is defined (the imports above, for the interpreter)."""
_MODULE_OF = {name: (module, name) for module, names in _SOURCES.items() for name in names}


def __getattr__(name: str):
    """A top-level name, imported from its module on first use (PEP 562); a submodule too
    (``jaxflex.data.load_dataset`` after ``import jaxflex``, as when every module was loaded)."""
    from jaxflex._lazy import lazy_attribute

    return lazy_attribute(__name__, name, _MODULE_OF, globals())


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__version__ = "0.1.0"

__all__ = [
    "ACCELEROMETER_SIGMA",
    "BASE_PARAMETERS",
    "DRIVES",
    "EFFECTS",
    "ENCODER_STEP",
    "AbstractDrive",
    "AbstractEffect",
    "ArmError",
    "CommandDrive",
    "Comparison",
    "CurrentDrive",
    "Dataset",
    "DesignResult",
    "Diagnosis",
    "DiscoveryReport",
    "FRFSettings",
    "FormulaTorque",
    "Fit",
    "MissingTorque",
    "Model",
    "Outputs",
    "ParameterSpace",
    "ParameterSpec",
    "Record",
    "RigidEstimate",
    "Testbed",
    "TorqueDrive",
    "TorqueMap",
    "VoltageDrive",
    "add_effect",
    "arm_to_toml",
    "base_space",
    "build_objective",
    "compare",
    "compare_inputs",
    "compare_predictions",
    "datasets",
    "design_input",
    "diagnose",
    "discover",
    "estimate_missing_torque",
    "estimate_rigid",
    "explain",
    "fit_and_validate",
    "fit_noise",
    "fitted_channels",
    "frf",
    "get_effect",
    "identify",
    "interval_table",
    "library",
    "load_arm",
    "load_dataset",
    "load_example",
    "load_fit",
    "load_record",
    "load_records",
    "make_records",
    "mode_shapes",
    "natural_frequencies",
    "noise_floor",
    "nrmse",
    "paper_inputs",
    "predicted_intervals",
    "prediction_table",
    "reference_input",
    "reference_parameters",
    "refit",
    "register_effect",
    "rigid_simulate",
    "save_record",
    "score_tests",
    "simulate",
    "simulate_batch",
    "torque_map",
    "uncertainty",
    "validate",
    "warm_start",
]
