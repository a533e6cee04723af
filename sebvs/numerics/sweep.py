"""What every stability-sweep case shares: the case itself, the three classes and how an
exception is classified, so the physics and emulator cases need nothing from each other."""
from __future__ import annotations

from dataclasses import dataclass, field

CLASSES = ("stable", "detected", "undetected")


@dataclass(frozen=True)
class SweepCase:
    """One setting to try. kind: "nav_servo" | "nav_contact" | "belt" | "arm" | "dvs"."""
    kind: str
    params: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.kind + "[" + ",".join(f"{k}={v}" for k, v in self.params.items()) + "]"


def classify_exception(exc: BaseException) -> tuple[str, str]:
    """Emulator-style cases: a ValueError with a message is a clear refusal (detected);
    anything else is a crash nobody meant (undetected)."""
    if isinstance(exc, ValueError) and str(exc):
        return "detected", f"ValueError: {exc}"
    return "undetected", f"{type(exc).__name__}: {exc}"


def summarise(results: list[dict]) -> dict:
    """{"counts": {class: n}, "by_kind": {kind: {class: n}}, "cases": results}."""
    counts = {c: 0 for c in CLASSES}
    by_kind: dict[str, dict[str, int]] = {}
    for r in results:
        counts[r["class"]] += 1
        k = by_kind.setdefault(r["kind"], {c: 0 for c in CLASSES})
        k[r["class"]] += 1
    return {"counts": counts, "by_kind": by_kind, "cases": results}
