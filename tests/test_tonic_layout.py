"""sebvs.dvs.tonic_layout.to_tonic: our events (t ns, p +1/-1) in Tonic's convention (t us,
p 0/1), so Tonic's frame transforms, which index the polarity channel with p, keep ON and
OFF apart."""
import numpy as np
import pytest

from sebvs.dvs.emulator import EVENT_DTYPE, EventEmulator
from sebvs.dvs.params import EmulatorParams
from sebvs.dvs.tonic_layout import TONIC_DTYPE, to_tonic


def tonic_frame(events: np.ndarray, width: int, height: int) -> np.ndarray:
    """[2, H, W] counts the way Tonic's ToFrame adds one slice: p as the channel index."""
    frame = np.zeros((2, height, width), np.int64)
    np.add.at(frame, (events["p"].astype(int), events["y"], events["x"]), 1)
    return frame


def test_both_polarities_survive_into_their_own_channels():
    ev = np.zeros(5, EVENT_DTYPE)
    ev["x"], ev["y"] = [0, 1, 2, 2, 3], [1, 1, 0, 0, 2]
    ev["t"] = [1_000, 1_999, 2_000, 5_000_001, 7_000_000_999]
    ev["p"] = [1, -1, -1, 1, -1]
    out = to_tonic(ev)
    assert out.dtype == TONIC_DTYPE and out.dtype.names == ("x", "y", "t", "p")
    np.testing.assert_array_equal(out["x"], ev["x"])
    np.testing.assert_array_equal(out["y"], ev["y"])
    np.testing.assert_array_equal(out["t"], [1, 1, 2, 5_000, 7_000_000])      # floored us
    np.testing.assert_array_equal(out["p"].astype(int), [1, 0, 0, 1, 0])
    frame = tonic_frame(out, 4, 3)
    assert frame[1].sum() == 2 and frame[0].sum() == 3      # ON in channel 1, OFF in 0
    assert frame[1, 1, 0] == 1 and frame[0, 1, 1] == 1 and frame[0, 0, 2] == 1
    # what handing our array over as it is would do: -1 indexes the last channel too
    merged = tonic_frame(ev, 4, 3)
    assert merged[0].sum() == 0 and merged[1].sum() == 5


def test_the_emulator_s_events_keep_their_counts_per_polarity():
    emu = EventEmulator(EmulatorParams(pos_thres=0.2, neg_thres=0.2, sigma_thres=0.0,
                                       cutoff_hz=0.0, downsample=1.0, blur=False, seed=1))
    dark, bright = np.full((8, 8), 40, np.uint8), np.full((8, 8), 200, np.uint8)
    bright[:, :4] = 40
    packets = [emu.step(f, t) for f, t in ((dark, 0), (bright, 10_000_000),
                                              (dark, 20_000_000))]
    ev = np.concatenate(packets)
    assert (ev["p"] > 0).any() and (ev["p"] < 0).any()
    t0 = int(ev["t"].min())
    out = to_tonic(ev, t_origin_ns=t0)
    frame = tonic_frame(out, 8, 8)
    assert frame[1].sum() == int((ev["p"] > 0).sum())
    assert frame[0].sum() == int((ev["p"] < 0).sum())
    np.testing.assert_array_equal(out["t"], (ev["t"] - t0) // 1000)
    assert out["t"].min() == 0 and (np.diff(out["t"]) >= 0).all()     # still in time order


def test_a_mapping_of_arrays_converts_and_bad_input_is_named():
    cols = {"x": np.array([3], np.uint16), "y": np.array([4], np.uint16),
            "t": np.array([2_500], np.int64), "p": np.array([-1], np.int8)}
    out = to_tonic(cols)
    assert out.tolist() == [(3, 4, 2, False)]
    assert to_tonic(np.zeros(0, EVENT_DTYPE)).dtype == TONIC_DTYPE
    with pytest.raises(ValueError, match="need fields x, y, t, p, got x, y, t"):
        to_tonic({k: cols[k] for k in "xyt"})
    with pytest.raises(ValueError, match="different lengths"):
        to_tonic({**cols, "t": np.array([1, 2], np.int64)})
    wide = np.zeros(1, EVENT_DTYPE)
    wide["x"] = 40_000
    with pytest.raises(ValueError, match="x spans 40000..40000, beyond Tonic's int16"):
        to_tonic(wide)
