"""The actors/ folder installs as the package `sebvs_actors`, not as a top-level `actors`
(a name any other project may install too). `actors.X`, the historical spelling in
topology files and in a checkout, is the same module: one copy of each class whichever
name imports it."""
import shutil
import subprocess
import sys
import textwrap
import tomllib
import warnings
from pathlib import Path

import pytest

from sebvs.runtime.topology import load_topology
from sebvs.runtime.worker import load_class
from tests import test_layers as layers

ROOT = Path(__file__).resolve().parents[1]

TOPOLOGY = """
[topology]
name = "t"

[actors.source]
run = "{package}.synthetic:PatternSource"

[actors.sink]
run = "{package}.synthetic:Sink"
inputs = {{ frames = "source/frames" }}
"""


def topology(tmp_path: Path, package: str) -> Path:
    path = tmp_path / f"{package}.toml"
    path.write_text(TOPOLOGY.format(package=package))
    return path


def actor_modules() -> dict[str, set]:
    """{file: the module objects sys.modules holds for it} over the actor modules."""
    found: dict[str, set] = {}
    for name, module in list(sys.modules.items()):
        file = getattr(module, "__file__", None)
        if file and name.partition(".")[0] in ("actors", "sebvs_actors"):
            found.setdefault(str(Path(file).resolve()), set()).add(id(module))
    return found


def python(code: str, cwd: Path) -> str:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_the_wheel_holds_sebvs_and_sebvs_actors_and_no_actors(monkeypatch):
    """What `pip install .` copies, as setuptools' build_py lists it (no build): every module
    under sebvs/ and actors/, the latter as sebvs_actors, and no top-level `actors`."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    # (and the shipped topologies and checkpoints as data inside sebvs: test_wheel_install)
    assert config["package-dir"]["sebvs_actors"] == "actors"
    assert "actors" not in config["package-dir"]
    # listed, not found: a find names packages by folder, and would install `actors`
    assert isinstance(config["packages"], list) and "actors" not in config["packages"]
    pytest.importorskip("setuptools")
    from setuptools.config.pyprojecttoml import apply_configuration
    from setuptools.dist import Distribution
    monkeypatch.chdir(ROOT)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # setuptools' deprecation notes on [project]
        dist = apply_configuration(Distribution({"script_name": "setup.py"}), "pyproject.toml")
        build = dist.get_command_obj("build_py")
        build.ensure_finalized()
        outputs = {Path(p).relative_to(build.build_lib).as_posix()
                   for p in build.get_outputs(include_bytecode=False)}
    assert {p.split("/")[0] for p in outputs} == {"sebvs", "sebvs_actors"}
    on_disk = {p.relative_to(ROOT).as_posix() for p in (ROOT / "sebvs").rglob("*.py")
               if "__pycache__" not in p.parts}
    on_disk |= {"sebvs_actors/" + p.name for p in (ROOT / "actors").glob("*.py")}
    missing = sorted(on_disk - outputs)
    assert not missing, ("modules a regular install would leave out (a package missing from "
                         f"pyproject.toml's [tool.setuptools] packages?): {missing}")


def test_both_spellings_load_one_class(tmp_path):
    old = load_topology(topology(tmp_path, "actors"))
    new = load_topology(topology(tmp_path, "sebvs_actors"))
    cls = new.actors["source"].cls
    assert old.actors["source"].cls is cls and old.actors["sink"].cls is new.actors["sink"].cls
    assert cls.__module__ == "sebvs_actors.synthetic"
    # the worker process imports the class again by the name the topology wrote
    assert load_class("actors.synthetic:PatternSource") is cls
    assert load_class("sebvs_actors.synthetic:PatternSource") is cls
    import actors.synthetic
    import sebvs_actors.synthetic
    assert actors.synthetic is sebvs_actors.synthetic
    assert sys.modules["actors"] is sys.modules["sebvs_actors"]
    doubles = {f: ids for f, ids in actor_modules().items() if len(ids) > 1}
    assert not doubles, f"actor modules loaded twice: {sorted(doubles)}"


@pytest.mark.parametrize("first, second",
                         [("actors", "sebvs_actors"), ("sebvs_actors", "actors")])
def test_either_name_first_from_a_checkout_is_one_module(first, second):
    out = python(f"""
        import sys
        import {first}.synthetic as a
        import {second}.synthetic as b
        from {second}.synthetic import PatternSource
        src = a.PatternSource("s", a.PatternSource.Params(width=8, height=8))
        assert a is b and isinstance(src, PatternSource), (a, b)
        assert b.__spec__.name == "sebvs_actors.synthetic", b.__spec__
        copies = {{}}
        for name, m in list(sys.modules.items()):
            if name.split(".")[0] in ("actors", "sebvs_actors"):
                copies.setdefault(m.__file__, set()).add(id(m))
        assert all(len(ids) == 1 for ids in copies.values()), copies
        print(a.__name__)
        """, cwd=ROOT)
    assert out.split() == ["sebvs_actors.synthetic"]


def test_a_projects_own_actors_package_keeps_its_name(tmp_path):
    """Outside the checkout, beside a package of one's own called `actors`: the topology's
    `actors.synthetic` is still sebvs's, `actors.mine` is the project's."""
    (tmp_path / "actors").mkdir()
    (tmp_path / "actors" / "__init__.py").write_text("")
    (tmp_path / "actors" / "mine.py").write_text(
        "from sebvs.runtime import Actor\n\nclass Mine(Actor):\n    outputs = ('frames',)\n")
    (tmp_path / "t.toml").write_text(TOPOLOGY.format(package="actors").replace(
        'run = "actors.synthetic:Sink"\ninputs = { frames = "source/frames" }',
        'run = "actors.mine:Mine"\nkeep = true'))
    out = python("""
        from sebvs.runtime.topology import load_topology
        t = load_topology("t.toml")
        import actors
        print(t.actors["source"].cls.__module__, t.actors["sink"].cls.__module__, actors.__name__)
        """, cwd=tmp_path)
    assert out.split() == ["sebvs_actors.synthetic", "actors.mine", "actors"]


def test_another_checkout_runs_its_own_actors(tmp_path):
    """`PYTHONPATH` and the working directory at another tree (a branch beside main, one
    venv): its sebvs and its actors run, by either name, not the ones the venv points at."""
    tree = tmp_path / "branch"
    for pkg in ("sebvs", "actors"):
        shutil.copytree(ROOT / pkg, tree / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    (tree / "t.toml").write_text(TOPOLOGY.format(package="actors"))
    out = python("""
        import sebvs, sebvs_actors
        from sebvs.runtime.topology import load_topology
        import actors.synthetic
        cls = load_topology("t.toml").actors["source"].cls
        assert cls is actors.synthetic.PatternSource
        for m in (sebvs, sebvs_actors, actors.synthetic):
            print(m.__file__)
        """, cwd=tree)
    assert [Path(p).resolve().relative_to(tree.resolve()).as_posix() for p in out.split()] == \
        ["sebvs/__init__.py", "actors/__init__.py", "actors/synthetic.py"]


def test_the_layer_check_knows_actors_by_both_names(tmp_path):
    for d in ("sebvs/runtime", "actors"):
        (tmp_path / d).mkdir(parents=True)
        (tmp_path / d / "__init__.py").write_text("")
    (tmp_path / "sebvs" / "__init__.py").write_text("")
    (tmp_path / "actors" / "sim.py").write_text("")
    (tmp_path / "sebvs" / "runtime" / "x.py").write_text("from actors.sim import Sim\n")
    (tmp_path / "sebvs" / "runtime" / "y.py").write_text("import sebvs_actors.sim\n")
    g = layers.import_graph(tmp_path)
    assert g["sebvs.runtime.x"] == g["sebvs.runtime.y"] == {"sebvs_actors.sim"}
    with pytest.raises(AssertionError, match="sebvs.runtime.x -> sebvs_actors.sim"):
        layers.test_imports_only_go_down(g)
