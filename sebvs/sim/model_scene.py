"""Anyone's compiled MuJoCo model as the camera core's scene: what sebvs.EventCamera and
sebvs.envs.EventCameraWrapper render.

    scene = ModelScene(model, "wrist", width=128, height=128,
                       photometry=default_photometry(model))
    CameraCore(params, {"luma", "rgb"}).use_scene(scene, ("model", id(scene)))

The camera renders its own copy of the model (taken when the scene is made), posed from
states (qpos, mocap_pos, mocap_quat) as the camera actor poses the project's scenes. The
copy carries the project's render-speed settings unless told otherwise: no MSAA, no
shadow map (sebvs.sim.scene.FAST_VISUAL; MuJoCo's defaults cost a CPU renderer 20-40x),
and an offscreen buffer at least the image's size.

Light (sebvs.sim.light.Photometry) for a model that does not declare its own: its MJCF
lights as they are, scaled so that a white surface facing the key light (the brightest
active light) and the camera receives DEFAULT_LUX (office light). Its render level, the
relative radiance such a surface renders at, is the key light's diffuse plus every
active light's ambient plus the headlight's ambient and diffuse (Rec. 709 luminance of
each colour); a light's attenuation and spot cone are left out.
"""
from __future__ import annotations

import copy

import mujoco
import numpy as np

from .light import ILLUMINANCE_LUX, Photometry
from .radiance import luminance
from .scene import Scene

DEFAULT_LUX = ILLUMINANCE_LUX["office"]     # 400 lux


class UnknownCamera(ValueError):
    """The camera asked for is not in the model (or the model has none); the message
    names it and the cameras the model has."""


def camera_names(model: mujoco.MjModel) -> tuple[str, ...]:
    """The model's cameras by name, in id order ("#k" for an unnamed camera k)."""
    out = []
    for k in range(model.ncam):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, k)
        out.append(name or f"#{k}")
    return tuple(out)


def resolve_camera(model: mujoco.MjModel, camera, where: str = "event camera"
                   ) -> "str | int | mujoco.MjvCamera":
    """What the renderers take for `camera`: a camera's name, the id of an unnamed one, or
    a mujoco.MjvCamera as it is (a free or tracking view).

    Parameters:
        model: the model the camera is looked up in.
        camera: a name, an id, a mujoco.MjvCamera, or None (the model's first camera).
        where: what the error message names.
    Returns:
        the camera's name (its id where it has none), or the MjvCamera. UnknownCamera in
        one line naming the camera and the model's cameras when it is not there.
    """
    if isinstance(camera, mujoco.MjvCamera):
        return camera
    names = camera_names(model)
    have = ", ".join(repr(n) for n in names) if names else "none"
    if camera is None:
        if not names:
            raise UnknownCamera(f"{where}: the model has no camera: add a <camera> to its "
                                f"MJCF, or pass camera=mujoco.MjvCamera() (a free view)")
        return names[0] if not names[0].startswith("#") else 0
    if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool):
        if not 0 <= int(camera) < model.ncam:
            raise UnknownCamera(f"{where}: the model has no camera id {int(camera)} "
                                f"(its cameras: {have})")
        name = names[int(camera)]
        return int(camera) if name.startswith("#") else name
    if isinstance(camera, str):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise UnknownCamera(f"{where}: the model has no camera named {camera!r} "
                                f"(its cameras: {have})")
        return camera
    raise UnknownCamera(f"{where}: camera must be a name, an id, a mujoco.MjvCamera or None, "
                        f"got {type(camera).__name__} (the model's cameras: {have})")


def render_level(model: mujoco.MjModel) -> float:
    """The relative radiance at which a white surface facing the key light and the camera
    renders under the model's lights (module docstring).

    Parameters:
        model: the model.
    Returns:
        key diffuse + every active light's ambient + the headlight's ambient and diffuse,
        as Rec. 709 luminance; 0 when nothing lights the model.
    """
    active = np.asarray(model.light_active, bool) if model.nlight else np.zeros(0, bool)
    diffuse = luminance(model.light_diffuse[active]) if active.any() else np.zeros(1)
    ambient = float(luminance(model.light_ambient[active]).sum()) if active.any() else 0.0
    head = model.vis.headlight
    head_level = float(luminance(head.ambient) + luminance(head.diffuse)) if head.active \
        else 0.0
    return float(np.max(diffuse)) + ambient + head_level


def default_photometry(model: mujoco.MjModel, lux: float = DEFAULT_LUX) -> Photometry:
    """The light of a model that declares none: its MJCF lights scaled so that a white
    surface facing the key light receives `lux` (module docstring).

    Parameters:
        model: the model.
        lux: that surface's illuminance (default 400 lux, office light; see
            sebvs.sim.light.ILLUMINANCE_LUX for others).
    Returns:
        the Photometry; ValueError in one line when nothing lights the model.
    """
    level = render_level(model)
    if not level > 0:
        raise ValueError("event camera: nothing lights the model (no active light and the "
                         "headlight off): add a <light>, or pass light=Photometry(...)")
    return Photometry(illuminance_lux=float(lux), render_level=level)


def check_size(width, height, where: str = "event camera") -> None:
    """ValueError in one line unless both are whole numbers of pixels in 1..8192."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 8192:
            raise ValueError(f"{where}: {name} must be an integer number of pixels in "
                             f"1..8192, got {v!r}")


def prepare_render(model: mujoco.MjModel, width: int, height: int, msaa: bool = False,
                   shadows: bool = False) -> None:
    """Set a model's copy up for the camera, in place: the offscreen buffer at least
    width x height, and (unless asked for) no MSAA and no shadow map (the project's
    render-speed settings, sebvs.sim.scene.FAST_VISUAL)."""
    g = model.vis.global_
    g.offwidth, g.offheight = max(g.offwidth, width), max(g.offheight, height)
    if not msaa:
        model.vis.quality.offsamples = 0
    if not shadows:
        model.vis.quality.shadowsize = 0
        if model.nlight:
            model.light_castshadow[:] = 0


def kinematics_with_tendons(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """The project scenes' kinematics (cameras and lights current), and the tendons' paths
    where the model has tendons (MuJoCo draws them)."""
    Scene.kinematics(model, data)
    if model.ntendon:
        mujoco.mj_tendon(model, data)


class ModelScene:
    """One compiled model and camera at one image size, as sebvs.sensors.camera.CameraCore
    renders a scene (the Scene methods it calls; module docstring)."""

    def __init__(self, model: mujoco.MjModel, camera, width: int, height: int,
                 photometry: Photometry, fast: bool = True,
                 where: str = "event camera") -> None:
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"{where}: model must be a mujoco.MjModel, got "
                            f"{type(model).__name__}")
        check_size(width, height, where)
        self.source = model
        self.view = resolve_camera(model, camera, where)
        # the camera core renders cameras[0] unless told; the name alone may not be
        # unique to an id (an unnamed camera has its id), so the view is the one entry
        self.cameras = (self.view,)
        self.width, self.height = int(width), int(height)
        self._photometry = photometry
        self.fast = bool(fast)

    def compile(self) -> mujoco.MjModel:
        """The camera's own copy of the model, with the render settings of the module
        docstring."""
        m = copy.deepcopy(self.source)
        prepare_render(m, self.width, self.height, msaa=not self.fast, shadows=not self.fast)
        return m

    def image_shape(self) -> tuple[int, int]:
        return self.height, self.width

    @staticmethod
    def rgb_blur() -> int:
        return 0                          # the modelled frame camera blurs; no box blur

    def photometry(self) -> Photometry:
        return self._photometry

    @staticmethod
    def state(data: mujoco.MjData) -> dict[str, np.ndarray]:
        """What poses the camera's copy: copies of qpos (nq,), mocap_pos (nmocap, 3) and
        mocap_quat (nmocap, 4), float64."""
        return {"qpos": data.qpos.copy(), "mocap_pos": data.mocap_pos.copy(),
                "mocap_quat": data.mocap_quat.copy()}

    @staticmethod
    def set_state(model: mujoco.MjModel, data: mujoco.MjData, state: dict) -> None:
        data.qpos[:] = state["qpos"]
        if model.nmocap:
            data.mocap_pos[:] = state["mocap_pos"]
            data.mocap_quat[:] = state["mocap_quat"]

    kinematics = staticmethod(kinematics_with_tendons)
