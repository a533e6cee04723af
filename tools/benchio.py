"""What every benchmark under tools/ does with its report: print it, and keep it if asked."""
from __future__ import annotations

import json
from pathlib import Path


def print_report(report: dict, path: str | None) -> None:
    """Print ``report`` as indented JSON; also write it to ``path`` (folders made) if given."""
    text = json.dumps(report, indent=2)
    print(text)
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(text)


def counts_arg(flag: str):
    """argparse's type for a comma-separated list of counts >= 1 (`--tiles 1,2,4`), its
    errors naming ``flag``."""
    import argparse

    def parse(text: str) -> tuple[int, ...]:
        try:
            values = tuple(int(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} {text!r}: give integers, e.g. 1,2,4")
        if not values or min(values) < 1:
            raise argparse.ArgumentTypeError(f"{flag} {text!r}: every count must be >= 1")
        return values
    return parse
