"""One thin module per actor: each wires library code to the runtime and holds no algorithm of its own."""
