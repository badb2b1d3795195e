"""What several test modules share: the packaged arm files, the real-rig data, the example
record and a complete fit file. Importable by name because ``pyproject.toml`` puts ``tests/`` on
pytest's ``pythonpath``."""

from __future__ import annotations

import importlib.util
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxflex
import jaxflex.datasets as datasets
from jaxflex.identification import FIT_FORMAT, describe_model
from jaxflex.model import Model
from jaxflex.rigs import arm_path

ROOT = Path(__file__).resolve().parents[1]
"""The checkout."""
ARMS = arm_path("reference").parent
"""The folder of the arm files packaged with jaxflex (``jaxflex/rigs``)."""
REFERENCE_ARM = ARMS / "reference.toml"
"""The arm file of the reference testbed."""
EXAMPLE = Path(jaxflex.__file__).parent / "data" / "example_pulse.csv"
"""A record file packaged with jaxflex, as ``jaxflex simulate`` writes one."""


def _local_copy() -> str | None:
    folder = os.environ.get(datasets.DATA_DIR_VARIABLE)
    return folder if folder and Path(folder).is_dir() else None


REAL_DATA_DIR = _local_copy()
"""The local copy named by JAXFLEX_DATA_DIR at start-up, or None to use the network (or skip)."""


def or_skip(function, *args):
    """``function(*args)``, or skip the test saying why the real-rig data are not there."""
    try:
        return function(*args)
    except datasets.DataUnavailable as err:
        pytest.skip(f"real-rig data unavailable: JAXFLEX_DATA_DIR unset and no network ({err})")


def arm_text(**replace: str) -> str:
    """The reference arm file with some lines replaced (key → new line, '' deletes it).

    ``top`` is a line put before the first table, ``extra`` one appended at the end.
    """
    lines = REFERENCE_ARM.read_text().splitlines()
    out = [replace.pop("top", "")]
    for line in lines:
        key = line.split("=")[0].strip()
        out.append(replace.pop(key) if key in replace else line)
    return "\n".join(out + list(replace.values())) + "\n"


def fit_data() -> dict:
    """A complete fit file of the reference model (what `jaxflex identify` writes)."""
    model = Model()
    params = {k: float(v) for k, v in model.space.reference().items()}
    names = list(params)
    eye = np.eye(len(names)).tolist()
    return json.loads(json.dumps({
        "format": FIT_FORMAT, "params": params, "names": names, "fixed": {},
        "model_description": describe_model(model), "cost": 1e-4, "cost_search": 2e-4,
        "intervals": {k: [0.9 * v, 1.1 * v] for k, v in params.items()},
        "std": {k: 0.05 * v for k, v in params.items()}, "covariance": eye, "correlation": eye,
        "noise": {"joint_angle": 1e-3, "tip_acceleration": 0.05}, "poorly_identifiable": [],
        "warnings": [], "history": {"best": [2e-4, 1e-4], "mean": [1e-3, 5e-4],
                                    "best_params": {k: [v, v] for k, v in params.items()}},
        "refinement": {"start": params, "end": params, "cost_start": 2e-4, "cost_end": 1e-4,
                       "accepted": True, "result": "successful", "message": "", "steps": 3,
                       "n_starts": 1},
        "method": "de", "seed": 0, "settings": {}, "timing": {"search": 1.0, "refine": 0.5},
        "record_names": ["rec"], "level": 0.95,
    }, default=float))


def docs_module(name: str):
    """``docs/NAME.py`` (``generated``: the generator of the pages' generated parts;
    ``benchmark_tables``, ``rig_file``), loaded by path: ``docs`` is no package."""
    spec = importlib.util.spec_from_file_location(f"docs_{name}", ROOT / "docs" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module
