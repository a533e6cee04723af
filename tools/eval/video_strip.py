"""Evenly spaced frames of episode videos, one row per video, in one PNG: a still a document
can show where a video cannot be committed (an `sebvs eval --video` episode is 0.5-3.5 MB).

    python tools/eval/video_strip.py out/eval/videos/nominal__indoor__event__ep0.mp4 \\
        out/eval/videos/nominal__outdoor__event__ep0.mp4 --frames 5 --out strip.png

Each frame keeps the video's caption (modality, tick, centre error), so the row reads as
the episode's timeline.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np


def read_frames(path: Path, count: int, skip: int) -> list[np.ndarray]:
    """``count`` frames spread evenly from frame ``skip`` to the last one of ``path``."""
    cap = cv2.VideoCapture(str(path))
    try:
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if not cap.isOpened() or total <= 0:
            raise ValueError(f"{path}: not a readable video")
        if skip >= total:
            raise ValueError(f"{path}: --skip {skip} is past its {total} frames")
        frames = []
        for k in np.linspace(skip, total - 1, count).round().astype(int):
            cap.set(cv2.CAP_PROP_POS_FRAMES, int(k))
            ok, frame = cap.read()
            if not ok:
                raise ValueError(f"{path}: frame {k} of {total} could not be read")
            frames.append(frame)
        return frames
    finally:
        cap.release()


def strip(videos: list[Path], count: int, skip: int, width: int) -> np.ndarray:
    """One row of ``count`` frames per video, each frame scaled to ``width`` px."""
    rows = []
    for path in videos:
        frames = [cv2.resize(f, (width, round(f.shape[0] * width / f.shape[1])),
                             interpolation=cv2.INTER_AREA) for f in read_frames(path, count, skip)]
        rows.append(np.hstack(frames))
    if len({r.shape[1] for r in rows}) > 1:
        raise ValueError("the videos give rows of different widths: give them the same size")
    return np.vstack(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("videos", nargs="+", type=Path, help="episode videos, one row each")
    ap.add_argument("--frames", type=int, default=5, help="frames per row (default 5)")
    ap.add_argument("--skip", type=int, default=10,
                    help="first frame to show (default 10: past the policy's first ticks)")
    ap.add_argument("--width", type=int, default=320, help="width of one frame in px")
    ap.add_argument("--out", type=Path, required=True, help="PNG to write")
    args = ap.parse_args(argv)
    if args.frames < 1 or args.width < 16 or args.skip < 0:
        ap.error("--frames >= 1, --width >= 16 and --skip >= 0")
    try:
        image = strip(args.videos, args.frames, args.skip, args.width)
    except ValueError as exc:
        print(f"video_strip: {exc}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), image)
    print(f"wrote {args.out}: {len(args.videos)} row(s) of {args.frames} frames, "
          f"{image.shape[1]} x {image.shape[0]} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
