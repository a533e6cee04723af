"""A recorded episode (sebvs/data/episode.py) replayed into the viewer.

The recorder taps camera/rgb, accumulator/frames and expert/action in every recording
topology (topologies/*_record.toml), so a replay writes them at those entity paths: a
recording looks like the run it came from. Rows are placed by their own tick and t_sim.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .entities import ViewLog

RGB_ENTITY = "camera/rgb"
EVENTS_ENTITY = "accumulator/frames"
COMMAND_ENTITY = "commands/expert/action"


class NotAnEpisode(ValueError):
    """The file is missing or is not an episode file; the message says which and why."""


def open_for_replay(path: str | Path):
    """The episode at ``path``, or NotAnEpisode naming the file and what is wrong (an
    episode its dataset's index lists must still be the file the index recorded)."""
    from sebvs.data.episode import open_episode     # h5py: only when a file is replayed
    from sebvs.dataset_files import EpisodeDamaged, verify_file
    from sebvs.h5named import FileUnreadable
    path = Path(path)
    if not path.is_file():
        raise NotAnEpisode(f"{path}: no such file")
    try:
        verify_file(path)
        return open_episode(path)
    except (FileUnreadable, EpisodeDamaged) as exc:     # each names the file already
        raise NotAnEpisode(str(exc)) from None
    except (OSError, ValueError) as exc:
        raise NotAnEpisode(f"{path}: not an episode file ({str(exc).splitlines()[0]})") \
            from None


def image_entities(ep) -> list[str]:
    return [RGB_ENTITY] + ([EVENTS_ENTITY] if ep.event_frame is not None else [])


def replay_episode(ep, view: ViewLog) -> int:
    """Write every row of the open episode ``ep``; returns the number of rows."""
    n = len(ep)
    ticks, t_sim = ep.tick[:], ep.t_sim[:]
    target = ep.target[:]
    truth = {k: v[:] for k, v in ep.truth.items()}
    latency = {k: v[:] for k, v in ep.latency.items()}
    representation = str(ep.attrs.get("event_representation") or "counts")
    if n:
        view.at(int(ticks[0]), float(t_sim[0]))
        view.episode({"event": "start", "episode": ep.attrs.get("sim_episode", "?")})
    for i in range(n):
        tick = int(ticks[i])
        view.at(tick, float(t_sim[i]))
        row_truth = {k: v[i] for k, v in truth.items()}
        view.image(RGB_ENTITY, ep.rgb[i], row_truth)
        if ep.event_frame is not None:
            view.events(EVENTS_ENTITY, ep.event_frame[i], representation, row_truth)
        view.command(COMMAND_ENTITY, ep.target_key, target[i])
        view.truth_scalars(row_truth)
        view.latency({hop: float(v[i]) for hop, v in latency.items()
                      if np.isfinite(v[i])}, tick)
    if n:
        view.episode({"event": "end", "episode": ep.attrs.get("sim_episode", "?"),
                      "reason": ep.attrs.get("end_reason", ""), "rows": n})
    return n
