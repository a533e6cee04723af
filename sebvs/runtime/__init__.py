"""The actor runtime: ZeroMQ actors in their own processes, wired by a topology file."""
from .actor import Actor
from .params import Range
from .wire import Message

__all__ = ["Actor", "Message", "Range"]
