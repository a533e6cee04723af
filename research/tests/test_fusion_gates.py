"""research/ideal8/fusion_gates.py: which tokens cover the target, how much event mass a patch
holds, and a checkpoint without a gate is refused by name."""

import numpy as np
import pytest
import torch

from sebvs.policy.checkpoint import model_config, save_checkpoint
from sebvs.policy.inputs import Normalisation
from sebvs.policy.model import ERP
from research.tests.study_loader import study_module


@pytest.fixture(scope="module")
def tool():
    with study_module("ideal8/fusion_gates") as module:
        yield module


def test_target_tokens_are_the_patches_the_box_overlaps(tool):
    # a 640 px image, a box from (100, 200) to (180, 260): at 160 px, x 25..45, y 50..65,
    # so patch columns 1 and 2 (16..48) and rows 3 and 4 (48..80) of a 10 x 10 grid
    mask = tool.target_tokens(np.array([100.0, 200.0, 180.0, 260.0]), np.array([640, 640]),
                              160, 16).reshape(10, 10)
    assert sorted(zip(*np.nonzero(mask))) == [(3, 1), (3, 2), (4, 1), (4, 2)]
    # a box on a patch edge does not spill into the next patch
    mask = tool.target_tokens(np.array([0.0, 0.0, 64.0, 64.0]), np.array([640, 640]),
                              160, 16).reshape(10, 10)
    assert mask.sum() == 1 and mask[0, 0]


def test_event_mass_is_summed_per_patch_over_every_plane(tool):
    events = np.zeros((4, 32, 32), np.float32)
    events[0, 0, 0] = 1.0                  # patch (0, 0)
    events[3, 31, 16] = 0.5                # patch (1, 1), another plane
    mass = tool.token_event_mass(events, 16)
    assert mass.tolist() == [1.0, 0.0, 0.0, 0.5]


def test_a_checkpoint_without_a_gate_is_refused(tool, tmp_path):
    pt = save_checkpoint(ERP("nav", 5, 32, stem="conv"),
                         model_config("nav", "rgb+event", Normalisation(size=32), "conv"),
                         tmp_path)
    with pytest.raises(SystemExit, match="conv-stem checkpoint; this reads the gate"):
        tool.collect(pt, tmp_path, 10, 0.15)


def test_frame_tokens_report_gate_and_event_share_per_token(tool):
    torch.manual_seed(0)
    stem = ERP("nav", 5, 32, stem="gated").eval().embed
    gate, share = tool.frame_tokens(stem, np.random.rand(5, 32, 32).astype(np.float32))
    assert gate.shape == share.shape == (4,)
    assert ((0 < gate) & (gate < 1)).all() and ((0 <= share) & (share <= 1)).all()
    with torch.no_grad():
        stem.gate.bias.fill_(-1e4)         # shut: nothing of the events reaches the tokens
    gate, share = tool.frame_tokens(stem, np.random.rand(5, 32, 32).astype(np.float32))
    assert np.allclose(share, 0) and np.allclose(gate, 0)


def test_rank_correlation_is_spearman_s(tool):
    a = np.array([1.0, 2.0, 3.0, 4.0])
    assert tool.rank_correlation(a, a ** 3) == pytest.approx(1.0)
    assert tool.rank_correlation(a, -a) == pytest.approx(-1.0)
    # ties take their mean rank: [0, 0, 1, 1] against 1..4 ranks as [0.5, 0.5, 2.5, 2.5]
    assert tool.rank_correlation(np.array([0.0, 0.0, 1.0, 1.0]), a) == \
        pytest.approx(np.corrcoef([0.5, 0.5, 2.5, 2.5], [0, 1, 2, 3])[0, 1])
    assert tool.rank_correlation(np.zeros(4), a) is None
