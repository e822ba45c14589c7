# The shared test harness (real roscore, roslaunch, database servers, Xvfb) for every test in the
# workspace: see src/ros_harness/src/ros_harness/pytest_plugin.py.
import os
import resource
from collections import defaultdict

import pytest

pytest_plugins = ["ros_harness.pytest_plugin"]

CPU_REPORT_FILES = int(os.environ.get("CPU_REPORT_FILES", "25"))  # files listed in the CPU report
_last_cpu = [None]
_cpu_by_file = defaultdict(float)
_worker_cpu = []        # (whole worker process, its test files): from each pytest-xdist worker
_last_teardown = [False]
SESSION_TEARDOWN = "(session fixtures stopped at the end: servers, roscore, Xvfb)"


def _cpu_seconds(children: bool = True) -> float:
    """user+sys of this process and (`children`) of its children that have ended (roslaunch,
    servers, ...)."""
    total = 0.0
    whose = [resource.RUSAGE_SELF] + ([resource.RUSAGE_CHILDREN] if children else [])
    for who in whose:
        usage = resource.getrusage(who)
        total += usage.ru_utime + usage.ru_stime
    return total


def pytest_collection_finish(session):
    _last_cpu[0] = _cpu_seconds()   # collection (imports) is not any test file's


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
    # the last teardown of a process also stops the session-scoped servers: their whole CPU would
    # otherwise land on whichever test file happened to run last
    _last_teardown[0] = nextitem is None
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    # The CPU since the previous report of this process: setup, call and teardown in turn, so a
    # module fixture's cost lands on the test that set it up or tore it down.
    outcome = yield
    now = _cpu_seconds()
    spent = 0.0 if _last_cpu[0] is None else now - _last_cpu[0]
    _last_cpu[0] = now
    report = outcome.get_result()
    key = "cpu_seconds"
    if call.when == "teardown" and _last_teardown[0]:
        key = "cpu_seconds_session_teardown"
    report.user_properties = list(report.user_properties) + [(key, spent)]


def pytest_runtest_logreport(report):
    for key, value in getattr(report, "user_properties", ()):
        if key == "cpu_seconds":
            _cpu_by_file[report.nodeid.split("::")[0]] += value
        elif key == "cpu_seconds_session_teardown":
            _cpu_by_file[SESSION_TEARDOWN] += value


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:    # a pytest-xdist worker: its whole CPU goes to the controller
        workeroutput["cpu_seconds"] = _cpu_seconds()
        workeroutput["cpu_in_files"] = sum(_cpu_by_file.values())


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    output = getattr(node, "workeroutput", {})
    if "cpu_seconds" in output:
        _worker_cpu.append((output["cpu_seconds"], output["cpu_in_files"]))


def pytest_terminal_summary(terminalreporter):
    if not _cpu_by_file or os.environ.get("PYTEST_XDIST_WORKER"):
        return
    total = sum(_cpu_by_file.values())
    terminalreporter.write_sep("=", f"CPU per test file (user+sys with its processes; all files "
                                    f"{total / 60:.1f} CPU-min)")
    for path, seconds in sorted(_cpu_by_file.items(), key=lambda kv: -kv[1])[:CPU_REPORT_FILES]:
        terminalreporter.write_line(f"{seconds:8.1f} s  {path}")
    if _worker_cpu:
        whole = sum(w for w, _ in _worker_cpu)
        outside = whole - sum(f for _, f in _worker_cpu)
        controller = _cpu_seconds(children=False)
        terminalreporter.write_line(
            f"{len(_worker_cpu)} workers: {whole / 60:.1f} CPU-min in all, {outside:.1f} s of it "
            f"outside the test files (start-up, collection); the controller: {controller:.1f} s")
