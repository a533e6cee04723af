"""A checkpoint's closed-loop ablation: the level of each channel of one part of its input,
and the `--set` that holds that part at those levels while `sebvs eval` runs.

    research/sensors/ablation_levels.py DATASET CHECKPOINT.pt [--part second|rgb] [--json OUT]

DATASET is the recording the checkpoint was trained on. The levels are the channels' mean
over its validation episodes (every k-th frame, as loss_by_condition.py --ablate does per
group), in the model's input units, so that an offline and a closed-loop ablation hold
the stream at the same level. "second" is the events (RGB+Event) or the frame difference
(RGB+Diff); "rgb" the frame. Printed: the levels, and the override for `sebvs eval --set`
(the policy actor's `ablate` parameter), which names the ablation in every action's meta
and in the actor's stats. research/sensors/ablation_plan.md is the plan that uses it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from research.sensors.loss_by_condition import MeanAblated, ablated_channels  # noqa: E402
from tools.eval.val_loss import frames_of, validation_of  # noqa: E402


def levels_of(data: Path, pt: Path, part: str = "second") -> dict:
    """{checkpoint, modality, part, channels, levels} over the checkpoint's validation
    frames in ``data``. ValueError where the modality has no such part beside another."""
    _, cfg, norm, episodes = validation_of(pt, data)
    channels = ablated_channels(cfg, part)
    frames = frames_of(data, episodes, cfg, norm)
    try:
        level = MeanAblated(frames, channels).level
    finally:
        frames.close()
    return {"checkpoint": str(pt), "modality": cfg["modality"], "part": part,
            "channels": channels, "levels": [float(v) for v in level]}


def override(levels: dict) -> str:
    """The policy actor's `ablate` as one `--set` (TOML inline table)."""
    values = ", ".join(repr(v) for v in levels["levels"])
    return (f'policy.ablate={{"{levels["modality"]}"={{channels={levels["channels"]}, '
            f'levels=[{values}]}}}}')


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("dataset", type=Path, help="the recording the checkpoint was trained on")
    ap.add_argument("checkpoint", type=Path, help="a .pt file, its .json record beside it")
    ap.add_argument("--part", choices=["second", "rgb"], default="second",
                    help="the part of the input to hold (default: second, the events or "
                         "the frame difference)")
    ap.add_argument("--json", type=Path, help="also write the levels here")
    args = ap.parse_args(argv)
    try:
        levels = levels_of(args.dataset, args.checkpoint, args.part)
    except (ValueError, FileNotFoundError) as e:
        print(f"ablation_levels: {e}", file=sys.stderr)
        return 2
    print(f"{levels['modality']} ({args.checkpoint}): channels {levels['channels']} at "
          f"{', '.join(f'{v:.6g}' for v in levels['levels'])}")
    print(f"--set '{override(levels)}'")
    if args.json:
        args.json.write_text(json.dumps(levels, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
