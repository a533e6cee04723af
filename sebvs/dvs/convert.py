"""Offline conversion: a video file or an image folder to an HDF5 event file."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
from tqdm import tqdm

from .emulator import EventEmulator
from .h5io import EventFileWriter
from .params import EmulatorParams

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}


def frames_of(source: Path, fps: float | None) -> tuple[Iterator[tuple[np.ndarray, int]], int]:
    """(iterator of (RGB uint8 frame, t ns), frame count) of a video or an image folder."""
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise ValueError(f"{source}: no images ({', '.join(sorted(IMAGE_SUFFIXES))})")
        if not fps:
            raise ValueError(f"{source}: an image folder needs --fps")
        period = 1e9 / fps

        def images():
            for i, path in enumerate(files):
                img = cv2.imread(str(path), cv2.IMREAD_COLOR)
                if img is None:
                    raise ValueError(f"{path}: not a readable image")
                yield cv2.cvtColor(img, cv2.COLOR_BGR2RGB), round(i * period)
        return images(), len(files)
    if not source.exists():
        raise ValueError(f"{source}: no such file or folder")
    cap = cv2.VideoCapture(str(source))
    if not cap.isOpened():
        raise ValueError(f"{source}: OpenCV cannot open this video")
    rate = fps or cap.get(cv2.CAP_PROP_FPS)
    if not rate or rate <= 0:
        raise ValueError(f"{source}: the video reports no frame rate; pass --fps")
    count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))

    def video():
        i = 0
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    return
                yield cv2.cvtColor(img, cv2.COLOR_BGR2RGB), round(i * 1e9 / rate)
                i += 1
        finally:
            cap.release()
    return video(), count


def convert(source: str | Path, out: str | Path, params: EmulatorParams,
            fps: float | None = None, progress: bool = True) -> dict:
    """Emulate events for every frame of ``source`` and write them to ``out``."""
    frames, count = frames_of(Path(source), fps)
    emu = EventEmulator(params)
    out = Path(out)
    # written beside and renamed at the end: an interrupted conversion leaves the file it
    # was told to replace (--force) as it was, never half of a new one
    partial = out.with_name(out.stem + ".partial" + out.suffix)
    writer = None
    n_frames = 0
    try:
        for frame, t_ns in tqdm(frames, total=count or None, unit="frame", disable=not progress,
                                desc="v2e"):
            events = emu.step(frame, t_ns)
            if writer is None:
                h, w = emu.shape
                writer = EventFileWriter(partial, w, h, {"emulator": params.to_dict(),
                                                         "source": str(source)})
            writer.append(events)
            n_frames += 1
        if writer is not None:
            writer.close()
    except BaseException:
        if writer is not None:
            writer.close()
        partial.unlink(missing_ok=True)
        raise
    if writer is None:
        raise ValueError(f"{source}: no frames")
    os.replace(partial, out)
    return {"frames": n_frames, "events": writer.count, "gap_restarts": emu.gap_restarts,
            "out": str(out)}
