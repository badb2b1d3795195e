"""The package's public surface: no module is hidden behind a function of the same name."""

import ast
import importlib
import os
import pkgutil
import subprocess
import sys
import types
from pathlib import Path

import pytest

import jaxflex

ROOT = Path(jaxflex.__file__).parents[1]


def test_no_public_module_shares_its_name_with_a_top_level_export():
    modules = {m.name for m in pkgutil.iter_modules(jaxflex.__path__) if m.name[0] != "_"}
    exports = {n for n in jaxflex.__all__ if not isinstance(getattr(jaxflex, n), types.ModuleType)}
    assert modules.isdisjoint(exports), sorted(modules & exports)


def test_importing_a_module_gives_the_module():
    for name in ("simulation", "frequency_response", "identification", "comparison",
                 "diagnosis", "discovery"):
        module = importlib.import_module(f"jaxflex.{name}")
        assert getattr(jaxflex, name) is module
    assert callable(jaxflex.simulate) and jaxflex.simulate.__module__ == "jaxflex.simulation"


def test_every_top_level_name_is_imported_on_first_use_from_its_module():
    """``jaxflex.X`` comes from the module the static imports name (what documentation tools
    read), and ``__all__`` lists exactly those names."""
    tree = ast.parse(Path(jaxflex.__file__).read_text(encoding="utf-8"))
    guarded = next(n for n in tree.body if isinstance(n, ast.If)
                   and ast.unparse(n.test) == "TYPE_CHECKING")
    static = {a.name: n.module for n in guarded.body for a in n.names}
    assert static.pop("datasets") == "jaxflex"
    assert {name: (module, name) for name, module in static.items()} == jaxflex._MODULE_OF
    assert set(jaxflex.__all__) == set(static) | {"datasets"}
    for name, module in static.items():
        assert getattr(jaxflex, name) is getattr(importlib.import_module(module), name)
    assert jaxflex.datasets is importlib.import_module("jaxflex.datasets")
    assert jaxflex.__getattr__("preprocess") is importlib.import_module("jaxflex.preprocess")
    with pytest.raises(AttributeError, match="module 'jaxflex' has no attribute 'simulte'"):
        jaxflex.simulte  # noqa: B018


def test_importing_jaxflex_loads_no_jax_and_sets_jax_up_when_it_is_imported():
    """``import jaxflex`` is light; whoever imports JAX afterwards gets it set up as jaxflex
    needs (float64, ``JAXFLEX_HOST_DEVICES`` CPU devices), as when jaxflex is imported after
    JAX, or first through :mod:`jaxflex.parallel`, which imports JAX before its own names
    exist."""
    script = (
        "import sys\n"
        "{first}\n"
        "loaded = 'jax' in sys.modules\n"
        "import jax\n"
        "print(loaded, jax.config.jax_enable_x64, jax.config.jax_num_cpu_devices)\n"
    )
    env = os.environ | {"JAXFLEX_HOST_DEVICES": "2", "PYTHONPATH": str(ROOT)}
    env.pop("JAX_ENABLE_X64", None)
    for first, jax_loaded in (("import jaxflex", False), ("import jax; import jaxflex", True),
                              ("import jaxflex.parallel", True)):
        done = subprocess.run([sys.executable, "-c", script.format(first=first)], env=env,
                              capture_output=True, text=True, check=True)
        assert done.stdout.split() == [str(jax_loaded), "True", "2"]


def test_the_figure_functions_are_named_in_jaxflex_plots_and_imported_on_first_use():
    """``jaxflex.plots`` names every figure a notebook draws: what static tools read is what
    ``__getattr__`` imports, and drawing one figure loads only its module."""
    import jaxflex.plots as plots

    path = Path(plots.__file__)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    guarded = next(n for n in tree.body if isinstance(n, ast.If)
                   and ast.unparse(n.test) == "TYPE_CHECKING")
    static = {a.asname or a.name: (n.module.rpartition(".")[2], a.name)
              for n in guarded.body for a in n.names}
    assert static == plots._SOURCES
    assert set(plots.__all__) == set(static) | {"new_figure", "save_figure"}
    for name, (module, attribute) in static.items():
        assert getattr(plots, name) is getattr(
            importlib.import_module(f"jaxflex.plots.{module}"), attribute)
    script = ("import sys\nfrom jaxflex.plots import plot_convergence\n"
              "print(sorted(m for m in sys.modules if m.startswith('jaxflex.plots.')))")
    loaded = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            check=True, env=os.environ | {"PYTHONPATH": str(ROOT)}).stdout
    assert loaded.strip() == "['jaxflex.plots._style', 'jaxflex.plots.identify']"
