"""A wheel built from the checkout, installed in a fresh venv and run from a directory
outside the checkout, finds its topologies and checkpoints (package data inside sebvs:
pyproject.toml, sebvs/shipped.py): both Gymnasium ids make and step, `sebvs eval` plays an
episode with the shipped checkpoints, and a command finds `topologies/...` as the docs
write it.

The venv gets no dependencies of its own: a .pth file puts the project venv's
site-packages on its path. That adds the directory only; the .pth files in it (the
editable install's finder among them) are not run, so the checkout's sebvs stays hidden and
the wheel's is the one imported (checked: every sebvs module's file lies in the new venv).
"""
import json
import os
import shutil
import site
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("gymnasium")
pytest.importorskip("setuptools")

ROOT = Path(__file__).resolve().parents[1]
# what the build reads: the package sources and the folders shipped as data in it
SOURCES = ("pyproject.toml", "README.md", "sebvs", "actors", "topologies", "checkpoints")


def run(cmd: list, cwd: Path, env: dict, timeout: float = 240) -> str:
    out = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True,
                         text=True, timeout=timeout)
    assert out.returncode == 0, f"{cmd[:3]} exited {out.returncode}:\n{out.stdout[-3000:]}" \
                                f"\n{out.stderr[-3000:]}"
    return out.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(the fresh venv's python, the environment to run it in, a directory outside the
    checkout)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"           # a copy: the build writes build/ and *.egg-info beside it
    src.mkdir()
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(path, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["MUJOCO_GL"] = env.get("MUJOCO_GL", "egl")
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", tmp / "dist", src], cwd=tmp, env=env)
    wheel, = (tmp / "dist").glob("sebvs-*.whl")
    venv = tmp / "venv"
    run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=tmp, env=env)
    python = venv / "bin" / "python"
    purelib = run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                  cwd=tmp, env=env).strip()
    deps = [p for p in site.getsitepackages() if Path(p).is_dir()]
    Path(purelib, "project_deps.pth").write_text("\n".join(deps) + "\n")
    run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps",
         "--no-index", "-q", wheel], cwd=tmp, env=env)
    away = tmp / "elsewhere"
    away.mkdir()
    return python, env, away


def test_the_wheel_s_sebvs_runs_both_envs_on_its_own_topologies(installed):
    python, env, away = installed
    venv = python.parent.parent
    out = run([python, "-c", textwrap.dedent("""
        import json, sys
        import gymnasium as gym
        import sebvs, sebvs.envs, sebvs_actors
        from sebvs.conditions import TOPOLOGIES
        from sebvs.sensor_pairs import checkpoint_dir
        steps = {}
        for env_id in sebvs.envs.ENV_IDS.values():
            env = gym.make(env_id, width=32, height=32, episode_s=0.2)
            obs, info = env.reset(seed=1)
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            steps[env_id] = [list(obs), info["tick"]]
            env.close()
        files = sorted({m.__file__ for name, m in list(sys.modules.items())
                        if name.split(".")[0] in ("sebvs", "sebvs_actors", "actors")
                        and getattr(m, "__file__", None)})
        print(json.dumps({"files": files, "topologies": str(TOPOLOGIES),
                          "checkpoints": [checkpoint_dir("physical"), checkpoint_dir("ideal8")],
                          "steps": steps}))
        """)], cwd=away, env=env)
    got = json.loads(out.strip().splitlines()[-1])
    assert got["files"] and all(f.startswith(str(venv)) for f in got["files"]), got["files"]
    assert Path(got["topologies"]).is_relative_to(venv)
    assert Path(got["topologies"], "nav_policy.toml").is_file()
    for directory in got["checkpoints"]:
        assert Path(directory).is_relative_to(venv) and list(Path(directory).glob("*-rgb.pt"))
    assert got["steps"] == {"SEBVS/ERPNav-v1": [["rgb", "events", "proprio"], 1],
                            "SEBVS/ERPArm-v1": [["rgb", "events", "proprio"], 1]}


def test_the_wheel_s_sebvs_eval_plays_an_episode_with_the_shipped_checkpoints(installed):
    python, env, away = installed
    sebvs = python.parent / "sebvs"
    assert not (away / "checkpoints").exists() and not (away / "topologies").exists()
    run([sebvs, "eval", "--task", "arm", "--modalities", "rgb", "--episodes", "1",
         "--scenarios", "single", "--no-expert", "--no-baseline", "--out", "ev"],
        cwd=away, env=env)
    results = json.loads((away / "ev" / "results.json").read_text())
    assert [(e["modality"], e["condition"]) for e in results["episodes"]] == \
        [("rgb", "nominal_physical")]
    assert results["episodes"][0]["metrics"]["n"] == 21       # 2 s at 10 Hz, both ends
    # a command's topology as the docs write it, from a directory that has none
    graph = run([sebvs, "graph", "topologies/nav_policy.toml"], cwd=away, env=env)
    assert str(python.parent.parent) in graph.splitlines()[0]
