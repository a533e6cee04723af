"""Fan-out of episodes: shards of a recording or evaluation run on a local pool of worker
processes or on a Ray cluster, each shard a topology run through the runtime's Supervisor
(docs/scale.md)."""
from .pool import (RayMissing, Shard, ShardsLost, Task, fan_out, run_task,
                   split_episodes)

__all__ = ["RayMissing", "Shard", "ShardsLost", "Task", "fan_out", "run_task",
           "split_episodes"]
