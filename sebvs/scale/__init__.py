"""Fan-out: shards of a recording or evaluation run on a local pool of worker processes or
on a Ray cluster, each shard a topology run through the runtime's Supervisor; the same
pool runs the points of a training sweep (docs/scale.md)."""
from .pool import (RayMissing, Shard, ShardsLost, Task, disjoint_cpu_sets, fan_out,
                   run_task, split_episodes)

__all__ = ["RayMissing", "Shard", "ShardsLost", "Task", "disjoint_cpu_sets", "fan_out",
           "run_task", "split_episodes"]
