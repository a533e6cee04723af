"""The import graph goes one way: each package imports only from layers below its own, and
no two modules import each other in a loop. Imports inside functions count too: a late
import hides a loop from Python, not from the design."""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# lower index = lower layer; a package may import only from strictly lower layers
LAYERS = (
    # where the shipped topologies and checkpoints are (a checkout's, or a wheel's copy)
    {"sebvs.shipped"},
    # the one-line hint for a missing optional extra; the two sensor pairs' overrides;
    # a dataset's files and their check against its index; HDF5 errors that name their file
    {"sebvs.extras", "sebvs.sensor_pairs", "sebvs.dataset_files", "sebvs.h5named"},
    # what any command may write
    {"sebvs.output_guard"},
    {"sebvs.runtime", "sebvs.dvs", "sebvs.sim", "sebvs.metrics"},
    # the tasks' conditions and scenarios as data: the recorder, the evaluator and the
    # Gymnasium environments read them
    {"sebvs.conditions"},
    # fan-out of episodes: runs topology shards through the runtime for data and eval
    {"sebvs.scale"},
    {"sebvs.data", "sebvs.experts"},
    # the sensor models on the scenes' light, and their validation against the experts
    {"sebvs.sensors"},
    # the event camera on anyone's MuJoCo model (the library API over the sensors)
    {"sebvs.event_camera"},
    {"sebvs.policy"},
    # the evaluator; the stream probe (reads sebvs.data and sebvs.policy.inputs)
    {"sebvs.eval", "sebvs.numerics", "sebvs.probe"},
    {"sebvs.cli", "sebvs.demo", "sebvs_actors"},
    # the field's tools on top of everything: Gymnasium environments, the rerun viewer
    {"sebvs.envs", "sebvs.view"},
)
RANK = {pkg: i for i, layer in enumerate(LAYERS) for pkg in layer}


def canonical(module: str) -> str:
    """The actors/ folder is the package sebvs_actors (pyproject.toml's package-dir);
    `actors.X`, its historical spelling, names the same module."""
    head, dot, rest = module.partition(".")
    return "sebvs_actors" + dot + rest if head == "actors" else module


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return canonical(".".join(parts[:-1] if parts[-1] == "__init__" else parts))


def imported_modules(path: Path, name: str, known: set[str]) -> set[str]:
    """Every project module `path` imports, anywhere in the file."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [canonical(a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            else:
                base = canonical(base)
            # `from pkg import mod` imports a module; `from mod import name` a name
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def package_of(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "sebvs" and len(parts) > 1 else parts[0]


def import_graph(root: Path, extra: set[str] = frozenset()) -> dict[str, set[str]]:
    """{module: the project modules it imports} over sebvs/ and actors/ under root."""
    files = sorted((root / "sebvs").rglob("*.py")) + sorted((root / "actors").glob("*.py"))
    names = {module_name(f, root): f for f in files}
    known = set(names) | set(extra)
    return {n: imported_modules(f, n, known) for n, f in names.items()}


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(ROOT)


def test_every_package_has_a_layer(graph):
    unplaced = {package_of(m) for m in graph} - set(RANK) - {"sebvs"}
    assert not unplaced, f"packages with no layer in LAYERS: {sorted(unplaced)}"


def test_imports_only_go_down(graph):
    upward = []
    for mod, targets in graph.items():
        src = package_of(mod)
        for t in targets:
            dst = package_of(t)
            if dst != src and dst != "sebvs" and RANK.get(dst, -1) >= RANK.get(src, -1):
                upward.append(f"{mod} -> {t}")
    assert not upward, "imports that do not go to a lower layer:\n" + "\n".join(upward)


def test_the_environments_and_the_recorder_do_not_import_the_evaluator(graph):
    # what they share with it (conditions, scenarios, topologies, the rates and event
    # frames a run implies) is sebvs.conditions, below all three
    users = [m for m in graph if m.startswith(("sebvs.envs", "sebvs.data"))]
    found = [f"{m} -> {t}" for m in users for t in graph[m] if t.startswith("sebvs.eval")]
    assert not found, "\n".join(found)


def test_no_module_imports_itself_through_others(graph):
    # depth-first search for a back edge; a package's __init__ importing its own modules
    # is how a package exposes them, so those edges are left out
    edges = {m: {t for t in ts if not m.startswith(t + ".") and not t.startswith(m + ".")}
             for m, ts in graph.items()}
    state: dict[str, int] = {}
    stack: list[str] = []
    loops = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for t in sorted(edges.get(m, ())):
            if state.get(t) == 1:
                loops.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(edges):
        if m not in state:
            visit(m)
    assert not loops, "import loops:\n" + "\n".join(loops)


def test_the_checks_see_a_planted_loop_and_an_upward_import(tmp_path):
    # the graph builder resolves relative and late imports: the two the design forbids
    pkg = tmp_path / "sebvs" / "experts"
    pkg.mkdir(parents=True)
    (tmp_path / "sebvs" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from .b import g\n")
    (pkg / "b.py").write_text("from . import a\nfrom ..eval.run import x\n")
    g = import_graph(tmp_path, extra={"sebvs.eval.run"})
    assert "sebvs.experts.b" in g["sebvs.experts.a"]
    assert {"sebvs.experts.a", "sebvs.eval.run"} <= g["sebvs.experts.b"]
    with pytest.raises(AssertionError, match="import loops"):
        test_no_module_imports_itself_through_others(g)
    with pytest.raises(AssertionError, match="lower layer"):
        test_imports_only_go_down(g)
