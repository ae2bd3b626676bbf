"""The benchmark as a Gymnasium environment (`ocplace.sim.env`): scenes, scoring, seeds, bad actions, vectors."""

import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from ocplace.errors import InvalidAction, PlaceEnvError
from ocplace.sim.dataset.config import smoke_config
from ocplace.sim.dataset.job import listed_scenes, verify_dataset
from ocplace.sim.env import ENV_ID, MAKE_ID
from ocplace.sim.env.place_env import SUCCESS_COLOUR
from ocplace.vocabulary import TEST_SUBSETS

OBSERVATION_KEYS = {
    "rgb",
    "depth",
    "boxes",
    "box_mask",
    "box_aabbs",
    "instruction",
    "held_footprint",
    "camera_intrinsics",
    "camera_pose",
}


def oracles(dataset, split) -> dict[str, np.ndarray]:
    """Scene id -> the oracle placement its scene.json records."""
    return {scene.name: scene.info().oracle.placement for scene in listed_scenes(dataset, split)}


def same_bytes(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[k] == b[k] if isinstance(a[k], str) else a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes()
        for k in a
    )


@pytest.mark.parametrize("split", TEST_SUBSETS)
def test_the_oracle_placement_succeeds_on_every_scene(smoke_dataset, split):
    env = gymnasium.make(ENV_ID, dataset=smoke_dataset, split=split, render_mode="rgb_array")
    truth = oracles(smoke_dataset, split)
    seen = []
    for episode in range(len(truth)):
        observation, info = env.reset(seed=episode) if episode == 0 else env.reset()
        assert set(observation) == OBSERVATION_KEYS and env.observation_space.contains(observation)
        assert "truth" not in info and "oracle" not in info  # ground truth only once the episode is over
        _, reward, terminated, truncated, info = env.step(truth[info["scene"]])
        assert (reward, terminated, truncated) == (1.0, True, False)
        assert info["success"] and info["reason"] is None and all(info["tuples_hold"])
        assert info["truth"]["oracle"] == truth[info["scene"]].tolist()
        seen.append(info["scene"])
    assert seen == sorted(truth)  # unseeded resets walk the split in its listing order
    frame = env.render()
    centre = env.unwrapped.scenes.record(len(truth) - 1).camera.table_to_pixel(truth[seen[-1]])
    assert tuple(frame[int(round(centre[1])), int(round(centre[0]))]) == SUCCESS_COLOUR  # the placement's marker
    env.close()


def test_a_seed_chooses_the_scene_and_gives_the_same_bytes(smoke_dataset):
    first = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen")
    second = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen")
    observation, info = first.reset(seed=11)
    assert info == {"scene": "seen-00003", "index": 3, "episode_index": 11}  # scene 11 mod 8
    assert same_bytes(observation, second.reset(seed=11)[0])
    assert not same_bytes(observation, second.reset(seed=12)[0])
    assert first.reset()[1]["scene"] == "seen-00004"  # then on from the seeded scene


def test_gymnasiums_episode_wrappers_work_on_it(smoke_dataset):
    """Issue 44: `info["episode"]` collided with RecordEpisodeStatistics's own key."""
    from gymnasium.wrappers import RecordEpisodeStatistics

    env = RecordEpisodeStatistics(gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen", max_episode_steps=1))
    _, info = env.reset(seed=2)
    *_, terminated, truncated, info = env.step(np.zeros(2))
    assert terminated and truncated  # TimeLimit marks its last step truncated too: both end the episode
    assert info["episode"]["l"] == 1 and info["episode"]["r"] in (0.0, 1.0)
    with pytest.raises(PlaceEnvError, match="max_episode_steps must be at least 1"):
        gymnasium.make_vec(ENV_ID, num_envs=2, dataset=smoke_dataset, max_episode_steps=0)


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_gymnasiums_own_vectorizers_are_refused_since_their_copies_would_replay_the_same_scenes(smoke_dataset, mode):
    with pytest.raises(PlaceEnvError, match="use the default mode"):
        gymnasium.make_vec(ENV_ID, num_envs=2, dataset=smoke_dataset, split="seen", vectorization_mode=mode)


def test_generated_scenes_are_the_datasets_scenes(smoke_dataset, library):
    """Generated on the fly with the dataset's configuration, a scene is the one `ocplace generate` wrote."""
    generated = gymnasium.make(ENV_ID, split="seen", generator=smoke_config())
    stored = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen")
    for seed in (0, 5):
        observation, info = generated.reset(seed=seed)
        expected, expected_info = stored.reset(seed=seed)
        assert info == expected_info and same_bytes(observation, expected)
        placement = np.array([0.1, -0.05])
        assert generated.step(placement)[1:] == stored.step(placement)[1:]  # reward, flags, info with the truth
    generated.close()


def test_bad_actions_score_zero_or_raise_a_typed_error(smoke_dataset):
    env = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen")
    scored = [
        ([np.nan, 0.0], "not finite"),
        ([0.0, -np.inf], "not finite"),
        ([5.0, 0.0], "leaves the table"),
        ([0.399, 0.0], "leaves the table"),  # the centre on the table, the footprint over its edge
    ]
    for action, reason in scored:
        env.reset(seed=2)
        _, reward, terminated, _, info = env.step(np.array(action))
        assert reward == 0.0 and terminated and not info["success"] and reason in info["reason"]
    bad = (
        np.zeros(3),
        np.zeros((2, 2)),
        0.5,
        "ab",
        [[0.0], [0.0]],
        {"x": 0},
        (10**400, 0),
        ["0.1", "0.2"],
        (True, False),
    )
    for action in bad:
        env.reset(seed=2)
        with pytest.raises(InvalidAction, match=r"placement \(x, y\)"):
            env.step(action)
        assert env.step(np.zeros(2))[2]  # the episode is still open after a malformed action
    raw = env.unwrapped
    with pytest.raises(PlaceEnvError, match="already ended"):
        raw.step(np.zeros(2))
    fresh = type(raw)(smoke_dataset, "seen")
    with pytest.raises(PlaceEnvError, match="reset"):
        fresh.step(np.zeros(2))
    assert verify_dataset(smoke_dataset) == []  # nothing was written into the dataset


def test_passes_gymnasiums_env_checker_without_warnings(smoke_dataset):
    env = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="unseen_obj", render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)


def test_the_vector_env_plays_the_single_envs_scenes(smoke_dataset):
    single = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen")
    truth = oracles(smoke_dataset, "seen")
    expected = {}
    for seed in range(len(truth)):
        observation, info = single.reset(seed=seed)
        _, reward, *_ = single.step(truth[info["scene"]] + [0.0, 0.02 * (seed % 3)])
        expected[info["scene"]] = (observation, reward)
    vector = gymnasium.make_vec(ENV_ID, num_envs=2, dataset=smoke_dataset, split="seen", max_episode_steps=1)
    observations, infos = vector.reset(seed=0)
    played = {}
    for _ in range(len(truth) // 2):
        episodes, scenes = infos["episode_index"], infos["scene"]
        actions = np.stack([truth[s] + [0.0, 0.02 * (e % 3)] for s, e in zip(scenes, episodes)])
        next_observations, rewards, terminated, _, infos = vector.step(actions)
        assert terminated.all() and list(infos["final_info"]["scene"]) == list(scenes)
        for worker, scene in enumerate(scenes):
            played[scene] = ({k: v[worker] for k, v in observations.items()}, rewards[worker])
        observations = next_observations
    _check_bad_batches(vector, truth)
    vector.close()
    assert sorted(played) == sorted(expected)
    for scene, (observation, reward) in played.items():
        assert same_bytes(observation, expected[scene][0]) and reward == expected[scene][1]
    assert {reward for _, reward in played.values()} == {0.0, 1.0}


def test_registered_by_its_module_qualified_id_without_an_import(smoke_dataset):
    """Gymnasium 1.x loads no plugins: the id names the module that registers the environment."""
    program = (
        "import gymnasium\n"
        f"env = gymnasium.make({MAKE_ID!r}, dataset={str(smoke_dataset)!r}, split='seen')\n"
        "print(env.reset(seed=1)[1]['scene'], gymnasium.spec('ocplace/Place-v0').vector_entry_point)\n"
    )
    run = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["seen-00001", "ocplace.sim.env.vector:make_vector_env"]


def test_the_physical_check_drops_the_held_object_when_asked(smoke_dataset, arena):
    """As the harness checks: the drop where the metric succeeds, nothing dropped where it fails."""
    from ocplace.sim.physical import physical_check

    env = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen", physical_check=True)
    truth = oracles(smoke_dataset, "seen")
    _, info = env.reset(seed=0)
    _, reward, _, _, info = env.step(truth[info["scene"]])
    expected = physical_check(arena, env.unwrapped.scenes.record(0), truth[info["scene"]])
    assert info["success"] and info["physical"]["dropped"]
    assert info["physical"]["success"] == expected.success and reward == float(expected.success)
    assert info["physical"]["held_offset"] == expected.held_offset
    env.reset()
    _, reward, _, _, info = env.step(np.array([5.0, 0.0]))
    assert reward == 0.0 and info["physical"] == {
        "success": False,
        "dropped": False,
        "held_offset": None,
        "max_disturbance": None,
    }
    env.close()


def test_writing_into_an_observation_never_changes_the_score(smoke_dataset):
    """Issue 43, defect 6: the observation's footprint was the record's own array, so a policy writing into
    `obs["held_footprint"]` changed its reward (0 -> 1 on seen-00000); `evaluate --policy` was immune."""
    env = gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen")
    truth = oracles(smoke_dataset, "seen")
    rewards = []
    for seed in range(len(truth)):
        _, info = env.reset(seed=seed)
        action = truth[info["scene"]] + [0.0, 0.03]
        _, plain, *_ = env.step(action)
        observation, _ = env.reset(seed=seed)
        for value in observation.values():
            if isinstance(value, np.ndarray):
                value[...] = 0  # the footprint shrinks to nothing, the boxes vanish
        _, edited, *_ = env.step(action)
        assert edited == plain, info["scene"]
        rewards.append(plain)
    assert set(rewards) == {0.0, 1.0}  # some placements fail: the footprint decides them
    env.close()


def _check_bad_batches(vector, truth) -> None:
    """Issue 43, defect 5: a (3, 2) action for 2 workers sent 2 rows, raised an untyped ValueError, and the
    next `step(NaN)` returned those rows' rewards; now a bad batch sends nothing."""
    _, infos = vector.reset(seed=0)
    good = np.stack([truth[scene] for scene in infos["scene"]])
    # The single environment's bad actions, one row each (issue 60: the vector path converted strings, booleans
    # and objects and scored them).
    same_as_single = ([["0.1", "0.2"], ["0", "0"]], [[True, False], [False, True]], np.array([[None, 0.0]] * 2))
    for bad in (np.concatenate([good, good[:1]]), [[10**400, 0.0], [0.0, 0.0]], good[:, :1], *same_as_single):
        with pytest.raises(InvalidAction, match="shape \\(2, 2\\)"):
            vector.step(bad)
    _, rewards, terminated, _, infos = vector.step(np.full((2, 2), np.nan))
    assert list(rewards) == [0.0, 0.0] and terminated.all()  # scored now, not the rows of a bad batch
    assert all("not finite" in reason for reason in infos["final_info"]["reason"])
    _, rewards, *_ = vector.step(np.stack([truth[scene] for scene in infos["scene"]]))
    assert list(rewards) == [1.0, 1.0]  # and the vector env goes on


def test_the_instruction_embedding_wrapper_gives_rl_libraries_a_vector(smoke_dataset):
    """Issue 44: Stable-Baselines3's `check_env` rejects the Text instruction; the wrapper embeds it with MiniLM."""
    from ocplace.models.instruction_embedding import InstructionEmbedding

    env = InstructionEmbedding(gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen"))
    observation, _ = env.reset(seed=1)
    assert env.observation_space.contains(observation)
    assert observation["instruction"].shape == (384,) and abs(np.linalg.norm(observation["instruction"]) - 1) < 1e-4
    other, _ = env.reset(seed=2)
    assert not np.array_equal(observation["instruction"], other["instruction"])  # another scene, another sentence
    *_, info = env.step(np.zeros(2))
    assert info["scene"] == "seen-00002"


def test_stable_baselines3_accepts_the_wrapped_environment(smoke_dataset):
    sb3_checker = pytest.importorskip(
        "stable_baselines3.common.env_checker",
        reason="the `rl` extra is not installed (it needs torch, CPU build; docs/evaluation.md)",
    )
    from ocplace.models.instruction_embedding import InstructionEmbedding

    sb3_checker.check_env(InstructionEmbedding(gymnasium.make(ENV_ID, dataset=smoke_dataset, split="seen")))
