"""Where an `mjcf` scene's model comes from: a file, or a file inside an installed package,
loaded and compiled, with a fixed camera added where the config names a pose for one.

    path = find_mjcf("envs/mujoco/assets/reacher.xml", package="gymnasium")
    spec = load_spec(path)
    add_camera(spec, "top", CameraPose.parse({"pos": [0, 0, 0.75], "lookat": [0, 0, 0]}))
    model = compile_spec(spec, path)

Every failure is a ValueError in one line naming the file (or the package) and what is
wrong with it: a path that does not exist, a package that is not installed, an MJCF that
does not parse or compile, a camera pose that is not one. The sim and camera actors build
their scenes from the same config, so both resolve the same file.
"""
from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

WHERE = "mjcf scene"
# the packages a stock model may come from, and the extra that brings each
EXTRAS = {"gymnasium": "gym"}


def one_line(exc: BaseException, limit: int = 300) -> str:
    """MuJoCo's multi-line compiler messages as one line (whitespace runs joined)."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def package_dir(package: str) -> Path:
    """The folder of an installed package, found without importing it.

    Parameters:
        package: an importable package name, e.g. "gymnasium".
    Returns:
        its directory. ValueError in one line when it is not installed (naming the extra
        that brings it, where the project has one) or is a module, not a package.
    """
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):        # a dotted name whose parent is missing
        spec = None
    if spec is None:
        extra = EXTRAS.get(package.split(".")[0])
        hint = f": pip install 'sebvs[{extra}]'" if extra else ""
        raise ValueError(f"{WHERE}: package {package!r} (config key 'package') is not "
                         f"installed{hint}")
    if not spec.submodule_search_locations:
        raise ValueError(f"{WHERE}: {package!r} (config key 'package') is a module, not a "
                         f"package with files in it")
    return Path(list(spec.submodule_search_locations)[0])


def find_mjcf(path: str, package: str = "") -> Path:
    """The MJCF file a config names.

    Parameters:
        path: the file; relative to the working directory, or to the package's folder
            when `package` is given.
        package: "" or an installed package that ships the file (a stock model).
    Returns:
        the file's path. ValueError in one line when there is no such file.
    """
    if not isinstance(path, str) or not path:
        raise ValueError(f"{WHERE}: config key 'path' (the MJCF file) is required, got "
                         f"{path!r}")
    if not isinstance(package, str):
        raise ValueError(f"{WHERE}: config key 'package' must be a package name, got "
                         f"{package!r}")
    where = package_dir(package) / path if package else Path(path).expanduser()
    if not where.is_file():
        inside = f" in package {package!r}" if package else ""
        what = "is a directory, not an MJCF file" if where.is_dir() else "no such MJCF file"
        raise ValueError(f"{WHERE}: {where}: {what}{inside} (config key 'path')")
    return where


def load_spec(path: Path) -> mujoco.MjSpec:
    """Parse the MJCF file (its includes and assets relative to it); ValueError in one
    line when it does not parse."""
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise ValueError(f"{WHERE}: {path} does not compile: {one_line(exc)}") from None


def compile_spec(spec: mujoco.MjSpec, path: Path) -> mujoco.MjModel:
    """The compiled model; ValueError in one line when MuJoCo's compiler refuses it."""
    try:
        return spec.compile()
    except ValueError as exc:
        raise ValueError(f"{WHERE}: {path} does not compile: {one_line(exc)}") from None


def _vector(value, key: str, n: int = 3) -> np.ndarray:
    ok = isinstance(value, (list, tuple)) and len(value) == n and all(
        not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        for v in value)
    if not ok:
        raise ValueError(f"{WHERE}: camera_pose.{key} must be {n} finite numbers, got "
                         f"{value!r}")
    return np.asarray(value, np.float64)


@dataclass(frozen=True)
class CameraPose:
    """A fixed camera in the world: at `pos` (m), looking at `lookat` (m), its image's up
    as close to `up` as the view allows, vertical field of view `fovy` (degrees)."""
    pos: tuple[float, float, float]
    lookat: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fovy: float = 45.0

    KEYS = ("pos", "lookat", "up", "fovy")

    @classmethod
    def parse(cls, table) -> "CameraPose":
        """The pose from the config's camera_pose table; ValueError in one line naming the
        key that is missing or wrong."""
        if not isinstance(table, dict):
            raise ValueError(f"{WHERE}: camera_pose must be a table {{ pos = [x, y, z], "
                             f"lookat = [x, y, z] }}, got {table!r}")
        unknown = sorted(set(table) - set(cls.KEYS))
        if unknown:
            raise ValueError(f"{WHERE}: camera_pose has no key {unknown[0]!r} (known: "
                             f"{', '.join(cls.KEYS)})")
        for key in ("pos", "lookat"):
            if key not in table:
                raise ValueError(f"{WHERE}: camera_pose.{key} = [x, y, z] is required")
        pos, lookat = _vector(table["pos"], "pos"), _vector(table["lookat"], "lookat")
        up = _vector(table.get("up", cls.up), "up")
        fovy = table.get("fovy", cls.fovy)
        if isinstance(fovy, bool) or not isinstance(fovy, (int, float)) or not 0 < fovy < 180:
            raise ValueError(f"{WHERE}: camera_pose.fovy must be in (0, 180) degrees, got "
                             f"{fovy!r}")
        if np.linalg.norm(lookat - pos) < 1e-9:
            raise ValueError(f"{WHERE}: camera_pose.lookat must differ from pos")
        if np.linalg.norm(up) < 1e-9:
            raise ValueError(f"{WHERE}: camera_pose.up must not be zero")
        return cls(tuple(pos), tuple(lookat), tuple(up), float(fovy))

    def quat(self) -> np.ndarray:
        """The camera frame's orientation, float64 (4,) w, x, y, z. A MuJoCo camera looks
        along its -z axis with +y up in the image; looking along `up`, the world's y (then
        x) stands in for it."""
        forward = np.subtract(self.lookat, self.pos)
        forward /= np.linalg.norm(forward)
        right = np.zeros(3)
        for up in (np.asarray(self.up, float), np.array([0.0, 1.0, 0.0]),
                   np.array([1.0, 0.0, 0.0])):
            right = np.cross(forward, up)
            if np.linalg.norm(right) > 1e-6 * np.linalg.norm(up):
                break
        right /= np.linalg.norm(right)
        image_up = np.cross(right, forward)
        mat = np.column_stack([right, image_up, -forward])      # camera axes in the world
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, mat.reshape(-1))
        return q


def add_camera(spec: mujoco.MjSpec, name: str, pose: CameraPose) -> None:
    """Add a fixed world camera `name` at `pose` to the spec (before it is compiled)."""
    spec.worldbody.add_camera(name=name, pos=list(pose.pos), quat=list(pose.quat()),
                              fovy=pose.fovy)
