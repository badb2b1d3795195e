"""Shared test set-up: float64 JAX, and the independent reference solver importable by name."""

import sys
from pathlib import Path

import jaxflex  # noqa: F401  (enables float64 before any test builds arrays)

sys.path.insert(0, str(Path(__file__).parent))
