"""Shared test set-up: float64 JAX before any test builds arrays, and the real-rig records as
CSV files. What test modules share by import lives in ``helpers.py``."""

from pathlib import Path

import pytest
from helpers import REAL_DATA_DIR

import jaxflex  # noqa: F401  (enables float64 before any test builds arrays)


@pytest.fixture(scope="session")
def rotflex_csv(tmp_path_factory) -> Path:
    """A folder with the ROTFLEX runs written as CSV (``jaxflex datasets get``); the test skips
    where the data cannot be had (no ``JAXFLEX_DATA_DIR`` copy and no network)."""
    from jaxflex import datasets

    out = tmp_path_factory.mktemp("rotflex")
    try:
        datasets.write("quanser_rotflex", out, REAL_DATA_DIR)
    except datasets.DataUnavailable as err:
        pytest.skip(f"real-rig data unavailable: JAXFLEX_DATA_DIR unset and no network ({err})")
    return out
