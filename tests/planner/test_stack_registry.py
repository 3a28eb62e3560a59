"""The stacks' registry (planner/stack/domains.py) is this user's alone: created 0700,
its files 0600 and never followed through a link; a directory that another user owns,
that others may write or that is a link is refused with a clear error; the console's
token is found there by the console's URL (docs/commands.md, "The stack's console")."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from planner.errors import StackRegistryError
from planner.ground.console_client import CONSOLE_ENV
from planner.stack import domains


def _mode(path: Path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


@pytest.fixture
def registry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Where the registry goes for this test (not yet made)."""
    path = tmp_path / "stacks"
    monkeypatch.setenv(domains.DIR_ENV, str(path))
    return path


def test_the_registry_and_its_files_are_private(registry: Path) -> None:
    with domains.claim() as held:
        held.publish({"env": {CONSOLE_ENV: "http://127.0.0.1:4242"}, domains.TOKEN_KEY: "t0k"})
        assert _mode(registry) == 0o700
        files = sorted(registry.iterdir())
        assert [f.name for f in files] == [
            f"domain-{held.domain}.json",
            f"domain-{held.domain}.lock",
        ]
        assert all(_mode(f) == 0o600 for f in files)
        assert domains.console_token("http://127.0.0.1:4242") == "t0k"
        assert domains.console_token("http://localhost:4242/") == "t0k"  # either name
        assert domains.console_token("http://127.0.0.1:4243") is None
        assert domains.console_token("not a url") is None
    assert domains.console_token("http://127.0.0.1:4242") is None  # the stack is gone


def test_the_runtime_directory_is_the_default(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(domains.DIR_ENV, raising=False)
    monkeypatch.setenv(domains.RUNTIME_ENV, str(tmp_path))
    assert domains.registry_dir() == tmp_path / "rover-stacks"
    assert _mode(tmp_path / "rover-stacks") == 0o700


def test_a_directory_others_may_write_is_refused(registry: Path) -> None:
    registry.mkdir(mode=0o700)
    os.chmod(registry, 0o777)
    with pytest.raises(StackRegistryError, match="has mode 0777: other users may have put"):
        domains.registry_dir()
    with pytest.raises(StackRegistryError, match=f"set {domains.DIR_ENV} to a directory"):
        domains.running()
    assert list(registry.iterdir()) == []  # nothing written in it


def test_a_directory_of_mine_others_may_read_is_made_private(registry: Path) -> None:
    registry.mkdir(mode=0o700)
    os.chmod(registry, 0o755)
    (registry / "domain-101.json").write_text("{}")
    os.chmod(registry / "domain-101.json", 0o644)
    assert domains.registry_dir() == registry
    assert _mode(registry) == 0o700


def test_a_link_is_refused(registry: Path, tmp_path: Path) -> None:
    target = tmp_path / "elsewhere"
    target.mkdir(mode=0o700)
    registry.symlink_to(target)
    with pytest.raises(StackRegistryError, match="is a symbolic link"):
        domains.registry_dir()


@pytest.mark.skipif(os.geteuid() != 0, reason="only root can give a directory to another user")
def test_a_directory_squatted_by_another_user_is_refused(registry: Path) -> None:
    registry.mkdir(mode=0o700)
    os.chown(registry, 4242, 4242)
    with pytest.raises(StackRegistryError, match="belongs to uid 4242, not to you"):
        domains.registry_dir()
    with pytest.raises(StackRegistryError, match="belongs to uid 4242"), domains.claim():
        pass


@pytest.mark.skipif(os.geteuid() != 0, reason="only root can give a file to another user")
def test_an_endpoints_file_of_another_user_is_ignored(registry: Path) -> None:
    with domains.claim() as held:
        held.publish({"env": {CONSOLE_ENV: "http://127.0.0.1:4242"}, domains.TOKEN_KEY: "t0k"})
        os.chown(registry / f"domain-{held.domain}.json", 4242, 4242)
        assert domains.running() == []
        assert domains.console_token("http://127.0.0.1:4242") is None


def test_an_endpoints_file_planted_as_a_link_is_not_followed(
    registry: Path, tmp_path: Path
) -> None:
    planted = tmp_path / "planted.json"
    planted.write_text('{"domain": 101, "env": {}, "console_token": "theirs"}')
    with domains.claim() as held:
        link = registry / f"domain-{held.domain}.json"
        link.symlink_to(planted)
        assert domains.running() == []
        held.publish({"env": {}})  # replaces the link, writes nothing through it
        assert not link.is_symlink() and "theirs" in planted.read_text()
