"""One command for a machine with a GPU: the published protocol on CUDA beside the CPU, same seeds.

    python -m studies.gpu_check [--case wing_panel] [--planner nashq|iql] [--seeds 0,1] [--threads 2]
                                [--episodes 100] [--json]

For each seed it runs ``python -m studies.marl speed`` once with ``--device cuda`` and once on the
CPU (``--threads``), each in a fresh process (the oracle set-up is shared through the disk cache and
kept out of the times), and prints per device: wall time of training and its split (oracle,
selection, updates), the greedy policy's mean max deformation and the mean return of the last ten
episodes. The two devices' runs differ in round-off (cuBLAS vs CPU kernels), so the runs are not
bit-identical; what must agree is their statistics: the script reports a two-sample
Kolmogorov-Smirnov test of the per-task max deformations of the two devices (all seeds pooled) and
the ratio of their mean max deformations. It exits 2 without CUDA.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import click
import numpy as np

from fixbench.bench.cli_common import run_command
from studies.marl import PLANNER_HELP, SEED_LEARNERS

#: the repository root, where ``python -m studies.marl`` finds the studies
ROOT = Path(__file__).resolve().parents[1]


def _run(case: str, planner: str, seed: int, episodes: int, device: str, threads: int) -> dict:
    cmd = [sys.executable, "-m", "studies.marl", "speed", "--case", case, "--planner", planner,
           "--seed", str(seed), "--episodes", str(episodes), "--device", device, "--threads", str(threads), "--json"]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=ROOT).stdout
    return json.loads(out)


PROG = "python -m studies.gpu_check"


@click.command(help=__doc__.split("\n")[0], context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--case", default="wing_panel", show_default=True)
@click.option("--planner", type=click.Choice(SEED_LEARNERS), default="nashq", show_default=True, help=PLANNER_HELP)
@click.option("--seeds", default="0,1", show_default=True)
@click.option("--episodes", type=int, default=100, show_default=True)
@click.option("--threads", type=int, default=2, show_default=True, help="torch threads of the CPU runs")
@click.option("--json", "as_json", is_flag=True)
def cli(case: str, planner: str, seeds: str, episodes: int, threads: int, as_json: bool) -> int:
    import torch

    if not torch.cuda.is_available():
        print("gpu_check: CUDA is not available on this machine", file=sys.stderr)
        return 2
    from scipy.stats import ks_2samp

    seed_list = [int(s) for s in seeds.split(",")]
    runs = {dev: [_run(case, planner, s, episodes, dev, threads) for s in seed_list]
            for dev in ("cuda", "cpu")}
    summary = {"case": case, "planner": planner, "seeds": seed_list, "episodes": episodes,
               "gpu": torch.cuda.get_device_name(0)}
    for dev, rs in runs.items():
        summary[dev] = {k: float(np.mean([r[k] for r in rs])) for k in
                        ("wall_s", "oracle_s", "select_s", "update_s", "mean_max_deformation_m")}
        summary[dev]["last10_return"] = float(np.mean([np.mean(r["episode_return"][-10:]) for r in rs]))
    u = {dev: np.concatenate([r["per_task_m"] for r in rs]) for dev, rs in runs.items()}
    ks = ks_2samp(u["cuda"], u["cpu"])
    summary["ks_statistic"], summary["ks_pvalue"] = float(ks.statistic), float(ks.pvalue)
    summary["mean_ratio_cuda_over_cpu"] = float(u["cuda"].mean() / u["cpu"].mean())
    summary["speedup_cuda_over_cpu"] = summary["cpu"]["wall_s"] / summary["cuda"]["wall_s"]
    if as_json:
        print(json.dumps(summary, indent=1))
    else:
        for k, v in summary.items():
            print(f"{k:>26}: {v}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit code (2: a usage error)."""
    return run_command(cli, argv, PROG)


if __name__ == "__main__":
    sys.exit(main())
