"""Thompson sampling on a learned surrogate shared across drilling positions (``surrogate-ts``).

Read top to bottom (cleanrl style): hyper-parameters, the ensemble, its best response, the loop.

The model. One regression, shared by every task, of y = log(max |u|) on x = [the task's features
(:func:`fixbench.solvers.transfer.scaled_features`, centred), the layout's pad coordinates
(``Problem.points`` of each agent's action, in agent order, scaled to [-1, 1] in the candidates'
bounding box)]. Deformation varies over orders of magnitude between a good and a bad layout, hence
the log; the target is standardised by the mean and standard deviation of all data seen so far. The
regressor is an ensemble of K small MLPs (x -> H -> H -> 1, ReLU; one batched module), each member
with its own random initialisation and its own online bootstrap of ALL the samples seen on every
task: every sample gets a Poisson(1) weight per member, drawn once when it arrives, and the member's
squared error is weighted by it (Osband et al. NeurIPS 2016, "Deep Exploration via Bootstrapped
DQN"). After every batch of samples each member takes a few AdamW steps on minibatches of the data.

Thompson sampling through the ensemble (Lu and Van Roy, NeurIPS 2017, "Ensemble Sampling"; Riquelme
et al., ICLR 2018, "Deep Bayesian Bandits Showdown", which found bootstrapped/ensemble posteriors
among the most robust ones for neural bandits): each new sample draws one member uniformly, as a
sample of the posterior over deformation models, and plays the layout that member thinks best. The
argmin over the joint layout space (hundreds of candidates per agent, to the power of the agents) is
taken by per-agent best response (coordinate descent, Gauss-Seidel: each agent in turn takes the
action of its own set with the lowest predicted log-deformation, the others fixed; sweeps until one
changes nothing, at most ``max_sweeps``), from a start that cycles over the task's own incumbent,
the best layouts of the ``transfer`` nearest solved tasks (:func:`fixbench.solvers.transfer.warm_layouts`),
and one uniform random layout. Best response is cheap because the first layer is linear: each agent
slot's contribution W1 x_i is tabulated once per retraining for all of its actions, so one agent's
response to the others is a table lookup, an addition and the last two layers over its actions.
A layout already evaluated on the task (or proposed twice in a batch) is replaced by a random
neighbour (one agent's action changed at random, repeatedly, until new; after ``tries`` changes a
repeat is accepted: a tiny joint space can be used up).

Rounds, not task by task: every round gives every training task a batch of ``batch`` samples
(larger when the budget is large, so that there are at most ``max_rounds`` retrainings), then the
ensemble is retrained on everything. Visiting the tasks task by task would fit the model to the
first tasks alone and give them none of what is learned on the later ones; in rounds, every position
gains from every other from the first batch on, the model sees all positions at every retraining
(no drift towards the latest task), and one round's best responses for all tasks are one batched
computation. The first ``initial_random`` samples of each task (round 0) are uniform random layouts
that seed the model.

Budget: split equally over the training tasks (``split_budget``; ``samples_per_task`` each when
unlimited), spent exactly; at least one sample per training task, else :class:`PlannerError`.
Per-task mode only. Returned layouts: on a training task the best layout evaluated there; on a task
outside the evaluator's tasks (held-out track, zero samples) the best response of the ENSEMBLE MEAN,
started from the nearest training task's best layout.

Measured (one thread, a shared 2-core machine): wing_panel (5 agents, 500 tasks) at 100 samples a
task, seed 0: mean max |u| 2.61 um (random search 21.8 um) in 222 s, of which best response 209 s,
training 8 s, oracle 2 s; 3x the training steps gave 2.51 um. wing_panel_small at 100 a task, seeds
0-2: 18.7 um (random 41.8 um); rounds of 10 samples a task (9 retrainings) gave 20.0 um.

Randomness: ``rng`` and a torch generator seeded from it (initial weights, minibatches); torch's
threads are set to ``threads`` and deterministic algorithms are asked for during the run (both
restored after), so the same seed gives the same bits.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.problem import Problem
from fixbench.solvers.base import (
    Planner,
    PlannerConfig,
    TracedEvaluator,
    at_least,
    random_layouts,
    require,
    require_budget,
    split_budget,
)
from fixbench.solvers.registry import register
from fixbench.solvers.torch_run import torch_run
from fixbench.solvers.transfer import nearest_tasks, scaled_features, warm_layouts


# ---------------------------------------------------------------------------------------------
# hyper-parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SurrogateConfig(PlannerConfig):
    tunable: ClassVar[dict[str, tuple]] = {
        "hidden": ("choice", [32, 64, 128]),
        "batch": ("int", 2, 10),
        "train_steps": ("int", 25, 300),
        "lr": ("log", 0.0001, 0.01),
        "transfer": ("int", 0, 5),
    }
    """What ``fixbench tune`` searches (bench/tune.py)."""

    ensemble: int = 5
    """Members K of the ensemble (the posterior samples Thompson sampling draws from)."""

    hidden: int = 64
    """Width of each member's two hidden layers."""

    initial_random: int = 10
    """Uniform random layouts per training task before the model is first used (round 0)."""

    batch: int = 5
    """Samples per training task per round (raised so that there are at most ``max_rounds`` rounds)."""

    max_rounds: int = 20
    """Most rounds after round 0, i.e. retrainings: bounds the training cost at large budgets."""

    train_steps: int = 100
    """AdamW steps per member after each round (minibatches drawn from all data seen so far)."""

    minibatch: int = 512
    """Samples per member per training step."""

    lr: float = 1e-3
    """AdamW learning rate."""

    weight_decay: float = 1e-4
    """AdamW weight decay."""

    transfer: int = 3
    """Best-response starts from the best layouts of this many solved tasks nearest by features."""

    max_sweeps: int = 4
    """Most Gauss-Seidel best-response sweeps over the agents per proposal."""

    tries: int = 50
    """Random one-agent changes tried to turn a repeated layout into a new one before accepting it."""

    samples_per_task: int = 100
    """Samples per training task when the budget is unlimited."""

    threads: int = 1
    """torch intra-op threads during the run (0: torch's setting); restored afterwards."""

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "ensemble", "hidden", "initial_random", "batch", "minibatch", "max_sweeps",
                 "samples_per_task")
        at_least(self, 0, "max_rounds", "train_steps", "weight_decay", "transfer", "tries", "threads")
        require(self, "lr", self.lr > 0, "positive")


# ---------------------------------------------------------------------------------------------
# the ensemble: K MLPs as one batched module
# ---------------------------------------------------------------------------------------------
class Ensemble(torch.nn.Module):
    """K independent MLPs d -> h -> h -> 1 (ReLU); layer weights (K, in, out), biases (K, 1, out).
    Initialised as ``nn.Linear`` is (uniform +-1/sqrt(fan_in)) from ``gen`` only."""

    def __init__(self, k: int, d: int, h: int, gen: torch.Generator):
        super().__init__()

        def init(fan_in: int, *shape: int) -> torch.nn.Parameter:
            return torch.nn.Parameter((torch.rand(*shape, generator=gen) * 2 - 1) / math.sqrt(fan_in))

        self.w1, self.b1 = init(d, k, d, h), init(d, k, 1, h)
        self.w2, self.b2 = init(h, k, h, h), init(h, k, 1, h)
        self.w3, self.b3 = init(h, k, h, 1), init(h, k, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (K, B, d) -> standardised log-deformation (K, B): member k on its own batch x[k]."""
        z = torch.relu(torch.baddbmm(self.b1, x, self.w1))
        z = torch.relu(torch.baddbmm(self.b2, z, self.w2))
        return torch.baddbmm(self.b3, z, self.w3)[..., 0]


class Responder:
    """Per-agent best response on one member (or the ensemble mean), from tables of the first layer.

    ``task[k]`` (n_tasks, h) = features @ W1 + b1 and ``slot[i][k]`` (actions of agent i, h) = pad
    coordinates @ W1 (agent i's rows): a layout's first layer is task + sum of its agents' rows.
    """

    def __init__(self, model: Ensemble, feats: torch.Tensor, pts: torch.Tensor, sets: list[np.ndarray]):
        with torch.no_grad():
            w1, f, s = model.w1.detach(), feats.shape[1], pts.shape[1]
            self.task = torch.einsum("tf,kfh->kth", feats, w1[:, :f]) + model.b1.detach()
            self.slot = [torch.einsum("as,ksh->kah", pts[torch.from_numpy(a)], w1[:, f + i * s:f + (i + 1) * s])
                         for i, a in enumerate(sets)]
            self.w2, self.b2 = model.w2.detach(), model.b2.detach()[:, 0]
            self.w3, self.b3 = model.w3.detach()[..., 0], model.b3.detach()[:, 0, 0]
        self.k, self.h = self.w2.shape[0], self.w2.shape[1]

    def scores(self, k: int, tasks: torch.Tensor, local: torch.Tensor, i: int) -> torch.Tensor:
        """Member k's prediction (Q, actions of agent i) of every action of agent i, the others fixed
        at ``local`` (Q, n_agents) positions in their sets."""
        base = self.task[k, tasks]
        for j, table in enumerate(self.slot):
            if j != i:
                base = base + table[k, local[:, j]]
        own, out = self.slot[i][k], []
        chunk = max(1, (1 << 21) // (own.shape[0] * self.h))  # ~8 MB of hidden units at a time
        for c in range(0, len(base), chunk):
            z = torch.relu(base[c:c + chunk, None, :] + own[None]).reshape(-1, self.h)
            z = torch.relu(torch.addmm(self.b2[k], z, self.w2[k]))
            out.append((z @ self.w3[k] + self.b3[k]).reshape(-1, own.shape[0]))
        return torch.cat(out) if out else base.new_empty((0, own.shape[0]))

    def respond(self, member: int | None, tasks: np.ndarray, local: np.ndarray,
                max_sweeps: int) -> tuple[np.ndarray, int]:
        """Gauss-Seidel best response of every query from ``local`` (Q, n_agents) positions, on member
        ``member`` (None: the ensemble mean). Returns (positions, sweeps summed over the queries)."""
        local = torch.from_numpy(local.copy())
        tasks_t = torch.from_numpy(np.asarray(tasks, dtype=np.int64))
        active = torch.arange(len(local))
        members = range(self.k) if member is None else [member]
        sweeps, total = 0, 0
        while len(active) and sweeps < max_sweeps:
            sweeps, total = sweeps + 1, total + len(active)
            changed = torch.zeros(len(active), dtype=torch.bool)
            for i in range(len(self.slot)):
                cur = local[active]
                s = sum(self.scores(k, tasks_t[active], cur, i) for k in members)
                best = torch.argmin(s, dim=1)
                changed |= best != cur[:, i]
                local[active, i] = best
            active = active[changed]
        return local.numpy(), total


# ---------------------------------------------------------------------------------------------
# inputs and proposals (gp-ucb uses them too)
# ---------------------------------------------------------------------------------------------
def pad_coordinates(problem: Problem) -> np.ndarray:
    """(n_options, 2 m) pad coordinates of every action, in [-1, 1] of the candidates' bounding box."""
    lo, hi = problem.candidates.min(axis=0), problem.candidates.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    n_opt = len(problem.points)
    return (2 * (problem.points.reshape(n_opt, -1, 2) - lo) / span - 1).reshape(n_opt, -1)


def set_positions(problem: Problem) -> np.ndarray:
    """Global action -> its position in its agent's set."""
    pos = np.zeros(len(problem.points), dtype=np.int64)
    for a in problem.action_sets:
        pos[a] = np.arange(len(a))
    return pos


def move_repeats(layouts: np.ndarray, done: set, batch: set, sets: list[np.ndarray], rng: np.random.Generator,
                 tries: int) -> tuple[np.ndarray, int]:
    """``layouts`` with every one already in ``done`` (evaluated on the task) or in ``batch`` (proposed in
    this batch) moved to a random neighbour (one agent's action changed at random, up to ``tries`` times,
    then the repeat is accepted); adds the results to ``batch``; returns them and how many moved."""
    out, moved = layouts.copy(), 0
    for r in range(len(out)):
        key, k = tuple(out[r].tolist()), 0
        while (key in done or key in batch) and k < tries:
            a = int(rng.integers(len(sets)))
            out[r, a] = sets[a][rng.integers(len(sets[a]))]
            key, k = tuple(out[r].tolist()), k + 1
        moved += k > 0
        batch.add(key)
    return out, moved


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
@register
class SurrogateTS(Planner):
    name = "surrogate-ts"
    family = "bandit"
    description = "Thompson sampling on a bootstrapped MLP ensemble of log-deformation shared by all tasks"
    Config = SurrogateConfig
    modes = ("per-task",)
    same_on_every_host = False

    def plan(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, mode: str):
        cfg = self.config
        require_budget(self.name, ev.remaining, len(ev.tasks), "one layout per task")
        gen = torch.Generator().manual_seed(int(rng.integers(2**31 - 1)))
        with torch_run(cfg.threads):
                return self._run(problem, ev, rng, gen)

    def _run(self, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator, gen: torch.Generator):
        cfg, n, sets = self.config, problem.n_agents, problem.action_sets
        t_start = time.perf_counter()
        t_fit = t_act = t_oracle = 0.0

        # inputs: centred scaled features; pad coordinates in [-1, 1] of the candidates' bounding box
        feats = scaled_features(problem)
        feats = torch.tensor(feats - feats.mean(axis=0), dtype=torch.float32)
        pts = torch.tensor(pad_coordinates(problem), dtype=torch.float32)
        pos = set_positions(problem)

        # the data: every evaluated (task, layout) and its log max deformation, bootstrap weights per member
        ids = ev.tasks
        shares = np.array(split_budget(ev.budget, len(ids), cfg.samples_per_task))
        cap = int(shares.sum())
        X = torch.zeros(cap, feats.shape[1] + n * pts.shape[1])
        Y = torch.zeros(cap)
        W = torch.zeros(cfg.ensemble, cap)
        size = 0
        seen = {int(t): set() for t in ids}

        model = Ensemble(cfg.ensemble, X.shape[1], cfg.hidden, gen)
        opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        steps = 0
        losses = []

        def evaluate(task: int, layouts: np.ndarray) -> None:
            nonlocal size, t_oracle
            t0 = time.perf_counter()
            u = ev.evaluate(task, layouts).max_u
            t_oracle += time.perf_counter() - t0
            m = len(layouts)
            X[size:size + m, :feats.shape[1]] = feats[task]
            X[size:size + m, feats.shape[1]:] = pts[torch.from_numpy(layouts)].reshape(m, -1)
            Y[size:size + m] = torch.from_numpy(np.log(np.maximum(u, 1e-30)))
            W[:, size:size + m] = torch.from_numpy(rng.poisson(1.0, (cfg.ensemble, m)).astype(np.float32))
            size += m
            seen[task].update(map(tuple, layouts.tolist()))

        def fit() -> Responder:
            """A few AdamW steps of every member on its bootstrap of all data; the new best-response tables."""
            nonlocal steps, t_fit
            t0 = time.perf_counter()
            y = Y[:size]
            mu, sd = y.mean(), y.std().clamp_min(1e-6) if size > 1 else torch.tensor(1.0)
            for _ in range(cfg.train_steps if size else 0):
                idx = torch.randint(0, size, (cfg.ensemble, cfg.minibatch), generator=gen)
                w = W.gather(1, idx)
                err = (model(X[idx]) - (Y[idx] - mu) / sd) ** 2
                loss = ((err * w).sum(dim=1) / w.sum(dim=1).clamp_min(1.0)).sum()
                opt.zero_grad()
                loss.backward()
                opt.step()
                steps += 1
            if size and cfg.train_steps:
                losses.append(float(loss.detach()) / cfg.ensemble)
            responder = Responder(model, feats, pts, sets)
            t_fit += time.perf_counter() - t0
            return responder

        # round 0: uniform random layouts seed the model
        left = shares.copy()
        moved = 0
        for t, s in zip(ids, shares):
            m = min(cfg.initial_random, int(s))
            if m:
                layouts, k = move_repeats(random_layouts(problem, rng, m), seen[int(t)], set(), sets, rng, cfg.tries)
                moved += k
                evaluate(int(t), layouts)
        left -= np.minimum(cfg.initial_random, shares)

        # rounds: retrain, then every training task gets a batch of Thompson samples
        batch = max(cfg.batch, math.ceil(int(left.max(initial=0)) / max(cfg.max_rounds, 1)))
        rounds, sweeps_sum, queries = 0, 0, 0
        while left.any():
            responder = fit()
            t0 = time.perf_counter()
            rounds += 1
            q_task, q_start = [], []
            counts = np.minimum(left, batch)
            for t, c in zip(ids, counts):
                if not c:
                    continue
                t = int(t)
                starts = [ev.best_layout[t][None]] if np.isfinite(ev.best[t]) else []
                starts.append(warm_layouts(problem, ev.best, ev.best_layout, t, cfg.transfer))
                starts.append(random_layouts(problem, rng, 1))
                starts = np.vstack(starts)
                _, first = np.unique(starts, axis=0, return_index=True)
                starts = starts[np.sort(first)]
                q_task += [t] * int(c)
                q_start.append(starts[np.arange(int(c)) % len(starts)])
            q_task = np.array(q_task, dtype=np.int64)
            q_local = pos[np.vstack(q_start)]
            member = rng.integers(cfg.ensemble, size=len(q_task))  # Thompson sampling: one member a sample
            for k in range(cfg.ensemble):
                rows = np.flatnonzero(member == k)
                if len(rows):
                    q_local[rows], sw = responder.respond(k, q_task[rows], q_local[rows], cfg.max_sweeps)
                    sweeps_sum += sw
            queries += len(q_task)
            proposals = np.column_stack([sets[i][q_local[:, i]] for i in range(n)])
            t_act += time.perf_counter() - t0
            for t in ids[counts > 0]:
                t0 = time.perf_counter()
                layouts, k = move_repeats(proposals[q_task == t], seen[int(t)], set(), sets, rng, cfg.tries)
                moved += k
                t_act += time.perf_counter() - t0
                evaluate(int(t), layouts)
            left -= counts

        # layouts: the best evaluated on each training task; the ensemble mean's best response elsewhere
        layouts = ev.best_layout.copy()
        held = np.setdiff1d(np.arange(problem.n_tasks), ids)
        held_sweeps = 0
        if len(held):
            responder = fit()
            t0 = time.perf_counter()
            f = scaled_features(problem)
            src = np.array([nearest_tasks(problem, ids, int(t), 1, f)[0] for t in held])
            local, held_sweeps = responder.respond(None, held, pos[ev.best_layout[src]], cfg.max_sweeps)
            layouts[held] = np.column_stack([sets[i][local[:, i]] for i in range(n)])
            t_act += time.perf_counter() - t0
        per_task = ev.task_samples[ids]
        info = {
            "samples_per_task": int(per_task.min()) if per_task.min() == per_task.max() else per_task.tolist(),
            "rounds": rounds,
            "batch": int(batch),
            "train_steps": steps,
            "final_loss": losses[-1] if losses else None,
            "br_sweeps_mean": sweeps_sum / queries if queries else 0.0,
            "held_out_sweeps": held_sweeps,
            "repeats_moved": int(moved),
            "time_fit_s": t_fit,
            "time_act_s": t_act,
            "time_oracle_s": t_oracle,
            "time_total_s": time.perf_counter() - t_start,
            "torch_threads": torch.get_num_threads(),
        }
        return layouts, info
