"""Typed overrides (sebvs/runtime/overrides.py): one merge rule, one parser of the
`actor.key=value` text, and no such text built anywhere else in the library."""
import ast
import json
import re
from pathlib import Path

import pytest

from sebvs.runtime.overrides import (as_mapping, layers, leaves, lookup, merge, parse_set,
                                     replace, resolved)
from sebvs.runtime.topology import TopologyError, load_topology

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "topologies" / "synthetic.toml"
NAV_POLICY = ROOT / "topologies" / "nav_policy.toml"


def test_later_wins_mappings_merge_anything_else_replaces():
    a = {"sim": {"config": {"lighting": "hdr", "width": 160}, "episodes": 2}}
    b = {"sim": {"config": {"lighting": "dusk"}, "randomise": {"objects": [1, 3]}},
         "topology": {"seed": 5}}
    assert merge(a, b) == {"sim": {"config": {"lighting": "dusk", "width": 160}, "episodes": 2,
                                   "randomise": {"objects": [1, 3]}},
                           "topology": {"seed": 5}}
    assert merge({"a": {"b": 1}}, {"a": 3}) == {"a": 3}           # a value replaces a table
    assert merge({"a": [1, 2]}, {"a": [3]}) == {"a": [3]}         # lists are values
    # a replaced table drops what it does not name, and later keys merge into it
    assert resolved(merge(a, {"sim": {"config": replace({"variant": "outdoor"})}},
                          {"sim": {"config": {"width": 96}}}))["sim"]["config"] == {
        "variant": "outdoor", "width": 96}
    # nothing is shared with the layers
    out = merge(a)
    out["sim"]["config"]["lighting"] = "low"
    assert a["sim"]["config"]["lighting"] == "hdr"


def test_merging_layers_first_is_applying_them_one_by_one():
    doc = {"actors": {"sim": {"config": {"lighting": "nominal", "variant": "indoor"},
                              "inputs": {"action": {"from": "policy/action", "queue": 8}}}}}
    steps = [{"sim": {"config": replace({"lighting": "hdr"})}},
             {"sim": {"config": {"variant": "outdoor"}, "inputs": {"action": "x/action"}}},
             {"sim": {"config": {"lighting": "dusk"}}}]
    one_by_one = doc
    for step in steps:
        one_by_one = resolved(merge(one_by_one, {"actors": step}))
    assert resolved(merge(doc, {"actors": merge(*steps)})) == one_by_one
    assert one_by_one["actors"]["sim"]["config"] == {"lighting": "dusk", "variant": "outdoor"}


def test_a_set_line_is_a_mapping_and_a_table_value_replaces():
    assert parse_set("sim.config.lighting=hdr") == {"sim": {"config": {"lighting": "hdr"}}}
    assert parse_set('camera.sensor="physical"') == {"camera": {"sensor": "physical"}}
    assert parse_set("topology.seed=5") == {"topology": {"seed": 5}}
    assert parse_set("emulator.overrides={downsample=2.0}") == {
        "emulator": {"overrides": replace({"downsample": 2.0})}}
    for bad, needle in (("sim", "expected actor.key=value"),
                        ("sim=3", "expected actor.key=value (or topology.key=value)"),
                        ("sim..x=3", "expected actor.key=value (or topology.key=value)")):
        with pytest.raises(TopologyError, match=re.escape(needle)):
            parse_set(bad)
    assert [line for _, line in layers(["a.b=1", {"c": {"d": 2}}])] == ["a.b=1", None]
    assert as_mapping(["a.b=1", {"a": {"c": 2}}]) == {"a": {"b": 1, "c": 2}}
    with pytest.raises(TypeError):
        layers("a.b=1")                  # one line where a list was meant
    assert dict(leaves({"sim": {"config": replace({"lighting": "hdr"})}, "t": {}})) == {
        ("sim", "config", "lighting"): "hdr", ("t",): {}}
    assert lookup({"sim": {"config": replace({"lighting": "hdr"})}}, "sim", "config",
                  "lighting") == "hdr"
    assert lookup({"sim": {}}, "sim", "config", default=7) == 7


def test_a_mapping_and_its_set_lines_load_the_same_topology():
    lines = ["policy.modality=rgb", 'policy.inputs={rgb="camera/rgb"}', "sim.episodes=3",
             "emulator.overrides.preset_version=2", "topology.seed=9"]
    mapping = {"policy": {"modality": "rgb", "inputs": replace({"rgb": "camera/rgb"})},
               "sim": {"episodes": 3}, "emulator": {"overrides": {"preset_version": 2}},
               "topology": {"seed": 9}}
    a, b = load_topology(NAV_POLICY, lines), load_topology(NAV_POLICY, mapping)
    assert a.digest == b.digest and a.seed == b.seed == 9
    assert list(b.actors["policy"].inputs) == ["rgb"]
    assert b.actors["emulator"].pruned                     # nothing reads events any more
    # nested: the topology's other emulator overrides stay
    assert b.actors["emulator"].params["overrides"] == {"downsample": 1.0, "preset_version": 2}
    # a table value replaces the table, as `--set 'key={...}'` always did
    c = load_topology(NAV_POLICY, ["emulator.overrides={preset_version=2}"])
    assert c.actors["emulator"].params["overrides"] == {"preset_version": 2}
    # mixed layers apply in order
    d = load_topology(NAV_POLICY, [{"sim": {"episodes": 4}}, "sim.episodes=5"])
    assert d.actors["sim"].params["episodes"] == 5


def test_an_actor_added_by_a_mapping_needs_its_run_and_errors_name_the_key_path(tmp_path):
    topo = load_topology(SYNTHETIC, {"tap": {"run": "actors.synthetic:Sink",
                                             "inputs": {"frames": "source/frames"}}})
    assert topo.actors["tap"].inputs["frames"].source == "source/frames"
    with pytest.raises(TopologyError) as err:
        load_topology(SYNTHETIC, {"tap": {"inputs": {"frames": "source/frames"}}})
    msg = str(err.value)
    assert "synthetic.toml: override tap.inputs: no actor 'tap'" in msg
    assert "a new actor's table needs its 'run'" in msg and len(msg.splitlines()) == 1
    with pytest.raises(TopologyError, match=r"^--set 'tap.width=3': no actor 'tap' .*add one "
                                            r"with tap.run=\"module:Class\" first"):
        load_topology(SYNTHETIC, ["tap.width=3"])
    with pytest.raises(TopologyError, match=r"synthetic.toml: override source.width.x: "
                                            r"'width' is not a table"):
        load_topology(SYNTHETIC, {"source": {"width": {"x": 1}}})
    with pytest.raises(TopologyError, match=r"^--set 'source.width.x=1': 'width' is not a "
                                            r"table"):
        load_topology(SYNTHETIC, ["source.width.x=1"])
    # a value's error names the file, table and key, whichever form gave it
    for given in (["source.width=-5"], {"source": {"width": -5}}):
        with pytest.raises(TopologyError, match=r"synthetic.toml: \[actors.source\] key "
                                                r"'width': -5 is out of range"):
            load_topology(SYNTHETIC, given)


def test_fanout_tasks_carry_plain_json(tmp_path):
    """A worker's Task carries a mapping that survives JSON (a Ray node, a spawned
    process), and the topology it loads from it is the one the driver checked."""
    from sebvs.eval.plan import EvalPlan, Run
    plan = EvalPlan(task="nav", modalities=["rgb"], conditions=["hdr"], episodes=1,
                    out=tmp_path, checkpoints=str(tmp_path / "none"), video=True)
    for modality in ("expert", "no_action", "rgb"):
        path, overrides = plan.overrides(Run("hdr", "indoor", modality))
        again = json.loads(json.dumps(overrides))
        assert again == overrides
        assert load_topology(path, again).digest == load_topology(path, overrides).digest


# ----------------------------------------------------- no `actor.key=value` text in the library
OVERRIDE_TEXT = re.compile(r"^[A-Za-z_]\w*(\.\w+)+=")
# where the text is read: the one parser
PARSERS = {"sebvs/runtime/overrides.py"}


def override_literals(path: Path, root: Path = ROOT) -> list[str]:
    """`actor.key=value`-shaped string literals (plain, or an f-string's leading text) in a
    file, but a metavar's placeholder (ACTOR.KEY=VALUE, the help's)."""
    tree = ast.parse(path.read_text(), str(path))
    skip = {id(k.value) for node in ast.walk(tree) if isinstance(node, ast.Call)
            for k in node.keywords if k.arg == "metavar"}
    # an f-string's pieces are read with it, from its start
    skip |= {id(v) for node in ast.walk(tree) if isinstance(node, ast.JoinedStr)
             for v in node.values}
    found = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            text = node.value
        elif isinstance(node, ast.JoinedStr) and node.values \
                and isinstance(node.values[0], ast.Constant):
            text = node.values[0].value
        else:
            continue
        if OVERRIDE_TEXT.match(text):
            found.append(f"{path.relative_to(root)}:{node.lineno}: {text[:50]!r}")
    return found


def test_no_library_code_builds_override_text():
    files = sorted((ROOT / "sebvs").rglob("*.py")) + sorted((ROOT / "actors").glob("*.py"))
    found = [hit for f in files if str(f.relative_to(ROOT)) not in PARSERS
             for hit in override_literals(f)]
    assert not found, ("actor.key=value text built in library code (give overrides as "
                       "nested mappings, sebvs/runtime/overrides.py):\n" + "\n".join(found))


def test_the_scan_sees_plain_and_formatted_override_text(tmp_path):
    planted = tmp_path / "sebvs" / "planted.py"
    planted.parent.mkdir()
    planted.write_text('hz = 3\nA = "sim.episode_s=2.0"\nB = f"sim.render_hz={hz}"\n'
                       'C = f"{hz}.x=1"\nD = "a sentence, sim.x=1 inside"\n'
                       'p.add_argument("--set", metavar="ACTOR.KEY=VALUE")\n')
    hits = override_literals(planted, tmp_path)
    assert [h.split(":")[1] for h in hits] == ["2", "3"], hits
