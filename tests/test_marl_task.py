"""A fixbench case as a BenchMARL task (bench/marl_task.py): the config's one-line errors, the task's specs,
and the snippet of docs/planners.md run as printed, a frame one FE sample."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import pytest

pytest.importorskip("benchmarl", reason="BenchMARL is not installed (pip install 'fixbench[marl]')")

import torch  # noqa: E402
from torchrl.envs import TransformedEnv  # noqa: E402

from fixbench.bench import marl_task  # noqa: E402
from fixbench.bench.marl_task import GROUP, FixbenchTask, FixbenchTaskConfig  # noqa: E402
from fixbench.cases.errors import CaseError  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore::DeprecationWarning")

ROOT = Path(__file__).resolve().parents[1]
CASE = "wing_panel_small"  # 5 robots, action sets of 20, 19, 19, 19, 19; 4 tasks


@pytest.mark.parametrize(("config", "key"), [
    ({"case": CASE, "robots": 3}, "robots"),
    ({"agents": 3}, "case"),
    ({"case": ""}, "case"),
    ({"case": "no_such_case"}, "no_such_case"),
    ({"case": CASE, "material": "wood"}, "material"),
    ({"case": CASE, "agents": True}, "agents"),
    ({"case": CASE, "agents": 0}, "agents.count"),
    ({"case": CASE, "tasks": [0, 9]}, "tasks"),
    ({"case": CASE, "tasks": ["0"]}, "tasks"),
    ({"case": CASE, "reward": "linear"}, "reward"),
    ({"case": CASE, "shuffle": "yes"}, "shuffle"),
])
def test_a_bad_config_stops_in_one_line_naming_its_key(config, key):
    with pytest.raises(CaseError) as err:
        FixbenchTask(name="t", config=config)
    assert "\n" not in str(err.value) and key in str(err.value)


def test_specs_one_group_of_robots_with_the_mask_and_an_episode_a_pass_over_the_tasks():
    task = FixbenchTask.of(FixbenchTaskConfig(case=CASE, tasks=[0, 2]))
    env = TransformedEnv(task.get_env_fun(num_envs=1, continuous_actions=False, seed=0, device="cpu")())
    robots = [f"robot_{i}" for i in range(5)]
    assert task.name == CASE and task.group_map(env) == {GROUP: robots}
    assert task.max_steps(env) == 2 and task.state_spec(env) is None
    mask = task.action_mask_spec(env)[GROUP, "action_mask"]
    assert mask.shape == (5, 20)
    td = env.rollout(10)  # stops when the episode is done
    assert td.batch_size == (2,) and env.samples == 2
    assert (td[GROUP, "action_mask"].sum(-1) == torch.tensor([20, 19, 19, 19, 19])).all()
    assert task.log_info(td)["fixbench/max_u_min"] == td["next", GROUP, "info", "max_u"].min().item() > 0


def scalars(folder: Path, name: str) -> list[float]:
    """One BenchMARL csv log (rows: iteration, value) of the one experiment under ``folder``."""
    (path,) = folder.glob(f"*/*/scalars/{name}.csv")
    with path.open() as f:
        return [float(row[1]) for row in csv.reader(f)]


@pytest.fixture
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_docs_snippet_runs_the_frames_asked_each_one_fe_sample(tmp_path, monkeypatch, one_thread):
    """The snippet of docs/planners.md (MAPPO, 400 frames, no shared policy) as printed, in tmp_path. Every
    env it makes is recorded: the samples they spent are the frames trained on plus the evaluation
    episodes' (one sample a task), and every frame's layout was measured (the batch's smallest max |u|
    is positive: an unmeasured step would hold -1)."""
    made = []

    def recording_make_env(*args, **kwargs):
        made.append(env := fixbench_make_env(*args, **kwargs))
        return env

    fixbench_make_env = marl_task.make_env
    monkeypatch.setattr(marl_task, "make_env", recording_make_env)
    monkeypatch.chdir(tmp_path)
    text = (ROOT / "docs" / "planners.md").read_text(encoding="utf-8")
    section = text[text.index("### BenchMARL experiments on a fixbench case"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    scope: dict = {}
    exec(compile(code, "docs/planners.md", "exec"), scope)  # noqa: S102 - the repository's own docs
    experiment, config = scope["experiment"], scope["config"]
    assert not config.share_policy_params
    assert experiment.total_frames == config.max_n_frames == 400
    assert scalars(tmp_path, "counters_total_frames") == [100.0, 200.0, 300.0, 400.0]
    episodes = scalars(tmp_path, "eval_reward_episode_len_mean")
    assert episodes and all(n == 4 for n in episodes)  # an evaluation episode: the 4 tasks, once each
    assert experiment.test_env.samples == 4 * len(episodes)
    assert sum(env.samples for env in made) == experiment.total_frames + experiment.test_env.samples
    assert all(m > 0 for m in scalars(tmp_path, "fixbench_max_u_min"))
