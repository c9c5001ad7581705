"""A BenchMARL task on any fixbench case, so that ``benchmarl`` experiments run on the PettingZoo env.

:class:`FixbenchTask` is a BenchMARL 1.5.2 task (a ``TaskClass``) whose env function returns TorchRL's
``PettingZooWrapper`` around ``make_env(case, ..., pad_actions=True)``: one group, ``robot``, every
robot's action set padded to the largest with an ``action_mask``, discrete actions only, no state, no
render. It subclasses BenchMARL's own ``PettingZooClass`` and keeps its specs (observation, action
mask, info, action and group map are read off the wrapped env as for any PettingZoo task); what it
changes is the env function, the action kind, the episode length and the name.

- **Config.** :class:`FixbenchTaskConfig` (case, material, agents, tasks, reward, shuffle) is checked
  when it is made, before any experiment starts: a wrong key or value is one line naming the key
  (:class:`~fixbench.cases.errors.CaseError`), and the env is built once so that the case, its
  material, robots and tasks are checked by the env itself.
- **Budget.** Every env step is one FE evaluation: a BenchMARL frame is one counted sample, and an
  evaluation episode (``max_steps``: one pass over the tasks) spends one sample a task.
- **Parameter sharing.** Every robot observes the same task features and has no agent id, so a
  policy shared between robots gives every robot the same action index: run experiments with
  ``share_policy_params=False`` (docs/planners.md#benchmarl-experiments-on-a-fixbench-case).

Nothing in fixbench imports this module (users do), so BenchMARL and TorchRL are imported at its top;
without them the import fails in one line naming the ``marl`` extra.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from fixbench.cases import make_env
from fixbench.cases.env import FixtureEnv
from fixbench.cases.errors import CaseError

try:
    from benchmarl.environments.pettingzoo.common import PettingZooClass
    from torchrl.envs import PettingZooWrapper
except ImportError as exc:  # one line naming the extra, as the planners that need TorchRL do
    raise ImportError(f"fixbench.bench.marl_task needs BenchMARL and TorchRL, which do not import here "
                      f"({exc}): pip install 'fixbench[marl]'") from None

GROUP = "robot"  # the one group of the task: robot_0, robot_1, ...
SOURCE = "fixbench task"  # what a config error names in place of a file


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclass(frozen=True)
class FixbenchTaskConfig:
    """Which problem the task plays: ``make_env``'s arguments (docs/planners.md, cases/env.py).

    ``case`` is a catalog name or a case TOML path; ``material`` and ``agents`` override the case's;
    ``tasks`` (task indices) builds the problem with only those tasks; ``reward`` is ``gaussian`` or
    ``bell``; ``shuffle`` visits the tasks of an episode in an order drawn from the env's seed.
    """

    case: str
    material: str | None = None
    agents: int | None = None
    tasks: tuple[int, ...] | None = None
    reward: str = "gaussian"
    shuffle: bool = False

    def __post_init__(self):
        if not isinstance(self.case, str) or not self.case:
            raise CaseError(SOURCE, "case", f"must be a case name or a case file path, got {self.case!r}")
        if self.material is not None and not isinstance(self.material, str):
            raise CaseError(SOURCE, "material", f"must be a material name, got {self.material!r}")
        if self.agents is not None and not _is_int(self.agents):
            raise CaseError(SOURCE, "agents", f"must be an integer, got {self.agents!r}")
        if self.tasks is not None:
            if not isinstance(self.tasks, (list, tuple)) or not all(map(_is_int, self.tasks)):
                raise CaseError(SOURCE, "tasks", f"must be a list of task indices, got {self.tasks!r}")
            object.__setattr__(self, "tasks", tuple(self.tasks))
        if not isinstance(self.shuffle, bool):
            raise CaseError(SOURCE, "shuffle", f"must be true or false, got {self.shuffle!r}")
        self.make_env()  # the case, material, agents, tasks and reward, each checked by the env in one line

    @classmethod
    def from_dict(cls, data: dict) -> FixbenchTaskConfig:
        """The config of a dict (BenchMARL's ``task.config``); an unknown or missing key is one line."""
        names = [f.name for f in fields(cls)]
        for key in data:
            if key not in names:
                raise CaseError(SOURCE, str(key), f"unknown key (keys: {', '.join(names)})")
        if "case" not in data:
            raise CaseError(SOURCE, "case", "missing: name a catalog case or a case file")
        return cls(**data)

    def make_env(self) -> FixtureEnv:
        """The padded env of this config (every call a new env, with its own counted evaluator)."""
        return make_env(self.case, material=self.material, agents=self.agents, tasks=self.tasks,
                        reward=self.reward, shuffle=self.shuffle, pad_actions=True)


def wrapped_env(settings: FixbenchTaskConfig, seed: int | None, device) -> PettingZooWrapper:
    """TorchRL's wrapper around a new env of ``settings``, its robots in the one group ``robot``."""
    env = settings.make_env()
    return PettingZooWrapper(env, categorical_actions=True, seed=seed, device=device,
                             group_map={GROUP: list(env.possible_agents)})


class FixbenchTask(PettingZooClass):
    """A fixbench case as a BenchMARL task: ``FixbenchTask.of(FixbenchTaskConfig("wing_panel_small"))``.

    BenchMARL keeps the config as the dict ``task.config`` (it pickles the task with an experiment and
    may update the dict); every use reads it again through :meth:`FixbenchTaskConfig.from_dict`.
    """

    def __init__(self, name: str, config: dict):
        super().__init__(name=name, config=config)
        self.settings()  # checked when the task is made, before an experiment starts

    @classmethod
    def of(cls, settings: FixbenchTaskConfig) -> FixbenchTask:
        """The task of a checked config, named after its case (BenchMARL's experiment names use it)."""
        return cls(name=Path(settings.case).stem, config=asdict(settings))

    def settings(self) -> FixbenchTaskConfig:
        return FixbenchTaskConfig.from_dict(self.config)

    def get_env_fun(self, num_envs, continuous_actions, seed, device):
        """A picklable function of no argument making the wrapped env (BenchMARL batches it itself)."""
        return functools.partial(wrapped_env, self.settings(), seed, device)

    def supports_continuous_actions(self) -> bool:
        return False

    def supports_discrete_actions(self) -> bool:
        return True

    def has_render(self, env) -> bool:
        return False

    def max_steps(self, env) -> int:
        """An evaluation episode: one pass over the tasks, one step (one sample) a task."""
        return len(self.settings().make_env().task_ids)

    @staticmethod
    def env_name() -> str:
        return "fixbench"

    @staticmethod
    def log_info(batch) -> dict[str, float]:
        """The smallest max |u| (m) a collected batch evaluated: its best layout (BenchMARL itself logs
        the mean of every info key, ``collection/robot/info/max_u``)."""
        return {"fixbench/max_u_min": batch["next", GROUP, "info", "max_u"].min().item()}
