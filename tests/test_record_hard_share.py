"""`sebvs record --hard-share F`: a chosen share of a dataset's episodes under hard
conditions, assigned by episode number (sebvs/data/condition_mix.py); each condition's
episodes are runs of their own, stamped with the condition's name, and the plan the dataset
keeps makes a rerun record only what is missing, as planned, and refuses another plan. A
hard episode draws from the randomised mix what its condition leaves open."""
import argparse
import json
import shutil
from fractions import Fraction
from pathlib import Path

import h5py
import pytest

from sebvs.cli import main
from sebvs.data.check import check_dataset
from sebvs.data.compare import compare_datasets, episode_differences
from sebvs.data.condition_mix import (MIX_KEPT, PLAN_KEY, RANDOMISED, ConditionMix,
                                      check_dataset_plan, condition_runs, mix_left,
                                      parse_conditions, parse_share)
from sebvs.data.episode import open_episode
from sebvs.data.index import DatasetIndex
from sebvs.data.record import (SHARD_INFO, STAGING, adopt_staged, hard_share_jobs,
                               requested_overrides)
from sebvs.data.stats import collect
from sebvs.runtime.overrides import lookup
from sebvs.runtime.topology import load_topology
from sebvs.sim.randomise import SceneRandomiser
from tests.test_scale import ROOT, SMALL_RECORD

TOPO = str(ROOT / "topologies" / "nav_record.toml")
ARM_TOPO = str(ROOT / "topologies" / "arm_record.toml")
NAV_HARD = ("hdr", "dusk_fast", "flicker_120")
HALF = ConditionMix(Fraction(1, 2), NAV_HARD)       # what the recordings below ask for


def record(tmp_path, out, episodes, *extra) -> int:
    return main(["record", TOPO, "--episodes", str(episodes), "--out", str(out),
                 "--runs-dir", str(tmp_path / "runs"), "--quiet", "--timeout", "120",
                 *SMALL_RECORD, *extra])


def conditions_of(out: Path) -> dict[int, str]:
    """Episode number -> its `condition` attribute, for the indexed episodes."""
    found = {}
    for k in sorted(DatasetIndex(out).numbers()):
        with open_episode(out / f"episode_{k:04d}.h5") as ep:
            found[k] = ep.attrs.get("condition")
    return found


# --------------------------------------------------------------------- the assignment
@pytest.mark.parametrize("share", [Fraction(0), Fraction(1, 6), Fraction(1, 4),
                                   Fraction(1, 3), Fraction(1, 2), Fraction(5, 7),
                                   Fraction(1)])
def test_every_prefix_holds_its_rounded_share_and_the_conditions_take_turns(share):
    mix = ConditionMix(share, NAV_HARD)
    assigned = mix.assign(range(100))
    for n in range(101):
        hard = sum(assigned[k] != RANDOMISED for k in range(n))
        assert hard == int(n * share + Fraction(1, 2)), (share, n)   # n * F, half up
    hard = [c for c in assigned.values() if c != RANDOMISED]
    assert hard == [NAV_HARD[j % 3] for j in range(len(hard))]
    # by number alone: the same whatever else is asked, and again on a second call
    assert mix.assign(range(40, 60)) == {k: assigned[k] for k in range(40, 60)}
    assert ConditionMix(share, NAV_HARD).assign(range(100)) == assigned


def test_the_hard_episodes_are_spread_not_bunched():
    mix = ConditionMix(Fraction(1, 6), NAV_HARD)
    hard = [k for k, c in mix.assign(range(36)).items() if c != RANDOMISED]
    assert hard == [2, 8, 14, 20, 26, 32]
    assert mix.counts(70) == {"hdr": 4, "dusk_fast": 4, "flicker_120": 4, RANDOMISED: 58}
    # a condition named twice gets twice the turns
    assert ConditionMix(Fraction(1), ("hdr", "hdr", "dusk_fast")).counts(6) == \
        {"hdr": 4, "dusk_fast": 2, RANDOMISED: 0}


def test_runs_of_one_condition_are_what_one_topology_run_records():
    assert condition_runs({0: "a", 1: "a", 2: "b", 4: "b", 5: "b"}) == \
        [("a", 0, 2), ("b", 2, 3), ("b", 4, 6)]
    assert condition_runs({}) == []


def test_shares_and_condition_lists_are_read_exactly_or_refused_in_one_line():
    assert parse_share("1/6") == Fraction(1, 6) and parse_share("0.5") == Fraction(1, 2)
    assert parse_share(" 0 ") == 0 and parse_share("1") == 1
    for bad in ("x", "1/0", "-0.1", "1.5", ""):
        with pytest.raises(ValueError, match="--hard-share") as exc:
            parse_share(bad)
        assert "\n" not in str(exc.value)
    assert parse_conditions("hdr, dusk_fast") == ("hdr", "dusk_fast")
    for bad in ("", "hdr,,dusk"):
        with pytest.raises(ValueError, match="--hard-conditions"):
            parse_conditions(bad)
    with pytest.raises(ValueError, match="at least one"):
        ConditionMix(Fraction(1, 2), ())


def test_a_plan_is_refused_by_a_dataset_of_another_plan_while_it_holds_episodes():
    stored = HALF.to_json()
    assert ConditionMix.from_json(json.loads(json.dumps(stored)), "d") == HALF
    check_dataset_plan(stored, ConditionMix(Fraction("0.5"), NAV_HARD), episodes=3,
                       where="d")                      # 0.5 is 1/2: the same plan
    check_dataset_plan(stored, None, episodes=0, where="d")     # nothing recorded yet
    check_dataset_plan(None, None, episodes=3, where="d")       # plain, as before
    refusals = [
        (stored, ConditionMix(Fraction(1, 3), NAV_HARD), "not --hard-share 1/3"),
        (stored, ConditionMix(Fraction(1, 2), ("hdr",)), "not --hard-share 1/2 "
                                                         "--hard-conditions hdr;"),
        (stored, ConditionMix(Fraction(1, 2), NAV_HARD, "outdoor"), "--scenario outdoor"),
        (stored, None, "give them again"),
        (None, HALF, "recorded without --hard-share"),
        ({**stored, "rule": "other"}, HALF, "not a hard-share plan"),
        # an earlier version's plan: its hard episodes drew nothing from the mix
        ({k: v for k, v in stored.items() if k != MIX_KEPT}, HALF, "by an earlier sebvs"),
        ({k: v for k, v in stored.items() if k != MIX_KEPT}, None, "by an earlier sebvs"),
    ]
    for have, asked, says in refusals:
        with pytest.raises(ValueError, match=says) as exc:
            check_dataset_plan(have, asked, episodes=3, where="d")
        assert "\n" not in str(exc.value)


# --------------------------------------------------------------------- the hard scenes
def shard_sim(topology, mix, *sets):
    """Each job's sim `randomise` and `config` overrides for `sebvs record topology
    --hard-share ... --set ...`."""
    args = argparse.Namespace(topology=topology, set=list(sets), sensor=None, condition=None,
                              scenario=None, episodes=4)
    jobs = hard_share_jobs(args, "recorder", Path("unused"), requested_overrides(args), mix)
    return {name: (lookup(job, "sim", "randomise"), lookup(job, "sim", "config") or {})
            for name, job in jobs.items()}


def test_a_hard_shard_draws_from_the_mix_what_its_condition_leaves_open():
    shards = shard_sim(TOPO, HALF)
    assert shards[RANDOMISED] == (None, {})                     # the topology's own mix
    mix = load_topology(TOPO).actors["sim"].params["randomise"]
    randomise, config = shards["hdr"]
    assert config == {"lighting": "hdr"}
    assert randomise == {k: mix[k] for k in ("variant", "target_speed", "rgb_blur")}
    assert "lighting" not in randomise and "flicker_hz" not in randomise
    assert set(shards["dusk_fast"][0]) == {"variant", "rgb_blur"}
    assert set(shards["flicker_120"][0]) == {"variant", "target_speed", "rgb_blur"}
    # the scenario's key is fixed too
    outdoor = shard_sim(TOPO, ConditionMix(Fraction(1, 2), ("hdr",), "outdoor"))["hdr"]
    assert outdoor == ({"target_speed": mix["target_speed"], "rgb_blur": mix["rgb_blur"]},
                       {"lighting": "hdr", "variant": "outdoor"})
    # the arm: a fixed conveyor takes its belt speed with it, a free one draws both
    arm = shard_sim(ARM_TOPO, ConditionMix(Fraction(1, 2), ("hdr", "dusk_moving"), "multi"))
    assert set(arm["hdr"][0]) == {"conveyor", "belt_speed", "rgb_blur"}
    assert set(arm["dusk_moving"][0]) == {"rgb_blur"}
    assert mix_left({"belt_speed": [0.1], "flicker_hz": [5.0], "objects": [1, 3]},
                    {"conveyor"}) == {"flicker_hz": [5.0], "objects": [1, 3]}
    # a plain --condition still records one condition in one scene
    plain = argparse.Namespace(topology=TOPO, set=[], sensor=None, condition="hdr",
                               scenario=None)
    assert lookup(requested_overrides(plain)[0], "sim", "randomise") == {}


def test_a_hard_shard_s_draws_hold_its_condition_and_both_scene_variants_occur():
    randomise, config = shard_sim(TOPO, HALF)["hdr"]
    sim = load_topology(TOPO, {"sim": {"config": config}}).actors["sim"].params
    draws = SceneRandomiser("nav", sim["config"], randomise)
    drawn = [draws.draw(seed) for seed in range(16)]      # 16 episode seeds
    assert {d["lighting"] for d in drawn} == {"hdr"}
    assert {d["variant"] for d in drawn} == {"indoor", "outdoor"}
    assert len({d["target_speed"] for d in drawn}) > 1


def test_a_set_line_that_draws_over_a_hard_condition_is_refused_in_one_line():
    with pytest.raises(ValueError, match="lighting into sim.randomise, which hard "
                                         "condition 'hdr' fixes") as exc:
        shard_sim(TOPO, HALF, 'sim.randomise.lighting=["low"]')
    assert "\n" not in str(exc.value)
    # what the conditions leave open may be set, and so may no mix at all
    shards = shard_sim(TOPO, HALF, 'sim.randomise.variant=["outdoor"]')
    assert shards["hdr"][0]["variant"] == ["outdoor"]
    assert shard_sim(TOPO, HALF, "sim.randomise={}")["hdr"][0] == {}


# --------------------------------------------------------------------- recordings
@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    """Episodes 0-3 at a hard share of 1/2: hdr, randomised, dusk_fast, randomised."""
    tmp = tmp_path_factory.mktemp("hard_share")
    out = tmp / "mixed"
    assert record(tmp, out, 4, "--hard-share", "1/2") == 0
    return tmp, out


def test_a_mixed_recording_names_each_episode_s_condition(mixed, capsys):
    tmp, out = mixed
    assert conditions_of(out) == {0: "hdr", 1: RANDOMISED, 2: "dusk_fast", 3: RANDOMISED}
    index = json.loads((out / "index.json").read_text())
    assert ConditionMix.from_json(index[PLAN_KEY], str(out)) == HALF
    assert check_dataset(out).ok and not (out / STAGING).exists()
    # a hard episode: its condition's light, the rest of its scene drawn from the mix left
    # to it (episode 0 draws outdoor, episode 2 indoor: both variants among the hard ones)
    shards = shard_sim(TOPO, HALF, *SMALL_RECORD[1::2])
    variants = set()
    for k, name in ((0, "hdr"), (2, "dusk_fast")):
        sim = load_topology(TOPO, [*SMALL_RECORD[1::2], {"sim": {"config": shards[name][1]}}]
                            ).actors["sim"].params
        with open_episode(out / f"episode_000{k}.h5") as ep:
            assert ep.attrs["sim_episode"] == k
            recorded, seed = ep.attrs["conditions"], ep.attrs["seed"]
        drawn = SceneRandomiser("nav", sim["config"], shards[name][0]).draw(seed)
        for key in ("lighting", "variant", "target_speed", "rgb_blur"):
            assert recorded[key] == drawn[key], (k, key)
        variants.add(recorded["variant"])
    assert variants == {"indoor", "outdoor"}
    with open_episode(out / "episode_0000.h5") as ep:
        assert ep.attrs["conditions"]["lighting"] == "hdr"      # the condition's light
    with open_episode(out / "episode_0002.h5") as ep:
        assert (ep.attrs["conditions"]["lighting"], ep.attrs["conditions"]["target_speed"]) \
            == ("dusk", "fast")
    # a randomised episode is the one the plain recording makes under its number: only
    # the stamped name differs
    assert record(tmp, tmp / "plain", 2) == 0
    only_stamp = lambda a, b: episode_differences(a, b) == [  # noqa: E731
        f"attribute condition: only in {a}"]
    assert only_stamp(out / "episode_0001.h5", tmp / "plain" / "episode_0001.h5")
    st = collect(out)
    assert st.condition_shares() == {"hdr": 1, "dusk_fast": 1, RANDOMISED: 2}
    assert "conditions         hdr 1 (25 %), dusk_fast 1 (25 %), randomised 2 (50 %)" \
        in st.summary()
    assert collect(tmp / "plain").condition_shares() == {}    # nothing named: no line


def test_a_rerun_records_only_the_missing_numbers_under_their_planned_conditions(
        mixed, tmp_path, capsys):
    src_tmp, src = mixed
    holes = tmp_path / "holes"
    shutil.copytree(src, holes)
    index = json.loads((holes / "index.json").read_text())
    index["episodes"] = [e for e in index["episodes"]
                         if e["file"] not in ("episode_0001.h5", "episode_0002.h5")]
    (holes / "index.json").write_text(json.dumps(index))
    for k in (1, 2):
        (holes / f"episode_000{k}.h5").unlink()
    capsys.readouterr()
    # and on to 6 episodes: 4 is the third hard one (flicker_120), 5 randomised
    assert record(tmp_path, holes, 6, "--hard-share", "0.5") == 0
    said = capsys.readouterr()
    assert "filling 4 missing episode(s) of 0-5" in said.err
    assert "hard share 1/2 of episodes 0-5: hdr 1, dusk_fast 1, flicker_120 1, " \
           "randomised 3" in said.err
    assert conditions_of(holes) == HALF.assign(range(6))
    with open_episode(holes / "episode_0004.h5") as ep:
        assert ep.attrs["conditions"]["flicker_hz"] == 120.0
    assert check_dataset(holes).ok
    # the refilled numbers are the episodes the first run recorded
    dropped = tmp_path / "first4"
    shutil.copytree(holes, dropped)
    index = json.loads((dropped / "index.json").read_text())
    index["episodes"] = index["episodes"][:4]
    (dropped / "index.json").write_text(json.dumps(index))
    result = compare_datasets(src, dropped)
    assert result.identical and len(result.same) == 4, result.different
    assert record(tmp_path, holes, 6, "--hard-share", "1/2") == 0
    assert "nothing to fill" in capsys.readouterr().err


def test_a_dataset_of_another_plan_or_none_is_refused_before_anything_runs(
        mixed, tmp_path, capsys):
    _, src = mixed
    out = tmp_path / "d"
    shutil.copytree(src, out)
    before = (out / "index.json").read_bytes()
    for extra, says in [(["--hard-share", "1/3"], "not --hard-share 1/3 --hard-conditions "
                                                  "hdr,dusk_fast,flicker_120;"),
                        (["--hard-share", "1/2", "--hard-conditions", "hdr"],
                         "not --hard-share 1/2 --hard-conditions hdr;"),
                        ([], "give them again"), (["--fill"], "give them again")]:
        capsys.readouterr()
        assert record(tmp_path, out, 6, *extra) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"sebvs record: {out}: recorded with --hard-share 1/2 "
                              f"--hard-conditions hdr,dusk_fast,flicker_120")
        assert says in err and "\n" not in err
    assert (out / "index.json").read_bytes() == before and len(list(out.iterdir())) == 5
    # an earlier version's plan (no mix_kept): refused whatever is asked, never extended
    old = json.loads(before)
    del old[PLAN_KEY][MIX_KEPT]
    (out / "index.json").write_text(json.dumps(old))
    for extra in (["--hard-share", "1/2"], []):
        assert record(tmp_path, out, 6, *extra) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"sebvs record: {out}: its 4 episode(s) were recorded with "
                              f"--hard-share 1/2") and "by an earlier sebvs" in err
        assert "\n" not in err
    assert len(list(out.iterdir())) == 5
    # a dataset recorded without a plan takes none afterwards
    index = json.loads(before)
    del index[PLAN_KEY]
    (out / "index.json").write_text(json.dumps(index))
    assert record(tmp_path, out, 6, "--hard-share", "1/2") == 2
    assert "holds 4 episode(s) recorded without --hard-share" in capsys.readouterr().err
    # and what the command line itself gets wrong, in one line each
    for extra, says in [(["--hard-share", "1/2", "--condition", "hdr"], "give one of them"),
                        (["--hard-conditions", "hdr"], "needs --hard-share"),
                        (["--hard-share", "1/2", "--hard-conditions", "hdr,nope"],
                         "unknown condition 'nope'"),
                        (["--hard-share", "1/2", "--hard-conditions", "fast_flicker"],
                         "'fast_flicker' is the ideal8 sensor pair's"),
                        (["--hard-share", "1/2", "--set", 'sim.randomise.lighting=["low"]'],
                         "which hard condition 'hdr' fixes")]:
        assert record(tmp_path, tmp_path / "new", 2, *extra) == 2
        err = capsys.readouterr().err.strip()
        assert says in err and "\n" not in err, err
    assert not (tmp_path / "new").exists()


def _dead_stage(out: Path, info: dict, keep_condition: bool) -> None:
    """A stage a dead driver left with episode 4 in it: episode 0's file renumbered."""
    stage = out / STAGING / "dead-4-5-try1"
    stage.mkdir(parents=True)
    (stage / SHARD_INFO).write_text(json.dumps({"base": 0, "first": 4, "stop": 5, **info}))
    shutil.copy(out / "episode_0000.h5", stage / "episode_0004.h5")
    with h5py.File(stage / "episode_0004.h5", "r+") as f:
        f.attrs["sim_episode"] = 4
        if not keep_condition:
            del f.attrs["condition"]


def test_a_staged_episode_keeps_the_condition_its_recorder_stored(mixed, tmp_path):
    _, src = mixed
    out = tmp_path / "d"
    shutil.copytree(src, out)
    stored = conditions_of(out)[0]
    assert stored        # every episode of a hard share says its condition itself
    _dead_stage(out, {}, keep_condition=True)
    assert adopt_staged(out) == ["episode_0004.h5"]
    assert conditions_of(out)[4] == stored and check_dataset(out).ok


def test_an_older_driver_s_staged_episode_is_adopted_with_its_shard_s_condition(mixed,
                                                                                tmp_path):
    # before the recorder stored a hard share's condition, the shard's info named it
    _, src = mixed
    out = tmp_path / "d"
    shutil.copytree(src, out)
    _dead_stage(out, {"condition": "flicker_120"}, keep_condition=False)
    assert adopt_staged(out) == ["episode_0004.h5"]
    assert conditions_of(out)[4] == "flicker_120" and check_dataset(out).ok
