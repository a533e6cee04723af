"""One thin module per actor: each wires library code to the runtime and holds no algorithm of its own.

This folder installs as the package ``sebvs_actors``, the modules' one name (their classes'
``__module__``, what a pickle records); a top-level ``actors`` in site-packages would
collide with any other project's. ``actors`` is the folder's name in a checkout and the
historical spelling topology files use: the loader reads ``run = "actors.sim:Sim"`` as
``sebvs_actors.sim`` (sebvs/runtime/topology.py, ``import_actor_module``).

Two rules keep one copy of each module whatever it is called:

- ``sebvs_actors`` is the actors/ folder beside the ``sebvs`` package in use: with
  ``PYTHONPATH`` and the working directory set to another checkout, that checkout's
  actors run with its sebvs, not the ones the venv's install points at.
- imported as ``actors`` (a checkout's root is on ``sys.path``: tests, workers), this file
  makes ``actors`` and every ``actors.X`` the very module objects ``sebvs_actors`` and
  ``sebvs_actors.X``, so no class is defined twice and ``isinstance`` holds across names.
"""
import importlib as _importlib
import importlib.abc as _abc
import importlib.util as _util
import os as _os
import sys as _sys

CANONICAL = "sebvs_actors"
_HERE = _os.path.dirname(_os.path.realpath(__file__))


def _load_folder(folder: str):
    """Execute ``folder``/__init__.py as the package sebvs_actors and return it."""
    spec = _util.spec_from_file_location(CANONICAL, _os.path.join(folder, "__init__.py"),
                                         submodule_search_locations=[folder])
    module = _util.module_from_spec(spec)
    _sys.modules[CANONICAL] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        _sys.modules.pop(CANONICAL, None)
        raise
    return _sys.modules[CANONICAL]


class _Alias(_abc.MetaPathFinder, _abc.Loader):
    """Finds ``<legacy>.X`` as the module sebvs_actors.X, imported once, under its own name."""

    def __init__(self, legacy: str):
        self.legacy = legacy

    def _canonical(self, name: str) -> str:
        return CANONICAL + name[len(self.legacy):]

    def find_spec(self, name, path=None, target=None):
        if not name.startswith(self.legacy + "."):
            return None
        try:
            if _util.find_spec(self._canonical(name)) is None:
                return None
        except ImportError:
            return None
        return _util.spec_from_loader(name, self)

    def create_module(self, spec):
        module = _importlib.import_module(self._canonical(spec.name))
        spec.loader_state = module.__spec__
        return module

    def exec_module(self, module):
        # the import system gave the module the alias's spec; it keeps its own
        module.__spec__ = module.__spec__.loader_state


if __name__ == CANONICAL:
    # installed beside a sebvs in another folder (the venv's install, a checkout's sebvs
    # first on sys.path): that checkout's actors/ is the package, as its sebvs is
    _sebvs = _importlib.import_module("sebvs")
    _root = _os.path.dirname(_os.path.dirname(_os.path.realpath(_sebvs.__file__)))
    _beside = _os.path.join(_root, "actors")
    if _os.path.dirname(_HERE) != _root and _os.path.isfile(_os.path.join(_beside, "__init__.py")):
        _load_folder(_beside)
else:
    # imported as `actors` from a checkout's root
    try:
        _canonical = _importlib.import_module(CANONICAL)
    except ModuleNotFoundError as exc:
        if exc.name != CANONICAL:
            raise
        _canonical = _load_folder(_HERE)    # a checkout that is not installed
    if not any(getattr(f, "legacy", None) == __name__ and type(f).__name__ == "_Alias"
               for f in _sys.meta_path):
        _sys.meta_path.insert(0, _Alias(__name__))
    _sys.modules[__name__] = _canonical
