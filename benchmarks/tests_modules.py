"""Modules of tests/ that benchmarks reuse (the hard-case suite, Bai's problems, the impulse-control
Jacobian), loaded from their files: one definition of each case, and no sys.path edits."""
import importlib.util
import os
import sys

TESTS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests")


def load(name: str):
    """tests/<name>.py as a module, registered under its name as pytest imports it; the tests/
    modules it imports (``import test_hard_cases``) are loaded first, the same way."""
    if name in sys.modules:
        return sys.modules[name]
    path = os.path.join(TESTS, name + ".py")
    while True:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
            return module
        except ModuleNotFoundError as exc:
            del sys.modules[name]
            if exc.name is None or not os.path.exists(os.path.join(TESTS, exc.name + ".py")):
                raise
            load(exc.name)
