"""The modality as a value (sebvs/policy/inputs.py, `Modality`): parsed once from its name
with one line for a wrong one, and the name wherever a name went before it was a value."""
import json
import pickle

import pytest

from sebvs.policy.inputs import (CONTROL_MODALITIES, MODALITIES, MODALITY_INPUTS,
                                 PAPER_MODALITIES, Modality, channel_names, channels,
                                 check_modality)


def test_each_name_parses_to_its_modality_and_a_modality_to_itself():
    assert [Modality.parse(n) for n in ("rgb", "event", "rgb+event", "rgb+diff")] == \
        [Modality.RGB, Modality.EVENT, Modality.RGB_EVENT, Modality.RGB_DIFF]
    assert Modality.parse(Modality.EVENT) is Modality.EVENT
    assert Modality("rgb+diff") is Modality.RGB_DIFF


@pytest.mark.parametrize("bad", ["x", "RGB", "", "rgb ", None, 3, ["rgb"], "e" * 500])
def test_any_other_value_is_refused_in_one_line(bad):
    for parse in (Modality.parse, Modality, check_modality, channels, channel_names):
        with pytest.raises(ValueError) as err:
            parse(bad)
        message = str(err.value)
        assert "\n" not in message and len(message) < 300, message
        assert message.endswith("(one of rgb, event, rgb+event, rgb+diff)"), message
        assert err.value.__cause__ is None and err.value.__context__ is None
    with pytest.raises(ValueError, match=r"^unknown modality 'x' \(one of rgb, event, "
                                         r"rgb\+event, rgb\+diff\)$"):
        Modality.parse("x")


def test_a_modality_is_its_name_at_every_edge():
    m = Modality.RGB_EVENT
    assert m == "rgb+event" and "rgb+event" == m and m != "rgb"
    assert hash(m) == hash("rgb+event")
    assert {"rgb+event": 1}[m] == 1 and {m: 1}["rgb+event"] == 1
    assert m in {"rgb", "rgb+event"} and "rgb+event" in {m}
    assert str(m) == "rgb+event" and f"nav-{m}.pt" == "nav-rgb+event.pt"
    assert repr(m) == "'rgb+event'" and f"{m!r}" == repr("rgb+event")
    assert json.dumps({m: [m]}) == '{"rgb+event": ["rgb+event"]}'
    assert pickle.loads(pickle.dumps(m)) is m
    assert m.value == "rgb+event" and type(m.value) is str


def test_streams_channels_and_names_follow_the_modality():
    assert Modality.RGB.streams == ("rgb",) and Modality.EVENT.streams == ("events",)
    assert Modality.RGB_EVENT.streams == ("rgb", "events")
    assert Modality.RGB_DIFF.streams == ("rgb", "rgb_prev")
    assert [m.channels() for m in Modality] == [3, 2, 5, 5]
    assert [m.channels(4) for m in Modality] == [3, 8, 11, 5]
    assert Modality.RGB_EVENT.channel_names(2) == ["r", "g", "b", "on_t0", "on_t1",
                                                   "off_t0", "off_t1"]
    assert Modality.RGB_DIFF.channel_names() == ["r", "g", "b", "up", "down"]
    assert [m.has_events for m in Modality] == [False, True, True, False]
    assert [m.reads_rgb for m in Modality] == [True, False, True, True]
    assert [m.reads_previous_frame for m in Modality] == [False, False, False, True]


def test_the_paper_has_three_and_rgb_diff_is_a_control():
    assert [m.is_control for m in Modality] == [False, False, False, True]
    assert PAPER_MODALITIES == (Modality.RGB, Modality.EVENT, Modality.RGB_EVENT)


def test_the_string_helpers_other_packages_call_stay_plain_strings():
    assert MODALITIES == ("rgb", "event", "rgb+event")
    assert CONTROL_MODALITIES == ("rgb+diff",)
    assert all(type(n) is str for n in MODALITIES + CONTROL_MODALITIES + tuple(MODALITY_INPUTS))
    assert MODALITY_INPUTS == {"rgb": ("rgb",), "event": ("events",),
                               "rgb+event": ("rgb", "events"), "rgb+diff": ("rgb", "rgb_prev")}
    assert channels("rgb+event", 4) == channels(Modality.RGB_EVENT, 4) == 11
    assert channel_names("event") == channel_names(Modality.EVENT) == ["on", "off"]
    assert check_modality("rgb+diff") is None
