"""The ERP model, input normalisation, checkpoints and tick pairing (no processes)."""
import json

import numpy as np
import pytest
import torch

from sebvs.policy.checkpoint import load_checkpoint, model_config, save_checkpoint
from sebvs.policy.infer import PolicySet, TickSync
from sebvs.policy.inputs import (Normalisation, channels, diff_input, event_input, model_input,
                                 rgb_input)
from sebvs.policy.model import ERP, count_parameters, sinusoidal_positions_2d

torch.set_num_threads(1)


@pytest.mark.parametrize("modality, ch, nav_params, arm_params", [
    ("rgb", 3, 103_682, 116_423), ("event", 2, 87_298, 100_039),
    ("rgb+event", 5, 136_450, 149_191)])
def test_variants_differ_only_in_input_channels(modality, ch, nav_params, arm_params):
    assert channels(modality) == ch
    nav, arm = ERP("nav", ch, 64), ERP("arm", ch, 64)
    assert count_parameters(nav) == nav_params     # at any size: positions are not weights
    assert count_parameters(arm) == arm_params
    # only the patch projection depends on the channels
    base = ERP("nav", 5, 64)
    shapes = {k: v.shape for k, v in nav.state_dict().items()}
    assert {k for k, s in shapes.items() if base.state_dict()[k].shape != s} == \
        ({"embed.proj.weight"} if ch != 5 else set())
    x = torch.rand(3, ch, 64, 64)
    nav.eval()
    y = nav(x)
    assert y.shape == (3, 2) and y.abs().max() <= 1
    assert arm(x).shape == (3, 6)


def test_token_count_and_shape_errors():
    m = ERP("nav", 5, 160)
    assert m.tokens.pos.shape == (1, 100, 64)          # 160 / 16 = 10 x 10 patches
    assert "tokens.pos" not in m.state_dict()
    with pytest.raises(ValueError, match=r"expected input \[B, 5, 160, 160\]"):
        m(torch.rand(1, 3, 160, 160))
    with pytest.raises(ValueError, match="multiple of the patch"):
        ERP("nav", 5, 100)


def test_conv_stem_gives_the_patch_grid_of_tokens():
    x = torch.rand(2, 5, 160, 160)
    patch, conv = ERP("arm", 5, 160).eval(), ERP("arm", 5, 160, stem="conv").eval()
    assert patch.embed(x).shape == conv.embed(x).shape == (2, 100, 64)
    assert conv(x).shape == (2, 6)
    # 3x3 stride-2 convolutions 5->16->32->64 (BatchNorm between) and a 64->64 projection
    assert count_parameters(conv.embed) == (5 * 16 * 9 + 2 * 16) + (16 * 32 * 9 + 2 * 32) + \
        (32 * 64 * 9 + 2 * 64) + (64 * 64 * 9 + 64)
    # a conv token sees beyond its patch (31 px receptive field), a patch token does not
    x2 = x.clone()
    x2[:, :, 15, 15] += 1.0                          # last pixel of patch (0, 0)
    conv_changed = (conv.embed(x2) - conv.embed(x)).abs().sum(dim=(0, 2)) > 0
    patch_changed = (patch.embed(x2) - patch.embed(x)).abs().sum(dim=(0, 2)) > 0
    assert conv_changed[0] and conv_changed[11]      # patch (0, 0) and its neighbour (1, 1)
    assert patch_changed[0] and not patch_changed[11]
    with pytest.raises(ValueError, match="unknown stem 'deep'"):
        ERP("arm", 5, 160, stem="deep")
    with pytest.raises(ValueError, match="power-of-two patch"):
        ERP("arm", 5, 144, patch=12, stem="conv")


def test_gated_stem_adds_event_tokens_through_its_gate():
    torch.manual_seed(0)
    m = ERP("nav", 7, 64, stem="gated").eval()              # rgb + 2 x 2 time bins
    stem = m.embed
    x = torch.rand(2, 7, 64, 64)
    rgb, events, gate = stem.gates(x)
    assert rgb.shape == events.shape == gate.shape == (2, 16, 64)
    assert torch.allclose(stem(x), rgb + gate * events)
    assert 0 < gate.min() and gate.max() < 1
    # the rgb planes reach only the rgb stem, the event planes only the event stem
    x_rgb, x_evt = x.clone(), x.clone()
    x_rgb[:, :3] += 1.0
    x_evt[:, 3:] += 1.0
    assert torch.equal(stem.gates(x_rgb)[1], events) and not torch.equal(stem.gates(x_rgb)[0], rgb)
    assert torch.equal(stem.gates(x_evt)[0], rgb) and not torch.equal(stem.gates(x_evt)[1], events)
    # a gate held shut leaves the rgb tokens alone: the events no longer change the action
    with torch.no_grad():
        stem.gate.bias.fill_(-1e4)
    assert torch.equal(stem(x), rgb) and torch.equal(m(x_evt), m(x))
    with torch.no_grad():
        stem.gate.bias.zero_()
    assert not torch.equal(m(x_evt), m(x))
    # both stems and the gate learn
    m.train()
    m.predict_loss_space(x).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0
               for p in (stem.rgb.net[0].weight, stem.events.net[0].weight, stem.gate.weight))


@pytest.mark.parametrize("stem", ["dual", "gated"])
@pytest.mark.parametrize("ch", [2, 3, 4])
def test_fusion_stems_need_rgb_and_event_planes(stem, ch):
    with pytest.raises(ValueError, match="fuses 3 rgb planes with 2K event planes .modality "
                                         r"rgb\+event., got \d input channels"):
        ERP("nav", ch, 64, stem=stem)


def test_dual_stem_is_the_gated_one_without_its_gate():
    torch.manual_seed(0)
    dual, gated = ERP("nav", 5, 64, stem="dual").eval(), ERP("nav", 5, 64, stem="gated").eval()
    x = torch.rand(2, 5, 64, 64)
    rgb, events = dual.embed.streams(x)
    assert torch.equal(dual.embed(x), rgb + events)
    # the same stems; the gate is the only difference in weights
    assert count_parameters(gated) - count_parameters(dual) == count_parameters(gated.embed.gate)
    assert {k for k in gated.state_dict()} - {k for k in dual.state_dict()} == \
        {"embed.gate.weight", "embed.gate.bias"}
    # an event plane moves the tokens at full weight: no gate holds it back
    x2 = x.clone()
    x2[:, 3:] += 1.0
    assert torch.allclose(dual.embed(x2) - dual.embed(x), dual.embed.streams(x2)[1] - events,
                          atol=1e-6)


def test_gated_stem_checkpoint_round_trip(tmp_path):
    torch.manual_seed(0)
    m = ERP("nav", 5, 32, stem="gated").eval()
    pt = save_checkpoint(m, model_config("nav", "rgb+event", Normalisation(size=32), "gated"),
                         tmp_path)
    model, cfg, _ = load_checkpoint(pt)
    assert cfg["stem"] == "gated" and isinstance(model.embed, type(m.embed))
    x = torch.rand(2, 5, 32, 32)
    assert torch.equal(model(x), m(x))


def test_conv_stem_checkpoint_round_trip_and_old_configs(tmp_path):
    norm = Normalisation(size=32)
    torch.manual_seed(0)
    m = ERP("arm", 3, 32, stem="conv").eval()
    pt = save_checkpoint(m, model_config("arm", "rgb", norm, "conv"), tmp_path)
    model, cfg, _ = load_checkpoint(pt)
    assert cfg["stem"] == "conv" and model.stem == "conv"
    x = torch.rand(2, 3, 32, 32)
    assert torch.equal(model(x), m(x))
    # a config from before the stem existed describes the patch stem
    old = json.loads(pt.with_suffix(".json").read_text())
    del old["stem"]
    pt.with_suffix(".json").write_text(json.dumps(old))
    with pytest.raises(ValueError, match="stem patch"):
        load_checkpoint(pt)


def test_sinusoidal_positions_are_distinct_and_bounded():
    pos = sinusoidal_positions_2d(10, 10, 64)
    assert pos.shape == (100, 64)
    assert pos.abs().max() <= 1
    d = torch.cdist(pos, pos)
    assert (d + torch.eye(100) * 10).min() > 0.1       # every patch position is distinct


def test_normalisation_round_trip():
    norm = Normalisation(size=32, event_clip=4)
    rgb = np.random.default_rng(0).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    x = rgb_input(rgb, norm)
    assert x.shape == (3, 32, 32) and x.dtype == np.float32
    assert np.array_equal(np.round(x.transpose(1, 2, 0) * 255).astype(np.uint8), rgb)
    ev = np.random.default_rng(1).integers(0, 10, (2, 32, 32), dtype=np.uint8)
    e = event_input(ev, norm)
    assert e.min() >= 0 and e.max() == 1
    assert np.array_equal(np.round(e * 4).astype(np.uint8), np.minimum(ev, 4))
    # recorded sizes differ from the model's (events downsampled): both area-resized
    both = model_input("rgb+event", norm, rgb=np.full((64, 48, 3), 255, np.uint8),
                       events=np.full((2, 16, 16), 2, np.uint8))
    assert both.shape == (5, 32, 32)
    assert np.allclose(both[:3], 1) and np.allclose(both[3:], 0.5)
    with pytest.raises(ValueError, match="needs an event frame"):
        model_input("event", norm, rgb=rgb)


@pytest.mark.parametrize("modality", ["rgb", "event", "rgb+event", "rgb+diff"])
def test_model_input_fills_one_array_with_each_stream_as_alone(modality):
    """Written in place, channel block by channel block: the same values, bit for bit, as
    each stream's own function (so lockstep results do not move), into a reused buffer."""
    rng = np.random.default_rng(3)
    norm = Normalisation(size=32, event_bins=2)
    rgb, prev = (rng.integers(0, 256, (48, 40, 3), dtype=np.uint8) for _ in range(2))
    ev = rng.integers(0, 12, (4, 16, 16), dtype=np.uint8)
    blocks = {"rgb": [rgb_input(rgb, norm)], "event": [event_input(ev, norm)],
              "rgb+event": [rgb_input(rgb, norm), event_input(ev, norm)],
              "rgb+diff": [rgb_input(rgb, norm), diff_input(rgb, prev, norm)]}[modality]
    buf = np.full((channels(modality, 2), 32, 32), np.nan, np.float32)
    x = model_input(modality, norm, rgb=rgb, events=ev, rgb_prev=prev, out=buf)
    assert x is buf
    np.testing.assert_array_equal(x, np.concatenate(blocks))
    np.testing.assert_array_equal(model_input(modality, norm, rgb=rgb, events=ev,
                                              rgb_prev=prev), x)
    with pytest.raises(ValueError, match=r"out must be float32 \["):
        model_input(modality, norm, rgb=rgb, events=ev, rgb_prev=prev, out=buf[1:])


def test_checkpoint_loads_weights_only_and_refuses_mismatch(tmp_path):
    norm = Normalisation(size=32)
    torch.manual_seed(0)
    m = ERP("nav", 2, 32)
    pt = save_checkpoint(m, model_config("nav", "event", norm), tmp_path)
    assert pt.name == "nav-event.pt"
    state = torch.load(pt, weights_only=True)
    assert all(torch.equal(state[k], v) for k, v in m.state_dict().items())
    model, cfg, n2 = load_checkpoint(pt, expect={"task": "nav", "modality": "event"})
    assert n2 == norm and not model.training
    with pytest.raises(ValueError, match="config has modality='event', expected 'rgb'"):
        load_checkpoint(pt, expect={"modality": "rgb"})
    # a config that does not describe the weights
    cfg_path = pt.with_suffix(".json")
    bad = json.loads(cfg_path.read_text())
    bad.update(modality="rgb", channels=3)
    cfg_path.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="weights do not match the config"):
        load_checkpoint(pt)


def test_policy_set_acts_and_tick_sync_pairs_by_tick(tmp_path):
    norm = Normalisation(size=32)
    for m in ("rgb", "event"):
        save_checkpoint(ERP("nav", channels(m), 32), model_config("nav", m, norm), tmp_path)
    ps = PolicySet({m: tmp_path / f"nav-{m}.pt" for m in ("rgb", "event")})
    y, _, ms = ps.act("event", events=np.zeros((2, 64, 64), np.uint8))
    assert y.shape == (2,) and y.dtype == np.float32 and ms > 0

    sync = TickSync(("rgb", "events"))
    frame = np.zeros((2, 2), np.uint8)
    sync.put("rgb", 0, frame, 0.0)
    assert sync.ready("rgb+event") is None and sync.ready("rgb") == 0
    sync.put("events", 1, frame, 0.1)
    sync.put("events", 0, frame, 0.0)
    assert sync.ready("rgb+event") == 0
    sync.take("rgb+event", 0)
    assert sync.ready("event") == 1
    sync.put("rgb", 0, frame, 0.0)                       # stale: dropped
    assert 0 not in sync.frames["rgb"]
    for t in range(2, 30):
        sync.put("rgb", t, frame, None)
    assert len(sync.frames["rgb"]) == sync.keep
