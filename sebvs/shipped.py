"""Where the files the project ships are: the topologies and the trained checkpoints.

    from sebvs.shipped import shipped_dir, shipped_path
    shipped_dir("topologies") / "nav_policy.toml"     # the installed copy, or the checkout's
    shipped_path("checkpoints/ideal8")                # as named where the working directory
                                                      # has it, else the shipped one

In a checkout (and an editable install) they are the repository's top-level topologies/
and checkpoints/ folders, beside the package. A wheel carries copies of them inside the
package, as sebvs/topologies and sebvs/checkpoints (pyproject.toml's package-dir maps the
two folders there), since nothing outside the package's folder is installed. The installed
copy is looked for first: beside an installed package lies site-packages, whose top-level
folders are other projects'.
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

NAMES = ("topologies", "checkpoints")
CHECKOUT = Path(__file__).resolve().parents[1]


def shipped_dir(name: str) -> Path:
    """The folder `name` ("topologies" | "checkpoints") of this installation.

    Parameters:
        name: one of NAMES.

    Returns:
        The wheel's copy inside the package where there is one, else the checkout's
        folder beside the package (which may be missing: then the caller's own message
        names the file it looked for). ValueError for another name.
    """
    if name not in NAMES:
        raise ValueError(f"no shipped folder {name!r} (one of {', '.join(NAMES)})")
    installed = resources.files("sebvs") / name
    if installed.is_dir():
        return Path(str(installed))
    return CHECKOUT / name


def shipped_path(path: str | Path) -> Path:
    """A path the project's commands name by default (`topologies/nav_policy.toml`,
    `checkpoints/ideal8`) as the user would mean it.

    Parameters:
        path: a path, typically relative to the working directory.

    Returns:
        `path` itself when it exists, is absolute or does not start with one of NAMES;
        else the same path inside the shipped folder when that exists there (a wheel
        install run from any directory, a checkout run from outside it), else `path`
        itself, so that a message about it names what the user gave.
    """
    path = Path(path)
    if path.is_absolute() or path.exists() or not path.parts or path.parts[0] not in NAMES:
        return path
    found = shipped_dir(path.parts[0]).joinpath(*path.parts[1:])
    return found if found.exists() else path


def topology_argument(text: str) -> str:
    """argparse's type for a command's TOPOLOGY: `topologies/nav_policy.toml`, as the docs
    write it, runs the shipped file from any directory (shipped_path)."""
    return str(shipped_path(text))
