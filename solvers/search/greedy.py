"""Person-by-person best response with random restarts (team decision theory).

From a random layout, each agent in turn evaluates every other candidate of its own set with the
other agents fixed (one batched oracle call) and moves to the best one if it is strictly better.
A restart stops at a *person-by-person optimum*: once every agent has been checked since the last
move without improving (no single agent can improve alone). Restarts run one after another, each
with all the budget that is left, until ``restarts`` have run or the budget is spent: a small
budget goes to one descent that can converge rather than to several that cannot. The layout with
the lowest true max among all evaluated is returned.

What the moves minimise: the *soft max*, the power mean of |u| over the measurement points,
(mean |u|^p)^(1/p) with ``soft_power`` p, from the same solve (no extra sample): the aggregation
structural optimisation uses for max-stress constraints (Kreisselmeier-Steinhauser style).
Why not the max itself: under a max, regions held by different agents trade the max between
them. On the fan the three blades, loaded alike and coupled through the hub, hold nearly equal
maxima; moving one blade's fixture to where it helps that blade raises the other blades' maxima a
little, so the max goes up and no single agent moves. Plain best response then stops far from the
optimum (measured on fan_small at 2 % of the joint space: +303 % mean gap; 0.5 % of descents from
random starts end within 5 %). The soft max credits the improved blade, and the agents follow each
other to the symmetric optimum (every start within 5 % for 2 <= p <= 16). ``soft_power = 0``
descends on the max itself.

Transfer (``transfer`` k > 0, per-task mode): tasks are solved in order, and the first descent of
each task starts from the best of the best layouts of the k already-solved tasks nearest by task
features (:mod:`fixbench.solvers.transfer`; each costs its one sample) instead of a random layout: the
chance the learners have of carrying what they found from one drilling position to the next.

Per-task mode runs this on each task with an equal share of the budget; shared mode runs it once
on the worst-over-tasks objective (n_tasks samples per layout): the budget loop of
:meth:`~fixbench.solvers.base.Planner.drive`. Budget: at least one layout must fit (one sample per
task, or n_tasks in shared mode), else :class:`PlannerError`. Beyond that it is a documented best
effort: when the budget ends in the middle of an agent's check, the alternatives that still fit are
evaluated (in random order), the best move among them is taken, and the restart stops unconverged
(``info["converged"]``).

Budgets too small for one round: when a task's budget cannot pay for one complete check of every
agent's set (the wing panel: 5 x 667 = 3,335 a task), best response cannot even finish a round,
and spending the budget on a few complete checks wastes it: below one agent's check (the seed's
protocol, 100 a task) greedy ended at 9,290 % regret, ten times random search's, and with room for
one agent's check but not a round it ended worse at 1,000 a task than at 300 (wing panel, 30 of
its tasks, 3 seeds, mean max: 256 um against 26 um at 300; with transfer 30.6 against 10.9).
Greedy then falls back to sampling: half of the task's budget on random layouts (the warm-start layouts among them),
the other half on sampled moves from the best of them: rounds of one random alternative per agent
(the agents in random order), each round evaluated at once, the best move taken when it improves
(``info["sampled"]`` counts the tasks). Measured (mean max um, 3 seeds; not against a reference):
wing panel at 100 samples a task (20 of its tasks) 21.6 against random's 23.9 and 28.8 for moves
alone; at 20 a task 53.8 against 50.6; wing_panel_small at 6 a task 154 against 152. Sampling from
one agent's check up to one round (the rule before was one agent's check), same 30 tasks at 1,000
a task: 9.8 um (5.5 with transfer) against the 256 (30.6) of the checks. From one round up best
response runs: at 4,000 a task it ends at 2.77 um with transfer against sampling's 3.34 (7.2
against 5.7 without transfer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from fixbench.cases.problem import Problem
from fixbench.solvers.base import Planner, PlannerConfig, Share, TracedEvaluator, at_least, random_layouts
from fixbench.solvers.descent import descend


@dataclass(frozen=True)
class GreedyConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "restarts": ("int", 4, 64),
        "soft_power": ("float", 1.0, 8.0),
        "transfer": ("int", 0, 5),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    restarts: int = 32
    """Most descents from random starts; fewer run when the budget is spent first."""

    soft_power: float = 4.0
    """Exponent p of the power mean the moves minimise (module doc); 0 descends on the max itself."""

    transfer: int = 0
    """Warm start: the first descent of a task starts from the best layouts of this many solved tasks
    nearest by task features (0: every descent starts at random)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "restarts")
        at_least(self, 0, "soft_power", "transfer")


class Greedy(Planner):
    name = "greedy"
    family = "local-search"
    description = "person-by-person best response from random starts (a team-theory local optimum)"
    Config = GreedyConfig

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        layouts, runs = self.drive(problem, ev, mode, lambda share: self._restarts(problem, share, rng),
                                   unlimited=math.inf, soft_power=cfg.soft_power or None, transfer=cfg.transfer)
        return layouts, _info(runs)

    def _restarts(self, problem: Problem, share: Share, rng: np.random.Generator) -> list[tuple[int, bool]]:
        """Restarts within the share's allowance of layouts: [(sweeps, converged) per restart]; the
        evaluator keeps the best. The first starts from the best of the warm layouts when there are any."""
        budget, evaluate, warm = share.allowance, share.score, share.warm
        if budget < sum(len(a) for a in problem.action_sets):  # not one complete round: sample moves
            start = warm[:int(min(len(warm), budget))] if len(warm) else None
            return [_sample_moves(problem, evaluate, budget, rng, start)]
        runs, spent = [], 0
        for i in range(self.config.restarts):
            if budget - spent < 1:
                break
            start = None
            if i == 0 and len(warm):
                start = warm[:int(min(len(warm), budget - spent))]  # what the budget allows
            sweeps, converged, used = _descend(problem, evaluate, budget - spent, rng, start)
            spent += used
            runs.append((sweeps, converged))
        return runs


def _descend(problem: Problem, evaluate, budget: float, rng: np.random.Generator, start: np.ndarray | None = None):
    """One restart from the best of ``start`` (else a random layout): (sweeps, converged, layouts
    evaluated) within ``budget`` layouts. Best response on the oracle (:func:`fixbench.solvers.descent.descend`):
    the agents in turn from a random one, each checking every other candidate of its set (:class:`_Check`)
    and moving only to a strictly lower value, until every agent has been checked since the last move."""
    n = problem.n_agents
    starts = random_layouts(problem, rng, 1) if start is None else start
    values = evaluate(starts)
    check = _Check(problem, evaluate, budget, rng, starts[int(np.argmin(values))], float(np.min(values)), len(starts))
    a = int(rng.integers(n))  # the first agent to move: a small budget must not always favour agent 0
    out = descend(check, check.positions[None], [(a + k) % n for k in range(n)], ties="stay", stop="others")
    return int(out.sweeps[0]), bool(out.converged[0]) and not check.partial, check.spent


class _Check:
    """The score of greedy's descent: agent i's check evaluates every other candidate of its set with
    the others fixed (one batched oracle call); the current layout scores its known value. When the
    budget cannot pay for a whole check, the alternatives that still fit are evaluated (in random
    order; the rest score inf), the check is ``partial`` and the last: the next turn stops the descent."""

    def __init__(self, problem: Problem, evaluate, budget: float, rng: np.random.Generator, layout: np.ndarray,
                 value: float, spent: int):
        self.sets, self.evaluate, self.budget, self.rng = problem.action_sets, evaluate, budget, rng
        self.layout, self.value, self.spent, self.partial = layout.copy(), value, spent, False
        self.positions = np.array([int(np.flatnonzero(s == g)[0]) for s, g in zip(self.sets, layout)])
        self.last: tuple[int, np.ndarray] | None = None  # the previous check: (agent, its scores)

    def __call__(self, i: int, rows: np.ndarray, cur: np.ndarray) -> np.ndarray | None:
        if self.partial:
            return None
        if self.last is not None:  # the previous agent stayed or moved: the current value is its score there
            j, prev = self.last
            self.value = prev[cur[0, j]]
            self.layout[j] = self.sets[j][cur[0, j]]
        s, here = self.sets[i], int(cur[0, i])
        alts = np.delete(np.arange(len(s)), here)
        fit = len(alts) if math.isinf(self.budget) else int(self.budget - self.spent)
        if fit < len(alts):
            self.partial = True
            alts = self.rng.permutation(alts)[:fit]  # best effort: what the budget still allows
        scores = np.full(len(s), np.inf)
        scores[here] = self.value
        if len(alts):
            trial = np.tile(self.layout, (len(alts), 1))
            trial[:, i] = s[alts]
            scores[alts] = self.evaluate(trial)
            self.spent += len(alts)
        self.last = (i, scores)
        return scores[None]


def _sample_moves(problem: Problem, evaluate, budget: int, rng: np.random.Generator,
                  start: np.ndarray | None = None) -> tuple[int, bool]:
    """The small-budget fallback (module doc) within ``budget`` layouts: (rounds of moves, None); the
    None marks it in ``info``."""
    k = max(1, int(budget) // 2)
    starts = random_layouts(problem, rng, k)
    if start is not None:
        starts = np.vstack([start, starts])[:max(k, len(start))]
    values = evaluate(starts)
    layout, value = starts[int(np.argmin(values))], float(np.min(values))
    spent, rounds = len(starts), 0
    n = problem.n_agents
    while budget - spent >= 1:
        k = int(min(n, budget - spent))
        agents = rng.permutation(n)[:k]
        trial = np.tile(layout, (k, 1))
        for j, a in enumerate(agents):
            alts = problem.action_sets[a][problem.action_sets[a] != layout[a]]
            if len(alts):
                trial[j, a] = alts[rng.integers(len(alts))]
        values = evaluate(trial)
        spent += k
        rounds += 1
        i = int(np.argmin(values))
        if values[i] < value:
            layout, value = trial[i], float(values[i])
    return rounds, None


def _info(runs: list[list[tuple[int, bool]]]) -> dict:
    """Per task (one entry in shared mode): restarts run, sweeps and convergence of each; tasks where
    the budget paid for no complete check (sampled moves instead) have converged ``[None]``."""
    return {"restarts": [len(r) for r in runs], "sweeps": [[s for s, _ in r] for r in runs],
            "converged": [[c for _, c in r] for r in runs],
            "sampled": sum(1 for r in runs if r and r[0][1] is None)}
