"""``rover devices`` and ``rover udev``: what is plugged in, and our udev files.

Two ``rover.commands`` entry points (:func:`register`, :func:`register_udev`); handlers
import their modules, so ``rover --help`` stays fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

__all__ = ["register", "register_udev"]


def register(subparsers: Any) -> None:
    """Add ``rover devices``."""
    parser = subparsers.add_parser(
        "devices",
        help="list serial ports and CAN interfaces, and which of our udev rules names each",
        description=(
            "List serial ports (pyserial list_ports: vid:pid, serial number, manufacturer, "
            "product, USB port, /dev/serial/by-id links) and CAN interfaces (/sys/class/net, "
            "type 280: driver, state, bitrate), which of our udev rules (udev/) would match "
            "each, whether /dev/rover-motor exists and where it points, and whether our "
            "files are installed. Exits 0 when it could look, whatever it found."
        ),
        epilog="examples: rover devices | rover devices --json | jq .summary",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    parser.add_argument(
        "--source",
        metavar="DIR",
        help="our udev files (default: $ROVER_UDEV_DIR, else udev/ of this checkout)",
    )
    parser.add_argument(
        "--rules-dir",
        type=Path,
        metavar="DIR",
        help="where installed rules are looked for (default: /etc/udev/rules.d)",
    )
    parser.add_argument(
        "--network-dir",
        type=Path,
        metavar="DIR",
        help="where installed networkd files are looked for (default: /etc/systemd/network)",
    )
    parser.set_defaults(func=_cmd_devices)


def register_udev(subparsers: Any) -> None:
    """Add ``rover udev`` with ``check`` and ``install``."""
    parser = subparsers.add_parser(
        "udev",
        help="check and install our udev rules and networkd files",
        description=(
            "Our udev rules (stable /dev/rover-motor, rovercan0) and systemd-networkd "
            "files, in udev/ of the checkout or share/rover_hil/udev of an install. See "
            "udev/README.md."
        ),
    )
    sub = parser.add_subparsers(dest="udev_command", metavar="ACTION")
    sub.required = True

    p = sub.add_parser(
        "check",
        help="check rules files with udev's own parser (udevadm verify, or udevadm test)",
        description=(
            "Check udev rules files with udev itself: 'udevadm verify' (systemd 254+), or "
            "where udevadm has no verify (systemd 252, Debian 12) 'udevadm test' in a "
            "private mount namespace that sees only these rules and keeps what it writes. "
            "Prints every problem as FILE:LINE: MESSAGE and which check ran; exits 1 if "
            "udev found anything, or if neither check can run here."
        ),
    )
    p.add_argument("files", nargs="*", type=Path, metavar="FILE", help="default: udev/*.rules")
    p.add_argument(
        "--source",
        metavar="DIR",
        help=(
            "where our files are (default: $ROVER_UDEV_DIR, else the checkout's udev/, "
            "else the install's)"
        ),
    )
    p.add_argument(
        "--errors-only",
        action="store_true",
        help="ignore style issues (udevadm verify --no-style; systemd 252 reports none)",
    )
    p.set_defaults(func=_cmd_check)

    p = sub.add_parser(
        "install",
        help="install our rules and networkd files and reload udev",
        description=(
            "Copy our rules to the rules directory and our networkd files to the network "
            "directory, then reload: 'udevadm control --reload-rules', 'udevadm trigger "
            "--action=change --subsystem-match=tty' and 'networkctl reload' (if present). "
            "Every action is printed. All or nothing: it checks first (udev's check of the "
            "rules, "
            "write access, udevadm, root) and writes nothing if any check fails; if writing "
            "fails half-way, it restores what was there."
        ),
        epilog=(
            "examples:\n"
            "  sudo rover udev install --serial A10KZ4PB   # pin the controller's adapter\n"
            "  sudo rover udev install --bench             # any adapter (bench only)\n"
            "  rover udev install --dry-run\n"
            "  rover udev install --no-reload --rules-dir img/etc/udev/rules.d "
            "--network-dir img/etc/systemd/network"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--dry-run", action="store_true", help="print the plan, change nothing")
    p.add_argument(
        "--rules-dir",
        type=Path,
        metavar="DIR",
        help="where rules go (default: /etc/udev/rules.d)",
    )
    p.add_argument(
        "--network-dir",
        type=Path,
        metavar="DIR",
        help="where networkd files go (default: /etc/systemd/network)",
    )
    p.add_argument(
        "--bench",
        action="store_true",
        help="install the bench rules (any serial number) instead of the pinned ones",
    )
    p.add_argument(
        "--serial",
        metavar="SERIAL",
        help="fill REPLACE_ME_WITH_SERIAL in the installed pinned rules (see 'rover devices')",
    )
    p.add_argument(
        "--usb-port",
        metavar="PORT",
        help="fill REPLACE_ME_WITH_USB_PORT (CH340/CH341 rules), e.g. 1-1.2",
    )
    p.add_argument(
        "--no-reload",
        action="store_true",
        help="install without reloading udev (no udevadm: containers, image builds)",
    )
    p.add_argument(
        "--source",
        metavar="DIR",
        help=(
            "where our files are (default: $ROVER_UDEV_DIR, else the checkout's udev/, "
            "else the install's)"
        ),
    )
    p.set_defaults(func=_cmd_install)


def _source(args: argparse.Namespace) -> Path:
    from udev.install import source_dir

    return source_dir(args.source)


def _cmd_devices(args: argparse.Namespace) -> int:
    from udev.devices import inventory
    from udev.install import DEFAULT_NETWORK_DIR, DEFAULT_RULES_DIR, InstallError

    try:
        source: Path | None = _source(args)
    except InstallError as exc:
        if args.source is not None:
            raise
        print(f"rover devices: {exc}; rule verdicts left out", file=sys.stderr)
        source = None
    found = inventory(
        source=source,
        rules_dir=args.rules_dir or DEFAULT_RULES_DIR,
        network_dir=args.network_dir or DEFAULT_NETWORK_DIR,
    )
    if args.json:
        print(json.dumps(found.to_json(), indent=2))
    else:
        print(found.render())
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from udev.verify import verify_rules

    files = list(args.files) or sorted(_source(args).glob("*.rules"))
    if not files:
        raise ValueError("no rules files to check")
    result = verify_rules(files, style=not args.errors_only)
    for finding in result.findings:
        print(finding)
    verdict = f"{len(result.findings)} problem(s)" if result.findings else "OK"
    print(f"checked {len(files)} file(s) with {result.checker}: {verdict}")
    return 0 if result.ok else 1


def _cmd_install(args: argparse.Namespace) -> int:
    from udev.install import (
        DEFAULT_NETWORK_DIR,
        DEFAULT_RULES_DIR,
        execute,
        plan_install,
    )

    plan = plan_install(
        source=args.source,
        rules_dir=args.rules_dir or DEFAULT_RULES_DIR,
        network_dir=args.network_dir or DEFAULT_NETWORK_DIR,
        bench=args.bench,
        serial=args.serial,
        usb_port=args.usb_port,
        reload=not args.no_reload,
    )
    for note in plan.notes:
        print(f"note: {note}")
    if args.dry_run:
        print("dry run: nothing is changed")
        for line in plan.lines(dry_run=True):
            print(line)
        if plan.problems:
            print("the install would fail, writing nothing:", file=sys.stderr)
            for problem in plan.problems:
                print(f"  {problem}", file=sys.stderr)
            return 1
        return 0
    execute(plan, out=print)
    print("done")
    return 0
