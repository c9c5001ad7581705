"""nashq / iql planners: valid layouts within budget, determinism, held-out tasks, weights."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from fixbench.cases.problem import Problem, load_problem
from fixbench.cases.spec import Effector
from fixbench.solvers.base import PlannerError
from fixbench.solvers.learners.marl_engine import Learner as _Learner
from fixbench.solvers.learners.marl_engine import StackedQ, Update, _q_row, load_weights
from fixbench.solvers.registry import get

SMALL = dict(episodes=3, hidden=32)


@pytest.fixture(scope="module")
def problem():
    p = load_problem("wing_panel_small")
    return Problem(p.spec.with_tasks([0, 1, 3]))


def test_hand_backprop_and_update_equal_autograd_and_adamw():
    """StackedQ.backward gives autograd's gradient of the summed per-agent mean Huber loss (repeated
    actions included), and Update equals torch's clip_grad_value_ + AdamW(amsgrad) + soft update."""
    g = torch.Generator().manual_seed(0)
    n, n_in, hidden, n_out, batch = 3, 6, 16, 9, 12
    net = StackedQ(n, n_in, hidden, n_out, g)
    x = torch.rand(n, batch, n_in, generator=g)
    a = torch.randint(0, n_out, (n, batch), generator=g)
    a[:, 1] = a[:, 0]  # the same action twice in a batch: column gradients must add up
    y = torch.randn(n, batch, generator=g) * 2  # large enough that some errors exceed the Huber delta
    q, saved = net.chosen(x, a)
    assert torch.allclose(q, net(x).gather(2, a[..., None])[..., 0], atol=1e-6)
    net.backward((q - y).clamp(-1, 1) / batch, saved)

    w, b = [], []
    for k, v in enumerate(net._views(net.flat.detach())):
        (w if k % 2 == 0 else b).append(v.clone().requires_grad_(True))
    h = x
    for k in range(3):
        h = torch.relu(torch.baddbmm(b[k], h, w[k]))
    q_ref = torch.baddbmm(b[3], h, w[3]).gather(2, a[..., None])[..., 0]
    torch.nn.functional.smooth_l1_loss(q_ref, y, reduction="none").mean(dim=1).sum().backward()
    ref = torch.cat([t.grad.reshape(-1) for pair in zip(w, b) for t in pair])
    assert (ref != 0).sum() > 0.3 * ref.numel()
    assert torch.allclose(net.flat.grad, ref, rtol=1e-5, atol=1e-7)

    # the update: clip at 1e-3 so that clipping bites, three steps
    target = StackedQ(n, n_in, hidden, n_out)
    target.load_state_dict(net.state_dict())
    p_ref, t_ref = net.flat.detach().clone().requires_grad_(True), target.flat.detach().clone()
    opt_ref = torch.optim.AdamW([p_ref], lr=1e-2, amsgrad=True)
    upd = Update(net, target, lr=1e-2, clip=1e-3, tau=0.1, device=torch.device("cpu"))
    p0 = net.flat.detach().clone()
    for step in range(3):
        grad = torch.randn(p_ref.shape, generator=g) * 1e-3 * (step + 1)
        net.flat.grad.copy_(grad)
        p_ref.grad = grad.clone()
        torch.nn.utils.clip_grad_value_([p_ref], 1e-3)
        opt_ref.step()
        with torch.no_grad():
            t_ref.lerp_(p_ref, 0.1)
        upd.step()
    assert torch.allclose(net.flat, p_ref, rtol=1e-6, atol=1e-8)
    assert torch.allclose(target.flat, t_ref, rtol=1e-6, atol=1e-8)
    assert not torch.allclose(target.flat, net.flat) and (net.flat - p0).abs().max() > 1e-3
    # moments that decay below the smallest normal float become zero (flush-to-zero), others just decay
    m = upd.state[0]
    m[:4], m[4] = 1e-38, 1e-3
    net.flat.grad.zero_()
    upd.step()
    assert (m[:4] == 0).all() and torch.isclose(m[4], torch.tensor(0.9e-3))


@pytest.mark.parametrize("name", ["nashq", "iql"])
def test_valid_layouts_within_budget(problem, name):
    r = get(name)(**SMALL).solve(problem, budget=10, seed=0)  # 3 full episodes of 3 tasks fit
    assert r.samples == 9 and r.info["episodes_run"] == 3 and r.layouts.shape == (3, problem.n_agents)
    problem.check_layouts(r.layouts)
    json.dumps(r.info)
    c = r.training.curves
    assert len(c["step_reward"].values) == 9 and len(c["episode_return"].values) == 3
    assert {k for k in c if k.startswith("td_loss/")} == {f"td_loss/agent{i}" for i in range(problem.n_agents)}
    assert all(len(c[f"td_loss/agent{i}"].values) == 3 for i in range(problem.n_agents))
    assert (c["episode_regret_true"].values >= -1e-15).all()
    r = get(name)(episodes=100, hidden=32).solve(problem, budget=7, seed=0)  # best effort: 2 episodes
    assert r.samples == 6 and r.info["budget_limited"]
    with pytest.raises(PlannerError):
        get(name)(**SMALL).solve(problem, budget=2, seed=0)
    with pytest.raises(PlannerError):
        get(name)(**SMALL).solve(problem, budget=20, seed=0, mode="shared")


@pytest.mark.parametrize("name", ["nashq", "iql"])
def test_same_seed_same_curves(problem, name):
    a, b, c = (get(name)(**SMALL).solve(problem, None, seed=s) for s in (3, 3, 4))
    for key in ("step_reward", "td_loss/agent0", "episode_regret_ref"):
        assert a.training.values(key).tobytes() == b.training.values(key).tobytes()
    assert (a.layouts == b.layouts).all()
    assert a.training.values("step_reward").tobytes() != c.training.values("step_reward").tobytes()


def test_held_out_tasks_cost_nothing(problem):
    r = get("nashq")(train_tasks=(0, 2), **SMALL).solve(problem, None, seed=0)
    assert r.samples == 3 * 2 and r.info["held_out_tasks"] == [1]
    assert set(r.training.values("step_task")) == {0, 2}
    problem.check_layouts(r.layouts)


def test_agent_counts():
    p = load_problem("wing_panel_small", agents=3)
    p = Problem(p.spec.with_tasks([0]))
    for name in ("nashq", "iql"):
        r = get(name)(episodes=2, hidden=16).solve(p, None, seed=0)
        assert r.layouts.shape == (1, 3) and r.info["greedy_converged"] in (True, False)
    p1 = Problem(load_problem("wing_panel_small", agents=1).spec.with_tasks([0]))
    r = get("nashq")(episodes=2, hidden=16).solve(p1, None, seed=0)
    assert r.layouts.shape == (1, 1)


def test_weights_round_trip(problem, tmp_path):
    path = tmp_path / "q.pt"
    get("nashq")(save_path=str(path), **SMALL).solve(problem, None, seed=0)
    net = load_weights(str(path))
    state = torch.load(path, weights_only=True)
    assert all(torch.equal(net.state_dict()[k], v) for k, v in state.items())
    x = torch.rand(problem.n_agents, 4, int(net.dims[1]))
    assert net(x).shape == (problem.n_agents, 4, max(len(s) for s in problem.action_sets))


def test_bad_device(problem):
    if torch.cuda.is_available():
        pytest.skip("CUDA present")
    with pytest.raises(PlannerError, match="CUDA"):
        get("nashq")(device="cuda", **SMALL).solve(problem, None, seed=0)



def test_figure4_panels(problem, tmp_path):
    from studies.marl import figure4

    r = get("iql")(**SMALL).solve(problem, None, seed=0)
    paths = figure4({"iql": r, "iql training": r.training}, tmp_path)
    assert len(paths) == 4 and all(p.stat().st_size > 0 for p in paths)


def _q(L, i, x):
    """Agent i's Q for each row of x, by the planner's own compiled forward pass."""
    w, b = L._host_weights()
    q = np.stack([_q_row(tuple(w + b), i, np.ascontiguousarray(row, dtype=np.float32)) for row in x])
    q[:, L.n_opts[i]:] = -np.inf  # outputs past the agent's own set are never chosen
    return q


def _plain_gauss_seidel(L, tasks, fixed, fixed_actions):
    """Best response swept until nothing changes or max_sweeps: the definition, without the cycle short-cut."""
    s, nb, n = L.feats_np[tasks], len(tasks), L.n
    a = fixed_actions.copy()
    jp = np.broadcast_to(L.centre_np, (nb, n, 2)).copy()
    jp[fixed] = L.pos_np[np.nonzero(fixed)[1], fixed_actions[fixed]]
    for i in range(n):
        x = np.concatenate([s, jp[:, L.others_np[i]].reshape(nb, -1)], axis=1)
        a[:, i] = np.where(fixed[:, i], a[:, i], _q(L, i, x).argmax(axis=1))
    free = ~fixed.all(axis=0)
    dirty = free.copy()
    for _ in range(L.max_sweeps):
        for i in range(n):
            if dirty[i]:
                dirty[i] = False
                oth = L.pos_np[L.others_np[i], a[:, L.others_np[i]]].reshape(nb, -1)
                new = np.where(fixed[:, i], a[:, i], _q(L, i, np.concatenate([s, oth], axis=1)).argmax(axis=1))
                if (new != a[:, i]).any():
                    a[:, i] = new
                    dirty |= free
                    dirty[i] = False
        if not dirty.any():
            break
    return a


def test_best_response_cycle_shortcut_gives_the_same_actions():
    """Cycling best response is cut short once a sweep's end state repeats; the actions must equal
    those after max_sweeps sweeps of the plain iteration (and the short-cut must actually happen)."""
    rng = np.random.default_rng(0)
    n, t = 5, 50
    sets = np.array_split(np.arange(2000), n)
    xy = rng.random((2000, 2))
    prob = SimpleNamespace(n_agents=n, action_sets=sets, candidate_sets=sets, features=rng.random((t, 2)),
                           candidates=xy, points=xy, n_tasks=t, spec=SimpleNamespace(effector=Effector()))
    cut = 0
    for max_sweeps in (3, 10):
        L = _Learner(prob, 256, max_sweeps, True, torch.device("cpu"), torch.Generator().manual_seed(1))
        for k in range(t):
            fixed = rng.random((1, n)) < 0.2
            fixed_actions = (rng.random((1, n)) * 400).astype(np.int64)
            a, sweeps, converged = L.greedy(np.array([k]), fixed, fixed_actions)
            assert np.array_equal(a, _plain_gauss_seidel(L, np.array([k]), fixed, fixed_actions))
            cut += not converged and sweeps < max_sweeps
        a, _, _ = L.greedy(np.arange(t))
        none = np.zeros((t, n), dtype=bool)
        assert np.array_equal(a, _plain_gauss_seidel(L, np.arange(t), none, np.zeros((t, n), dtype=np.int64)))
    assert cut > 0


def test_heldout_benchmark_rows():
    """studies.marl.heldout: the held-out track's split (train on tasks 0, k, 2k, ...), the learner's
    held-out layouts cost nothing; baselines pay per task; gaps >= 0."""
    from studies.marl import heldout

    rows = heldout("wing_spar_small", "nashq", every=2, episodes=2, per_task=(1, 3), baselines=("random",),
                   hidden=16)
    learner, *base = rows
    assert (learner["train_tasks"], learner["held_out_tasks"]) == (2, 1)  # tasks 0 and 2 of 3; task 1 held out
    assert learner["samples_per_held_out_task"] == 0 and learner["samples"] == 2 * learner["train_tasks"]
    assert [r["samples"] for r in base] == [learner["held_out_tasks"] * b for b in (1, 3)]
    assert all(r["gap_to_best_found_pct"] >= 0 for r in rows)


def test_batching_study_scores_each_run_against_the_proven_optimum():
    """studies.marl batching: every run spends its episodes on every position, its regret is its mean
    gap to the exact planner's optimum (>= 0) and equals a direct run's of the same seed; the base setting
    is level with itself (P = 1/2) and the intervals hold their point estimates."""
    from studies.marl import batching

    rows = batching("fan_small", ("iql",), (1, 2), seeds=2, episodes=2)
    problem = load_problem("fan_small")
    assert [r["positions_per_step"] for r in rows] == [1, 2]
    assert all(r["samples"] == 2 * problem.n_tasks and min(r["regret_pct"]) >= 0 for r in rows)
    opt = get("exact")().solve(problem, None).max_deformation
    again = get("iql")(episodes=2, threads=1).solve(problem, None, seed=1).max_deformation
    assert rows[0]["regret_pct"][1] == 100 * float(np.mean(again / opt - 1))
    assert rows[0]["p_below_base"][0] == 0.5
    for r in rows:
        assert r["regret_mean_ci"][0] <= r["regret_mean_pct"] <= r["regret_mean_ci"][1]
        assert r["regret_iqm_ci"][0] <= r["regret_iqm_pct"] <= r["regret_iqm_ci"][1]


def test_update_floor_times_the_updates_own_products():
    """studies.marl floor: the products it times do the floating-point work torch counts in a real update,
    the lower bound it derives lies below what the update costs on the same machine, and the thread
    counts it sets are the caller's again afterwards."""
    import numba

    from studies.marl import update_floor

    before = torch.get_num_threads(), numba.get_num_threads()
    r = update_floor("wing_panel_small", threads=2 if before[0] == 1 else 1, repeat=5)
    assert (torch.get_num_threads(), numba.get_num_threads()) == before
    assert r["threads"] != before[0]
    assert r["bmm_gflop"] == r["products_gflop"] > 0
    assert r["protocol_updates"] == 4 * 100
    assert 0 < r["floor_updates_s"] <= r["updates_s_at_this_rate"]
    assert r["adamw_mb"] == 11 * 4 * r["params"] / 1e6


def test_studies_take_only_the_learners_with_the_seed_reward(capsys):
    """studies.marl runs the seed's protocol (Gaussian reward, a device): a learner without them is a
    usage error (one line, exit code 2), not a traceback after the oracle's set-up."""
    from studies.marl import main

    assert main(["speed", "--planner", "vdn"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "'vdn' is not one of 'nashq', 'iql'" in err


@pytest.mark.parametrize("args, says", [(["--per-step", "1,x"], "'--per-step': '1,x' is not a comma-separated list"),
                                        (["--per-step", "0"], "positions_per_step must be at least 1"),
                                        (["--planners", "random"], "unexpected keyword argument 'episodes'")])
def test_batching_study_checks_its_settings_before_any_work(capsys, monkeypatch, args, says):
    """studies.marl batching: a bad setting is one line and exit code 2, before the problem is loaded."""
    import studies.marl

    def no_problem(*a, **k):
        raise AssertionError("the problem was loaded before the settings were checked")

    monkeypatch.setattr(studies.marl, "load_problem", no_problem)
    assert studies.marl.main(["batching", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and says in err

def test_gpu_paths_on_the_cpu_agree_with_the_fused_ones(problem, monkeypatch):
    """What runs on a GPU (torch's AdamW + lerp; weights copied to the host for best response), run here
    on the CPU: the same update as the fused pass to float32 round-off, and a whole short training
    through it gives valid layouts with every best response still computed."""
    from fixbench.solvers.learners import marl_engine

    g = torch.Generator().manual_seed(1)
    nets = [StackedQ(3, 6, 16, 9, torch.Generator().manual_seed(2)) for _ in range(2)]
    targets = [StackedQ(3, 6, 16, 9) for _ in range(2)]
    for net, tgt in zip(nets, targets):
        tgt.load_state_dict(net.state_dict())
    ups = [Update(nets[0], targets[0], 1e-2, 1e-3, 0.1, torch.device("cpu")),
           Update(nets[1], targets[1], 1e-2, 1e-3, 0.1, torch.device("cpu"), fused=False)]
    assert ups[0].cpu and not ups[1].cpu
    for step in range(3):
        grad = torch.randn(nets[0].flat.shape, generator=g) * 1e-3 * (step + 1)
        for net, up in zip(nets, ups):
            net.flat.grad = grad.clone()
            up.step()
    torch.testing.assert_close(nets[1].flat, nets[0].flat, rtol=1e-6, atol=1e-8)
    torch.testing.assert_close(targets[1].flat, targets[0].flat, rtol=1e-6, atol=1e-8)
    assert not torch.equal(nets[0].flat, StackedQ(3, 6, 16, 9, torch.Generator().manual_seed(2)).flat)

    class GpuLikeUpdate(Update):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs, fused=False)

    copies = []
    host = marl_engine.Learner._host_weights

    def copied(self):  # as from a GPU: a fresh host copy of the weights for every action choice
        w, b = host(self)
        copies.append(1)
        return [a.copy() for a in w], [a.copy() for a in b]

    monkeypatch.setattr("fixbench.solvers.learners.nashq.Update", GpuLikeUpdate)
    monkeypatch.setattr(marl_engine.Learner, "_host_weights", copied)
    r = get("nashq")(**SMALL).solve(problem, None, seed=0)
    problem.check_layouts(r.layouts)
    assert r.samples == 9 and len(copies) > 1  # training steps' best responses and the greedy policy
    assert all(np.isfinite(r.training.values(f"td_loss/agent{i}")).all() for i in range(problem.n_agents))


@pytest.mark.parametrize("name", ["nashq", "iql"])
def test_a_learner_is_scored_by_its_incumbent_and_its_policy_beside_it(problem, name):
    """The scoring rule: a learner whose policy layout is worse than one it evaluated on a task is
    scored there by the latter; the policy is kept as the second figure, never in the objective."""
    res = get(name)(**SMALL).solve(problem, None, seed=4)
    trace = np.asarray(res.trace)
    best_seen = np.array([trace[trace[:, 0] == t, 3].min() for t in range(problem.n_tasks)])
    np.testing.assert_array_equal(res.max_deformation, best_seen)
    assert res.policy_layouts is not None and res.policy_max_deformation is not None
    worse = res.policy_max_deformation > res.max_deformation
    assert worse.any()  # 3 episodes: on some task the policy has not found the best layout it evaluated
    assert (res.layouts[worse] != res.policy_layouts[worse]).any(axis=1).all()
    assert res.objective == res.max_deformation.mean()
    assert res.policy_objective == res.policy_max_deformation.mean()
