"""A checkpoint's JSON config is validated like a topology before torch allocates anything:
hostile or mistaken values are one-line CheckpointErrors naming the file and the key, and
a config edited away from its weights (an input side, a modality) is refused."""
import json
import math
import time
from pathlib import Path

import pytest
import torch

import sebvs.policy.model as model_module
from sebvs.policy.checkpoint import (CONFIG_RECORD, CheckpointError, load_checkpoint,
                                     model_config, read_config, save_checkpoint)
from sebvs.policy.checkpoint_schema import MAX_CONFIG_BYTES, validate_config
from sebvs.policy.inputs import Normalisation
from sebvs.policy.model import ERP

torch.set_num_threads(1)
SHIPPED = sorted(Path(__file__).resolve().parents[1].glob("checkpoints/*.pt"))


@pytest.fixture
def ckpt(tmp_path):
    """A small event checkpoint (32 px) -> (its .pt, its config as saved)."""
    torch.manual_seed(0)
    pt = save_checkpoint(ERP("nav", 2, 32), model_config("nav", "event",
                                                         Normalisation(size=32)), tmp_path)
    return pt, json.loads(pt.with_suffix(".json").read_text())


def edited(pt: Path, good: dict, change) -> None:
    cfg = json.loads(json.dumps(good))
    change(cfg)
    pt.with_suffix(".json").write_text(json.dumps(cfg))


def refused(pt: Path) -> str:
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(pt)
    message = str(info.value)
    assert "\n" not in message
    assert str(pt.with_suffix("")) in message          # the file, .pt or .json
    return message


def no_torch_work(monkeypatch, *, weights_read: bool = False):
    """Fail the test if a refused config reached torch: no model built and, unless
    ``weights_read``, not even the weights read."""
    def boom(*args, **kwargs):
        raise AssertionError("a refused config reached torch")
    if not weights_read:
        monkeypatch.setattr(torch, "load", boom)
    monkeypatch.setattr(model_module, "ERP", boom)
    monkeypatch.setattr(model_module, "sinusoidal_positions_2d", boom)


def without_record(pt: Path) -> None:
    """Make ``pt`` a checkpoint as saved before the config record existed."""
    state = torch.load(pt, weights_only=True)
    del state[CONFIG_RECORD]
    torch.save(state, pt)


def norm_field(key, value):
    return lambda c: c["normalisation"].update({key: value})


def field(key, value):
    return lambda c: c.update({key: value})


HOSTILE = {
    "size 1e9": (field("size", 1e9), r"json: size: expected int, got float"),
    "size 48000": (field("size", 48000), r"json: size: 48000 is out of range"),
    "size -160": (field("size", -160), r"json: size: -160 is out of range"),
    "size '160'": (field("size", "160"), r"json: size: expected int, got str '160'"),
    "size 160.0": (field("size", 160.0), r"json: size: expected int, got float"),
    "size 40": (lambda c: (c.update(size=40), c["normalisation"].update(size=40)),
                r"json: size: 40 is not a multiple of the patch size 16"),
    "size true": (field("size", True), r"json: size: expected int, got bool"),
    "rgb_scale nan": (norm_field("rgb_scale", math.nan),
                      r"json: normalisation.rgb_scale: nan is not a finite number"),
    "rgb_scale inf": (norm_field("rgb_scale", math.inf),
                      r"json: normalisation.rgb_scale: inf is not a finite number"),
    "rgb_scale -inf": (norm_field("rgb_scale", -math.inf),
                       r"json: normalisation.rgb_scale: -inf is not a finite number"),
    "rgb_scale negative": (norm_field("rgb_scale", -1 / 255),
                           r"json: normalisation.rgb_scale: .* is out of range"),
    "rgb_scale zero": (norm_field("rgb_scale", 0), r"json: normalisation.rgb_scale: 0.0 is out"),
    "event_clip 0": (norm_field("event_clip", 0), r"json: normalisation.event_clip: 0 is out"),
    "event_clip nan": (norm_field("event_clip", math.nan),
                       r"json: normalisation.event_clip: expected int"),
    "event_clip 256": (norm_field("event_clip", 256), r"normalisation.event_clip: 256 is out"),
    "event_bins 0": (norm_field("event_bins", 0), r"json: normalisation.event_bins: 0 is out"),
    "event_bins huge": (norm_field("event_bins", 10 ** 6), r"normalisation.event_bins: 1000000"),
    "resize unknown": (norm_field("resize", "INTER_CUBIC"),
                       r"json: normalisation.resize: 'INTER_CUBIC' is not one of"),
    "normalisation key unknown": (norm_field("gamma", 2.2),
                                  r"json: normalisation.gamma: unknown key"),
    "normalisation not a table": (field("normalisation", [1, 2]),
                                  r"json: normalisation: expected a table"),
    "modality unknown": (field("modality", "lidar"), r"json: modality: 'lidar' is not one of"),
    "task unknown": (field("task", "fly"), r"json: task: 'fly' is not one of 'nav', 'arm'"),
    "stem unknown": (field("stem", "resnet"), r"json: stem: 'resnet' is not one of"),
    "version unknown": (field("version", 2), r"json: version: 2 is not one of 1"),
    "version missing": (lambda c: c.pop("version"), r"json: version is missing"),
    "size missing": (lambda c: c.pop("size"), r"json: size is missing"),
    "channels a string": (field("channels", "2"), r"json: channels: expected int"),
    "channel_order not a list": (field("channel_order", "on,off"),
                                 r"json: channel_order: expected a list"),
    "emulator not a table": (field("emulator", 2), r"json: emulator: expected a table"),
    "emulator version 3": (field("emulator", {"preset": "physical", "preset_version": 3}),
                           r"json: emulator.preset_version: 3 is not one of 1, 2"),
    "emulator version 2.0": (field("emulator", {"preset_version": 2.0}),
                             r"json: emulator.preset_version: 2.0 is not one of 1, 2"),
    "emulator version missing": (field("emulator", {"preset": "physical"}),
                                 r"json: emulator.preset_version: missing"),
    "emulator preset a number": (field("emulator", {"preset": 7, "preset_version": 1}),
                                 r"json: emulator.preset: expected str, got int 7"),
    "emulator key unknown": (field("emulator", {"preset_version": 1, "noise": "low"}),
                             r"json: emulator.noise: unknown key \(known: preset, "
                             r"preset_version\)"),
}


@pytest.mark.parametrize("case", HOSTILE, ids=list(HOSTILE))
def test_a_hostile_config_is_refused_naming_its_key_before_torch(ckpt, monkeypatch, case):
    pt, good = ckpt
    change, message = HOSTILE[case]
    edited(pt, good, change)
    no_torch_work(monkeypatch)
    assert pytest.raises(CheckpointError, load_checkpoint, pt).match(message)
    assert "\n" not in refused(pt)


@pytest.mark.parametrize("size", [10 ** 9, 48000, 1e9, 2 ** 70])
def test_a_huge_size_fails_fast_without_allocating(ckpt, monkeypatch, size):
    """48000 px built a 2.3 GB positional table before failing; now nothing is built."""
    pt, good = ckpt
    edited(pt, good, lambda c: (c.update(size=size), c["normalisation"].update(size=size)))
    no_torch_work(monkeypatch)
    t0 = time.perf_counter()
    assert "json: size: " in refused(pt)
    assert time.perf_counter() - t0 < 0.5


def test_a_size_that_is_not_the_weights_is_refused_naming_size(tmp_path):
    """The size changes no weight's shape (the positional table is rebuilt from it, not
    stored): weights trained at 160 px beside a config saying 320 loaded, and ran at 320."""
    torch.manual_seed(0)
    pt = save_checkpoint(ERP("nav", 3, 160), model_config("nav", "rgb",
                                                          Normalisation(size=160)), tmp_path)
    good = json.loads(pt.with_suffix(".json").read_text())
    load_checkpoint(pt)
    edited(pt, good, lambda c: (c.update(size=320), c["normalisation"].update(size=320)))
    message = refused(pt)
    assert "size is 320 in nav-rgb.json, but the weights were saved with size 160" in message


@pytest.mark.parametrize("change, key", [
    (norm_field("event_clip", 4), "normalisation.event_clip is 4"),
    (norm_field("rgb_scale", 1 / 127.5), "normalisation.rgb_scale is 0.00784"),
    (lambda c: c.update(modality="rgb", channels=3, channel_order=["r", "g", "b"]),
     "modality is 'rgb' in nav-event.json"),
])
def test_inputs_edited_away_from_the_weights_are_refused_naming_the_key(ckpt, change, key):
    pt, good = ckpt
    edited(pt, good, change)
    message = refused(pt)
    assert "weights do not match the config" in message and key in message


def test_rgb_event_and_rgb_diff_weights_are_told_apart(tmp_path):
    """Both take 5 planes, so no shape tells a frame-difference model from an event one."""
    torch.manual_seed(0)
    pt = save_checkpoint(ERP("nav", 5, 32), model_config("nav", "rgb+diff",
                                                         Normalisation(size=32)), tmp_path)
    good = json.loads(pt.with_suffix(".json").read_text())
    edited(pt, good, lambda c: c.update(modality="rgb+event",
                                        channel_order=["r", "g", "b", "on", "off"]))
    message = refused(pt)
    assert "modality is 'rgb+event' in nav-rgb+diff.json" in message


INCONSISTENT = {
    "channels": (field("channels", 3), "json: channels: 3 do not match modality 'event'"),
    "channel_order": (field("channel_order", ["off", "on"]),
                      "json: channel_order: ['off', 'on'] is not modality 'event'"),
    "normalisation.size": (norm_field("size", 64),
                           "json: normalisation.size: 64 is not the model's size 32"),
    "stem": (field("stem", "gated"), "json: stem: the gated stem fuses rgb and event planes: "
                                     "it needs modality rgb+event, not event"),
}


@pytest.mark.parametrize("case", INCONSISTENT, ids=list(INCONSISTENT))
def test_fields_that_disagree_are_refused_before_a_model_is_built(ckpt, monkeypatch, case):
    """Checked on a checkpoint saved before the config record, which has only its config
    to go by (one with the record names what its weights were saved with instead)."""
    pt, good = ckpt
    without_record(pt)
    load_checkpoint(pt)                                     # an older checkpoint loads
    change, message = INCONSISTENT[case]
    edited(pt, good, change)
    no_torch_work(monkeypatch, weights_read=True)
    assert message in refused(pt)


def test_a_damaged_config_record_is_refused(ckpt):
    pt, _ = ckpt
    state = torch.load(pt, weights_only=True)
    state[CONFIG_RECORD] = torch.tensor([0xFF, 0xFE], dtype=torch.uint8)
    torch.save(state, pt)
    assert f"damaged, its {CONFIG_RECORD} entry is unreadable" in refused(pt)


def test_a_deeply_nested_or_huge_config_is_refused_in_one_line(ckpt, monkeypatch):
    pt, _ = ckpt
    js = pt.with_suffix(".json")
    js.write_text("[" * 100_000 + "]" * 100_000)
    no_torch_work(monkeypatch)
    for read in (read_config, load_checkpoint):         # RecursionError escaped both
        with pytest.raises(CheckpointError, match="json: too deeply nested to read$"):
            read(pt)
    js.write_text(json.dumps({"task": "nav", "pad": "x" * MAX_CONFIG_BYTES}))
    with pytest.raises(CheckpointError, match="json: over 1,048,576 bytes, not a config$"):
        read_config(pt)
    js.write_text("[]")
    with pytest.raises(CheckpointError, match="json: expected a JSON object$"):
        load_checkpoint(pt)


def test_a_refused_expectation_does_not_echo_a_megabyte(ckpt):
    pt, good = ckpt
    with pytest.raises(CheckpointError, match=r"config has task='nav', expected 'arm'$"):
        load_checkpoint(pt, expect={"task": "arm"})
    edited(pt, good, field("dataset", "y" * 500_000))
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(pt, expect={"dataset": "x"})
    assert len(str(info.value)) < 400


def test_normalisation_checks_its_fields_wherever_it_is_made():
    assert Normalisation.from_dict({"size": 32}) == Normalisation(size=32)
    assert Normalisation(rgb_scale=1).to_dict()["rgb_scale"] == 1.0
    with pytest.raises(ValueError, match=r"^rgb_scale: nan is not a finite number$"):
        Normalisation(rgb_scale=math.nan)
    with pytest.raises(ValueError, match=r"^size: 48000 is out of range"):
        Normalisation(size=48000)
    with pytest.raises(ValueError, match=r"^event_clip: 0 is out of range"):
        Normalisation(event_clip=0)
    with pytest.raises(ValueError, match=r"^x.json: normalisation.rgb_scale: inf is not"):
        Normalisation.from_dict({"rgb_scale": math.inf}, where="x.json: normalisation")
    with pytest.raises(ValueError, match=r"^normalisation.size: expected int, got str"):
        Normalisation.from_dict({"size": "160"})


def test_a_checkpoint_of_non_finite_weights_is_not_written(ckpt):
    pt, good = ckpt
    before = pt.read_bytes(), pt.with_suffix(".json").read_bytes()
    m = ERP("nav", 2, 32)
    with torch.no_grad():
        m.head.mlp[1].weight[0, 0] = math.nan
    with pytest.raises(CheckpointError, match="not written, weight head.mlp.1.weight is not"):
        save_checkpoint(m, model_config("nav", "event", Normalisation(size=32)), pt.parent)
    # nor one whose config would not load, or does not describe the model
    with pytest.raises(CheckpointError, match="not written: .*size: 40 is not a multiple"):
        save_checkpoint(ERP("nav", 2, 32), model_config("nav", "event",
                                                        Normalisation(size=40)), pt.parent)
    with pytest.raises(CheckpointError, match="not written, config size 64 is not the model"):
        save_checkpoint(ERP("nav", 2, 32), model_config("nav", "event",
                                                        Normalisation(size=64)), pt.parent)
    assert (pt.read_bytes(), pt.with_suffix(".json").read_bytes()) == before


@pytest.mark.skipif(not SHIPPED, reason="no checkpoints in this checkout")
def test_the_shipped_checkpoints_pass_the_schema_and_still_load():
    """A guard for the schema, not the bug: every checkpoint the repository carries (saved
    before the config record) meets it, and loads as before."""
    for pt in SHIPPED:
        cfg = read_config(pt)
        fields, norm = validate_config(cfg, pt.with_suffix(".json"))
        assert norm.size == fields["size"] == cfg["size"]
    model, cfg, _ = load_checkpoint(SHIPPED[0])
    assert model.size == cfg["size"]


@pytest.mark.parametrize("record", [{"preset": "physical", "preset_version": 2},
                                    {"preset": None, "preset_version": 1},
                                    {"preset_version": 2}])
def test_the_emulator_record_is_accepted_and_optional(ckpt, record):
    """Training writes {"preset", "preset_version"} for modalities with events; the shipped
    checkpoints have none (version 1, as an evaluation reads it)."""
    from sebvs.policy.checkpoint_schema import check_emulator
    pt, good = ckpt
    assert "emulator" not in good
    load_checkpoint(pt)
    edited(pt, good, field("emulator", record))
    _, cfg, _ = load_checkpoint(pt)
    assert cfg["emulator"] == record
    assert check_emulator(record, "x") == {"preset": None, **record}
