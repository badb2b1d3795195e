"""The package's public surface: no module is hidden behind a function of the same name."""

import importlib
import pkgutil
import types

import jaxflex


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
