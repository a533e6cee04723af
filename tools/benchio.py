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
