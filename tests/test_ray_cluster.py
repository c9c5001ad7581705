"""`fixbench run --executor ray`: connects to the cluster that is there (RAY_ADDRESS, --ray-address,
`ray start`), else starts a private instance; says which first; a bad address is one line, exit 2."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import psutil
import pytest

from fixbench.bench.cli import main
from fixbench.bench.records.rows import load_results
from fixbench.bench.running.executors import RayExecutor

ray = pytest.importorskip("ray")

TWO_CELLS = """
name = "two"
cases = ["fan_small"]
materials = ["aluminium"]
planners = ["random"]
seeds = [0, 1]
budget = 60
tasks = 2
agents = 2
"""

#: a Ray head of 2 CPUs that prints its GCS address, then waits to be stopped (10 minutes at most)
HEAD = """
import logging, time
import ray
ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level=logging.ERROR)
print(ray.get_runtime_context().gcs_address, flush=True)
time.sleep(600)
"""


@pytest.fixture
def ray_env(monkeypatch):
    """No cluster from the environment, no token authentication (set explicitly: a private
    instance would otherwise turn it on in os.environ for the tests after), a Ray temp folder of
    our own (a `ray start` on this machine is not found); Ray shut down afterwards."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    tmp = tempfile.mkdtemp(prefix="fbray", dir="/tmp")  # short: Ray's socket paths live under it
    monkeypatch.setenv("RAY_TMPDIR", tmp)
    yield tmp
    if ray.is_initialized():
        ray.shutdown()
    shutil.rmtree(tmp, ignore_errors=True)


@pytest.fixture
def ray_head(ray_env):
    """The GCS address of a Ray head (2 CPUs) in a child process; it and everything it started are
    stopped afterwards."""
    proc = subprocess.Popen([sys.executable, "-c", HEAD], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, env=dict(os.environ))
    try:
        address = proc.stdout.readline().strip()
        assert address, f"the Ray head did not start (exit code {proc.poll()})"
        yield address
    finally:
        try:
            family = psutil.Process(proc.pid).children(recursive=True)  # its GCS, raylet, workers
        except psutil.NoSuchProcess:
            family = []
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        _gone, alive = psutil.wait_procs(family, timeout=10)
        for p in alive:
            p.kill()


def run_ray(capfd, tmp_path, *args: str) -> tuple[int, list[str]]:
    """`fixbench run TWO_CELLS --executor ray ARGS`: its exit code and its stderr lines."""
    path = tmp_path / "m.toml"
    path.write_text(TWO_CELLS)
    rc = main(["run", str(path), "--out", str(tmp_path / "out"), "--executor", "ray", *args])
    return rc, capfd.readouterr().err.strip().splitlines()


@pytest.mark.slow
def test_ray_connects_to_the_cluster_in_ray_address(ray_head, monkeypatch, capfd, tmp_path):
    monkeypatch.setenv("RAY_ADDRESS", ray_head)
    rc, err = run_ray(capfd, tmp_path, "--workers", "3")
    assert rc == 0, err
    assert err[0] == (f"fixbench run: Ray: connected to the cluster at {ray_head} (2 CPUs; from RAY_ADDRESS), "
                      "at most 2 cells in flight"), err
    rows = load_results(tmp_path / "out")
    assert len(rows) == 2 and (rows["error"] == "").all()
    assert not ray.is_initialized(), "the run leaves the cluster when it ends"


@pytest.mark.slow
def test_ray_starts_a_private_instance_without_a_cluster(ray_env, capfd):
    ex = RayExecutor(workers=2)  # a run's rows under it: test_harness.py::test_ray_gives_the_same_rows_as_local
    try:
        err = capfd.readouterr().err.strip().splitlines()
        assert err[0] == "fixbench run: Ray: started a private local instance (2 CPUs)", err
        assert ex.workers == 2 and ray.cluster_resources()["CPU"] == 2
    finally:
        ex.close()
    assert not ray.is_initialized(), "close() stops the private instance"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


class _NotRay(BaseHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture
def web_server():
    """The port of an HTTP/1 server (as the Ray dashboard's): something listens, but no Ray cluster."""
    server = ThreadingHTTPServer(("", 0), _NotRay)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield server.server_address[1]
    server.shutdown()
    server.server_close()


@pytest.mark.parametrize("where", ["RAY_ADDRESS", "--ray-address", "ray start's file"])
def test_ray_address_where_nothing_listens_is_one_line(ray_env, monkeypatch, capfd, tmp_path, where):
    address = f"127.0.0.1:{_free_port()}"
    args = []
    if where == "RAY_ADDRESS":
        monkeypatch.setenv("RAY_ADDRESS", address)
    elif where == "--ray-address":
        args = ["--ray-address", address]
    else:
        (tmp_path / "ray").mkdir()
        (tmp_path / "ray" / "ray_current_cluster").write_text(address)
        monkeypatch.setenv("RAY_TMPDIR", str(tmp_path))
    rc, err = run_ray(capfd, tmp_path, *args)
    assert rc == 2 and len(err) == 1 and "Traceback" not in err[0], err
    assert address.split(":")[1] in err[0] and "cannot reach a Ray cluster there" in err[0], err
    assert ("ray_current_cluster" if where == "ray start's file" else where) in err[0], err
    assert not ray.is_initialized()


def test_ray_address_of_something_else_is_one_line(ray_env, web_server, capfd, tmp_path):
    rc, err = run_ray(capfd, tmp_path, "--ray-address", f"127.0.0.1:{web_server}")
    assert rc == 2 and len(err) == 1 and "no Ray cluster answers there" in err[0], err
    assert err[0].startswith("fixbench: --ray-address: ") and f":{web_server}" in err[0], err


def test_malformed_ray_address_is_one_line(ray_env, capfd, tmp_path):
    rc, err = run_ray(capfd, tmp_path, "--ray-address", "nowhere")
    assert rc == 2 and len(err) == 1 and "--ray-address: nowhere" in err[0], err
