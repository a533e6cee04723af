"""What the viewer shows, and where: one place for the entity paths and their archetypes.

The live tap (live.py) and the episode replay (replay.py) both write through ``ViewLog``,
so a run and its recording look the same in the viewer:

    <actor>/<output>                 an image: RGB, or an event frame in the colours of
                                     `sebvs events show` (ON blue, OFF red, on white)
    <image>/truth/bbox, /centroid    the target's truth over that image (nav), scaled from
    <image>/truth/cubes              the RGB frame's pixels to the image's; the cubes (arm)
    truth/<name>                     scalar truth: distance, visible
    commands/<actor>/<output>        the command, one series per component (v, w / x..yaw)
    latency/<a>_to_<b>               each hop's latency, microseconds (sebvs.data.recording
                                     .hop_latencies: the same hops the recorder stores)
    run/episodes                     episode start and end, as text

Timelines: ``tick`` (the control tick) and ``sim_time`` (simulated seconds).
"""
from __future__ import annotations

import collections
from typing import Any

import numpy as np

from sebvs.dvs.render import event_counts, event_image

# the names of a command's components, by the array's name (nav "action", arm "pose")
COMMAND_NAMES = {"action": ["v", "w"], "pose": ["x", "y", "z", "roll", "pitch", "yaw"]}
TRUTH_SCALARS = ("distance", "visible")
BOX_COLOUR = (40, 200, 80)
CENTROID_COLOUR = (255, 200, 0)


def command_names(key: str, dim: int) -> list[str]:
    names = COMMAND_NAMES.get(key)
    return names if names and len(names) == dim else [f"{key}[{i}]" for i in range(dim)]


def hop_entity(hop: str) -> str:
    """"sim->camera" -> "latency/sim_to_camera" (">" would need escaping in a path)."""
    return "latency/" + hop.replace("->", "_to_")


def _finite(values, n: int) -> list[float] | None:
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        return None
    return out if len(out) == n and all(np.isfinite(out)) else None


def truth_marks(truth: dict, size: tuple[int, int]) -> dict[str, Any]:
    """The target's truth in an image of ``size`` (w, h) pixels: {"bbox": [u0, v0, u1, v1],
    "centroid": [u, v], "cubes": ([[u, v], ...], [rgb, ...], target index)}, each present
    only when the truth gives it (nav: bbox when visible, centroid when in front; arm: the
    visible cubes). The truth's pixels are the RGB frame's ("image" [w, h])."""
    marks: dict[str, Any] = {}
    if not isinstance(truth, dict):
        return marks
    image = _finite(truth.get("image", ()), 2)
    sx, sy = (size[0] / image[0], size[1] / image[1]) if image and min(image) > 0 else (1, 1)
    visible = truth.get("visible")
    bbox = _finite(truth.get("bbox", ()), 4)
    if bbox and visible not in (False, 0, 0.0) and bbox[2] > bbox[0] and bbox[3] > bbox[1]:
        marks["bbox"] = [bbox[0] * sx, bbox[1] * sy, bbox[2] * sx, bbox[3] * sy]
    centroid = _finite(truth.get("centroid", ()), 2)
    if centroid and min(centroid) >= 0:
        marks["centroid"] = [centroid[0] * sx, centroid[1] * sy]
    cubes = truth.get("cubes")
    if isinstance(cubes, list):
        uv, colours, target = [], [], truth.get("target", -1)
        for i, c in enumerate(cubes):
            p = _finite(c.get("uv", ()), 2) if isinstance(c, dict) else None
            if p and c.get("visible"):
                uv.append([p[0] * sx, p[1] * sy])
                rgb = _finite(c.get("rgb", ()), 3) or [1.0, 1.0, 1.0]
                colours.append([int(255 * min(max(v, 0), 1)) for v in rgb])
                if i == target:
                    target = len(uv) - 1
        if uv:
            marks["cubes"] = (uv, colours, target)
    return marks


def layout(rrb, images: list[str]):
    """The viewer's default layout (rerun.blueprint ``rrb``): the images side by side, each
    with its truth drawn over it, above the commands, the hop latencies, the scalar truth
    and the episodes' log. Left to itself the viewer gives each entity its own view."""
    series = rrb.Horizontal(rrb.TimeSeriesView(origin="commands", name="commands"),
                            rrb.TimeSeriesView(origin="latency", name="latency per hop (us)"),
                            rrb.TimeSeriesView(origin="truth", name="truth"),
                            rrb.TextLogView(origin="run", name="episodes"),
                            column_shares=[3, 3, 2, 2])
    if not images:
        return rrb.Blueprint(series, collapse_panels=False)
    top = rrb.Horizontal(*[rrb.Spatial2DView(origin=p, name=p) for p in images])
    return rrb.Blueprint(rrb.Vertical(top, series, row_shares=[3, 2]), collapse_panels=False)


class ViewLog:
    """Writes SEBVS streams into one rerun recording; counts the rows per entity.

    ``rr`` is the rerun module (imported by the command, never at import of this module),
    ``rec`` the RecordingStream whose sink the command chose.
    """

    def __init__(self, rr, rec) -> None:
        self.rr = rr
        self.rec = rec
        self.rows: collections.Counter = collections.Counter()
        self.sizes: dict[str, tuple[int, int]] = {}     # image entity -> (w, h)
        self._named: set[str] = set()                   # series whose names were sent
        self._hop_tick: dict[str, int] = {}             # hop -> newest tick logged
        self._shown: set[str] = set()                   # truth marks on screen now

    # ------------------------------------------------------------------ time
    def at(self, tick: int | None, t_sim: float | None) -> None:
        """Place what follows on the timelines (a value that is None leaves its timeline
        out of those rows)."""
        self.rec.reset_time()
        if tick is not None:
            self.rec.set_time("tick", sequence=int(tick))
        if t_sim is not None:
            self.rec.set_time("sim_time", duration=float(t_sim))

    def _log(self, path: str, *archetypes) -> None:
        self.rec.log(path, *archetypes)
        self.rows[path] += 1

    # ------------------------------------------------------------------ images
    def image(self, path: str, rgb: np.ndarray, truth: dict | None = None) -> None:
        """An RGB frame [H, W, 3] uint8 (copied: the caller's buffer may be a ring slot)."""
        rgb = np.array(rgb, dtype=np.uint8, copy=True)
        self._log(path, self.rr.Image(rgb))
        self.sizes[path] = (rgb.shape[1], rgb.shape[0])
        self.overlay(path, truth)

    def events(self, path: str, frame: np.ndarray, representation: str = "counts",
               truth: dict | None = None) -> None:
        """An accumulator's event frame, drawn as `sebvs events show` draws it."""
        img = event_image(event_counts(frame, representation))
        self._log(path, self.rr.Image(img))
        self.sizes[path] = (img.shape[1], img.shape[0])
        self.overlay(path, truth)

    def overlay(self, path: str, truth: dict | None) -> None:
        """The target's truth over the image at ``path`` (nothing when there is none)."""
        if not truth or path not in self.sizes:
            return
        rr, marks = self.rr, truth_marks(truth, self.sizes[path])
        drawn = {}
        if "bbox" in marks:
            drawn["bbox"] = rr.Boxes2D(array=[marks["bbox"]], colors=[BOX_COLOUR],
                                       array_format=rr.Box2DFormat.XYXY, labels=["target"])
        if "centroid" in marks:
            drawn["centroid"] = rr.Points2D([marks["centroid"]], colors=[CENTROID_COLOUR],
                                            radii=2.0)
        if "cubes" in marks:
            uv, colours, target = marks["cubes"]
            drawn["cubes"] = rr.Points2D(uv, colors=colours, radii=3.0,
                                         labels=["target" if i == target else ""
                                                 for i in range(len(uv))])
        for name in ("bbox", "centroid", "cubes"):
            entity = f"{path}/truth/{name}"
            if name in drawn:
                self._log(entity, drawn[name])
                self._shown.add(entity)
            elif entity in self._shown:
                # not given this tick (target out of view): clear the last one, which the
                # viewer would otherwise keep showing
                self.rec.log(entity, rr.Clear(recursive=False))
                self._shown.discard(entity)

    # ------------------------------------------------------------------ series
    def command(self, path: str, key: str, values: np.ndarray) -> None:
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if path not in self._named:
            self._named.add(path)
            self.rec.log(path, self.rr.SeriesLines(names=command_names(key, values.size)),
                         static=True)
        self._log(path, self.rr.Scalars(values))

    def truth_scalars(self, truth: dict) -> None:
        for name in TRUTH_SCALARS:
            v = truth.get(name) if isinstance(truth, dict) else None
            if isinstance(v, (bool, int, float, np.number)) and np.isfinite(float(v)):
                self._log(f"truth/{name}", self.rr.Scalars(float(v)))

    def latency(self, hops: dict[str, float], tick: int | None) -> None:
        """Per-hop latencies (us). A hop that several messages share (sim->camera is in
        the RGB frame's stamps and in the event frame's) is logged once per tick."""
        for hop, us in hops.items():
            if not np.isfinite(us):
                continue
            if tick is not None:
                if self._hop_tick.get(hop, -1) >= tick:
                    continue
                self._hop_tick[hop] = tick
            self._log(hop_entity(hop), self.rr.Scalars(float(us)))

    def episode(self, meta: dict) -> None:
        """An episode's start or end (the sim's `episode` message)."""
        event = meta.get("event", "?")
        text = f"episode {meta.get('episode', '?')} {event}"
        if event == "end":
            text += f": {meta.get('reason') or 'ended'}"
            for key in ("steps", "rows"):
                if key in meta:
                    text += f", {meta[key]} {key}"
            if meta.get("outcome"):
                text += f", outcome {meta['outcome']}"
        self._log("run/episodes", self.rr.TextLog(text))
