"""Our ``udev/`` files and how ``rover udev install`` puts them in place.

Rules (``*.rules``) go to ``/etc/udev/rules.d``, systemd-networkd files (``*.network``,
``*.link``, ``*.netdev``) to ``/etc/systemd/network``. ``X-bench.rules`` is the bench
variant of ``X.rules``: exactly one is installed, never both (both would claim
``/dev/rover-motor``). ``--serial`` and ``--usb-port`` fill the pinned rules'
placeholders (:data:`PLACEHOLDER_SERIAL`, :data:`PLACEHOLDER_USB_PORT`).

All or nothing: :func:`plan_install` checks everything first and lists the problems;
:func:`execute` refuses a plan with problems, stages every file beside its target,
renames them into place and on failure restores what it replaced; a failed reload
leaves the (valid) files. Without udevadm it refuses unless ``reload=False``
(``--no-reload``). udev/README.md, "Install".
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from udev.errors import UdevError
from udev.verify import CheckUnavailableError, verify_rules

__all__ = [
    "BENCH_SUFFIX",
    "DEFAULT_NETWORK_DIR",
    "DEFAULT_RULES_DIR",
    "ENV_SOURCE_DIR",
    "NETWORKD_SUFFIXES",
    "PLACEHOLDER_SERIAL",
    "PLACEHOLDER_USB_PORT",
    "ROS_PACKAGE",
    "FileAction",
    "InstallError",
    "InstallPlan",
    "SourceFile",
    "execute",
    "fill_placeholders",
    "plan_install",
    "source_dir",
    "source_files",
]

logger = logging.getLogger(__name__)

PLACEHOLDER_SERIAL = "REPLACE_ME_WITH_SERIAL"
PLACEHOLDER_USB_PORT = "REPLACE_ME_WITH_USB_PORT"
DEFAULT_RULES_DIR = Path("/etc/udev/rules.d")
DEFAULT_NETWORK_DIR = Path("/etc/systemd/network")
NETWORKD_SUFFIXES = (".network", ".link", ".netdev")
BENCH_SUFFIX = "-bench.rules"
#: Environment variable naming the source directory (after --source, before the defaults).
ENV_SOURCE_DIR = "ROVER_UDEV_DIR"
#: The ROS 2 package whose share directory an install puts ``udev/`` in (setup.py).
ROS_PACKAGE = "rover_hil"
INSTALLED_MODE = 0o644
RELOAD_TIMEOUT_S = 30.0
RELOAD_SKIPPED = (
    "reload skipped (--no-reload): run 'udevadm control --reload-rules && "
    "udevadm trigger --action=change --subsystem-match=tty' where udev runs"
)

Runner = Callable[[Sequence[str]], "subprocess.CompletedProcess[str]"]


class InstallError(UdevError):
    """The install was refused or failed; the message says why and what to do."""


@dataclass(frozen=True)
class SourceFile:
    """One file of the source directory: ``kind`` is ``rules`` or ``networkd``;
    ``variant`` is ``pinned`` or ``bench`` for a rules file that has both, else None."""

    path: Path
    kind: str
    variant: str | None = None

    @property
    def name(self) -> str:
        return self.path.name


def _installed_dirs(module_file: Path) -> list[tuple[str, Path]]:
    """Where an install put ``share/rover_hil/udev``: the ament index's (ROS 2 sourced),
    then the nearest ancestor of the module holding one (colcon, pip, venv alike)."""
    found: list[tuple[str, Path]] = []
    try:
        packages = importlib.import_module("ament_index_python.packages")
        share = packages.get_package_share_directory(ROS_PACKAGE)
    except (ImportError, LookupError, ValueError, OSError):  # no ROS 2 sourced, or not in it
        pass
    else:
        found.append(("the ament index", Path(share) / "udev"))
    for prefix in module_file.parents:
        share_udev = prefix / "share" / ROS_PACKAGE / "udev"
        if share_udev.is_dir():
            found.append(("the install prefix", share_udev))
            break
    return found


def _holds_rules(directory: Path) -> bool:
    """Whether ``directory`` holds udev rules files (not just this package's code)."""
    return any(directory.glob("*.rules"))


def source_dir(explicit: str | Path | None = None) -> Path:
    """The ``udev/`` source directory: ``explicit`` (``--source``), else
    ``$ROVER_UDEV_DIR``, else the first that exists of the checkout's ``udev/`` and the
    installed ``share/rover_hil/udev`` (:func:`_installed_dirs`).

    Raises:
        InstallError: the directory named, or every default, does not exist.
    """
    if explicit is not None:
        candidates = [("--source", Path(explicit))]
    elif os.environ.get(ENV_SOURCE_DIR):
        candidates = [(f"${ENV_SOURCE_DIR}", Path(os.environ[ENV_SOURCE_DIR]))]
    else:
        here = Path(__file__).resolve()
        # An installed package holds only the code, a checkout the rules too.
        candidates = [("the checkout", here.parent), *_installed_dirs(here)]
        candidates = [(o, p) for o, p in candidates if o != "the checkout" or _holds_rules(p)]
    for _origin, path in candidates:
        if path.is_dir():
            return path
    missing = "; ".join(
        f"udev source directory {path} (from {origin}) does not exist"
        for origin, path in candidates
    )
    raise InstallError(
        f"{missing}. Run from a checkout of rover-hil or an install of it "
        f"(share/{ROS_PACKAGE}/udev), or pass --source DIR, or set {ENV_SOURCE_DIR}"
    )


def source_files(directory: Path) -> list[SourceFile]:
    """The rules and networkd files of ``directory``, sorted by name (as udev reads them)."""
    names = {p.name for p in directory.iterdir() if p.is_file()}
    found: list[SourceFile] = []
    for name in sorted(names):
        path = directory / name
        if name.endswith(BENCH_SUFFIX):
            found.append(SourceFile(path, "rules", "bench"))
        elif name.endswith(".rules"):
            has_bench = name[: -len(".rules")] + BENCH_SUFFIX in names
            found.append(SourceFile(path, "rules", "pinned" if has_bench else None))
        elif name.endswith(NETWORKD_SUFFIXES):
            found.append(SourceFile(path, "networkd"))
    return found


def _bench_partner(name: str) -> str:
    if name.endswith(BENCH_SUFFIX):
        return name[: -len(BENCH_SUFFIX)] + ".rules"
    return name[: -len(".rules")] + BENCH_SUFFIX


_SERIAL_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._:-]{0,63}")
_USB_PORT_RE = re.compile(r"[0-9]+-[0-9]+(\.[0-9]+)*")


def fill_placeholders(text: str, serial: str | None = None, usb_port: str | None = None) -> str:
    """``text`` with the serial and USB-port placeholders replaced where given; raises
    ValueError for a value udev could not match literally or that does not look right.
    """
    if serial is not None:
        if not _SERIAL_RE.fullmatch(serial):
            raise ValueError(
                f"serial number {serial!r}: expected letters, digits and . _ : - "
                "(as 'rover devices' prints it)"
            )
        text = text.replace(PLACEHOLDER_SERIAL, serial)
    if usb_port is not None:
        if not _USB_PORT_RE.fullmatch(usb_port):
            raise ValueError(
                f"USB port {usb_port!r}: expected a port path such as 1-1.2 "
                "(the 'usb port' that 'rover devices' prints)"
            )
        text = text.replace(PLACEHOLDER_USB_PORT, usb_port)
    return text


@dataclass(frozen=True)
class FileAction:
    """One file to put in place; ``state`` is ``new``, ``replace`` or ``unchanged``."""

    source: Path
    target: Path
    content: bytes
    state: str


@dataclass(frozen=True)
class InstallPlan:
    """Everything an install would do, and why it cannot, if it cannot.

    ``commands`` run after the files are in place (reloads). ``problems`` make
    :func:`execute` refuse the plan; ``notes`` are printed and change nothing.
    """

    files: tuple[FileAction, ...]
    mkdirs: tuple[Path, ...]
    commands: tuple[tuple[str, ...], ...]
    notes: tuple[str, ...] = ()
    problems: tuple[str, ...] = ()
    skipped_reload: bool = False

    def lines(self, *, dry_run: bool) -> list[str]:
        """The actions, one line each, as :func:`execute` prints them."""
        would = "would " if dry_run else ""
        out = [f"{would}create directory {d}" for d in self.mkdirs]
        for action in self.files:
            if action.state == "unchanged":
                out.append(f"{action.target} is up to date ({action.source.name})")
            else:
                what = "replace" if action.state == "replace" else "install"
                out.append(f"{would}{what} {action.target} from {action.source} (mode 0644)")
        out.extend(f"{would}run: {' '.join(cmd)}" for cmd in self.commands)
        if self.skipped_reload:
            out.append(RELOAD_SKIPPED)
        return out


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _udev_check(
    rules: Sequence[tuple[SourceFile, str]], udevadm: str | None, notes: list[str]
) -> list[str]:
    """What udev finds wrong with ``rules`` as they would be installed, one
    ``FILE:LINE: message`` each (source file names); a note where udev cannot check."""
    if not rules:
        return []
    if udevadm is None:
        notes.append("the rules were not checked by udev here: udevadm not found")
        return []
    with tempfile.TemporaryDirectory(prefix="rover-udev-install-") as tmp:
        staged = {}
        for src, text in rules:
            path = Path(tmp, src.name)
            path.write_text(text, encoding="utf-8")
            staged[str(path)] = str(src.path)
        try:
            result = verify_rules(list(map(Path, staged)), udevadm=udevadm)
        except CheckUnavailableError as exc:
            notes.append(f"the rules were not checked by udev here: {exc}")
            return []
    return [f"{staged.get(f.path, f.path)}:{f.line}: {f.message}" for f in result.findings]


def plan_install(
    *,
    source: str | Path | None = None,
    rules_dir: Path = DEFAULT_RULES_DIR,
    network_dir: Path = DEFAULT_NETWORK_DIR,
    bench: bool = False,
    serial: str | None = None,
    usb_port: str | None = None,
    reload: bool = True,
    which: Callable[[str], str | None] = shutil.which,
    euid: Callable[[], int] = os.geteuid,
) -> InstallPlan:
    """Work out an install without changing anything (module docstring).

    Raises InstallError only when there is nothing to plan (no source directory, no
    files, bad ``serial``/``usb_port``); all else is in :attr:`InstallPlan.problems`.
    """
    directory = source_dir(source)
    if bench and (serial is not None or usb_port is not None):
        raise InstallError(
            "--serial and --usb-port fill the pinned rules; the bench rules match any unit"
        )
    wanted = [
        f
        for f in source_files(directory)
        if f.variant is None or f.variant == ("bench" if bench else "pinned")
    ]
    if not wanted:
        raise InstallError(f"no .rules or networkd files in {directory}")
    problems: list[str] = []
    notes: list[str] = []
    files: list[FileAction] = []
    to_check: list[tuple[SourceFile, str]] = []
    for src in wanted:
        target_dir = rules_dir if src.kind == "rules" else network_dir
        text = src.path.read_text(encoding="utf-8")
        if src.kind == "rules":
            try:
                text = fill_placeholders(text, serial, usb_port)
            except ValueError as exc:
                raise InstallError(str(exc)) from None
            to_check.append((src, text))
            if PLACEHOLDER_SERIAL in text:
                notes.append(
                    f"{src.name} still has {PLACEHOLDER_SERIAL}: its rules pinned by serial "
                    f"number match nothing until it is set (edit {src.path}, or pass "
                    "--serial SERIAL; 'rover devices' shows it)"
                )
            if PLACEHOLDER_USB_PORT in text:
                notes.append(
                    f"{src.name} still has {PLACEHOLDER_USB_PORT}: its rules pinned by USB "
                    "port (for chips without a serial number) match nothing; fine unless the "
                    "controller is on such a chip, then pass --usb-port PORT"
                )
            if src.variant is not None:
                partner = target_dir / _bench_partner(src.name)
                if partner.exists():
                    problems.append(
                        f"{partner} is installed: it and {src.name} would both claim "
                        f"/dev/rover-motor; remove it first (sudo rm {partner})"
                    )
        content = text.encode("utf-8")
        target = target_dir / src.name
        if target.is_file():
            state = "unchanged" if target.read_bytes() == content else "replace"
        elif target.exists():
            problems.append(f"{target} exists and is not a regular file")
            state = "replace"
        else:
            state = "new"
        files.append(FileAction(src.path, target, content, state))
    problems.extend(_udev_check(to_check, which("udevadm"), notes))

    mkdirs: list[Path] = []
    root = euid() == 0
    for target_dir in sorted({a.target.parent for a in files}):
        if target_dir.exists() and not target_dir.is_dir():
            problems.append(f"{target_dir} exists and is not a directory")
            continue
        if not target_dir.exists():
            mkdirs.append(target_dir)
        anchor = _nearest_existing(target_dir)
        if not os.access(anchor, os.W_OK):
            if root:
                problems.append(f"cannot write to {anchor} (read-only file system?)")
            else:
                problems.append(
                    f"cannot write to {anchor}: not root; run 'sudo rover udev install' "
                    "(or install into a directory you own with --rules-dir/--network-dir)"
                )

    commands: list[tuple[str, ...]] = []
    rules_change = any(a.state != "unchanged" and a.target.suffix == ".rules" for a in files)
    network_change = any(a.state != "unchanged" and a.target.suffix != ".rules" for a in files)
    if reload:
        udevadm = which("udevadm")
        if udevadm is None:
            problems.append(
                "udevadm not found: udev is not installed or not on PATH (containers and CI "
                "runners often lack it), so the rules could not be reloaded. Pass --no-reload "
                "to install the files anyway and reload later where udev runs"
            )
        elif not root:
            problems.append("reloading udev needs root: run 'sudo rover udev install'")
        elif rules_change:
            commands.append((udevadm, "control", "--reload-rules"))
            commands.append((udevadm, "trigger", "--action=change", "--subsystem-match=tty"))
        networkctl = which("networkctl")
        if network_change:
            if networkctl is None:
                notes.append(
                    "networkctl not found: the .network file needs systemd-networkd; "
                    "without it, bring CAN up with udev/can-up.sh"
                )
            elif root and udevadm is not None:
                commands.append((networkctl, "reload"))
    if any(a.target.name.endswith("can.rules") and a.state != "unchanged" for a in files):
        notes.append(
            "CAN interfaces are renamed only when they appear: replug the USB-CAN adapter "
            "(or reboot) to get rovercan0"
        )
    return InstallPlan(
        files=tuple(files),
        mkdirs=tuple(mkdirs),
        commands=tuple(commands),
        notes=tuple(notes),
        problems=tuple(problems),
        skipped_reload=not reload and (rules_change or network_change),
    )


def _run(cmd: Sequence[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        list(cmd), capture_output=True, text=True, timeout=RELOAD_TIMEOUT_S, check=False
    )


@dataclass
class _Transaction:
    created_dirs: list[Path] = field(default_factory=list)
    staged: dict[Path, Path] = field(default_factory=dict)  # target -> temp file
    committed: list[tuple[Path, bytes | None]] = field(default_factory=list)

    def rollback(self) -> None:
        for tmp in self.staged.values():
            with contextlib.suppress(OSError):
                tmp.unlink()
        for target, previous in reversed(self.committed):
            try:
                if previous is None:
                    target.unlink()
                else:
                    target.write_bytes(previous)
            except OSError as exc:  # pragma: no cover - best effort, reported
                logger.error("rollback of %s failed: %s", target, exc)
        for directory in reversed(self.created_dirs):
            with contextlib.suppress(OSError):
                directory.rmdir()


def execute(
    plan: InstallPlan,
    *,
    out: Callable[[str], object] = print,
    run: Runner = _run,
) -> None:
    """Carry out ``plan``, printing every action through ``out`` as it happens.

    Raises InstallError, before changing anything, if the plan has problems; after
    rolling back, if a file cannot be put in place; and after the files are in place,
    if a reload command fails (the files then stay; the message says what to run).
    """
    if plan.problems:
        raise InstallError("nothing was installed:\n" + "\n".join(f"  {p}" for p in plan.problems))
    tx = _Transaction()
    to_write = [a for a in plan.files if a.state != "unchanged"]
    try:
        for directory in plan.mkdirs:
            out(f"create directory {directory}")
            missing = []
            probe = directory
            while not probe.exists():
                missing.append(probe)
                probe = probe.parent
            directory.mkdir(parents=True)
            tx.created_dirs.extend(reversed(missing))
        for action in to_write:
            fd, name = tempfile.mkstemp(
                dir=action.target.parent, prefix=f".{action.target.name}.", suffix=".tmp"
            )
            tx.staged[action.target] = Path(name)
            with os.fdopen(fd, "wb") as fh:
                fh.write(action.content)
                fh.flush()
                os.fchmod(fh.fileno(), INSTALLED_MODE)
        for action in plan.files:
            if action.state == "unchanged":
                out(f"{action.target} is up to date ({action.source.name})")
                continue
            previous = action.target.read_bytes() if action.target.is_file() else None
            what = "replace" if previous is not None else "install"
            out(f"{what} {action.target} from {action.source} (mode 0644)")
            os.replace(tx.staged[action.target], action.target)
            del tx.staged[action.target]
            tx.committed.append((action.target, previous))
    except BaseException as exc:
        tx.rollback()
        if isinstance(exc, OSError):
            raise InstallError(
                f"install failed and was rolled back, nothing changed: {exc}"
            ) from exc
        raise
    for cmd in plan.commands:
        out(f"run: {' '.join(cmd)}")
        try:
            result = run(cmd)
        except (OSError, subprocess.SubprocessError) as exc:
            raise InstallError(
                f"the files are installed, but '{' '.join(cmd)}' could not run: {exc}; "
                "run it by hand"
            ) from exc
        if result.returncode != 0:
            detail = (result.stderr or result.stdout or "").strip()
            raise InstallError(
                f"the files are installed, but '{' '.join(cmd)}' failed with status "
                f"{result.returncode}: {detail or 'no message'}; run it by hand"
            )
    if plan.skipped_reload:
        out(RELOAD_SKIPPED)
