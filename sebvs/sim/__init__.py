"""MuJoCo scenes (nav, arm, and anyone's MJCF file: mjcf), rendering and stability checks.

`make_scene(name, **config)` is the one entry point actors use; scene modules are imported
lazily so a nav-only process never imports the arm (and vice versa).
"""
from __future__ import annotations

import importlib
import os

# mujoco picks its GL backend when first imported; every sebvs.sim module imports it, so
# the default is set here, before any of them (see sebvs/sim/render.py; osmesa works too).
os.environ.setdefault("MUJOCO_GL", "egl")

from .scene import Scene

# name -> "module:Class"; the module is imported on first use.
SCENES: dict[str, str] = {
    "nav": "sebvs.sim.nav:NavScene",
    "arm": "sebvs.sim.arm:ArmScene",
    "mjcf": "sebvs.sim.mjcf_scene:MjcfScene",     # your own MJCF file (docs/own_robot.md)
}


def make_scene(name: str, **config) -> Scene:
    """Build the scene `name` ("nav" | "arm" | "mjcf") from its config; ValueError on a bad name/key."""
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r} (known: {', '.join(sorted(SCENES))})")
    module, cls = SCENES[name].split(":")
    return getattr(importlib.import_module(module), cls)(**config)


__all__ = ["Scene", "SCENES", "make_scene"]
