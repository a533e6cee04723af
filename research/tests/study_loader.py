"""A study script under research/ imported as a module for its tests, as tests/tools_loader.py
imports the tools: the studies are programs that put the checkout on sys.path themselves."""
import contextlib
import importlib.util
import sys
from pathlib import Path

RESEARCH = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def study_module(name: str):
    """research/<name>.py ("sensors/sensor_study", "ideal8/copycat"), imported under its
    file's stem and registered in sys.modules while the block runs (dataclasses look their
    class's module up there), unregistered after it."""
    path = RESEARCH / f"{name}.py"
    name = path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(name, None)
