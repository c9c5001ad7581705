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
  code's bell reward (``reward="bell"``);
- ``infos[agent]`` holds the same numeric keys at ``reset`` and at every ``step`` (``INFO_KEYS``; the
  libraries build their info spec from the reset infos, torchrl's ``PettingZooWrapper`` among them):
  after a step, ``max_ux``, ``max_uy``, ``max_w``, ``max_u``, ``max_uxy`` (m) and ``reward_gaussian``,
  ``reward_bell`` of the layout just evaluated, ``task`` (the task it was evaluated on), ``layout``
  (its global action indices, one an agent) and ``pads`` (the candidate indices of the pads it placed,
  -1 for none); at reset, before anything is evaluated, the measured keys hold -1.0 (no measured value
  is negative), ``layout`` and ``pads`` hold -1 and ``task`` is the task the agents are asked about;
- ``pad_actions=True`` gives every agent the action space of the largest set, ``Discrete(max)``, and
  the observation ``{"observation": features, "action_mask": int8 vector}`` (PettingZoo's convention,
  read by ``pettingzoo.test.parallel_api_test`` and torchrl's ``PettingZooWrapper``): 1 for the
  agent's own actions ``0..len(set)-1``, 0 for the padding, which a step refuses like any index
  outside the set. It lets libraries that stack agents into one group (one action size a group) run
  on robots with sets of different sizes; the default keeps each agent's own ``Discrete(len(set))``
  and the bare feature vector;
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
from fixbench.cases.problem import Deformation, Evaluator, Problem, load_problem
from fixbench.cases.spec import load_case_spec

REWARDS = ("gaussian", "bell")
# what a step measures, in infos; the env never asks for the soft max (``soft_u`` stays out: always NaN here)
MEASURED = tuple(k for k in Deformation.__dataclass_fields__ if k != "soft_u")
INFO_KEYS = (*MEASURED, "task", "layout", "pads")
UNMEASURED = -1.0  # a measured key's value at reset


class FixtureEnv(ParallelEnv):
    """Team fixture-planning bandit over ``problem`` (see the module docstring).

    ``task_ids`` restricts an episode to those tasks of ``problem`` (indices into ``problem.tasks``;
    default all). ``evaluator`` lets a planner share its own counted evaluator with the env;
    otherwise the env makes ``problem.evaluator(budget)``. ``pad_actions`` pads every action set to
    the largest with an ``action_mask`` in the observation (see the module docstring).
    """

    metadata = {"name": "fixbench_fixture_v0", "render_modes": [], "is_parallelizable": True}
    render_mode = None  # nothing to render: `fixbench show` and `fixbench evaluate --plot` draw the part

    def __init__(self, problem: Problem, budget: int | None = None, reward: str = "gaussian",
                 shuffle: bool = False, task_ids=None, evaluator: Evaluator | None = None,
                 pad_actions: bool = False):
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
        sizes = [len(s) for s in problem.action_sets]
        self.pad_actions = bool(pad_actions)
        if self.pad_actions:
            n = max(sizes)
            self._masks = {a: (np.arange(n) < k).astype(np.int8) for a, k in zip(self.possible_agents, sizes)}
            masked = spaces.Dict({"observation": box, "action_mask": spaces.Box(0, 1, shape=(n,), dtype=np.int8)})
            self.observation_spaces = {a: masked for a in self.possible_agents}
            self.action_spaces = {a: spaces.Discrete(n) for a in self.possible_agents}
        else:
            self.observation_spaces = {a: box for a in self.possible_agents}
            self.action_spaces = {a: spaces.Discrete(k) for a, k in zip(self.possible_agents, sizes)}
        self._n_pads = problem.pads(np.zeros((1, problem.n_agents), dtype=np.int64)).shape[1]
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
        if self.pad_actions:
            return {a: {"observation": o.copy(), "action_mask": self._masks[a].copy()} for a in self.agents}
        return {a: o.copy() for a in self.agents}

    def _infos(self, info: dict) -> dict:
        """``info`` for every live agent, a dict of its own (a wrapper may pop keys from one)."""
        return {a: dict(info) for a in self.agents}

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.np_random = np.random.default_rng(seed)
            for i, a in enumerate(self.possible_agents):
                self.action_spaces[a].seed(seed + i)
        self._order = self.np_random.permutation(self.task_ids) if self.shuffle else self.task_ids.copy()
        self._pos = 0
        self.agents = list(self.possible_agents)
        info = {**dict.fromkeys(MEASURED, UNMEASURED), "task": self.task, "layout": [-1] * self.problem.n_agents,
                "pads": [-1] * self._n_pads}
        return self._obs(), self._infos(info)

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
        row = self.ev.evaluate(task, layout).row(0)
        info = {**{k: row[k] for k in MEASURED}, "task": task, "layout": layout[0].tolist(),
                "pads": self.problem.pads(layout)[0].tolist()}
        r = row[self.reward_key]
        self._pos += 1
        done = self._pos >= len(self._order)
        out = (self._obs(), {a: r for a in self.agents}, {a: done for a in self.agents},
               {a: False for a in self.agents}, self._infos(info))
        if done:
            self.agents = []
        return out

    def render(self):
        return None

    def close(self):
        pass


class PositionBatchEnv:
    """The game of :class:`FixtureEnv` vectorised over positions: each step presents the episode's next
    ``per_step`` tasks (fewer at its end) and takes one joint answer for each, so that a learner acts on
    all of them with one batched forward and learns from all of them in one update.

    Every answer is still one counted sample on the shared evaluator, evaluated one after the other in
    the episode's order: with ``per_step=1`` a run sees exactly what it sees on :class:`FixtureEnv`
    (the same order for the same ``reset`` seed, the same samples). Written here rather than taken from
    a library: PettingZoo's parallel API steps one context for the whole team, and gymnasium's and
    TorchRL's vector envs batch copies of an env, each with its own episode; this batches the positions
    of one episode, which is what keeps every position visited once an episode.

    >>> env = PositionBatchEnv(load_problem("wing_panel_small"), per_step=2)
    >>> env.reset(seed=0).tolist()
    [0, 1]
    >>> env.step(np.zeros((2, env.problem.n_agents), dtype=np.int64))["max_u"].shape
    (2,)
    >>> env.tasks.tolist(), env.samples
    ([2, 3], 2)
    """

    def __init__(self, problem: Problem, per_step: int, evaluator: Evaluator | None = None, task_ids=None,
                 shuffle: bool = False, budget: int | None = None):
        src = problem.spec.source
        if isinstance(per_step, bool) or not isinstance(per_step, (int, np.integer)) or per_step < 1:
            raise CaseError(src, "per_step", f"must be a positive integer, got {per_step!r}")
        self.problem, self.per_step, self.shuffle = problem, int(per_step), bool(shuffle)
        self.ev = evaluator if evaluator is not None else problem.evaluator(budget)
        ids = np.arange(problem.n_tasks) if task_ids is None else np.asarray(task_ids, dtype=np.int64)
        if ids.ndim != 1 or len(ids) == 0:
            raise CaseError(src, "tasks", "need a non-empty list of task indices")
        for t in ids:
            problem.check_task(int(t))
        self.task_ids = ids
        self.sizes = np.array([len(s) for s in problem.action_sets], dtype=np.int64)
        self._order, self._pos = ids.copy(), len(ids)  # over until reset

    @property
    def samples(self) -> int:
        """Oracle samples spent so far (one per answer)."""
        return self.ev.samples

    @property
    def done(self) -> bool:
        """Whether the episode has visited every task (then :meth:`reset`)."""
        return self._pos >= len(self._order)

    @property
    def tasks(self) -> np.ndarray:
        """The tasks (indices into ``problem.tasks``) the agents are asked about now."""
        return self._order[self._pos:self._pos + self.per_step].copy()

    def reset(self, seed: int | None = None) -> np.ndarray:
        """A new episode, in the tasks' order or shuffled as :class:`FixtureEnv` shuffles with ``seed``;
        returns the first step's tasks."""
        rng = np.random.default_rng(seed)
        self._order = rng.permutation(self.task_ids) if self.shuffle else self.task_ids.copy()
        self._pos = 0
        return self.tasks

    def step(self, actions) -> dict:
        """Evaluate one joint answer per task of :attr:`tasks`: ``actions`` (n, agents), indices into each
        agent's own set. Returns arrays of n values: the measured keys of ``FixtureEnv``'s infos (m),
        ``reward_gaussian``, ``reward_bell`` and ``task``. Anything but integers inside the sets is
        refused in one line, before any sample is spent."""
        src = self.problem.spec.source
        if self.done:
            raise CaseError(src, "step", "episode is over; call reset()")
        tasks, a = self.tasks, np.asarray(actions)
        if a.shape != (len(tasks), len(self.sizes)) or a.dtype.kind not in "iu":
            raise CaseError(src, "actions", f"must be integers of shape {(len(tasks), len(self.sizes))}, "
                            f"got {a.dtype} {a.shape}")
        bad = (a < 0) | (a >= self.sizes)
        if bad.any():
            k, i = np.argwhere(bad)[0]
            raise CaseError(src, f"actions[{k}, {i}]", f"{int(a[k, i])} is outside 0..{self.sizes[i] - 1}")
        self.ev.afford(len(tasks))  # all or nothing
        layouts = np.column_stack([s[a[:, i]] for i, s in enumerate(self.problem.action_sets)])
        rows = [self.ev.evaluate(int(t), layouts[k:k + 1]).row(0) for k, t in enumerate(tasks)]
        self._pos += len(tasks)
        out = {k: np.array([r[k] for r in rows]) for k in (*MEASURED, "reward_gaussian", "reward_bell")}
        return {**out, "task": tasks}


def make_env(case: str | Path | Problem, material: str | None = None, agents: int | None = None,
             tasks=None, budget: int | None = None, reward: str = "gaussian",
             shuffle: bool = False, pad_actions: bool = False) -> FixtureEnv:
    """A :class:`FixtureEnv` over a catalog case, a TOML path or a :class:`Problem`.

    With a case name or path, ``tasks`` (a list of task indices) builds a problem with only those
    tasks (same part, mesh and candidates; cheaper to set up), and the env's task indices refer to
    that problem. With a :class:`Problem`, ``material`` and ``agents`` must be left out and
    ``tasks`` selects the tasks of that problem an episode visits (its oracle is shared).
    ``pad_actions`` pads the action sets to the largest with an action mask (:class:`FixtureEnv`).
    """
    if isinstance(case, Problem):
        if material is not None or agents is not None:
            raise CaseError(case.spec.source, "make_env", "material/agents apply to a case name, not a Problem")
        return FixtureEnv(case, budget=budget, reward=reward, shuffle=shuffle, task_ids=tasks, pad_actions=pad_actions)
    if tasks is None:
        problem = load_problem(case, material=material, agents=agents)
    else:
        spec = load_case_spec(case, material, agents)
        idx = [int(t) for t in tasks]
        for t in idx:
            if not 0 <= t < len(spec.tasks):
                raise CaseError(spec.source, "tasks", f"task {t} is not in 0..{len(spec.tasks) - 1}")
        problem = Problem(spec.with_tasks(idx))
    return FixtureEnv(problem, budget=budget, reward=reward, shuffle=shuffle, pad_actions=pad_actions)
