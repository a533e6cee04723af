"""SEBVS: MuJoCo robots seen through an emulated event camera and a modelled frame camera.

    import sebvs
    cam = sebvs.EventCamera(model, camera="wrist", width=128, height=128)   # docs/own_robot.md

`import sebvs` stays light: EventCamera (and UnknownCamera, its bad-camera error) load
sebvs.event_camera, and with it mujoco, on first use.
"""
__version__ = "0.1.0"

_LAZY = {"EventCamera": "sebvs.event_camera", "UnknownCamera": "sebvs.event_camera"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sebvs' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
