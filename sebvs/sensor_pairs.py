"""The two sensor pairs a topology can run, and the checkpoints trained on each.

``physical`` (the default): the frame camera and the event sensor each model their chip
on the scene's linear light (docs/sensors.md): ``camera.sensor="physical"`` and the
emulator's "physical" preset. The checkpoints in checkpoints/ were trained on it (the
sensor study, research/sensors/plan.md).

``ideal8``: the benchmark before it, where both sensors read one ideal 8-bit render:
``camera.sensor="ideal8"`` and the emulator's "paper" preset (the paper's v2e settings).
Its checkpoints are in checkpoints/ideal8/; research/ideal8/'s pages are its results.

    from sebvs.sensor_pairs import topology_overrides
    load_topology("topologies/nav_policy.toml", topology_overrides("ideal8"))

The overrides are nested mappings (sebvs/runtime/overrides.py).
"""
from __future__ import annotations

SENSORS = ("physical", "ideal8")
DEFAULT_SENSOR = "physical"
_EMULATOR_PRESET = {"physical": "physical", "ideal8": "paper"}
_CHECKPOINTS = {"physical": "checkpoints", "ideal8": "checkpoints/ideal8"}
# each pair's nominal condition of `sebvs eval` (sebvs/conditions.py): what `sebvs eval
# --sensor` and the Gymnasium environments run when no condition is named
DEFAULT_CONDITION = {"physical": "nominal_physical", "ideal8": "nominal"}


def check_sensor(name: str) -> str:
    if name not in SENSORS:
        raise ValueError(f"unknown sensor pair {name!r} (one of {', '.join(SENSORS)})")
    return name


def camera_override(name: str) -> dict:
    """The topology override that puts the camera on this pair's frame sensor."""
    return {"camera": {"sensor": check_sensor(name)}}


def emulator_preset(name: str) -> str:
    """The event emulator's preset of this pair ("physical" or the paper's)."""
    return _EMULATOR_PRESET[check_sensor(name)]


def emulator_override(name: str) -> dict:
    """The topology override that gives the event emulator this pair's preset."""
    return {"emulator": {"preset": emulator_preset(name)}}


def sensor_overrides(name: str) -> dict:
    """The camera's and the emulator's overrides of this pair (`sebvs record --sensor`)."""
    return {**camera_override(name), **emulator_override(name)}


def checkpoint_dir(name: str) -> str:
    """Where the shipped checkpoints trained on this pair are: relative to the working
    directory where it has them (a checkout, as always), else the installation's own
    (sebvs/shipped.py: a wheel's copy, or the checkout beside the package)."""
    from sebvs.shipped import shipped_path
    return str(shipped_path(_CHECKPOINTS[check_sensor(name)]))


def topology_overrides(name: str) -> dict:
    """Everything a closed-loop topology (camera, emulator, policy) needs to run this pair
    with the checkpoints trained on it: `sebvs demo --sensor`."""
    return {**sensor_overrides(name), "policy": {"directory": checkpoint_dir(name)}}
