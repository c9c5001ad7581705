"""The env in TorchRL's ``PettingZooWrapper`` as it is, no adapter: random and Q-value rollouts on robots
with action sets of different sizes (``pad_actions=True``), and the snippet of docs/planners.md."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torchrl", reason="torchrl is not installed (pip install 'fixbench[marl]')")

import torch  # noqa: E402
from tensordict.nn import TensorDictModule, TensorDictSequential  # noqa: E402
from torchrl.envs import PettingZooWrapper  # noqa: E402
from torchrl.modules import MLP, QValueModule  # noqa: E402

from fixbench.cases import make_env  # noqa: E402
from fixbench.cases.env import MEASURED, UNMEASURED  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning")

ROOT = Path(__file__).resolve().parents[1]
GROUP = "robot"  # TorchRL's default group of the agents robot_0, robot_1, ...
EPISODES = 5


def wrap(case: str):
    """TorchRL's wrapper around the padded env, the env's problem and its robots' action-set sizes."""
    env = make_env(case, pad_actions=True)
    sizes = [len(s) for s in env.problem.action_sets]
    return PettingZooWrapper(env, categorical_actions=True, seed=0), env.problem, sizes


def check_rollout(td, problem, sizes: list[int]) -> None:
    """Every action inside its robot's own set, the layout the env evaluated is the one the actions name,
    the reward is the oracle's for that layout, and reset infos hold the documented placeholders."""
    acts = td[GROUP, "action"].numpy()
    assert (acts < np.array(sizes)).all() and (acts >= 0).all()
    assert (td[GROUP, "action_mask"].sum(-1).numpy() == sizes).all()  # the mask each action was drawn under
    info = td["next", GROUP, "info"]
    ev = problem.evaluator()
    for t in range(len(td)):
        layout = info["layout"][t, 0].numpy().astype(np.int64)
        want = [problem.action_sets[i][a] for i, a in enumerate(acts[t])]
        assert layout.tolist() == want
        d = ev.evaluate(int(info["task"][t, 0]), layout[None])
        assert td["next", GROUP, "reward"][t, :, 0].numpy() == pytest.approx(d.reward_gaussian[0], rel=1e-6)
        assert info["max_u"][t].numpy() == pytest.approx(d.max_u[0], rel=1e-6)
    first = td[GROUP, "info"]
    for k in MEASURED:
        assert (first[k][0] == UNMEASURED).all()


@pytest.mark.parametrize("case", ["wing_panel_pairs_small", "wing_panel_small"])
def test_random_rollout_in_torchrl(case):
    env, problem, sizes = wrap(case)
    assert len(set(sizes)) > 1  # both cases: robots with action sets of different sizes
    spec = env.full_action_spec[GROUP, "action"]
    assert spec.shape == (len(sizes),) and spec.space.n == max(sizes)  # one action size for the group
    steps = EPISODES * problem.n_tasks
    td = env.rollout(steps, break_when_any_done=False)
    assert td.batch_size == (steps,)
    assert td["next", "done"].sum() == EPISODES  # one episode per pass over the tasks, reset in between
    check_rollout(td, problem, sizes)


def test_q_value_policy_with_the_mask():
    """TorchRL's QValueModule, which needs one action size a group, picks only unmasked actions."""
    torch.manual_seed(0)
    env, problem, sizes = wrap("wing_panel_pairs_small")
    spec = env.full_action_spec[GROUP, "action"]
    n_obs = env.observation_spec[GROUP, "observation", "observation"].shape[-1]
    net = TensorDictModule(MLP(in_features=n_obs, out_features=spec.space.n, num_cells=[16]),
                           in_keys=[(GROUP, "observation", "observation")], out_keys=[(GROUP, "action_value")])
    q = QValueModule(spec=spec, action_value_key=(GROUP, "action_value"),
                     out_keys=[(GROUP, "action"), (GROUP, "action_value"), (GROUP, "chosen_action_value")],
                     action_mask_key=(GROUP, "action_mask"))
    td = env.rollout(2 * problem.n_tasks, TensorDictSequential(net, q), break_when_any_done=False)
    check_rollout(td, problem, sizes)


def test_without_padding_the_q_value_module_refuses_the_stacked_action_spec():
    """Why ``pad_actions`` exists (docs/planners.md): the default env rolls out, Q-learners refuse it."""
    env = PettingZooWrapper(make_env("wing_panel_pairs_small"), categorical_actions=True, seed=0)
    assert env.rollout(2)[GROUP, "action"].shape == (2, 3)
    with pytest.raises(ValueError, match="action_space was not specified/not compatible"):
        QValueModule(spec=env.full_action_spec[GROUP, "action"], action_value_key=(GROUP, "action_value"))


def test_docs_snippet_runs():
    """The copyable snippet of docs/planners.md (its TorchRL section) runs as printed."""
    text = (ROOT / "docs" / "planners.md").read_text(encoding="utf-8")
    section = text[text.index("### The env in TorchRL and BenchMARL"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    scope: dict = {}
    exec(compile(code, "docs/planners.md", "exec"), scope)  # noqa: S102 - the repository's own docs
    max_u = scope["td"]["next", GROUP, "info", "max_u"]
    assert max_u.shape == (4, 3) and max_u.min() > 0  # one episode of the case's 4 tasks, 3 robots
