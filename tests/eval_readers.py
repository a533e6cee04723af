"""The evaluation readers for their tests: sebvs.eval.compare and sebvs.eval.table, each
module's functions with main(argv), its `sebvs eval compare` / `sebvs eval table` command
line, beside them."""
import contextlib
from types import SimpleNamespace

from sebvs import cli
from sebvs.eval import compare, results, table


def _reader(module, command: str) -> SimpleNamespace:
    names = {k: getattr(module, k) for k in dir(module) if not k.startswith("__")}
    names.update({k: getattr(results, k) for k in ("read_results", "episodes_by_key")})
    return SimpleNamespace(**names, main=lambda argv: cli.main(["eval", command, *argv]))


@contextlib.contextmanager
def reader(command: str):
    """`command` ("compare" or "table") as a namespace: its module's functions and main."""
    yield _reader({"compare": compare, "table": table}[command], command)
