"""Text and Graphviz views of a topology, pruned actors marked."""
from __future__ import annotations

from .topology import Topology


def describe(topo: Topology) -> str:
    lines = [f"topology {topo.name} ({topo.path}), clock {topo.clock}, seed {topo.seed}, "
             f"restart {topo.restart}, transport {topo.transport}"]
    for a in topo.actors.values():
        mark = "  [pruned: no output consumed]" if a.pruned else ""
        lines.append(f"  {a.name}  ({a.run}){mark}")
        for i in a.inputs.values():
            lines.append(f"      <- {i.name:<10} from {i.source}  (queue {i.queue})")
        for out in a.cls.outputs:
            users = [f"{n}.{i.name}" for n, i in topo.consumers(a.name, out)]
            lines.append(f"      -> {out:<10} to {', '.join(users) or '(nobody)'}")
    return "\n".join(lines)


def to_dot(topo: Topology) -> str:
    lines = [f'digraph "{topo.name}" {{', "  rankdir=LR;"]
    for a in topo.actors.values():
        style = ', style=dashed, color=gray' if a.pruned else ""
        label = f"{a.name}\\n{a.run}" + ("\\n(pruned)" if a.pruned else "")
        lines.append(f'  "{a.name}" [shape=box, label="{label}"{style}];')
    for a in topo.actors.values():
        for i in a.inputs.values():
            lines.append(f'  "{i.producer}" -> "{a.name}" [label="{i.output}->{i.name}"];')
    lines.append("}")
    return "\n".join(lines)
