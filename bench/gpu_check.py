"""One command for a machine with a GPU: the published protocol on CUDA beside the CPU, same seeds.

    python -m fixbench.bench.gpu_check [--case wing_panel] [--planner nashq] [--seeds 0,1] [--threads 2]
                              [--episodes 100] [--json]

For each seed it runs ``python -m fixbench.bench.marl speed`` once with ``--device cuda`` and once on the
CPU (``--threads``), each in a fresh process (the oracle set-up is shared through the disk cache and
kept out of the times), and prints per device: wall time of training and its split (oracle,
selection, updates), the greedy policy's mean max deformation and the mean return of the last ten
episodes. The two devices' runs differ in round-off (cuBLAS vs CPU kernels), so the runs are not
bit-identical; what must agree is their statistics: the script reports a two-sample
Kolmogorov-Smirnov test of the per-task max deformations of the two devices (all seeds pooled) and
the ratio of their mean max deformations. It exits 2 without CUDA.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np


def _run(case: str, planner: str, seed: int, episodes: int, device: str, threads: int) -> dict:
    cmd = [sys.executable, "-m", "fixbench.bench.marl", "speed", "--case", case, "--planner", planner,
           "--seed", str(seed), "--episodes", str(episodes), "--device", device, "--threads", str(threads), "--json"]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fixbench.bench.gpu_check", description=__doc__.split("\n")[0])
    ap.add_argument("--case", default="wing_panel")
    ap.add_argument("--planner", default="nashq")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--threads", type=int, default=2, help="torch threads of the CPU runs")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    import torch

    if not torch.cuda.is_available():
        print("gpu_check: CUDA is not available on this machine", file=sys.stderr)
        return 2
    from scipy.stats import ks_2samp

    seeds = [int(s) for s in args.seeds.split(",")]
    runs = {dev: [_run(args.case, args.planner, s, args.episodes, dev, args.threads) for s in seeds]
            for dev in ("cuda", "cpu")}
    summary = {"case": args.case, "planner": args.planner, "seeds": seeds, "episodes": args.episodes,
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
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        for k, v in summary.items():
            print(f"{k:>26}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
