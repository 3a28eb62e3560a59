"""Fixtures shared by the whole suite.

Every test is guarded against leaks: a test that leaves a thread running, a child
process alive or a file descriptor (pty, socket, serial port, bus) open fails. Parts
that legitimately keep process-wide resources mark the test ``allow_leaks``.

Tests marked ``socketcan`` skip, saying why, where there is no ``vcan0``. With
``ROVER_REQUIRE_SOCKETCAN=1`` in the environment (the CI job that brings ``vcan0`` up)
such a skip is an error instead, so that a missing interface fails loudly.

Tests marked ``rclpy`` run real ROS 2 (rclpy, Fast DDS): they need the ROS 2 Jazzy
wheels (the ``ros`` extra, which ``.ci/bootstrap`` installs) and the private network
namespace of ``.ci/test`` (``ROVER_PRIVATE_NETNS=1``), because DDS discovery multicasts,
or else ROS 2 told to discover on this host only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``,
as the workflow's ros:jazzy job does).
Tests marked ``browser`` drive Debian's ``chromium`` (headless) through Playwright for
Python; where either is missing they skip, and with ``ROVER_REQUIRE_BROWSER=1`` (set by
``.ci/test``) that skip is an error.
Test modules that import the ROS 2 message classes cannot even be collected without
ROS 2. Where either is missing they skip, saying why; with ``ROVER_REQUIRE_RCLPY=1``
(set by ``.ci/test``) such a skip is an error instead.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Generator, Iterator

import pytest
from hypothesis import HealthCheck, settings

from bridge.ros.rosport.discovery import use_fast_discovery
from firmware_proto.runtime.procname import set_process_name
from tests.lanes import lane_marks, soak_rank
from tests.procs import children as children_of

# Every test's time limit (a test past it fails with every thread's stack; pytest goes on),
# and a garbage collector that does not hold up the real-time parts a test runs in process.
pytest_plugins = ("tests.timeouts", "tests.heap", "tests.stalls")

# Seeded and reproducible: the same examples on every run and every machine.
settings.register_profile(
    "ci",
    derandomize=True,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

IN_VCAN_VM = os.environ.get("ROVER_IN_VCAN_VM") == "1"
"""Whether this runs inside .ci/vcan-vm (its software CPU: the tests' slack there)."""

#: How long (s) a test's threads, children and file descriptors get to end after it
#: before they are a leak. Inside .ci/vcan-vm (``ROVER_IN_VCAN_VM=1``) Python runs about
#: 6x slower on a software CPU that the host can stall for seconds, and a thread that ends
#: a moment after its test had been reported leaked (a teardown took 3.1 s there): the
#: grace is longer, a bound on a hang, not a timing check.
LEAK_GRACE_S = 15.0 if IN_VCAN_VM else 3.0
REQUIRE_SOCKETCAN_ENV = "ROVER_REQUIRE_SOCKETCAN"
REQUIRE_RCLPY_ENV = "ROVER_REQUIRE_RCLPY"
REQUIRE_BROWSER_ENV = "ROVER_REQUIRE_BROWSER"

#: Each pytest-xdist worker talks ROS 2 on a DDS domain of its own (``ROS_DOMAIN_ID``,
#: inherited by every process a test starts), so that two tests running at once never
#: see each other's topics. A domain given in the environment is kept for ``gw0``.
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if _WORKER.startswith("gw"):
    _base = int(os.environ.get("ROS_DOMAIN_ID") or "0")
    os.environ["ROS_DOMAIN_ID"] = str((_base + int(_WORKER[2:])) % 100)


#: The tests' own rclpy nodes, and every process a test starts, find each other as the
#: product's do (docs/rosport.md, "Discovery"); a profile file of the user's own wins.
use_fast_discovery()


def _run_dir(variable: str, prefix: str, leaf: str = "") -> None:
    """Unless set already, ``variable`` names a new directory of this run (``leaf``
    inside it, if given); pytest-xdist's workers inherit it, and the process that made it
    removes it when it exits."""
    if variable not in os.environ:
        made = tempfile.mkdtemp(prefix=prefix)
        os.environ[variable] = os.path.join(made, leaf) if leaf else made
        atexit.register(shutil.rmtree, made, ignore_errors=True)


#: The processes a test starts log their stalls (docs/realtime.md) to a log of this run's
#: own, not to the host's shared one.
_run_dir("ROVER_STALL_LOG", "rover-test-stalls-", "stalls.jsonl")
#: Every ``rover stack up`` and ``rover demo`` a test starts claims its ROS domain in one
#: directory for the whole run (planner/stack/domains.py), so that two at once, on two workers,
#: get two domains (in a directory of each test's own, a stack and a demo both took
#: domain 101 and drove on each other's topics), and none takes one that the user's own
#: stacks hold.
_run_dir("ROVER_STACK_DIR", "rover-test-stacks-")

IN_PRIVATE_NETNS = os.environ.get("ROVER_PRIVATE_NETNS") == "1"
LOCALHOST_DISCOVERY = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST"
SKIP_NETNS_REASON = (
    "ROS 2 tests run only in the private network namespace of .ci/test "
    "(ROVER_PRIVATE_NETNS=1) or with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: "
    "DDS discovery multicasts"
)
SKIP_RCLPY_REASON = (
    "ROS 2 Jazzy (rclpy and the message packages) is not installed here: "
    "pip install -e '.[ros]' (or .ci/bootstrap), or source /opt/ros/jazzy/setup.bash"
)


def _ros_available() -> bool:
    from bridge.ros.rosport.rclpy_backend import rclpy_available

    return rclpy_available()


def rclpy_required() -> bool:
    """Whether ROS 2 tests must run here (``ROVER_REQUIRE_RCLPY=1``)."""
    return os.environ.get(REQUIRE_RCLPY_ENV, "") == "1"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark each test's lanes (tests/lanes.py: ``slow``, ``extended``, ``virtual``,
    ``soak``); skip, saying why, the ROS 2 tests whose environment is missing: ROS 2
    itself, or the private network namespace. In the test command's soak part, the
    longest tests first."""
    ros = _ros_available()
    for item in items:
        slow, extended, virtual, idle = lane_marks(item.nodeid)
        if slow:
            item.add_marker(pytest.mark.slow)
        if extended:
            item.add_marker(pytest.mark.extended)
        if virtual:
            item.add_marker(pytest.mark.virtual)
        if idle:
            item.add_marker(pytest.mark.soak)
        if item.get_closest_marker("rclpy"):
            if not ros:
                item.add_marker(pytest.mark.skip(reason=SKIP_RCLPY_REASON))
            elif not (IN_PRIVATE_NETNS or LOCALHOST_DISCOVERY):
                item.add_marker(pytest.mark.skip(reason=SKIP_NETNS_REASON))
    if os.environ.get(TEST_PART_ENV) == "soak":
        # The longest first (tests/lanes.py SOAK_LONGEST_FIRST); a stable sort.
        items.sort(key=lambda item: soak_rank(item.nodeid))


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(
    collector: pytest.Collector,
) -> Generator[None, pytest.CollectReport, pytest.CollectReport]:
    """A test module that cannot import for want of ROS 2 is skipped, saying why (an
    error with ``ROVER_REQUIRE_RCLPY=1``), instead of breaking the collection."""
    report = yield
    if (
        report.failed
        and isinstance(collector, pytest.Module)
        and not rclpy_required()
        and "BackendUnavailableError" in str(report.longrepr)
        and not _ros_available()
    ):
        report.outcome = "skipped"
        report.longrepr = (str(collector.path), 0, f"Skipped: {SKIP_RCLPY_REASON}")
    return report


TEST_PART_ENV = "ROVER_TEST_PART"
"""The part of ``.ci/test`` a pytest process runs (``host``, ``soak``...), in its name."""


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "allow_leaks: the test may leave process-wide resources (named in a comment)"
    )
    # Named for top and process accounting (docs/testing.md, "Where the CPU goes"):
    # pytest, pytest-gw0, or with .ci/test's part pytest-host-gw0, pytest-serial...
    part = os.environ.get(TEST_PART_ENV, "")
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    set_process_name("-".join(n for n in ("pytest", part, worker) if n))


def socketcan_required() -> bool:
    """Whether SocketCAN tests must run here (``ROVER_REQUIRE_SOCKETCAN=1``)."""
    return os.environ.get(REQUIRE_SOCKETCAN_ENV, "") == "1"


def browser_required() -> bool:
    """Whether browser tests must run here (``ROVER_REQUIRE_BROWSER=1``)."""
    return os.environ.get(REQUIRE_BROWSER_ENV, "") == "1"


def _skip_reason(report: pytest.TestReport) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2]).removeprefix("Skipped: ")
    return str(longrepr)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """Turn the skip of a ``socketcan`` (``rclpy``) test into an error when SocketCAN
    (ROS 2) is required."""
    outcome = yield
    report: pytest.TestReport = outcome.get_result()  # type: ignore[attr-defined]
    if not report.skipped:
        return
    for marker, what, required, env in (
        ("socketcan", "SocketCAN", socketcan_required(), REQUIRE_SOCKETCAN_ENV),
        ("rclpy", "ROS 2", rclpy_required(), REQUIRE_RCLPY_ENV),
        ("browser", "browser", browser_required(), REQUIRE_BROWSER_ENV),
    ):
        if item.get_closest_marker(marker) and required:
            report.outcome = "failed"
            report.longrepr = (
                f"{env}=1: this {what} test must run here, but it would "
                f"have been skipped: {_skip_reason(report)}"
            )


def _fds() -> set[int]:
    return {int(name) for name in os.listdir("/proc/self/fd")}


def _fd_target(fd: int) -> str | None:
    """What ``fd`` is open on (``/proc/self/fd``'s link); None once it is closed."""
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return None


def still_open(fds: set[int]) -> dict[int, str]:
    """Those of ``fds`` open now, each with what it is open on, in order. One that closed
    since it was listed was not left open: a fresh-clone run failed on ``12->?`` (a link
    already gone) after the leak check's whole wait, in the VM."""
    return {fd: target for fd in sorted(fds) if (target := _fd_target(fd)) is not None}


@pytest.fixture
def c_compiler() -> None:
    """Skip where there is no C compiler (``$CC`` or gcc): the batch twins' C kernel, like
    the C firmware core, is built with it (.ci/bootstrap installs gcc)."""
    from tests.firmware_proto.c_harness import compiler  # only where a test asks

    if compiler() is None:
        pytest.skip("gcc not found (set CC): the C kernel cannot be built here")


@pytest.fixture(params=["c", "numpy"])
def kernel(request: pytest.FixtureRequest) -> str:
    """Each way the batch twins' forces are computed (``emulator.batch_kernel.KERNELS``
    but ``auto``); ``c`` skips where there is no C compiler."""
    if request.param == "c":
        request.getfixturevalue("c_compiler")
    return str(request.param)


@pytest.fixture(autouse=True)
def _no_leaks(request: pytest.FixtureRequest) -> Iterator[None]:
    if request.node.get_closest_marker("allow_leaks"):
        yield
        return
    threads_before = set(threading.enumerate())
    children_before = children_of(os.getpid())
    fds_before = _fds()
    yield
    deadline = time.monotonic() + LEAK_GRACE_S
    while True:
        threads = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
        children = children_of(os.getpid()) - children_before
        fds = _fds() - fds_before
        if not (threads or children or fds) or time.monotonic() > deadline:
            break
        time.sleep(0.02)
    problems = []
    if threads:
        problems.append("threads still running: " + ", ".join(t.name for t in threads))
    if children:
        problems.append(f"child processes still alive: {sorted(children)}")
    open_fds = still_open(fds)
    if open_fds:
        problems.append(
            "file descriptors left open: "
            + ", ".join(f"{fd}->{target}" for fd, target in open_fds.items())
        )
    if problems:
        pytest.fail("leak: " + "; ".join(problems), pytrace=False)
