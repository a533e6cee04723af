"""What a command may write: the one rule every writing command of `sebvs` applies.

    from sebvs.output_guard import check_output_file
    check_output_file("out/events.h5", inputs=["video.mp4"], force=args.force)

Never written, not even with ``--force``:
  - a command's own input (the same file, however it is spelled: links resolve, and a
    hard link to it is the same file);
  - a dataset's index (``index.json`` in a folder of episode files) and any episode file
    (``episode_NNNN.h5`` and its ``.partial``): they are recordings, which no command makes
    again, and the only writer of a dataset is `sebvs record`;
  - a folder, where a file is written.

Written only with ``--force``: a file that exists. A folder output (a dataset, an
evaluation, a training's checkpoints) is checked by the command that knows what in it is
its own (`check_output_dir`). A refusal is an ``OutputRefused``: one line naming the path
and why, which each command prints as ``sebvs <command>: ...`` and exits 2.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterable

from .dataset_files import EPISODE_RE, INDEX


class OutputRefused(ValueError):
    """An output path the command must not write; the message names it and why."""


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:     # either does not exist (yet): compare where they would be
        return a.resolve() == b.resolve()


def is_dataset_dir(path: str | Path) -> bool:
    """A folder that holds a dataset's index."""
    return (Path(path) / INDEX).is_file()


def protected_reason(path: str | Path) -> str | None:
    """Why ``path`` is never an output (a dataset's index or an episode file), or None."""
    p = Path(path)
    if p.name == INDEX and (is_dataset_dir(p.parent) or any(
            EPISODE_RE.match(q.name) for q in _listing(p.parent))):
        return "it is a dataset's index"
    if EPISODE_RE.match(p.name) and (p.exists() or is_dataset_dir(p.parent)):
        return "it is a recorded episode (only `sebvs record` writes episodes)"
    return None


def _listing(folder: Path) -> list[Path]:
    try:
        return list(folder.iterdir())
    except OSError:
        return []


def check_output_file(path: str | Path, *, inputs: Iterable[str | Path] = (),
                      force: bool = False, flag: str = "--force") -> Path:
    """Refuse a file output a command must not write (module docstring).

    Parameters:
        path: where the command would write.
        inputs: the files the command reads; the output may be none of them.
        force: the user asked to replace an existing file (``flag``).
        flag: the option that says so, named in the refusal.

    Returns:
        ``path`` as a Path.

    Raises:
        OutputRefused: one line naming the path and why.
    """
    p = Path(path)
    for source in inputs:
        if _same_file(p, Path(source)):
            raise OutputRefused(f"{p}: refused, it is this command's input {source}")
    why = protected_reason(p)
    if why:
        raise OutputRefused(f"{p}: refused, {why}")
    if p.is_dir():
        raise OutputRefused(f"{p}: a folder; give a file to write")
    if p.exists() and not force:
        raise OutputRefused(f"{p}: exists; give {flag} to replace it")
    return p


def check_output_dir(path: str | Path, *, inputs: Iterable[str | Path] = (),
                     force: bool = False, owns: Callable[[Path], bool] = lambda p: False,
                     what: str = "output", flag: str = "--force") -> Path:
    """Refuse a folder output a command must not write into.

    Parameters:
        path: the folder the command writes into (made if missing).
        inputs: folders the command reads (a dataset, a checkpoint folder): the output is
            none of them.
        force: the user asked to write into a non-empty folder that is not the command's.
        owns: whether a non-empty folder is this command's own output (one it may resume
            or add to: `sebvs record`'s dataset, `sebvs eval`'s results).
        what: what the command makes, for the refusal ("dataset", "evaluation").
        flag: the option that allows a foreign non-empty folder, named in the refusal.

    Returns:
        ``path`` as a Path.

    Raises:
        OutputRefused: one line naming the folder and why.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputRefused(f"{p}: a file; the {what} goes into a folder")
    for source in inputs:
        if _same_file(p, Path(source)):
            raise OutputRefused(f"{p}: refused, it is this command's input {source}")
    if not p.exists() or owns(p):
        return p
    if is_dataset_dir(p):
        raise OutputRefused(f"{p}: refused, it is a dataset (only `sebvs record` writes "
                            f"into one)")
    if _listing(p) and not force:
        raise OutputRefused(f"{p}: a folder that holds other files and no {what} of this "
                            f"command's; give {flag} to write into it, or an empty or new "
                            f"folder")
    return p
