"""The event camera: the v2e-model emulator, the accumulator that turns events into frames, and event files."""
