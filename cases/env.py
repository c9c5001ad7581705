"""A PettingZoo ``ParallelEnv`` over any fixbench problem: one task per step, one answer per agent.

The multi-robot fixture planning game of the reference implementation (a contextual bandit played by
a team, docs/protocol.md), on the counted oracle:

- each step presents one task (a drilling position, an operating condition); every agent observes
  the task's feature vector (``float32`` ``Box``, bounds = the range of the problem's features);
- each agent answers with an index into its OWN action set (``Discrete(len(set))``): a candidate,
  or, where a robot places several pads (a pair end effector, m pads, an idle robot), one of its
  feasible pad tuples (``problem.options``); the joint answer is a layout, evaluated once on the
  oracle (one counted sample per step, ``env.samples``);
- every agent receives the same reward: the seed paper's Gaussian reward by default, or the reference
  code's bell reward (``reward="bell"``); ``infos[agent]`` carries ``max_u``, ``max_uxy``, ``max_w``,
  ``max_ux``, ``max_uy``, both rewards, the task index, the global layout and the candidate indices
  of the pads it placed (``pads``, -1 for none);
- one episode is one pass over the tasks, in order or shuffled with the seed given to ``reset``;
  after the last task every agent is terminated and ``env.agents`` is empty.

>>> env = make_env("wing_panel_small", tasks=[0, 1, 2])
>>> obs, infos = env.reset(seed=0)
>>> obs, rew, term, trunc, infos = env.step({a: 0 for a in env.agents})
>>> env.samples
1

A step beyond the evaluator's budget raises :class:`fixbench.cases.errors.BudgetExhausted` and spends nothing.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from fixbench.cases.errors import CaseError
from fixbench.cases.problem import Evaluator, Problem, load_problem
from fixbench.cases.spec import load_case_spec

REWARDS = ("gaussian", "bell")


class FixtureEnv(ParallelEnv):
    """Team fixture-planning bandit over ``problem`` (see the module docstring).

    ``task_ids`` restricts an episode to those tasks of ``problem`` (indices into ``problem.tasks``;
    default all). ``evaluator`` lets a planner share its own counted evaluator with the env;
    otherwise the env makes ``problem.evaluator(budget)``.
    """

    metadata = {"name": "fixbench_fixture_v0", "render_modes": [], "is_parallelizable": True}
    render_mode = None  # nothing to render: `fixbench show` and `fixbench evaluate --plot` draw the part

    def __init__(self, problem: Problem, budget: int | None = None, reward: str = "gaussian",
                 shuffle: bool = False, task_ids=None, evaluator: Evaluator | None = None):
        if reward not in REWARDS:
            raise CaseError(problem.spec.source, "reward", f"must be one of {', '.join(REWARDS)}, got '{reward}'")
        self.problem = problem
        self.ev = evaluator if evaluator is not None else problem.evaluator(budget)
        self.reward_key = f"reward_{reward}"
        self.shuffle = bool(shuffle)
        ids = np.arange(problem.n_tasks) if task_ids is None else np.asarray(task_ids, dtype=np.int64)
        if ids.ndim != 1 or len(ids) == 0:
            raise CaseError(problem.spec.source, "tasks", "need a non-empty list of task indices")
        for t in ids:
            problem.check_task(int(t))
        self.task_ids = ids
        self.possible_agents = [f"robot_{i}" for i in range(problem.n_agents)]
        self.agents: list[str] = []
        feats = problem.features.astype(np.float32)
        low, high = feats.min(axis=0), feats.max(axis=0)
        box = spaces.Box(low=low, high=high, shape=low.shape, dtype=np.float32)
        self.observation_spaces = {a: box for a in self.possible_agents}
        self.action_spaces = {a: spaces.Discrete(len(s)) for a, s in zip(self.possible_agents, problem.action_sets)}
        self._feats = feats
        self._order = ids.copy()
        self._pos = 0
        self.np_random = np.random.default_rng()

    @property
    def samples(self) -> int:
        """Oracle samples spent so far (one per step)."""
        return self.ev.samples

    @property
    def task(self) -> int:
        """The task (index into ``problem.tasks``) the agents are asked about now."""
        return int(self._order[min(self._pos, len(self._order) - 1)])

    @functools.cache  # noqa: B019 - spaces never change; the same object each call
    def observation_space(self, agent):
        return self.observation_spaces[agent]

    @functools.cache  # noqa: B019
    def action_space(self, agent):
        return self.action_spaces[agent]

    def _obs(self) -> dict:
        o = self._feats[self.task]
        return {a: o.copy() for a in self.agents}

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.np_random = np.random.default_rng(seed)
            for i, a in enumerate(self.possible_agents):
                self.action_spaces[a].seed(seed + i)
        self._order = self.np_random.permutation(self.task_ids) if self.shuffle else self.task_ids.copy()
        self._pos = 0
        self.agents = list(self.possible_agents)
        return self._obs(), {a: {"task": self.task} for a in self.agents}

    def layout(self, actions: dict) -> np.ndarray:
        """Global action indices of a joint answer (one action per agent).

        Every action must be an integer (Python or numpy, not a bool, float or string) in
        ``0..n-1`` of its agent's own set; anything else is refused (one line, no sample spent).
        """
        src = self.problem.spec.source
        if not isinstance(actions, dict):
            raise CaseError(src, "actions", f"must be a dict {{agent: action}}, got {type(actions).__name__}")
        out = []
        for i, a in enumerate(self.possible_agents):
            if a not in actions:
                raise CaseError(src, "actions", f"no action for agent '{a}'")
            act, n = actions[a], len(self.problem.action_sets[i])
            if isinstance(act, np.ndarray) and act.ndim == 0:
                act = act[()]
            if isinstance(act, (bool, np.bool_)) or not isinstance(act, (int, np.integer)):
                raise CaseError(src, f"actions['{a}']", f"must be an integer in 0..{n - 1}, got {act!r}")
            if not 0 <= int(act) < n:
                raise CaseError(src, f"actions['{a}']", f"{int(act)} is outside 0..{n - 1} (agent '{a}' "
                                f"has {n} actions)")
            out.append(self.problem.action_sets[i][int(act)])
        unknown = set(actions) - set(self.possible_agents)
        if unknown:
            raise CaseError(src, "actions", f"unknown agent(s) {sorted(map(str, unknown))}")
        return np.array([out], dtype=np.int64)

    def step(self, actions: dict):
        if not self.agents:
            raise CaseError(self.problem.spec.source, "step", "episode is over; call reset()")
        task, layout = self.task, self.layout(actions)
        d = self.ev.evaluate(task, layout)
        row = d.row(0)
        # strict values: a number the step did not compute (soft_u) is None, not NaN (NaN != NaN)
        info = {**{k: (v if np.isfinite(v) else None) for k, v in row.items()}, "task": task,
                "layout": layout[0].tolist(), "pads": self.problem.pads(layout)[0].tolist()}
        r = row[self.reward_key]
        self._pos += 1
        done = self._pos >= len(self._order)
        agents = self.agents
        obs = {a: self._feats[self.task].copy() for a in agents}
        rewards = {a: r for a in agents}
        terms = {a: done for a in agents}
        truncs = {a: False for a in agents}
        infos = {a: info for a in agents}
        if done:
            self.agents = []
        return obs, rewards, terms, truncs, infos

    def render(self):
        return None

    def close(self):
        pass


def make_env(case: str | Path | Problem, material: str | None = None, agents: int | None = None,
             tasks=None, budget: int | None = None, reward: str = "gaussian",
             shuffle: bool = False) -> FixtureEnv:
    """A :class:`FixtureEnv` over a catalog case, a TOML path or a :class:`Problem`.

    With a case name or path, ``tasks`` (a list of task indices) builds a problem with only those
    tasks (same part, mesh and candidates; cheaper to set up), and the env's task indices refer to
    that problem. With a :class:`Problem`, ``material`` and ``agents`` must be left out and
    ``tasks`` selects the tasks of that problem an episode visits (its oracle is shared).
    """
    if isinstance(case, Problem):
        if material is not None or agents is not None:
            raise CaseError(case.spec.source, "make_env", "material/agents apply to a case name, not a Problem")
        return FixtureEnv(case, budget=budget, reward=reward, shuffle=shuffle, task_ids=tasks)
    if tasks is None:
        problem = load_problem(case, material=material, agents=agents)
    else:
        spec = load_case_spec(case, material, agents)
        idx = [int(t) for t in tasks]
        for t in idx:
            if not 0 <= t < len(spec.tasks):
                raise CaseError(spec.source, "tasks", f"task {t} is not in 0..{len(spec.tasks) - 1}")
        problem = Problem(spec.with_tasks(idx))
    return FixtureEnv(problem, budget=budget, reward=reward, shuffle=shuffle)
