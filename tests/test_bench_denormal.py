"""tools/bench/bench_denormal.py: it finds subnormal weights where a training left them, and
reads a resume file's model and settings back."""
import json
from dataclasses import replace

import torch

from tests.tools_loader import tool_module


def _model_with_subnormals():
    from sebvs.policy.inputs import channels
    from sebvs.policy.model import ERP
    model = ERP("nav", channels("rgb", 1), 32, stem="conv")
    with torch.no_grad():
        w = model.encoder.linear1.weight
        w[:3, :5] = 1e-40                       # 15 subnormal floats in one tensor
        w[3, 0] = 0.0                           # zero is not subnormal
        w[4, 0] = 1.2e-38                       # nor is the smallest normal's neighbour above
    return model


def test_census_counts_subnormals_and_names_their_tensor():
    with tool_module("bench/bench_denormal") as tool:
        c = tool.census(_model_with_subnormals(), None)
    assert c["model"] == 15 and c["adam_state"] == 0
    assert list(c["tensors"]) == ["encoder.linear1.weight"]
    assert c["tensors"]["encoder.linear1.weight"].startswith("15 of ")


def test_the_tool_reads_a_resume_file_and_reports_both_modes(tmp_path, capsys):
    from sebvs.policy.resume import fingerprint, save_state
    from sebvs.policy.train import settings_for
    model = _model_with_subnormals()
    s = settings_for("nav", stem="conv")
    s = replace(s, norm=replace(s.norm, size=32))
    opt = torch.optim.Adam(model.parameters(), lr=s.lr, weight_decay=s.weight_decay)
    path = tmp_path / "nav-rgb.resume.pt"
    save_state(path, {"fingerprint": fingerprint(s, "rgb", "data"), "epoch": 3,
                      "model": model.state_dict(), "optimizer": opt.state_dict()})
    with tool_module("bench/bench_denormal") as tool:
        assert tool.main([str(path), "--repeats", "1", "--batch", "2",
                          "--json", str(tmp_path / "r.json")]) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert (report["kind"], report["modality"], report["epoch"]) == ("resume", "rgb", 3)
    assert report["subnormals"]["model"] == 15
    assert set(report["median_ms"]) == {"saved_as_trained", "saved_flush", "saved_zeroed",
                                        "fresh_as_trained"}
    # flushing or zeroing a weight of 1e-40 changes no output here: each such product is
    # far below the rounding of the sums it joins
    assert report["inference_outputs_identical"] == {"flush": True, "zeroed": True}
