"""A recording's frames as the probe's (input, truth) pairs.

    frames = load_frames("datasets/probe/expert/hdr__indoor")    # every indexed episode
    x = frames.inputs("event", range(10))       # float32 [10, 2, 160, 160], as a policy sees
    frames.centroid[k], frames.visible[k], frames.episode[k]

The frames are kept as the files store them (uint8 RGB and event counts) and turned into
model input per batch by sebvs.policy.inputs.model_input with the shipped checkpoints'
Normalisation, so the probe reads exactly what a policy of that modality reads. The truth
is the sim's, per frame (sebvs/sim/nav.py `truth`): `truth/centroid` [T, 2] px (the
projected cube centre, -1 behind the camera), `truth/visible` [T] (the cube's box overlaps
the image), in the recorded image's pixels; here the centroid is also given as a fraction
of the image's width and height.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sebvs.data.episode import open_episode
from sebvs.data.index import DatasetIndex
from sebvs.dataset_files import verify_entries
from sebvs.policy.inputs import Modality, Normalisation, model_input

# what the probe reads, by the policies' modality names: the frame camera, the events, both
SENSORS = {"rgb": "rgb", "event": "event", "both": "rgb+event"}
TRUTH_KEYS = ("centroid", "visible")


class ProbeDataError(ValueError):
    """A dataset the probe cannot use; its message is one line naming the dataset."""


@dataclass
class Frames:
    """Every frame of a dataset's episodes, in index order."""
    root: Path
    files: list[str]             # episode file names, index order
    episode: np.ndarray          # [N] int, the frame's episode (position in `files`)
    rgb: np.ndarray | None       # [N, H, W, 3] uint8
    events: np.ndarray | None    # [N, 2K, h, w] uint8
    centroid: np.ndarray         # [N, 2] float, px of the recorded image (NaN: not visible)
    visible: np.ndarray          # [N] bool
    image: tuple[int, int]       # (width, height) of the recorded image, px
    attrs: dict                  # the first episode's attributes (scene, conditions, ...)

    @property
    def centroid_fraction(self) -> np.ndarray:
        """[N, 2] the centroid as a fraction of the image's width and height."""
        return self.centroid / np.array(self.image, np.float64)

    def frames_of(self, episodes) -> np.ndarray:
        """Indices of the frames of the given episode positions."""
        return np.flatnonzero(np.isin(self.episode, np.asarray(list(episodes), int)))

    def inputs(self, sensor: str, index, norm: Normalisation | None = None) -> np.ndarray:
        """float32 [len(index), C, S, S]: frames `index` as a `sensor` policy sees them
        (rgb: 3 channels; event: ON, OFF counts clipped and scaled; both: rgb then events)."""
        modality = Modality.parse(SENSORS[sensor])
        norm = norm or Normalisation()
        index = np.asarray(index, int)
        out = np.empty((len(index), modality.channels(norm.event_bins), norm.size, norm.size),
                       np.float32)
        for i, k in enumerate(index):
            model_input(modality, norm,
                        rgb=self.rgb[k] if self.rgb is not None else None,
                        events=self.events[k] if self.events is not None else None,
                        out=out[i])
        return out


def _truth_of(ep, name: str, root: Path) -> np.ndarray:
    missing = [k for k in TRUTH_KEYS if k not in ep.truth]
    if missing:
        raise ProbeDataError(
            f"{root}: {name} has no truth/{' or truth/'.join(missing)} (the probe needs the "
            f"sim's per-frame truth: record with `sebvs record`, whose scenes give it)")
    return ep.truth


def load_frames(root: str | Path, sensors=("rgb", "event", "both"),
                verify: bool = True) -> Frames:
    """Read a dataset's frames and truth (only the streams `sensors` need).

    Parameters:
        root: the dataset folder (index.json and episode files).
        sensors: which of SENSORS the caller will ask `inputs` for.
        verify: refuse the dataset when an episode differs from its index
            (sebvs/dataset_files.py).

    Returns:
        The Frames. ProbeDataError (one line naming the dataset) when it is not a dataset,
        holds no episodes, an episode lacks the truth or a stream a sensor needs.
    """
    root = Path(root)
    if not (root / "index.json").is_file():
        raise ProbeDataError(f"{root}: not a dataset (no index.json)")
    index = DatasetIndex(root)
    entries = index.episodes()
    if not entries:
        raise ProbeDataError(f"{root}: the dataset holds no episodes")
    for s in sensors:
        if s not in SENSORS:
            raise ProbeDataError(f"unknown sensor {s!r} (one of {', '.join(SENSORS)})")
    if verify:
        try:
            verify_entries(root, entries)
        except ValueError as exc:
            raise ProbeDataError(str(exc)) from None
    want_rgb = any(Modality.parse(SENSORS[s]).reads_rgb for s in sensors)
    want_events = any(Modality.parse(SENSORS[s]).has_events for s in sensors)
    rgb, events, cent, vis, epi, files = [], [], [], [], [], []
    attrs, image = {}, None
    for k, entry in enumerate(entries):
        with open_episode(root / entry["file"]) as ep:
            truth = _truth_of(ep, entry["file"], root)
            if want_events and ep.event_frame is None:
                raise ProbeDataError(f"{root}: {entry['file']} has no event frames "
                                     f"(recorded without the event chain)")
            c = np.asarray(truth["centroid"][()], np.float64).reshape(len(ep), 2)
            v = np.asarray(truth["visible"][()], np.float64).reshape(len(ep))
            v = np.nan_to_num(v, nan=0.0) > 0.5
            if "image" in truth:
                wh = np.asarray(truth["image"][()], np.float64).reshape(len(ep), 2)
                shape = tuple(int(x) for x in wh[np.isfinite(wh).all(1)][0]) \
                    if np.isfinite(wh).all(1).any() else None
            else:
                shape = None
            shape = shape or (int(ep.rgb.shape[2]), int(ep.rgb.shape[1]))
            if image is None:
                image, attrs = shape, dict(ep.attrs)
            elif shape != image:
                raise ProbeDataError(f"{root}: {entry['file']} has {shape[0]} x {shape[1]} "
                                     f"px images, the first episode {image[0]} x {image[1]}")
            c = np.where(v[:, None] & np.isfinite(c), c, np.nan)
            if want_rgb:
                rgb.append(np.asarray(ep.rgb[()]))
            if want_events:
                events.append(np.asarray(ep.event_frame[()]))
            cent.append(c)
            vis.append(v)
            epi.append(np.full(len(ep), k, int))
            files.append(entry["file"])
    return Frames(root=root, files=files, episode=np.concatenate(epi),
                  rgb=np.concatenate(rgb) if want_rgb else None,
                  events=np.concatenate(events) if want_events else None,
                  centroid=np.concatenate(cent), visible=np.concatenate(vis),
                  image=image, attrs=attrs)
