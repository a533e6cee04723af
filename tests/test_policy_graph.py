"""Inference graphs (sebvs/policy/graph.py): the frozen graph computes what the model does,
and a graph that cannot be built or disagrees falls back to eager with a reason."""
import numpy as np
import pytest
import torch

from sebvs.policy.checkpoint import model_config, save_checkpoint
from sebvs.policy.graph import FROZEN_ATOL, check_graph, inference_graph
from sebvs.policy.infer import PolicySet
from sebvs.policy.inputs import Normalisation, channels
from sebvs.policy.model import ERP

torch.set_num_threads(1)


def trained_like(task: str, modality: str, stem: str, size: int = 32) -> ERP:
    """A model whose BatchNorm layers hold statistics far from the identity, so that
    folding them into the convolutions is exercised, not skipped as a no-op."""
    torch.manual_seed(3)
    model = ERP(task, channels(modality), size, stem=stem)
    for bn in (m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)):
        bn.running_mean.uniform_(-0.5, 0.5)
        bn.running_var.uniform_(0.2, 3.0)
        bn.weight.data.uniform_(0.5, 1.5)
        bn.bias.data.uniform_(-0.2, 0.2)
    return model.eval()


@pytest.mark.parametrize("task, modality, stem", [
    ("nav", "rgb", "patch"), ("nav", "event", "conv"), ("nav", "rgb+event", "conv"),
    ("arm", "rgb+event", "gated"), ("arm", "rgb+event", "dual"), ("arm", "rgb", "conv")])
def test_frozen_graph_matches_the_model(task, modality, stem):
    model = trained_like(task, modality, stem)
    example = torch.zeros(1, model.in_channels, 32, 32)
    run, used, why = inference_graph(model, example, "frozen")
    assert (used, why) == ("frozen", None)
    assert run is not model
    gen = torch.Generator().manual_seed(1)
    with torch.inference_mode():
        for _ in range(3):
            x = torch.rand(example.shape, generator=gen) * 4 - 2
            want, got = model(x), run(x)
            assert got.shape == want.shape
            assert float((got - want).abs().max()) < 1e-5


def test_eager_is_the_model_itself():
    model = trained_like("nav", "rgb", "conv")
    run, used, why = inference_graph(model, torch.zeros(1, 3, 32, 32), "eager")
    assert run is model and used == "eager" and why is None
    with pytest.raises(ValueError, match="unknown inference graph 'jit'"):
        check_graph("jit")


def test_a_graph_that_cannot_be_built_falls_back_to_eager(monkeypatch):
    model = trained_like("nav", "event", "conv")

    def refuse(*a, **k):
        raise RuntimeError("TorchScript is not in this build")
    monkeypatch.setattr(torch.jit, "freeze", refuse)
    run, used, why = inference_graph(model, torch.zeros(1, 2, 32, 32), "frozen")
    assert run is model and used == "eager"
    assert why == "cannot freeze: RuntimeError: TorchScript is not in this build"


def test_a_graph_that_disagrees_with_the_model_falls_back_to_eager(monkeypatch):
    model = trained_like("nav", "event", "conv")
    real = torch.jit.optimize_for_inference

    def off_by_a_little(module):
        frozen = real(module)
        return lambda x: frozen(x) + 10 * FROZEN_ATOL
    monkeypatch.setattr(torch.jit, "optimize_for_inference", off_by_a_little)
    run, used, why = inference_graph(model, torch.zeros(1, 2, 32, 32), "frozen")
    assert run is model and used == "eager"
    assert why.startswith("frozen graph differs from eager by 0.001")


def test_policy_set_on_frozen_graphs_acts_like_eager(tmp_path):
    norm = Normalisation(size=32)
    for m, stem in (("rgb", "patch"), ("rgb+event", "conv")):
        save_checkpoint(trained_like("nav", m, stem), model_config("nav", m, norm, stem),
                        tmp_path)
    table = {m: tmp_path / f"nav-{m}.pt" for m in ("rgb", "rgb+event")}
    eager, frozen = PolicySet(table), PolicySet(table, graph="frozen")
    assert {m: p.graph for m, p in frozen.policies.items()} == \
        {"rgb": "frozen", "rgb+event": "frozen"} and frozen.fallbacks == {}
    assert {p.graph for p in eager.policies.values()} == {"eager"}
    frozen.warm_up()
    rng = np.random.default_rng(0)
    for _ in range(3):
        obs = {"rgb": rng.integers(0, 256, (64, 64, 3), dtype=np.uint8),
               "events": rng.integers(0, 5, (2, 64, 64), dtype=np.uint8)}
        for m in table:
            want, _, _ = eager.act(m, **obs)
            got, _, ms = frozen.act(m, **obs)
            assert got.dtype == np.float32 and ms > 0
            np.testing.assert_allclose(got, want, atol=1e-5)
    with pytest.raises(ValueError, match="unknown inference graph"):
        PolicySet(table, graph="fast")
