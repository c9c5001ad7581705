"""Faults around a run: damaged rows, a second writer, unwritable directories, strict JSON output."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from conftest import strict_json_loads
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fixbench.bench.cli import main
from fixbench.bench.records.rows import CHECKSUM, load_results
from fixbench.bench.records.store import Store, load_traces
from fixbench.bench.running.runner import run_matrix

TINY = """
name = "tiny"
cases = ["fan_small"]
materials = ["aluminium"]
planners = ["random", "greedy"]
seeds = [0, 1]
budget = 60
tasks = 2
agents = 2
"""


@pytest.fixture
def done_run(tmp_path):
    """A finished tiny run: (matrix path, run dir, {cell id: row file bytes})."""
    m = tmp_path / "m.toml"
    m.write_text(TINY)
    out = tmp_path / "run"
    assert run_matrix(m, out, workers=1, progress=False)["run"] == 4
    return m, out, {p.stem: p.read_bytes() for p in (out / "rows").glob("*.json")}


def _damage(path: Path, kind: str) -> None:
    row = json.loads(path.read_text())
    if kind == "truncated":
        path.write_bytes(path.read_bytes()[:40])
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "garbage":
        path.write_bytes(b"\x00\xff not json at all")
    elif kind == "empty object":
        path.write_text("{}")
    elif kind == "wrong value":  # valid JSON, plausible, but not what was measured
        row["objective_m"] = row["objective_m"] / 2
        path.write_text(json.dumps(row))
    elif kind == "foreign cell":
        row["cell"] = "0" * len(row["cell"])
        row[CHECKSUM] = ""
        path.write_text(json.dumps(row))


@pytest.mark.parametrize("kind", ["truncated", "empty", "garbage", "empty object", "wrong value", "foreign cell"])
def test_a_damaged_row_is_moved_aside_and_its_cell_recomputed(done_run, kind, capsys):
    m, out, before = done_run
    victim = sorted((out / "rows").glob("*.json"))[0]
    _damage(victim, kind)
    df = load_results(out)  # what `fixbench report` reads: skipped and counted, no crash
    assert len(df) == 3 and df.attrs["damaged"] == 1
    capsys.readouterr()
    summary = run_matrix(m, out, workers=1, progress=False)
    err = capsys.readouterr().err
    assert summary["run"] == 1 and summary["damaged_moved"] == 1
    assert err.count("\n") == 1 and str(victim) in err and "moved to" in err
    moved = sorted(p.name for p in (out / "damaged").iterdir())
    assert sum(n.startswith(victim.name) for n in moved) == 1  # kept, never deleted (with its files)
    after = {p.stem: p.read_bytes() for p in (out / "rows").glob("*.json")}
    assert after.keys() == before.keys()
    assert all(after[c] == b for c, b in before.items() if c != victim.stem)  # the others untouched
    assert json.loads(after[victim.stem]) == json.loads(before[victim.stem]) | {"wall_s": json.loads(
        after[victim.stem])["wall_s"], "cpu_s": json.loads(after[victim.stem])["cpu_s"],
        "setup_s": json.loads(after[victim.stem])["setup_s"], CHECKSUM: json.loads(after[victim.stem])[CHECKSUM]}


@pytest.mark.parametrize("kind", ["truncated", "edited", "missing"])
def test_a_damaged_trace_damages_its_row(done_run, kind, capsys):
    m, out, before = done_run
    cell = sorted(before)[0]
    trace = out / "traces" / f"{cell}.parquet"
    original = trace.read_bytes()
    assert json.loads(before[cell])["trace_sha1"] == hashlib.sha1(original).hexdigest()
    if kind == "truncated":
        trace.write_bytes(original[: len(original) // 2])
    elif kind == "edited":  # a valid Parquet file, with a value that was not measured
        df = pd.read_parquet(trace)
        df.loc[df.index[-1], "best"] /= 2
        df.to_parquet(trace, index=False)
    else:
        trace.unlink()
    assert len(load_results(out)) == 3 and cell not in set(load_traces(out)["cell"])  # report: skipped
    capsys.readouterr()
    summary = run_matrix(m, out, workers=1, progress=False)
    err = capsys.readouterr().err
    assert summary["run"] == 1 and summary["damaged_moved"] == 1
    assert err.count("\n") == 1 and f"its traces file {cell}.parquet" in err
    moved = [p.name for p in (out / "damaged").iterdir()]
    assert sum(n.startswith(f"{cell}.json") for n in moved) == 1  # the row and its trace kept
    assert sum(n.startswith(f"traces-{cell}") for n in moved) == (0 if kind == "missing" else 1)
    assert trace.read_bytes() == original  # recomputed, the same bytes (same seed)
    assert len(load_traces(out)["cell"].unique()) == 4


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(min_value=0, max_value=4000), junk=st.binary(max_size=64))
def test_random_damage_never_reaches_the_user_as_a_traceback(done_run, cut, junk, capsys):
    _, out, before = done_run
    victim = sorted((out / "rows").glob("*.json"))[1]
    data = before[victim.stem]
    victim.write_bytes(data[:cut] + junk + data[cut + len(junk):])
    df = load_results(out)
    assert len(df) in (3, 4)  # either still a valid row (damage hit nothing) or skipped
    victim.write_bytes(data)


def test_a_second_writer_is_refused_in_one_line(done_run, capsys):
    m, out, _ = done_run
    with open(out / ".lock", "a+") as f:  # another process holds the run directory
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        f.write("pid 4242")
        f.flush()
        os.unlink(out / "rows" / sorted(os.listdir(out / "rows"))[0])  # so that there is work to do
        assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "another fixbench run is writing here (pid 4242)" in err
    assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 0  # released: taken over


def test_a_lock_of_a_dead_process_is_taken_over(done_run, capsys):
    m, out, _ = done_run
    code = f"import fcntl; f = open({str(out / '.lock')!r}, 'a+'); fcntl.flock(f, fcntl.LOCK_EX)"
    subprocess.run([sys.executable, "-c", code], check=True)  # took the lock and died holding it
    os.unlink(out / "rows" / sorted(os.listdir(out / "rows"))[0])
    assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 0


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores file permissions")
def test_an_unwritable_out_is_one_line_and_exit_2(tmp_path, capsys):
    m = tmp_path / "m.toml"
    m.write_text(TINY)
    locked = tmp_path / "ro"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        assert main(["run", str(m), "--out", str(locked / "run"), "--workers", "1"]) == 2
    finally:
        locked.chmod(0o700)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Permission denied" in err


def test_a_failed_write_leaves_no_temporary_file(done_run, monkeypatch):
    _, out, _ = done_run
    store = Store(out)
    import pandas as pd

    def full_disk(self, *a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pd.DataFrame, "to_parquet", full_disk)
    row = json.loads(next((out / "rows").glob("*.json")).read_text())
    with pytest.raises(OSError):
        store.write(row, pd.DataFrame({"a": [1]}), None)
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]


def test_an_empty_matrix_copy_from_a_full_disk_does_not_lock_the_directory_for_ever(tmp_path):
    m = tmp_path / "m.toml"
    m.write_text(TINY)
    out = tmp_path / "run"
    out.mkdir()
    (out / "matrix.toml").write_text("")  # what a full disk left behind
    assert run_matrix(m, out, workers=1, progress=False)["run"] == 4
    assert (out / "matrix.toml").read_text() == TINY


@pytest.mark.parametrize("args", [
    ["solve", "fan_small", "--planner", "random", "--budget", "30", "--json"],
    ["solve", "fan_small", "--planner", "random", "--budget", "30", "--json", "--heldout-every", "2"],
    ["evaluate", "fan_small", "--task", "0", "--layout", "0,30,60", "--json"],
    ["solvers", "--json"],
    ["validate", "--json", "--no-parts"],  # the parts' rows: test_cli.test_validate_parts (minutes)
    ["cache", "info", "--json"],
])
def test_every_json_output_is_strict_json(args, capsys):
    assert main(args) in (0, 1)
    strict_json_loads(capsys.readouterr().out)


def test_a_case_path_is_found_beside_the_matrix_and_checked_before_any_work(tmp_path, plate_toml, capsys,
                                                                         monkeypatch):
    case = Path(plate_toml())
    folder = tmp_path / "study"
    folder.mkdir()
    (folder / "part.toml").write_text(case.read_text())
    m = folder / "m.toml"
    m.write_text(TINY.replace('"fan_small"', '"part.toml"').replace("tasks = 2", "tasks = 3"))
    monkeypatch.chdir(tmp_path)  # not the matrix's folder
    assert main(["run", str(m), "--out", str(tmp_path / "run"), "--workers", "1"]) == 0
    assert len(load_results(tmp_path / "run")) == 4 and not load_results(tmp_path / "run")["error"].any()
    m.write_text(TINY.replace('"fan_small"', '"part.toml"').replace("tasks = 2", "tasks = 50"))
    assert main(["run", str(m), "--out", str(tmp_path / "run2"), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "tasks" in err and "only 3" in err
    assert not (tmp_path / "run2").exists()


def test_an_out_under_a_file_is_one_line_and_exit_2(tmp_path, capsys):
    m = tmp_path / "m.toml"
    m.write_text(TINY)
    (tmp_path / "plain").write_text("a file, not a folder")
    assert main(["run", str(m), "--out", str(tmp_path / "plain" / "run"), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Not a directory" in err and "Traceback" not in err


@pytest.fixture
def small_fs(tmp_path, monkeypatch):
    """A real 8 MiB file system (tmpfs) at tmp_path/fs, where the platform lets the tests mount one
    (root, mount allowed); unmounted after. The oracle's disk cache is off, so that its own
    warning does not mix with the faults under test."""
    mnt = tmp_path / "fs"
    mnt.mkdir()
    if os.geteuid() != 0 or not shutil.which("mount") or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("mounting a small file system needs root and a platform that allows it")
    monkeypatch.setenv("FIXBENCH_CACHE_DIR", "off")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def _finished(m: Path, out: Path) -> dict[str, bytes]:
    """Run ``m`` into ``out`` to the end; the row files' bytes by cell id."""
    assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 0
    return {p.stem: p.read_bytes() for p in (out / "rows").glob("*.json")}


def _measured_row(data: bytes) -> dict:
    """A row without its timings (and the checksum over them): what a recomputed cell repeats."""
    return {k: v for k, v in json.loads(data).items() if k not in ("wall_s", "cpu_s", "setup_s", CHECKSUM)}


def _measured(out: Path) -> dict[str, dict]:
    return {p.stem: _measured_row(p.read_bytes()) for p in (out / "rows").glob("*.json")}


def test_a_full_file_system_is_one_line_keeps_the_rows_and_resumes(small_fs, capsys):
    m = small_fs.parent / "m.toml"
    m.write_text(TINY)
    out = small_fs / "run"
    full = _finished(m, out)
    lost = sorted(full)[:2]
    for cell in lost:
        for f in out.glob(f"*/{cell}.*"):
            f.unlink()
    filler = small_fs / "filler"
    with open(filler, "wb", buffering=0) as f, contextlib.suppress(OSError):  # to the last byte
        while f.write(b"x" * 512):
            pass
    capsys.readouterr()
    assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left on device" in err and str(out) in err, err
    kept = {p.stem: p.read_bytes() for p in (out / "rows").glob("*.json")}
    assert kept == {c: b for c, b in full.items() if c not in lost}  # finished rows intact
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    filler.unlink()  # the cause gone, the directory resumes
    assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 0
    assert _measured(out) == {c: _measured_row(b) for c, b in full.items()}


def test_a_read_only_file_system_is_one_line_keeps_the_rows_and_resumes(small_fs, capsys):
    m = small_fs.parent / "m.toml"
    m.write_text(TINY)
    out = small_fs / "run"
    full = _finished(m, out)
    lost = sorted(full)[0]
    for f in out.glob(f"*/{lost}.*"):
        f.unlink()
    subprocess.run(["mount", "-o", "remount,ro", str(small_fs)], check=True)
    capsys.readouterr()
    assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Read-only file system" in err and str(out) in err, err
    assert {p.stem: p.read_bytes() for p in (out / "rows").glob("*.json")} == {
        c: b for c, b in full.items() if c != lost}
    subprocess.run(["mount", "-o", "remount,rw", str(small_fs)], check=True)
    assert main(["run", str(m), "--out", str(out), "--workers", "1"]) == 0
    assert _measured(out) == {c: _measured_row(b) for c, b in full.items()}


def test_run_files_are_readable_as_the_umask_allows(done_run):
    _, out, _ = done_run
    mask = os.umask(0)
    os.umask(mask)
    for p in [out / "matrix.toml", *out.glob("rows/*.json"), *out.glob("traces/*.parquet")]:
        assert p.stat().st_mode & 0o777 == 0o666 & ~mask, p


def test_without_a_terminal_progress_is_plain_lines(tmp_path, capsys):
    m = tmp_path / "m.toml"
    m.write_text(TINY)
    run_matrix(m, tmp_path / "run", workers=1, progress=False, plain_every=1e-9)
    lines = [x for x in capsys.readouterr().err.splitlines() if "proof" not in x]  # (the reference phase's)
    assert len(lines) == 3 and all("cells done" in x and "ETA" in x for x in lines)  # cells 1..3 of 4


#: a planner that waits for a file the test creates: a run of it cannot finish before the test
#: interrupts it, whatever the machine's speed (no race between the run and the signal)
GATE = """
import pathlib, time
from dataclasses import dataclass
from fixbench.solvers import Planner, PlannerConfig
from fixbench.solvers.base import random_layouts

@dataclass(frozen=True)
class GateConfig(PlannerConfig):
    gate: str = ""

class Gate(Planner):
    name = "gate"
    description = "waits for a file, then one random layout a task"
    Config = GateConfig
    def plan(self, problem, ev, rng, mode):
        while not pathlib.Path(self.config.gate).exists():
            time.sleep(0.05)
        layouts = random_layouts(problem, rng, problem.n_tasks)
        for t in range(problem.n_tasks):
            ev.evaluate(t, layouts[t:t + 1])
        return layouts, {}
"""


def test_ctrl_c_stops_quietly_keeps_the_rows_and_says_how_to_resume(tmp_path):
    import signal
    import time

    (tmp_path / "gate_plugin.py").write_text(GATE)
    gate = tmp_path / "open"
    m = tmp_path / "m.toml"  # 4 random cells, then 4 gate cells that wait for ``gate``
    m.write_text(TINY.replace('planners = ["random", "greedy"]\n', "")
                 .replace("seeds = [0, 1]", "seeds = [0, 1, 2, 3]")
                 + f'[[planners]]\nname = "random"\n[[planners]]\nname = "gate_plugin:Gate"\n'
                   f'config = {{ gate = "{gate}" }}\n')
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(tmp_path) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    # Ctrl-C's default action for the run, whatever the suite inherited: a shell starts a background job
    # (`make test &`, a CI step) with SIGINT ignored, and Python then installs no KeyboardInterrupt handler
    proc = subprocess.Popen([sys.executable, "-m", "fixbench", "run", str(m), "--out", str(out), "--workers", "1"],
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=env, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 900  # a generous bound for a loaded machine, not a timing condition:
    while time.monotonic() < deadline and len(list((out / "rows").glob("*.json"))) < 2:  # the gate holds
        time.sleep(0.05)                                                               # the run open
    if len(list((out / "rows").glob("*.json"))) < 2:
        os.killpg(proc.pid, signal.SIGKILL)  # leave no run behind waiting on the gate
        pytest.fail("the random cells did not finish in 15 minutes")
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C sends: the whole process group
    err = proc.communicate(timeout=600)[1]
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.count("\n") == 1 and "the same command resumes" in err, err
    store = Store(out)
    done = len(store.finished())
    assert 2 <= done <= 4 and store.damaged == []  # the gate cells never finished
    gate.touch()
    resumed = subprocess.run([sys.executable, "-m", "fixbench", "run", str(m), "--out", str(out), "--workers", "1"],
                             capture_output=True, text=True, env=env, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{8 - done} run (0 failed), {done} already done" in resumed.stdout + resumed.stderr


_VALUES = st.one_of(st.integers(-5, 10**6), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.booleans(), st.lists(st.integers(-3, 3), max_size=3), st.just("[[1, 2], [3]]"),
                    st.just("{ a = 1 }"))


def _mutate(text: str, data) -> str:
    """Replace one value of one line (keeping the key), or cut the text, or splice junk in."""
    lines = text.splitlines()
    how = data.draw(st.sampled_from(["value", "cut", "junk", "drop"]))
    if how == "cut":
        return text[:data.draw(st.integers(0, len(text)))]
    if how == "junk":
        i = data.draw(st.integers(0, len(text)))
        return text[:i] + data.draw(st.text(max_size=12)) + text[i:]
    i = data.draw(st.sampled_from([k for k, ln in enumerate(lines) if "=" in ln]))
    if how == "drop":
        return "\n".join(lines[:i] + lines[i + 1:])
    key = lines[i].split("=")[0]
    v = data.draw(_VALUES)
    lines[i] = f"{key}= {json.dumps(v) if not isinstance(v, str) or not v.startswith(('[', '{')) else v}"
    return "\n".join(lines)


def _load_matrix(path: Path) -> None:
    from fixbench.bench.running.matrix import load_matrix

    load_matrix(path).cells()


def _load_case(path: Path) -> None:
    from fixbench.cases.spec import load_case_spec

    load_case_spec(str(path))


@pytest.mark.parametrize("template,load", [(TINY, _load_matrix), ("PLATE", _load_case)], ids=["matrix", "case"])
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_malformed_files_never_give_a_traceback(tmp_path, template, load, data):
    """Random malformed matrix and case files: a one-line FixbenchError or success, nothing else."""
    from fixbench.cases.errors import FixbenchError
    from tests.conftest import PLATE

    p = tmp_path / "file.toml"
    p.write_text(_mutate(PLATE if template == "PLATE" else template, data), encoding="utf-8",
                 errors="surrogatepass")
    try:
        load(p)
    except FixbenchError as exc:
        assert "\n" not in str(exc)


def test_workers_stop_when_the_driver_is_killed(tmp_path):
    """A driver killed outright (SIGKILL: no clean-up runs) leaves no worker computing on."""
    import signal
    import time

    import psutil

    (tmp_path / "sleepy.py").write_text(
        "import time\nfrom fixbench.solvers import Planner\n\n"
        "class Sleepy(Planner):\n    name = 'sleepy'\n    description = 'never finishes'\n\n"
        "    def plan(self, problem, ev, rng, mode):\n"
        f"        open({str(tmp_path / 'started')!r}, 'w').close()\n        time.sleep(600)\n")
    m = tmp_path / "m.toml"
    m.write_text(TINY.replace('planners = ["random", "greedy"]', 'planners = ["sleepy:Sleepy"]'))
    env = {**os.environ, "PYTHONPATH": str(tmp_path) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, "-m", "fixbench", "run", str(m), "--out", str(tmp_path / "run"),
                             "--workers", "1"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (tmp_path / "started").exists():  # the worker is in its cell
        time.sleep(0.1)
    workers = [c for c in psutil.Process(proc.pid).children() if "resource_tracker" not in " ".join(c.cmdline())]
    assert workers, "no worker started"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    gone, alive = psutil.wait_procs(workers, timeout=15)
    for p in alive:
        p.kill()
    assert not alive, "a worker outlived its killed driver"
