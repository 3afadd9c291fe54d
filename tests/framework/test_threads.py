"""The process's one thread policy (runtime.threads): pinned, or following the machine's free cores."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from splat_framework.runtime import threads


@pytest.fixture
def policy(monkeypatch):
    """A fresh policy on a pretend 4-core machine; torch's count is restored afterwards."""
    before = torch.get_num_threads()
    monkeypatch.setattr(threads, "available_cores", lambda: 4)
    monkeypatch.delenv("SPLAT_THREADS", raising=False)
    p = threads.ThreadPolicy()
    p.most = 4
    counts = []
    monkeypatch.setattr(torch, "set_num_threads", counts.append)
    monkeypatch.setattr(torch, "get_num_threads", lambda: counts[-1] if counts else 4)
    p.counts = counts
    yield p
    monkeypatch.undo()
    torch.set_num_threads(before)


def test_free_cores_are_a_power_of_two_within_the_start_count(monkeypatch):
    monkeypatch.setattr(threads, "available_cores", lambda: 8)
    assert threads.free_cores(8, 0) == 8
    assert threads.free_cores(8, 0.3) == 8  # a third of a core busy elsewhere: still all 8
    assert threads.free_cores(8, 1) == 4  # 7 free: 4 (each count is a compiled graph of its own)
    assert threads.free_cores(8, 6) == 2
    assert threads.free_cores(8, 30) == 1  # never 0
    assert threads.free_cores(4, 0) == 4  # never above what the process started with
    assert threads.free_cores(8, None) is None  # unknown load: leave it


def test_the_count_follows_the_load_after_two_readings_a_second_apart(policy, monkeypatch):
    load = {"others": 3.1}
    monkeypatch.setattr(policy.meter, "read", lambda: load["others"])
    assert policy.follow(now=0.0) is None  # one reading of 1 free core: not yet
    assert policy.follow(now=0.5) is None  # too soon to read again
    assert policy.follow(now=1.0) == 1 and policy.counts == [1]  # the second reading agrees
    load["others"] = 0.2
    assert policy.follow(now=2.0) is None
    load["others"] = 2.9  # a burst elsewhere: the pending change is dropped
    assert policy.follow(now=3.0) is None
    load["others"] = 0.0
    assert policy.follow(now=4.0) is None
    assert policy.follow(now=5.0) == 4 and policy.counts == [1, 4]
    assert policy.changes == 2
    # metrics.json keeps the setting, every count the run used, the gradient slots and the matches' count
    assert policy.record() == {"setting": "auto", "counts": [1, 4], "gradient_slots": 4, "matching": 4}


def test_a_pinned_count_is_set_once_for_the_whole_process_and_never_follows(policy, monkeypatch):
    monkeypatch.setattr(policy.meter, "read", lambda: 3.0)
    monkeypatch.setenv("SPLAT_THREADS", "2")
    assert policy.start() == 2 and policy.counts == [2]
    for t in range(5):
        assert policy.follow(now=float(t)) is None
    assert policy.record() == {"setting": "2", "counts": [2], "gradient_slots": 4, "matching": 4}
    monkeypatch.setenv("SPLAT_THREADS", "off")
    assert policy.start() is None
    assert [policy.follow(now=10.0 + t) for t in range(3)] == [None] * 3 and policy.counts == [2]


def test_opencv_pool_follows_too(policy, monkeypatch):
    cv2 = pytest.importorskip("cv2")
    before = cv2.getNumThreads()
    monkeypatch.setattr(policy.meter, "read", lambda: 3.0)
    try:
        policy.follow(now=0.0)
        policy.follow(now=1.0)
        assert cv2.getNumThreads() == 1
        cv2.setNumThreads(before)  # OpenCV loaded after the count was set, under a pinned count
        monkeypatch.setenv("SPLAT_THREADS", "1")
        policy.follow(now=5.0)
        assert cv2.getNumThreads() == torch.get_num_threads() == 1
    finally:
        cv2.setNumThreads(before)


def test_every_phase_and_every_cpu_render_let_the_count_follow(monkeypatch):
    from splat_framework.console import phase
    from splat_framework.render import rasterize

    calls = []
    monkeypatch.setattr(threads.POLICY, "follow", lambda now=None: calls.append(1))
    with phase("work", 3) as ph:
        ph.advance()
        ph.update(info="x")
    assert len(calls) == 2
    means = torch.tensor([[0.0, 0.0, 2.0]])
    rasterize(means, torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.1), torch.ones(1),
              torch.ones(1, 3), torch.eye(4), torch.tensor([[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]]), 8, 8)
    assert len(calls) == 3


def test_in_a_fresh_process_a_busy_machine_lowers_torch_threads():
    """torch itself (not a stand-in) runs fewer threads once every core is busy elsewhere."""
    code = (
        "import time, torch; from splat_framework.runtime import threads as t\n"
        "t.others_running = lambda: 0\n"  # idle at the start, whatever this machine is doing
        "t.POLICY.meter.read = lambda: float(t.available_cores())\n"  # then every core busy elsewhere
        "torch.set_num_threads(2); t.POLICY.start(); print(torch.get_num_threads())\n"
        "now = time.monotonic()\n"  # the readings a second apart, after the start's own
        "for later in (1.5, 3.0): t.POLICY.follow(now=now + later)\n"
        "print(torch.get_num_threads())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["2", "1"]


def test_a_count_set_by_the_caller_before_a_run_is_the_new_ceiling(policy, monkeypatch):
    """A sweep's in-process worker sets torch's count before each run: that count bounds "auto"."""
    monkeypatch.setattr(threads, "others_running", lambda: 0)
    monkeypatch.setattr(policy.meter, "read", lambda: 0.0)
    torch.set_num_threads(2)  # the caller, not the policy
    policy.start()
    assert policy.most == 2
    policy.follow(now=0.0)
    policy.follow(now=1.0)
    assert torch.get_num_threads() == 2  # idle machine, yet never above the caller's 2


def test_a_run_starts_with_the_cores_free_at_that_moment(policy, monkeypatch):
    """No kernel is loaded yet at the start, so the first count needs no second reading."""
    monkeypatch.setattr(threads, "others_running", lambda: 3)
    assert policy.start() is None  # "auto": nothing pinned
    assert policy.counts == [1]


def test_the_cpu_meter_subtracts_this_process_s_own_time(monkeypatch):
    """The reading is the machine's busy time less this process's own, per second of wall time."""
    from splat_framework.runtime import resources

    samples = iter([(10.0, 100.0, 3.0), (12.5, 101.0, 3.9), (12.5, 101.0, 3.9)])  # (busy, wall, own)
    monkeypatch.setattr(resources, "_cpu_sample", lambda: next(samples))
    meter = resources.CpuMeter()
    assert meter.read() is None  # the first reading has nothing to compare with
    assert meter.read() == pytest.approx(1.6)  # 2.5 busy core-seconds, 0.9 of them this process's
    assert meter.read() is None  # no wall time passed


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` (Linux /proc)."""
    import os

    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_the_cpu_meter_counts_other_processes_busy_cores_not_this_one():
    """On the real /proc: a busy child's CPU time shows in the reading, this process's own does not.

    Bounds that hold at any load (CI runs two test workers on two cores): the reading is at least
    the child's share of the interval, and at most the cores left when this process's share is
    taken away."""
    import os
    import time

    from splat_framework.runtime.resources import CpuMeter

    meter = CpuMeter()
    if meter.read() is None and meter.last is None:
        pytest.skip("no /proc/stat on this system")
    cores = len(os.sched_getaffinity(0))
    slack = 0.15  # clock ticks (10 ms) over about a second, and the readings' few microseconds apart
    own, start = time.process_time(), time.monotonic()
    end = start + 0.8
    while time.monotonic() < end:
        pass
    mine = meter.read()
    own_share = (time.process_time() - own) / (time.monotonic() - start)
    assert mine is not None and mine <= cores - own_share + slack
    child = subprocess.Popen([sys.executable, "-c", "import time\nend = time.monotonic() + 5\nwhile time.monotonic() < end: pass"])
    try:
        time.sleep(1.0)  # the interpreter's start-up is over
        meter.read()
        before, start = _cpu_seconds(child.pid), time.monotonic()
        time.sleep(1.0)
        theirs = meter.read()
        child_share = (_cpu_seconds(child.pid) - before) / (time.monotonic() - start)
    finally:
        child.kill()
        child.wait()
    assert child_share > 0.05  # the child ran at all
    assert theirs is not None and theirs >= child_share - slack


def test_without_proc_or_affinity_the_policy_leaves_the_count_alone(policy, monkeypatch):
    """Issue 62 (macOS, Windows): no /proc and no sched_getaffinity mean no load reading; "auto"
    then keeps the count the run started with, and nothing fails."""
    import builtins

    import torch

    from splat_framework.runtime import resources

    real_open = builtins.open

    def no_proc(path, *args, **kwargs):
        if str(path).startswith("/proc"):
            raise FileNotFoundError(2, "No such file or directory", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", no_proc)
    monkeypatch.delattr(resources.os, "sched_getaffinity", raising=False)
    monkeypatch.setattr(resources.os, "listdir", lambda p: (_ for _ in ()).throw(FileNotFoundError(str(p))))
    assert resources.available_cores() == max(1, resources.os.cpu_count() or 1)
    assert resources.others_running() is None and resources.CpuMeter().read() is None
    before = torch.get_num_threads()
    monkeypatch.setenv("SPLAT_THREADS", "auto")
    policy.start()
    for t in range(3):
        assert policy.follow(now=1e9 + t) is None
    assert torch.get_num_threads() == before


def test_matching_runs_on_the_machines_cores_whatever_the_load_or_the_pin(policy, monkeypatch):
    # the matches depend on the thread count (torch's sums split by thread) and are cached for every
    # later run, so they are computed on the machine's cores: alone, under load or pinned, the same
    monkeypatch.setattr(threads, "POLICY", policy)
    monkeypatch.setattr(policy.meter, "read", lambda: 3.1)  # one core free
    policy.counts.append(1)  # the load left the run one thread
    with threads.machine_threads() as n:
        assert n == 4 and torch.get_num_threads() == 4
        assert [policy.follow(now=float(t)) for t in range(4)] == [None] * 4  # the load is not followed inside
    assert torch.get_num_threads() == 1 and policy.held == 0  # the count before, following again
    assert policy.follow(now=10.0) is None and policy.follow(now=11.0) is None  # 1 free: already 1
    monkeypatch.setenv("SPLAT_THREADS", "2")
    policy.counts.append(2)
    with threads.machine_threads() as n:
        assert n == 4 and torch.get_num_threads() == 4
    assert torch.get_num_threads() == 2
    monkeypatch.setenv("SPLAT_THREADS", "off")  # off never touches the count
    with threads.machine_threads() as n:
        assert n == 2 and policy.counts[-1] == 2
    assert threads.machine_thread_count() == 2
