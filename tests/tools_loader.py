"""A script under tools/ imported as a module for its tests: the tools are programs that
put the checkout on sys.path themselves, not a package."""
import contextlib
import importlib.util
import sys
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[1] / "tools"


@contextlib.contextmanager
def tool_module(name: str):
    """tools/<name>.py (name may hold a folder: "bench/bench_sim"), imported under its file's
    stem and registered in sys.modules while the block runs (dataclasses look their class's
    module up there), unregistered after it."""
    path = TOOLS / f"{name}.py"
    name = path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(name, None)
