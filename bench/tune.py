"""Tuning parity: the same declared budget of trials for every planner, spent on problems that are
never reported.

``fixbench tune PLANNER --trials N`` runs Optuna's TPE sampler (seeded) over the Config fields the
planner marks tunable (``Config.tunable``: field -> ``("int", lo, hi)``, ``("float", lo, hi)``,
``("log", lo, hi)`` or ``("choice", [values])``), each trial scoring the planner on the tuning
problems: the ``*_small`` catalog cases (their optima proven by ``exact``), per-task mode, at the
paper's 100 samples a position, scored like every run (incumbents, ``fixbench.solvers.base``). The
objective is the mean over cases and seeds of log(1 + relative regret): a case whose regret is in
the thousands of per cent does not drown the others. The planner's defaults are the first trial, so
the tuned configuration is never worse than the defaults on the tuning problems. Only ``*_small``
cases are accepted: the paper's parts (and anything a matrix reports) are never tuned on.

Each track is tuned for itself (``track``): ``per-task`` as above; ``held-out`` on the held-out split of
the same cases (:func:`fixbench.bench.records.keys.split`, every ``heldout_every``-th position: the
planner pays ``samples_per_task`` on each training position and acts on the others with no sample), the
objective its regret on the held-out positions alone. What wins searching each position rarely carries
to positions never sampled, so a configuration tuned on one track is not the other's.

The result is a matrix fragment (``--out FILE.toml``): one ``[[planners]]`` entry labelled
"PLANNER (tuned)" (per-task) or "PLANNER (tuned held-out)", restricted to its track (``mode``), with the
fields that differ from the defaults (``config``) and, as data, a ``tuning`` table: the track, trials,
cases, seeds and samples a position spent and the objective of the defaults and of the tuned
configuration (:func:`figures`). ``tuning`` is provenance: the matrix loader checks its shape and no cell
depends on it; ``fixbench tune-table`` reads it (:func:`read_entry`). The norm this follows: the same
tuning budget for every method, on tasks that are not reported (Papoudakis et al. NeurIPS 2021
Datasets and Benchmarks; Gorsane et al. NeurIPS 2022).
"""

from __future__ import annotations

import functools
import json
import math
import numbers
from dataclasses import fields
from pathlib import Path

import numpy as np

from fixbench.bench.records.keys import split
from fixbench.bench.running.matrix import FIGURES, TRACKS, read_figures
from fixbench.cases.errors import CaseError

#: the tuning problems: the small variants of the catalog's parts (never a reported problem)
TUNING_CASES = ("wing_panel_small", "wing_spar_small", "bus_panel_small", "fan_small")
KINDS = ("int", "float", "log", "choice")


def space(cls) -> dict[str, tuple]:
    """The planner's declared search space, checked: every key a Config field, every spec well formed."""
    spec = dict(getattr(cls.Config, "tunable", {}) or {})
    names = {f.name for f in fields(cls.Config)}
    for key, s in spec.items():
        if key not in names:
            raise CaseError(cls.__module__, f"{cls.Config.__name__}.tunable", f"'{key}' is not a config field")
        if not (isinstance(s, tuple) and s and s[0] in KINDS and (len(s) == 3 or (s[0] == "choice" and len(s) == 2))):
            raise CaseError(cls.__module__, f"{cls.Config.__name__}.tunable.{key}",
                            f"must be (kind, lo, hi) or ('choice', [values]) with kind one of {', '.join(KINDS)}")
    return spec


def _suggest(trial, key: str, s: tuple):
    kind = s[0]
    if kind == "int":
        return trial.suggest_int(key, s[1], s[2])
    if kind == "float":
        return trial.suggest_float(key, s[1], s[2])
    if kind == "log":
        return trial.suggest_float(key, s[1], s[2], log=True)
    return trial.suggest_categorical(key, list(s[1]))


@functools.cache
def _tuning_problem(case: str) -> tuple:
    """A tuning case's problem and its proven optimum of each position (``exact``: minutes of CPU, so
    computed once a process)."""
    from fixbench.bench.references.prove import compute_reference
    from fixbench.cases.problem import problem_for

    ref = compute_reference(case, None, None, None, ("per-task",))
    if ref["error"] or ref["per_task"] is None:
        raise CaseError(case, "", f"has no regret reference to tune against: {ref['error']}")
    return problem_for(case, None, None, None), np.asarray(ref["per_task"], dtype=float)


def tune(planner: str, trials: int, cases=TUNING_CASES, seeds=(0,), samples_per_task: int = 100,
         echo=print, track: str = "per-task", heldout_every: int = 2) -> dict:
    """Tune ``planner`` with ``trials`` trials for ``track``; returns {"config": tuned overrides, "default":
    objective of the defaults, "tuned": objective of the tuned config, "trials": [...]}."""
    import optuna

    from fixbench.solvers.base import PlannerError
    from fixbench.solvers.registry import get

    cls = get(planner)
    spec = space(cls)
    if trials < 1:
        raise CaseError("--trials", "", f"must be at least 1, got {trials}")
    if track not in TRACKS:
        raise CaseError("--track", "", f"must be one of {', '.join(TRACKS)}, got '{track}'")
    if heldout_every < 2:
        raise CaseError("--heldout-every", "", f"must be 2 or more, got {heldout_every}")
    for case in cases:
        if not str(case).endswith("_small"):
            raise CaseError("--cases", "", f"'{case}' is not a *_small tuning case: tuning on a problem that is "
                            "reported is not allowed")
    problems = []
    for case in cases:
        p, optima = _tuning_problem(case)
        train, held = split(p.n_tasks, heldout_every) if track == "held-out" else (None, range(p.n_tasks))
        if not held:
            raise CaseError(case, "", f"has {p.n_tasks} positions: none is held out at --heldout-every {heldout_every}")
        problems.append((case, p, train, float(np.mean(optima[list(held)]))))

    def score(config: dict, first: bool) -> float:
        """The objective of ``config``; infinite where it cannot run at this budget (a trial TPE learns
        to avoid), an error naming the case where the defaults cannot (nothing to compare with)."""
        vals = []
        for case, p, train, ref in problems:
            for seed in seeds:
                try:
                    res = cls(**config).solve(p, samples_per_task * (p.n_tasks if train is None else len(train)),
                                              seed=seed, train_tasks=train)
                except PlannerError as exc:
                    if first:
                        raise CaseError(case, "", f"{planner}'s defaults cannot run on this tuning case at "
                                        f"{samples_per_task} samples a position, so there is nothing to tune "
                                        f"against: {exc}") from None
                    echo(f"{planner}: {json.dumps(config)} cannot run on {case}: {exc}")
                    return math.inf
                vals.append(math.log1p(max(res.objective / ref - 1, 0.0)))
        return float(np.mean(vals))

    sampler = optuna.samplers.TPESampler(seed=0)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="minimize", sampler=sampler)
    defaults = {f.name: getattr(cls.Config(), f.name) for f in fields(cls.Config) if f.name in spec}
    if spec:
        study.enqueue_trial(defaults)
    records = []
    for i in range(trials if spec else 1):
        trial = study.ask()
        config = {k: _suggest(trial, k, s) for k, s in spec.items()}
        value = score(config, first=i == 0)
        study.tell(trial, value)
        records.append({"trial": i, "config": config, "objective": value})
        echo(f"{planner} trial {i + 1}/{trials}: {json.dumps(config)} -> {value:.4f}")
    best = min(records, key=lambda r: (r["objective"], r["trial"]))
    tuned = {k: v for k, v in best["config"].items() if v != defaults.get(k)}
    return {"planner": planner, "config": tuned, "default": records[0]["objective"], "tuned": best["objective"],
            "trials": records, "cases": list(cases), "seeds": list(seeds), "samples_per_task": samples_per_task,
            "track": track, "heldout_every": heldout_every if track == "held-out" else None}


#: the command that writes a tuned entry (named where one is refused)
WRITER = "`fixbench tune PLANNER --out FILE.toml`"


def figures(result: dict) -> dict:
    """The ``tuning`` table of a tuning result: how it was tuned (track, ``heldout_every`` for the
    held-out track only, trials, cases, seeds, samples a position) and the objective (mean log(1 +
    regret)) of the defaults and of the tuned config, at full precision."""
    track = result.get("track", "per-task")
    out = {"track": track, "heldout_every": result.get("heldout_every") if track == "held-out" else None,
           "trials": len(result["trials"]), "cases": list(result["cases"]), "seeds": list(result["seeds"]),
           "samples_per_task": result["samples_per_task"], "objective_default": float(result["default"]),
           "objective_tuned": float(result["tuned"])}
    return {k: out[k] for k in FIGURES if out[k] is not None}


def matrix_entry(result: dict) -> str:
    """The ``[[planners]]`` entry of a tuning result, restricted to its track, its figures in its
    ``tuning`` table (:func:`figures`; read back by :func:`read_entry`)."""
    cfg = ", ".join(f"{k} = {_toml(v)}" for k, v in sorted(result["config"].items()))
    track = result.get("track", "per-task")
    held = track == "held-out"
    return ("# tuned by `fixbench tune`: `tuning` says how, and the objective (mean log(1 + regret)) of the "
            "defaults and of the tuned config\n"
            f"[[planners]]\nname = {_toml(result['planner'])}\n"
            f"label = {_toml(result['planner'] + (' (tuned held-out)' if held else ' (tuned)'))}\n"
            f"mode = {_toml([track])}\n"
            + (f"config = {{ {cfg} }}\n" if cfg else "")
            + f"tuning = {_inline(figures(result))}\n")


def _inline(table: dict) -> str:
    return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in table.items()) + " }"


def _toml(v) -> str:
    """A TOML value: a boolean, string, whole number, float (full precision) or a list of them."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):
        return repr(float(v))
    return repr(v)


def write_entry(result: dict, out: Path) -> None:
    from fixbench.cases.files import write_text_atomic

    write_text_atomic(Path(out), matrix_entry(result))


def read_entry(path: Path) -> dict:
    """A tuned entry written by ``write_entry``: planner, trials, the two objectives, the config, the
    track it runs in, and its ``tuning`` table (``figures``); a file without that table, or with a
    malformed one, is a one-line CaseError naming the file and the key."""
    import tomllib

    from fixbench.cases.units import Reader

    source = str(path)
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(source, "", f"is not valid TOML: {exc}") from None
    planners = data.get("planners")
    if not isinstance(planners, list) or not planners:
        raise CaseError(source, "planners", f"missing: not a tuned [[planners]] entry (write one with {WRITER})")
    entry = Reader(planners[0], source, "planners[0]")
    name = entry.text("name")
    if "tuning" not in entry.data:
        raise entry.error("tuning", f"missing: the tuned entry's figures (write them with {WRITER})")
    figs = read_figures(entry.data["tuning"], source, entry.key("tuning"))
    config = entry.raw("config", {}, (dict,))
    modes = entry.raw("mode", [], (list,))
    return {"planner": name, "trials": figs["trials"], "default": figs["objective_default"],
            "tuned": figs["objective_tuned"], "config": dict(config),
            "track": ", ".join(modes) if modes else f"both (tuned {figs['track']})", "tuning": figs}


def tuning_table(folder: Path) -> str:
    """The Markdown table of every tuned entry (``*.toml``) in ``folder``, by planner and track: the track
    it runs in (an entry without ``mode`` runs in both, tuned for its ``tuning.track``), the objective of
    the defaults and of the tuned config, each with the geometric-mean regret it stands for, and the tuned
    config (``fixbench tune-table``)."""
    from fixbench.bench.reporting.tables import fmt

    def regret(x: float) -> str:
        return f"{x:.4f} ({math.expm1(x) * 100:.0f} %)"

    lines = ["| planner | runs in | trials | defaults: mean log(1 + regret) | tuned | tuned config |",
             "|---|---|--:|--:|--:|---|"]
    entries = sorted((read_entry(p) for p in sorted(Path(folder).glob("*.toml"))),
                     key=lambda e: (e["planner"], e["track"]))
    for e in entries:
        cfg = ", ".join(f"{k} = {fmt(v) if isinstance(v, float) else _toml(v)}" for k, v in sorted(e["config"].items()))
        lines.append(f"| `{e['planner']}` | {e['track']} | {e['trials']} | {regret(e['default'])} | "
                     f"{regret(e['tuned'])} | {cfg or '(the defaults)'} |")
    return "\n".join(lines) + "\n"
