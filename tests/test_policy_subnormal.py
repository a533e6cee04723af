"""sebvs/policy/subnormal.py and `sebvs train --zero-subnormals`: weights that weight decay
drove below float32's smallest normal are set to zero after every step, with Adam's moments,
and nothing else is touched; a training without the option is as before, resume files
included."""
import json
import re

import pytest
import torch

from sebvs.policy.inputs import Normalisation, channels
from sebvs.policy.model import ERP
from sebvs.policy.resume import fingerprint
from sebvs.policy.subnormal import ZeroSubnormals, count_subnormals, zero_subnormals_
from sebvs.policy.train import _epoch, settings_for, train
from tests.policy_data import make_dataset

torch.set_num_threads(1)


def _model():
    torch.manual_seed(0)
    model = ERP("nav", channels("rgb", 1), 32, stem="conv")
    with torch.no_grad():
        w = model.encoder.linear1.weight
        w[:2, :4] = 1e-40                      # 8 subnormal
        w[2, 0], w[2, 1], w[2, 2] = 0.0, 1.2e-38, -3e-39   # zero, normal, subnormal
    return model


def test_zeroing_takes_the_subnormals_of_weights_and_adam_state_and_nothing_else():
    model = ERP("nav", channels("rgb", 1), 32, stem="conv")
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    model(torch.rand(2, 3, 32, 32)).sum().backward()
    opt.step()                                 # Adam has its moments now
    p = model.encoder.linear1.weight
    with torch.no_grad():
        p[:2, :4] = 1e-40                      # 8 subnormal
        p[2, 0], p[2, 1], p[2, 2] = 0.0, 1.2e-38, -3e-39   # zero, normal, subnormal
        opt.state[p]["exp_avg"][0, :3] = 5e-41
        opt.state[p]["exp_avg_sq"][1, :2] = 1e-45
    before = {k: v.clone() for k, v in model.state_dict().items()}
    assert zero_subnormals_(model, opt) == 9 + 3 + 2
    assert count_subnormals(p) == 0
    assert count_subnormals(opt.state[p]["exp_avg"]) == 0
    assert count_subnormals(opt.state[p]["exp_avg_sq"]) == 0
    w = p.detach()
    assert float(w[2, 1]) == pytest.approx(1.2e-38, rel=1e-6) and float(w[2, 0]) == 0
    for k, v in model.state_dict().items():    # every other float is as it was
        if v.is_floating_point():
            kept = (before[k] == 0) | (before[k].abs() >= torch.finfo(v.dtype).tiny)
            assert torch.equal(v[kept], before[k][kept]), k
    assert zero_subnormals_(model, opt) == 0


def test_an_epoch_with_the_zeroer_leaves_no_subnormal_weight():
    batches = [(torch.rand(2, 3, 32, 32), torch.rand(2, 2)) for _ in range(3)]
    for zero in (False, True):
        model = _model()
        opt = torch.optim.Adam(model.parameters(), lr=0.0)     # the weights stay put
        zeroer = ZeroSubnormals(model, opt) if zero else None
        _epoch(model, batches, torch.nn.MSELoss(), opt, progress=False, after_step=zeroer)
        left = count_subnormals(model.encoder.linear1.weight)
        assert (left == 0) if zero else (left == 9)
        if zero:
            assert zeroer.total == 9


def test_the_option_is_recorded_and_absent_from_old_fingerprints(tmp_path):
    s = settings_for("nav")
    assert "zero_subnormals" not in fingerprint(s, "rgb", "h")     # resume files stay valid
    on = settings_for("nav", zero_subnormals=True)
    assert json.loads(fingerprint(on, "rgb", "h"))["settings"]["zero_subnormals"] is True
    data = make_dataset(tmp_path / "d", episodes=3, frames=8, target="gain")
    said = []
    cfg = train(data, tmp_path / "on", "nav", ["rgb"], epochs=1, batch=4,
                norm=Normalisation(size=32), zero_subnormals=True, progress=False,
                log=said.append)["rgb"]
    assert cfg["training"]["zero_subnormals"] is True
    assert any(re.fullmatch(r"  epoch 1: train \S+  val \S+  lr \S+  [\d,]+ s  "
                            r"subnormals zeroed 0", line) for line in said), said
    cfg = train(data, tmp_path / "off", "nav", ["rgb"], epochs=1, batch=4,
                norm=Normalisation(size=32), progress=False, log=said.append)["rgb"]
    assert "zero_subnormals" not in cfg["training"]
