"""Executors: run jobs (references and cells) on local processes or on a Ray cluster.

Both call :func:`execute` on every job and hand each result to the driver as soon as
it is done, so results are identical whichever runs them (for deterministic planners). A job that
exceeds the timeout is stopped and comes back as an error; so does a worker that dies.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import socket
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import wait

import psutil

from fixbench.bench.references.prove import compute_reference, prove_position
from fixbench.bench.running.cells import run_cell
from fixbench.cases.errors import CaseError

Job = tuple  # ("reference", args) | ("position", (position,)) | ("cell", (cell, reference))
#: thread pools a worker would otherwise size to the whole machine (BLAS inside SuperLU, numba, torch)
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
OnResult = Callable[[Job, dict | None, str], None]  # (job, result or None, error text)


def execute(job: tuple) -> dict:
    """Entry point of every executor: ("reference", args), ("position", (position,)) or ("cell", (cell, reference))."""
    kind, payload = job
    if kind == "reference":
        return {"reference": compute_reference(*payload)}
    if kind == "position":
        return prove_position(payload[0])
    cell, reference = payload
    return run_cell(cell, reference)


def _affinity(job: Job):
    kind, payload = job
    return payload[:4] if kind == "reference" else payload[0].problem_key


def _exit_when_orphaned(parent: int, every: float = 1.0) -> None:  # pragma: no cover - a worker thread
    """Stop the worker once its driver is gone (killed: no one reads its result, and a learner cell
    would otherwise go on for many minutes on a core someone else needs)."""
    while True:
        time.sleep(every)
        if os.getppid() != parent:
            os._exit(3)


def _worker(conn, threads: int, parent: int) -> None:  # pragma: no cover - runs in a child process
    import signal
    import threading

    import numba
    from tqdm import tqdm

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's to handle: it stops us quietly
    threading.Thread(target=_exit_when_orphaned, args=(parent,), daemon=True).start()
    # a progress bar in a job (exact's) would make tqdm's cross-process lock, a named semaphore that a
    # worker stopped by force (Ctrl-C, a cell's timeout) leaves behind, and the resource tracker then
    # warns of it when the driver exits; one process needs only a thread lock
    tqdm.set_lock(threading.RLock())
    from fixbench.cases.problem import set_cache_size

    numba.set_num_threads(threads)
    set_cache_size(1)  # jobs arrive grouped by problem: an older model is not needed again
    try:
        import torch

        torch.set_num_threads(threads)
    except ImportError:
        pass
    while True:
        try:
            job = conn.recv()
        except EOFError:
            return
        if job is None:
            return
        conn.send(execute(job))


class LocalExecutor:
    """A pool of worker processes (spawned: safe with numba and torch threads), one job each.

    Jobs sharing a problem go to the worker that built it, so its FE model and oracle are reused;
    a worker keeps only its current problem's model (``set_cache_size(1)``). A worker moving on to
    another problem while holding more than ``recycle_mb`` of memory is replaced by a fresh process
    (a safety net: on the default matrix workers stay near 0.8 GB RSS, and a restart costs seconds
    of imports).
    """

    def __init__(self, workers: int | None = None, timeout: float | None = None, recycle_mb: float = 1000.0,
                 env: dict[str, str] | None = None):
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.timeout = timeout
        self.recycle_mb = recycle_mb
        self.env = dict(env or {})  # extra environment of the workers (the run's oracle cache folder)
        self.ctx = mp.get_context("spawn")
        self.slots: list[dict] = []  # kept between run() calls (references, then cells) until close()

    def _too_big(self, slot: dict) -> bool:
        """Whether a worker's resident memory passed ``recycle_mb`` (it is then replaced between problems)."""
        try:
            return psutil.Process(slot["proc"].pid).memory_info().rss > self.recycle_mb * 2**20
        except psutil.Error:
            return False

    def _start(self):
        parent, child = self.ctx.Pipe()
        threads = max(1, (os.cpu_count() or 1) // self.workers)
        child_env = {**{k: str(threads) for k in THREAD_VARS}, **self.env}
        saved = {k: os.environ.get(k) for k in child_env}
        os.environ.update(child_env)  # inherited by the spawned child, read by its imports
        try:
            proc = self.ctx.Process(target=_worker, args=(child, threads, os.getpid()), daemon=True)
            proc.start()
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        child.close()
        return {"proc": proc, "conn": parent, "job": None, "since": 0.0, "key": None}

    def run(self, jobs: list[Job], on_result: OnResult) -> None:
        queue = list(jobs)
        while len(self.slots) < min(self.workers, len(queue)):
            self.slots.append(self._start())
        slots = self.slots
        try:
            while queue or any(s["job"] is not None for s in slots):
                for s in slots:
                    if s["job"] is None and queue:
                        i = next((i for i, j in enumerate(queue) if _affinity(j) == s["key"]), 0)
                        job = queue.pop(i)
                        if s["key"] is not None and _affinity(job) != s["key"] and self._too_big(s):
                            self._replace(s)  # a fresh process: memory does not pile up
                        s["job"], s["since"], s["key"] = job, time.monotonic(), _affinity(job)
                        s["conn"].send(job)
                busy = [s for s in slots if s["job"] is not None]
                ready = wait([s["conn"] for s in busy], timeout=0.2)
                for s in busy:
                    job = s["job"]
                    if s["conn"] in ready:
                        try:
                            result = s["conn"].recv()
                        except (EOFError, OSError):
                            code = s["proc"].exitcode
                            self._replace(s)
                            on_result(job, None, f"worker died (exit code {code})")
                        else:
                            s["job"] = None
                            on_result(job, result, "")
                    elif self.timeout and time.monotonic() - s["since"] > self.timeout:
                        self._replace(s)
                        on_result(job, None, f"timeout: stopped after {self.timeout:g} s")
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop the workers (politely, then by force)."""
        for s in self.slots:
            try:
                s["conn"].send(None)
            except (OSError, BrokenPipeError):
                pass
            s["proc"].join(timeout=2)
            if s["proc"].is_alive():
                s["proc"].kill()
        self.slots = []

    def _replace(self, slot: dict) -> None:
        """Stop a slot's worker (politely when idle) and start a fresh one (the slot becomes idle)."""
        if slot["job"] is None:
            try:
                slot["conn"].send(None)
            except OSError:
                pass
            slot["proc"].join(timeout=5)
        if slot["proc"].is_alive():
            slot["proc"].kill()
            slot["proc"].join()
        slot["conn"].close()
        slot.update(self._start())


class RayExecutor:
    """The same jobs as Ray tasks (one CPU each), on the Ray cluster that is there or on a private
    local instance.

    The cluster is the one ``address`` names (``--ray-address``; ``auto``: the one Ray finds), else
    the one ``RAY_ADDRESS`` names (as on a cluster's nodes and in the jobs submitted to it), else the
    one ``ray start`` started on this machine (Ray records its address in its temp folder). Its CPUs
    bound the jobs in flight and ``workers`` caps them. With none of these, or ``address="local"``,
    a private instance with ``workers`` CPUs (default: one per core) is started: it never attaches
    to anything else. The run's first line on stderr says which; an address where no Ray cluster
    answers is a :class:`CaseError` naming it (checked first: Ray itself retries for many minutes).
    """

    def __init__(self, workers: int | None = None, timeout: float | None = None, address: str | None = None,
                 env: dict[str, str] | None = None):
        import ray

        self.ray = ray
        self.owned = not ray.is_initialized()  # a connection or instance of ours: close() ends it
        quiet = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR}
        if not self.owned:
            self.workers = _in_flight(workers, int(ray.cluster_resources().get("CPU", 0)))
            _say(f"using the instance this process is connected to, at most {_count(self.workers, 'cell')} in flight")
        elif (cluster := _find_cluster(address)) is None:
            self.workers = max(1, workers or os.cpu_count() or 1)
            ray.init(address="local", num_cpus=self.workers, **quiet)
            _say(f"started a private local instance ({_count(self.workers, 'CPU')})")
        else:
            source, named, where = cluster
            if "://" not in where:
                _check_answers(source, named, where)
            try:
                ray.init(address=address, **quiet)  # as given: Ray finds the same cluster (and its token)
            except Exception as exc:  # a version mismatch, missing authentication, ...
                raise CaseError(source, named, f"could not connect to a Ray cluster there: {_reason(exc)}") from None
            cpus = int(ray.cluster_resources().get("CPU", 0))
            self.workers = _in_flight(workers, cpus)
            _say(f"connected to the cluster at {where} ({_count(cpus, 'CPU')}; from {source}), "
                 f"at most {_count(self.workers, 'cell')} in flight")
        self.timeout = timeout
        options = {"runtime_env": {"env_vars": dict(env)}} if env else {}
        self.remote = ray.remote(num_cpus=1, max_retries=0, **options)(_ray_execute)

    def run(self, jobs: list[Job], on_result: OnResult) -> None:
        ray, queue, running = self.ray, list(jobs), {}
        while queue or running:
            while queue and len(running) < self.workers:  # bounded in flight: start time ~ submit
                job = queue.pop(0)
                running[self.remote.remote(job)] = (job, time.monotonic())
            done, _ = ray.wait(list(running), num_returns=1, timeout=0.2)
            for ref in done:
                job, _ = running.pop(ref)
                try:
                    on_result(job, ray.get(ref), "")
                except Exception as exc:  # the task itself failed (worker died, ...)
                    on_result(job, None, f"ray task failed: {type(exc).__name__}: {exc}".splitlines()[0])
            if self.timeout:
                for ref, (job, since) in list(running.items()):
                    if time.monotonic() - since > self.timeout:
                        ray.cancel(ref, force=True)
                        running.pop(ref)
                        on_result(job, None, f"timeout: stopped after {self.timeout:g} s")

    def close(self) -> None:
        """Stop the private instance, or leave the cluster (its nodes go on); an instance this
        process was connected to before is left as it was."""
        if self.owned:
            self.ray.shutdown()
            self.owned = False


def _say(what: str) -> None:
    print(f"fixbench run: Ray: {what}", file=sys.stderr, flush=True)


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'' if n == 1 else 's'}"


def _in_flight(workers: int | None, cpus: int) -> int:
    """Jobs in flight on a cluster of ``cpus`` CPUs, ``workers`` capping them; a cluster that has
    none yet (one an autoscaler grows) gets ``workers``, or 1."""
    if cpus < 1:
        return workers or 1
    return min(workers, cpus) if workers else cpus


def _find_cluster(address: str | None) -> tuple[str, str, str] | None:
    """(where it was named, its address as named, its address) of the Ray cluster to connect to,
    found as ``ray.init`` finds it (:func:`ray._private.services.canonicalize_bootstrap_address`:
    HOST:PORT, this machine's own address for ``localhost``); None: start a private instance.
    Where it was named: ``--ray-address``, ``RAY_ADDRESS`` or the file ``ray start`` writes."""
    from ray._common.utils import get_ray_address_file
    from ray._private.services import canonicalize_bootstrap_address

    env = os.environ.get("RAY_ADDRESS", "")
    if address and (address != "auto" or not env):
        source, given = "--ray-address", address
    elif env:
        source, given = "RAY_ADDRESS", env
    else:
        source, given = get_ray_address_file(None), None
    if given and "://" in given:
        return source, given, given  # Ray Client (ray://): ray.init checks it
    try:
        found = canonicalize_bootstrap_address(address)
    except ValueError:
        raise CaseError(source, given or "", "not a Ray cluster's address (HOST:PORT, auto or local)") from None
    except ConnectionError:  # auto, and no cluster on this machine
        raise CaseError(source, given or "", "no Ray cluster runs on this machine (`ray start --head` starts one)") \
            from None
    return None if found is None else (source, given or found, found)


#: what an HTTP/2 client sends first (the preface, then an empty SETTINGS frame); gRPC, Ray's
#: protocol, is HTTP/2, and a server of it answers with a SETTINGS frame of its own
_HTTP2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _check_answers(source: str, named: str, address: str, timeout: float = 10.0) -> None:
    """Raise :class:`CaseError` (naming the address as ``source`` named it) unless a gRPC server
    answers at ``address`` (HOST:PORT), as a Ray cluster's GCS does: ``ray.init`` would otherwise
    retry for many minutes (a port where nothing listens, a host that is down, the dashboard's
    port). TLS clusters (``RAY_USE_TLS``) are only checked to accept connections."""
    host, _, port = address.rpartition(":")
    hint = ("; `ray stop` clears this file, --ray-address local starts a private instance"
            if source not in ("--ray-address", "RAY_ADDRESS") else "")
    reply = b""
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout) as conn:
            if os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true"):
                return
            conn.sendall(_HTTP2_HELLO)
            while len(reply) < 9 and (chunk := conn.recv(9 - len(reply))):
                reply += chunk
    except (OSError, ValueError) as exc:
        why = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        raise CaseError(source, named, f"cannot reach a Ray cluster there: {why}{hint}") from None
    if reply[3:4] != b"\x04":
        raise CaseError(source, named, "no Ray cluster answers there (a Ray head's address is its GCS port, "
                        f"6379 unless `ray start --port` chose another){hint}")


def _reason(exc: BaseException) -> str:
    """The first line of ``exc``, with a hint where the cluster refused a driver without its token."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    causes, cause = [], exc
    while cause is not None:
        causes.append(str(cause))
        cause = cause.__cause__ or cause.__context__
    if any("Unauthenticated" in c or "AuthToken" in c or "authentication token" in c for c in causes):
        text += (" (the cluster wants its authentication token: set RAY_AUTH_MODE=token, with the token in "
                 "RAY_AUTH_TOKEN or ~/.ray/auth_token)")
    return text


def _ray_execute(job: Job) -> dict:  # pragma: no cover - runs in a Ray worker
    import numba

    numba.set_num_threads(1)
    return execute(job)
