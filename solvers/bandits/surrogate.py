"""Thompson sampling on a learned surrogate shared across drilling positions (``surrogate-ts``).

Read top to bottom (cleanrl style): hyper-parameters, the ensemble, its best response, the run (fit,
propose, act on held-out tasks). The rounds loop itself (data, round 0, batch size, warm starts,
repeats, budget, held-out tasks) is :mod:`fixbench.solvers.bandits.bandit`'s, shared with ``gp-ucb``.

The model. One regression, shared by every task, of y = log(max |u|) on x = [the task's features
(:func:`fixbench.solvers.encoding.task_features`, scaled by their spread, centred), the layout's pad coordinates
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
neighbour (:func:`fixbench.solvers.bandits.bandit.move_repeats`).

Rounds, not task by task: every round gives every training task a batch of ``batch`` samples
(larger when the budget is large, so that there are at most ``max_rounds`` retrainings), then the
ensemble is retrained on everything. Visiting the tasks task by task would fit the model to the
first tasks alone and give them none of what is learned on the later ones; in rounds, every position
gains from every other from the first batch on, the model sees all positions at every retraining
(no drift towards the latest task), and one round's best responses for all tasks are one batched
computation. The first ``initial_random`` samples of each task (round 0) are uniform random layouts
that seed the model.

On a task outside the evaluator's tasks (held-out track, zero samples) the layout is the best
response of the ENSEMBLE MEAN (retrained once more on everything), started from the nearest training
task's best layout.

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
from collections.abc import Iterator
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from fixbench.cases.problem import Problem
from fixbench.solvers.bandits.bandit import BanditConfig, BanditRun, RoundsBandit
from fixbench.solvers.base import TracedEvaluator, Training, at_least, require
from fixbench.solvers.descent import descend
from fixbench.solvers.encoding import pad_coordinates


# ---------------------------------------------------------------------------------------------
# hyper-parameters (and the loop's: initial_random, tries, samples_per_task, threads in BanditConfig)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SurrogateConfig(BanditConfig):
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

    def __post_init__(self) -> None:
        super().__post_init__()
        at_least(self, 1, "ensemble", "hidden", "minibatch")
        at_least(self, 0, "train_steps", "weight_decay")
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
        """Best response of every query from ``local`` (Q, n_agents) positions, on member ``member`` (None:
        the ensemble mean): :func:`~fixbench.solvers.descent.descend`, agents in order, each to its lowest
        prediction (the first of equal ones), a query stopping after a sweep that moved none. Returns
        (positions, sweeps summed over the queries)."""
        tasks_t = torch.from_numpy(np.asarray(tasks, dtype=np.int64))
        members = range(self.k) if member is None else [member]

        def score(i: int, rows: np.ndarray, cur: np.ndarray) -> torch.Tensor:
            return sum(self.scores(k, tasks_t[torch.from_numpy(rows)], torch.from_numpy(cur), i) for k in members)

        out = descend(score, local, range(len(self.slot)), max_sweeps=max_sweeps, ties="first", stop="sweep")
        return out.layout, int(out.sweeps.sum())


# ---------------------------------------------------------------------------------------------
# the run: bootstrap weights, retraining, Thompson samples, the ensemble mean on held-out tasks
# ---------------------------------------------------------------------------------------------
class ThompsonRun(BanditRun):
    """One run of ``surrogate-ts`` on the rounds loop (:class:`fixbench.solvers.bandits.bandit.BanditRun`)."""

    def __init__(self, cfg: SurrogateConfig, problem: Problem, ev: TracedEvaluator, rng: np.random.Generator):
        super().__init__(cfg, problem, ev, rng)
        self.gen = torch.Generator().manual_seed(int(rng.integers(2**31 - 1)))
        # inputs: centred scaled features; pad coordinates in [-1, 1] of the candidates' bounding box
        self.feats = torch.tensor(self.features - self.features.mean(axis=0), dtype=torch.float32)
        self.pts = torch.tensor(pad_coordinates(problem, interval=(-1.0, 1.0)), dtype=torch.float32)
        self.W = torch.zeros(cfg.ensemble, len(self.y))  # Poisson(1) bootstrap weight of every sample per member
        self.model = Ensemble(cfg.ensemble, self.feats.shape[1] + self.n * self.pts.shape[1], cfg.hidden, self.gen)
        self.opt = torch.optim.AdamW(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.responder: Responder | None = None
        self.steps, self.losses, self.sweeps, self.queries = 0, [], 0, 0

    def evaluate(self, task: int, layouts: np.ndarray) -> None:
        """Evaluate and store, then draw each member's bootstrap weight of the new samples (once, as they arrive)."""
        super().evaluate(task, layouts)
        m = len(layouts)
        self.W[:, self.size - m:self.size] = torch.from_numpy(
            self.rng.poisson(1.0, (self.cfg.ensemble, m)).astype(np.float32))

    def fit(self, rnd: int) -> None:
        """A few AdamW steps of every member on its bootstrap of all data; the new best-response tables."""
        cfg, size, gen = self.cfg, self.size, self.gen
        with self.timed("fit"):
            X = self.inputs(np.arange(size), self.feats, self.pts)
            Y = torch.from_numpy(self.y[:size]).float()
            mu, sd = Y.mean(), Y.std().clamp_min(1e-6) if size > 1 else torch.tensor(1.0)
            for _ in range(cfg.train_steps if size else 0):
                idx = torch.randint(0, size, (cfg.ensemble, cfg.minibatch), generator=gen)
                w = self.W.gather(1, idx)
                err = (self.model(X[idx]) - (Y[idx] - mu) / sd) ** 2
                loss = ((err * w).sum(dim=1) / w.sum(dim=1).clamp_min(1.0)).sum()
                self.opt.zero_grad()
                loss.backward()
                self.opt.step()
                self.steps += 1
            if size and cfg.train_steps:
                self.losses.append(float(loss.detach()) / cfg.ensemble)
            self.responder = Responder(self.model, self.feats, self.pts, self.sets)

    def propose(self, tasks: np.ndarray, counts: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        """Thompson sampling: every sample of the round draws one member and takes its best response, all
        tasks' at once; then, task by task, repeats moved to random neighbours."""
        cfg = self.cfg
        with self.timed("act"):
            q_start = []
            for t, c in zip(tasks.tolist(), counts.tolist()):
                starts = self.starts(t)
                q_start.append(starts[np.arange(c) % len(starts)])
            q_task = np.repeat(tasks, counts)
            q_local = self.pos[np.vstack(q_start)]
            member = self.rng.integers(cfg.ensemble, size=len(q_task))  # Thompson sampling: one member a sample
            for k in range(cfg.ensemble):
                rows = np.flatnonzero(member == k)
                if len(rows):
                    q_local[rows], sweeps = self.responder.respond(k, q_task[rows], q_local[rows], cfg.max_sweeps)
                    self.sweeps += sweeps
            self.queries += len(q_task)
            proposals = self.layouts_of(q_local)
        for t in tasks.tolist():
            with self.timed("act"):
                layouts = self.unrepeated(t, proposals[q_task == t])
            yield t, layouts

    def act_held_out(self, held: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, int]:
        """The ensemble mean's best response, retrained on everything first."""
        self.fit(self.rounds)
        with self.timed("act"):
            local, sweeps = self.responder.respond(None, held, self.pos[starts], self.cfg.max_sweeps)
            return self.layouts_of(local), sweeps

    def model_info(self) -> dict:
        return {"train_steps": self.steps, "final_loss": self.losses[-1] if self.losses else None,
                "br_sweeps_mean": self.sweeps / self.queries if self.queries else 0.0}

    def model_curves(self, training: Training) -> Training:
        return training.add("fit", fit_loss=self.losses)  # a member's loss at the last step of each fit


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
class SurrogateTS(RoundsBandit):
    name = "surrogate-ts"
    family = "bandit"
    description = "Thompson sampling on a bootstrapped MLP ensemble of log-deformation shared by all tasks"
    Config = SurrogateConfig
    modes = ("per-task",)
    Run = ThompsonRun
