"""`sebvs view`: a live nav run and a recorded episode written to .rrd and read back."""
import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import h5py
import numpy as np
import pytest

from sebvs.cli import main
from sebvs.data.episode import EpisodeWriter, open_episode
from sebvs.dvs.render import event_image
from sebvs.view.cli import MISSING_RERUN

ROOT = Path(__file__).resolve().parents[1]
NAV_RECORD = ROOT / "topologies" / "nav_record.toml"
H, W, T = 16, 20, 6


def write_episode(path: Path) -> dict:
    """A tiny nav episode: random RGB, event frames at half size with one saturated ON
    and one OFF pixel, a target visible on even rows, no sim->camera latency on row 0."""
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 255, (T, H, W, 3), dtype=np.uint8)
    ev = np.zeros((T, 2, H // 2, W // 2), np.uint8)
    ev[:, 0, 1, 2] = 9
    ev[:, 1, 3, 4] = 9
    action = rng.uniform(-1, 1, (T, 2)).astype(np.float32)
    bbox = np.array([[2.0 + i, 4.0, 10.0 + i, 12.0] for i in range(T)])
    w = EpisodeWriter(path, "nav", {"scene": "nav", "event_representation": "counts"})
    for i in range(T):
        w.append(rgb=rgb[i], event_frame=ev[i], action=action[i], t_sim=0.1 * i, tick=50 + i,
                 latency={"sim->camera": 100.0 + i} if i else {},
                 truth={"bbox": bbox[i], "centroid": bbox[i].reshape(2, 2).mean(0),
                        "visible": i % 2 == 0, "image": [W, H], "distance": 1.0 + i})
    w.finish("time_limit")
    return {"rgb": rgb, "ev": ev, "action": action, "bbox": bbox}


def read_rrd(path: Path) -> dict:
    """entity -> {"rows": [row, ...] ordered by tick, "static": {component: value}}; a row
    is {"tick", "sim_time", component: value, "image": [H, W, 3] array for an Image}."""
    from rerun.chunk import RrdReader
    out: dict = {}
    for chunk in RrdReader(path).stream().to_chunks():
        rb = chunk.to_record_batch()
        ent = out.setdefault(chunk.entity_path.lstrip("/"), {"rows": [], "static": {}})
        names = [n for n in rb.schema.names if not n.startswith("rerun.") and n != "log_time"]
        if chunk.is_static:
            ent["static"].update({n: rb.column(n).to_pylist() for n in names})
            continue
        rows = [{} for _ in range(rb.num_rows)]
        for name in names:
            col = rb.column(name)
            if name == "Image:buffer":
                flat = col.flatten().flatten().to_numpy(zero_copy_only=False)
                at = 0
                for row, fmt in zip(rows, rb.column("Image:format").to_pylist()):
                    h, w = fmt[0]["height"], fmt[0]["width"]
                    row["image"] = flat[at:at + h * w * 3].reshape(h, w, 3)
                    at += h * w * 3
            else:
                for row, value in zip(rows, col.to_pylist()):
                    row[name] = value
        ent["rows"].extend(rows)
    for ent in out.values():
        ent["rows"].sort(key=lambda r: r.get("tick", -1))
    return out


def col(got: dict, entity: str, name: str, only_with: str | None = None) -> list:
    """One column of an entity's rows (None where a row lacks it); ``only_with``: just the
    rows that have that component (an archetype's rows, not its Clears)."""
    return [r.get(name) for r in got[entity]["rows"] if only_with is None or only_with in r]


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


# ---------------------------------------------------------------- without rerun, bad input
def test_without_rerun_the_command_says_which_extra(tmp_path, monkeypatch, capsys):
    ep = tmp_path / "ep.h5"
    write_episode(ep)
    monkeypatch.setitem(sys.modules, "rerun", None)     # `import rerun` raises ImportError
    assert main(["view", str(ep), "--save", str(tmp_path / "x.rrd")]) == 2
    assert one_line_error(capsys) == MISSING_RERUN
    assert not (tmp_path / "x.rrd").exists()


def test_the_command_line_does_not_import_rerun():
    code = ("import sys, sebvs.cli; sebvs.cli.build_parser(); "
            "print(sorted(m for m in ('rerun', 'h5py', 'sebvs.view.live') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_bad_input_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys):
    pytest.importorskip("rerun")
    ep = tmp_path / "ep.h5"
    write_episode(ep)
    (tmp_path / "garbage.h5").write_text("not hdf5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = [1, 2, 3]
    rrd = str(tmp_path / "x.rrd")
    cases = [(["view", str(tmp_path / "missing.h5"), "--save", rrd], "no such file"),
             (["view", str(tmp_path / "garbage.h5"), "--save", rrd], "not a readable HDF5 file"),
             (["view", str(tmp_path / "other.h5"), "--save", rrd], "not an episode file"),
             (["view", "no-such-run-xyz", "--save", rrd], "no live run named"),
             (["view", str(ep), "--save", str(tmp_path / "no" / "x.rrd")], "does not exist")]
    for argv, expected in cases:
        assert main(argv) == 2, argv
        err = one_line_error(capsys)
        assert err.startswith("sebvs view: ") and expected in err, (argv, err)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(ep)]) == 2             # the native viewer: no window here
    err = one_line_error(capsys)
    assert "no display" in err and "--save" in err and "--serve" in err
    assert not Path(rrd).exists()


# ---------------------------------------------------------------- replay
def test_replay_writes_every_row_with_truth_commands_and_latency(tmp_path, capsys):
    pytest.importorskip("rerun")
    ep, rrd = tmp_path / "ep.h5", tmp_path / "ep.rrd"
    data = write_episode(ep)
    assert main(["view", str(ep), "--save", str(rrd), "--json", str(tmp_path / "s.json")]) == 0
    assert f"{T} rows replayed" in capsys.readouterr().out
    got = read_rrd(rrd)
    assert json.loads((tmp_path / "s.json").read_text())["rows"] == T

    assert col(got, "camera/rgb", "tick") == list(range(50, 50 + T))
    assert [t.total_seconds() for t in col(got, "camera/rgb", "sim_time")] == \
        pytest.approx([0.1 * i for i in range(T)])
    np.testing.assert_array_equal(np.stack(col(got, "camera/rgb", "image")), data["rgb"])
    assert col(got, "accumulator/frames", "tick") == list(range(50, 50 + T))
    for i, img in enumerate(col(got, "accumulator/frames", "image")):
        np.testing.assert_array_equal(img, event_image(data["ev"][i]))
        assert img.shape == (H // 2, W // 2, 3)
        assert tuple(img[1, 2]) == (0, 0, 255) and tuple(img[3, 4]) == (255, 0, 0)
        assert tuple(img[0, 0]) == (255, 255, 255)

    # the box where the target is visible (even rows), cleared where it is not
    box = "camera/rgb/truth/bbox"
    assert col(got, box, "tick", "Boxes2D:centers") == [50 + i for i in range(0, T, 2)]
    for centers, half, k in zip(col(got, box, "Boxes2D:centers", "Boxes2D:centers"),
                                col(got, box, "Boxes2D:half_sizes", "Boxes2D:centers"),
                                range(0, T, 2)):
        u0, v0, u1, v1 = data["bbox"][k]
        np.testing.assert_allclose(centers, [[(u0 + u1) / 2, (v0 + v1) / 2]])
        np.testing.assert_allclose(half, [[(u1 - u0) / 2, (v1 - v0) / 2]])
    cleared = col(got, box, "tick", "Clear:is_recursive")
    assert cleared == [50 + i for i in range(1, T, 2)]
    # over the half-size event frame the same box, halved
    half = col(got, "accumulator/frames/truth/bbox", "Boxes2D:half_sizes", "Boxes2D:centers")
    np.testing.assert_allclose(half[0], [[(data["bbox"][0][2] - data["bbox"][0][0]) / 4, 2.0]])

    cmd = "commands/expert/action"
    np.testing.assert_allclose(np.array(col(got, cmd, "Scalars:scalars")), data["action"],
                               rtol=1e-6)
    assert got[cmd]["static"]["SeriesLines:names"] == [["v", "w"]]
    lat = "latency/sim_to_camera"
    assert col(got, lat, "tick") == list(range(51, 50 + T))          # none on row 0
    assert [s[0] for s in col(got, lat, "Scalars:scalars")] == [100.0 + i for i in range(1, T)]
    assert [s[0] for s in col(got, "truth/distance", "Scalars:scalars")] == \
        [1.0 + i for i in range(T)]
    assert len(col(got, "run/episodes", "TextLog:text")) == 2


# ---------------------------------------------------------------- a live nav run
def camera_rgb_sent(sup) -> int:
    reply = sup.request("camera", {"cmd": "stats"}, 5.0)
    assert reply and reply["ok"], reply
    return reply["result"]["actor_stats"]["rgb"]


def test_live_nav_run_is_written_and_matches_what_the_run_recorded(tmp_path, capsys):
    """The viewer attaches to a recording nav run for 3 s. Every episode the recorder
    finished inside that window must be in the .rrd, tick for tick and byte for byte: the
    viewer's RGB and event frames and commands are the messages the run sent."""
    pytest.importorskip("rerun")
    from sebvs.runtime.supervisor import Supervisor
    from sebvs.runtime.topology import load_topology

    ds, rrd, summary = tmp_path / "ds", tmp_path / "live.rrd", tmp_path / "live.json"
    overrides = [f"recorder.out={json.dumps(str(ds))}", "sim.randomise={}",
                 "sim.episode_s=0.5"]
    sup = Supervisor(load_topology(NAV_RECORD, overrides), runs_dir=tmp_path / "runs",
                     echo=lambda s: None)
    sup.start()
    try:
        sent_before = camera_rgb_sent(sup)
        assert main(["view", str(sup.rundir), "--save", str(rrd), "--for", "3",
                     "--json", str(summary)]) == 0
        sent = camera_rgb_sent(sup) - sent_before
    finally:
        code = sup.stop()
    assert code == 0
    out = capsys.readouterr().out
    assert "s attached, written to" in out
    s = json.loads(summary.read_text())
    got = read_rrd(rrd)

    for entity in ("camera/rgb", "camera/rgb/truth/bbox", "camera/rgb/truth/centroid",
                   "accumulator/frames", "accumulator/frames/truth/bbox",
                   "commands/expert/action", "latency/sim_to_camera",
                   "latency/camera_to_emulator", "latency/emulator_to_accumulator",
                   "latency/camera_to_expert", "truth/distance", "run/episodes"):
        assert entity in got, (entity, sorted(got))
    ticks = col(got, "camera/rgb", "tick")
    st = s["outputs"]["camera/rgb"]
    unreadable = st["dropped_overwritten"] + st["torn"] + st["malformed"]
    # every frame the viewer could read is in the file, each tick once, and no more than
    # the camera sent while the viewer was attached
    assert len(ticks) == st["received"] - unreadable == s["entities"]["camera/rgb"] > 10
    assert len(set(ticks)) == len(ticks) <= sent
    # one event frame and one command per control tick, as RGB frames
    assert abs(len(col(got, "accumulator/frames", "tick")) - len(ticks)) <= 3
    assert abs(len(col(got, "commands/expert/action", "tick")) - len(ticks)) <= 3
    lat = np.array(col(got, "latency/sim_to_camera", "Scalars:scalars"))
    assert len(lat) > 10 and (lat > 0).all() and (lat < 5e6).all()    # us

    # the recorder's finished episodes that lie inside the viewer's window
    frames = dict(zip(ticks, col(got, "camera/rgb", "image")))
    events = dict(zip(col(got, "accumulator/frames", "tick"),
                      col(got, "accumulator/frames", "image")))
    commands = dict(zip(col(got, "commands/expert/action", "tick"),
                        col(got, "commands/expert/action", "Scalars:scalars")))
    # each stream has its own window (an event frame comes after its tick's RGB frame):
    # an episode counts when it lies inside all three
    first = max(min(m) for m in (frames, events, commands))
    last = min(max(m) for m in (frames, events, commands))
    lost = sum(v for src in ("camera/rgb", "accumulator/frames", "expert/action")
               for k, v in s["outputs"][src].items() if k != "received")
    inside = 0
    for path in sorted(ds.glob("episode_*.h5")):
        with open_episode(path) as ep:
            ep_ticks = ep.tick[:].tolist()
            if not (first <= ep_ticks[0] and ep_ticks[-1] <= last):
                continue
            inside += 1
            if lost:
                continue        # the viewer lost some of them: only the counts hold
            for i, tick in enumerate(ep_ticks):
                np.testing.assert_array_equal(frames[tick], ep.rgb[i])
                np.testing.assert_array_equal(events[tick], event_image(ep.event_frame[i]))
                np.testing.assert_allclose(commands[tick], ep.action[i], rtol=1e-6)
    assert inside >= 1, (first, last, sorted(p.name for p in ds.glob("*.h5")))


# ---------------------------------------------------------------- --serve
def test_serve_hosts_the_web_viewer_on_loopback_and_stops_it(tmp_path):
    pytest.importorskip("rerun")
    from sebvs.runtime.ports import free_port_block
    ep = tmp_path / "ep.h5"
    write_episode(ep)
    port = free_port_block(2)
    proc = subprocess.Popen([sys.executable, "-m", "sebvs.cli", "view", str(ep), "--serve",
                             "--grpc-port", str(port), "--web-port", str(port + 1)],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        url = None
        deadline = time.monotonic() + 45
        for line in proc.stdout:
            if "web viewer at " in line:
                url = line.split("web viewer at ", 1)[1].strip()
            if "serving" in line or time.monotonic() > deadline:
                break
        assert url and url.startswith(f"http://127.0.0.1:{port + 1}/?url="), url
        page = urllib.request.urlopen(url, timeout=10).read().decode()
        assert "<html" in page.lower() and "wasm" in page.lower()
        children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True,
                                  text=True).stdout.split()
        assert children                                 # the rerun --serve-web child
        listening = subprocess.run(["ss", "-ltnH"], capture_output=True, text=True).stdout
        ours = [l for l in listening.splitlines() if f":{port} " in l or f":{port + 1} " in l]
        assert ours and all("127.0.0.1:" in l for l in ours), ours
        proc.send_signal(signal.SIGINT)
        assert proc.wait(15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    for pid in children:
        assert not Path(f"/proc/{pid}").exists() or \
            Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"


# ---------------------------------------------------------------- what is drawn
def test_event_frames_of_every_representation_become_on_off_counts():
    from sebvs.dvs.render import FULL_COUNT, event_counts, event_image
    hist = np.zeros((6, 2, 2), np.uint8)      # 3 bins: ON bins 0..2, OFF bins 3..5
    hist[0, 0, 0], hist[2, 0, 0], hist[4, 1, 1] = 1, 2, 5
    np.testing.assert_array_equal(event_counts(hist, "histogram"),
                                  [[[3, 0], [0, 0]], [[0, 0], [0, 5]]])
    voxel = np.zeros((2, 2, 2), np.float32)   # signed: net polarity per pixel
    voxel[:, 0, 1] = [0.5, 1.0]
    voxel[:, 1, 0] = [-2.0, 0.5]
    np.testing.assert_allclose(event_counts(voxel, "voxel"),
                               [[[0, 1.5], [0, 0]], [[0, 0], [1.5, 0]]])
    counts = np.ones((2, 2, 2), np.uint8)
    assert event_counts(counts) is counts
    with pytest.raises(ValueError, match="even number"):
        event_counts(np.zeros((3, 2, 2), np.uint8), "histogram")
    # a time surface: a fresh event (255) in full colour, an old one (25) faded, where
    # read as counts every pixel the episode had seen would be at full colour
    surface = np.zeros((2, 1, 3), np.uint8)
    surface[0, 0] = [255, 25, 0]
    shown = event_counts(surface, "time_surface")
    np.testing.assert_allclose(shown[0, 0], [FULL_COUNT, 25 * FULL_COUNT / 255, 0])
    fresh, faded, white = event_image(shown)[0]
    assert fresh[0] == 0 and 0 < white[0] - faded[0] < white[0] - fresh[0]


def test_truth_marks_scale_to_the_image_and_keep_only_what_is_given():
    from sebvs.view.entities import truth_marks
    nav = {"bbox": [10, 20, 30, 40], "centroid": [20, 30], "visible": True, "image": [160, 80]}
    assert truth_marks(nav, (80, 40)) == {"bbox": [5, 10, 15, 20], "centroid": [10, 15]}
    assert truth_marks(dict(nav, visible=False, centroid=[-1, -1]), (160, 80)) == {}
    arm = {"image": [100, 100], "target": 2,
           "cubes": [{"uv": [10, 10], "visible": True, "rgb": [1, 0, 0]},
                     {"uv": [50, 50], "visible": False, "rgb": [0, 1, 0]},
                     {"uv": [90, 20], "visible": True, "rgb": [0, 0, 1]}]}
    uv, colours, target = truth_marks(arm, (200, 200))["cubes"]
    assert uv == [[20, 20], [180, 40]] and colours == [[255, 0, 0], [0, 0, 255]]
    assert target == 1                        # the third cube, second of those visible
