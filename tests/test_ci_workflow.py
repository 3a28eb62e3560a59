""".github/workflows/ci.yml, checked as far as possible without running it (no PyYAML,
no GitHub here): the three jobs exist, every action is pinned by a full commit SHA with
its release named, every command it runs exists in the repository, the markers it
selects are this suite's, and every command of the ros:jazzy job is in that image or
installed by the job before it runs."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
WORKFLOW = ROOT / ".github" / "workflows" / "ci.yml"
LINES = WORKFLOW.read_text(encoding="utf-8").splitlines()
MARKERS = {
    line.split(":", 1)[0]
    for line in tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"][
        "pytest"
    ]["ini_options"]["markers"]
}


def _jobs() -> dict[str, list[str]]:
    """Job id -> its lines (the block under ``jobs:`` indented by two spaces)."""
    start = LINES.index("jobs:")
    jobs: dict[str, list[str]] = {}
    current: list[str] = []
    for line in LINES[start + 1 :]:
        if re.fullmatch(r"  [A-Za-z0-9_-]+:", line):
            current = jobs.setdefault(line.strip()[:-1], [])
        elif line and not line.startswith(" "):
            break
        else:
            current.append(line)
    return jobs


def _run_commands(lines: list[str]) -> list[str]:
    """Every command line of the job's ``run:`` steps (single lines and ``|`` blocks)."""
    commands: list[str] = []
    block_indent: int | None = None
    for line in lines:
        indent = len(line) - len(line.lstrip())
        if block_indent is not None:
            if line.strip() and indent > block_indent:
                commands.append(line.strip())
                continue
            block_indent = None
        match = re.match(r"\s*(?:- )?run: (.*)$", line)
        if match:
            if match.group(1).strip() == "|":
                block_indent = indent
            else:
                commands.append(match.group(1).strip())
    return commands


JOBS = _jobs()


def test_the_three_jobs_are_there() -> None:
    assert set(JOBS) == {"test", "vcan", "ros2"}
    for lines in JOBS.values():
        assert any(line.strip().startswith("runs-on: ubuntu-latest") for line in lines)
        assert any(line.strip().startswith("timeout-minutes:") for line in lines)
    assert "permissions:" in LINES


def test_every_action_is_pinned_by_commit_with_its_release_named() -> None:
    uses = [line for line in LINES if re.match(r"\s*(- )?uses:", line)]
    assert uses
    for line in uses:
        assert re.fullmatch(
            r"\s*(- )?uses: [\w.-]+/[\w.-]+@[0-9a-f]{40}  # v\d+\.\d+\.\d+", line
        ), f"not pinned by a full commit SHA with '# vX.Y.Z': {line.strip()}"
    # The same action is pinned to the same commit everywhere.
    pins: dict[str, set[str]] = {}
    for line in uses:
        action, sha = line.split("uses: ", 1)[1].split("  #")[0].split("@")
        pins.setdefault(action, set()).add(sha)
    assert all(len(shas) == 1 for shas in pins.values()), pins


@pytest.mark.parametrize("job", sorted(JOBS))
def test_every_file_a_job_runs_exists(job: str) -> None:
    commands = _run_commands(JOBS[job])
    assert commands
    referenced = [
        path
        for command in commands
        for path in re.findall(r"(?:src/rover_hil/)?((?:\.ci|udev|tests)/[\w./-]+)", command)
    ]
    assert referenced or job == "ros2"
    for path in referenced:
        assert (ROOT / path).is_file(), f"{job}: {path} does not exist"


@pytest.mark.parametrize("job", sorted(JOBS))
def test_selected_markers_are_the_suites(job: str) -> None:
    for command in _run_commands(JOBS[job]):
        _, found, pytest_args = command.partition("-m pytest ")
        for marker in re.findall(r"-m (\w+)", pytest_args) if found else []:
            assert marker in MARKERS, f"{job}: unknown marker {marker}"


def test_the_test_job_runs_the_test_command() -> None:
    assert any(c.endswith("bash .ci/test") for c in _run_commands(JOBS["test"]))


def test_the_vcan_job_brings_vcan0_up_and_fails_loudly_without_it() -> None:
    commands = _run_commands(JOBS["vcan"])
    assert 'sudo apt-get install -y "linux-modules-extra-$(uname -r)"' in commands
    assert "sudo bash udev/vcan-up.sh" in commands
    pytest_runs = [c for c in commands if "pytest" in c]
    assert len(pytest_runs) == 1
    assert "ROVER_REQUIRE_SOCKETCAN=1" in pytest_runs[0]
    assert "-m socketcan" in pytest_runs[0]
    # vcan-up.sh comes before the tests, so a kernel without vcan stops the job there.
    assert commands.index("sudo bash udev/vcan-up.sh") < commands.index(pytest_runs[0])


def test_the_ros2_job_builds_installs_and_runs_rclpy_and_launch_tests() -> None:
    lines = JOBS["ros2"]
    assert "    container: ros:jazzy" in lines
    commands = _run_commands(lines)
    assert any(c.startswith("rosdep install --from-paths src") for c in commands)
    assert any(c.startswith("colcon build --packages-select rover_hil") for c in commands)
    assert any("pytest -m rclpy" in c for c in commands)
    assert "launch_test src/rover_hil/tests/bridge/launch_hil.py" in commands
    assert "          path: src/rover_hil" in lines


# What the ros:jazzy image (ros-base on Ubuntu noble; osrf/docker_images,
# ros/jazzy/ubuntu/noble/ros-core and ros-base Dockerfiles) has: bash and coreutils,
# apt-get, git, rosdep (initialised), colcon, python3 and the ROS 2 base (ros2, after
# sourcing). It runs as root and has no sudo, no pip and no ensurepip (venv).
ROS_JAZZY_IMAGE = {
    "apt-get",
    "cd",
    "colcon",
    "git",
    "grep",
    "python3",
    "ros2",
    "rosdep",
    "source",
    "tee",
    "test",
}
FROM_APT = {
    "pip3": "python3-pip",
    "python3 -m pip": "python3-pip",
    "python3 -m venv": "python3-venv",
}
"""Commands the image lacks, by the Debian package that brings them."""
FROM_ROSDEP = {"launch_test": "launch_testing"}
"""Commands that package.xml's dependencies bring, through ``rosdep install``."""


def _simple_commands(command: str) -> list[list[str]]:
    """The words of each simple command in a shell line (split at ``|``, ``&&``, ``;``),
    leading ``NAME=value`` assignments dropped."""
    out = []
    for part in re.split(r"\|\||&&|;|\|", command):
        words = part.split()
        while words and re.fullmatch(r"[A-Za-z_]\w*=\S*", words[0]):
            words.pop(0)
        if words:
            out.append(words)
    return out


def _command_key(words: list[str]) -> str:
    if words[0].endswith("python3") and words[1:2] == ["-m"] and len(words) > 2:
        return f"python3 -m {words[2]}"
    return words[0]


def _not_in_image(commands: list[str]) -> list[str]:
    """The commands of a ros:jazzy job that would not exist when they run: neither in the
    image nor installed by an earlier ``apt-get install`` or ``rosdep install`` of the job
    (a venv's commands count once the venv is made)."""
    depends = set(
        re.findall(r"<\w*depend>([\w-]+)</\w*depend>", (ROOT / "package.xml").read_text())
    )
    installed: set[str] = set()
    rosdep_ran = venv_made = False
    problems = []
    for command in commands:
        for words in _simple_commands(command):
            key = _command_key(words)
            if words[0].startswith(".venv/bin/"):
                ok, need = venv_made, "a venv made before"
            elif key in FROM_APT:
                ok, need = FROM_APT[key] in installed, f"apt-get install {FROM_APT[key]} before"
            elif key in FROM_ROSDEP:
                ok = rosdep_ran and FROM_ROSDEP[key] in depends
                need = f"rosdep install of {FROM_ROSDEP[key]} (package.xml) before"
            else:
                ok, need = key in ROS_JAZZY_IMAGE, f"{key}, which ros:jazzy lacks"
            if not ok:
                problems.append(f"{command!r} needs {need}")
            if words[:2] == ["apt-get", "install"]:
                installed.update(w for w in words[2:] if not w.startswith("-"))
            rosdep_ran = rosdep_ran or words[:2] == ["rosdep", "install"]
            venv_made = venv_made or key == "python3 -m venv"
    return problems


def test_the_ros2_job_uses_only_what_the_image_has_or_installs_first() -> None:
    assert _not_in_image(_run_commands(JOBS["ros2"])) == []


def test_the_image_check_catches_what_the_image_lacks() -> None:
    job = [
        "      - run: |",
        "          rosdep install --from-paths src --ignore-src -y",
        "          apt-get install -y --no-install-recommends python3-pip",
        "          python3 -m venv --system-site-packages .venv",
        "          .venv/bin/python -m pytest -m rclpy",
        "          sudo launch_test x.py",
        "      - run: ros2 pkg executables rover_hil | grep -q rover_bridge",
    ]
    assert _not_in_image(_run_commands(job)) == [
        "'python3 -m venv --system-site-packages .venv' needs apt-get install python3-venv before",
        "'sudo launch_test x.py' needs sudo, which ros:jazzy lacks",
    ]
