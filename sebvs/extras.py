"""Optional libraries, imported where a command needs them and nowhere else.

`import sebvs` and the core commands never import these; a command that needs one calls
``require`` at the point of use, so a missing library is one line naming the extra to
install instead of a traceback.
"""
from __future__ import annotations

import importlib
from types import ModuleType


class MissingExtra(ImportError):
    """An optional library is not installed; the message says which extra brings it."""


def require(module: str, package: str, extra: str, what: str = "this") -> ModuleType:
    """Import ``module`` (from the PyPI ``package`` of the ``extra``) or raise MissingExtra:
    "<what> needs <package>: pip install 'sebvs[<extra>]'"."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtra(f"{what} needs {package}: pip install 'sebvs[{extra}]'") from None
