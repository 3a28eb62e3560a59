#!/usr/bin/env bash
# Bring up a SocketCAN virtual CAN interface (vcan0) for CI and benches; idempotent.
# When the kernel cannot, say exactly why and how to fix it. Run with --help.
set -euo pipefail

prog=$(basename "$0")
name=vcan0

usage() {
    cat <<EOF
Usage: $prog [--name IFACE] [-h|--help]

Bring up a virtual CAN interface for CI and bench tests: load the vcan kernel module
(modprobe vcan), create the interface (ip link add dev IFACE type vcan) and set it up
(ip link set up IFACE). Idempotent: an interface that is already vcan is only set up.
Needs root (CAP_NET_ADMIN).

Options:
  --name IFACE   interface name (default: vcan0)
  -h, --help     show this help and exit

Exit status:
  0  IFACE is a vcan interface and up
  1  any other failure (the message says which)
  2  usage error
  3  not run as root
  4  the running kernel cannot do it: no vcan module, or no SocketCAN (AF_CAN);
     the message says which, and how to fix it
  6  IFACE exists but is not a vcan interface

Examples:
  sudo udev/vcan-up.sh
  sudo udev/vcan-up.sh --name vcan1
EOF
}

# die STATUS LINE...: every line on stderr, prefixed with the script name.
die() {
    local status=$1
    shift
    local line
    for line in "$@"; do
        echo "$prog: $line" >&2
    done
    exit "$status"
}

while (($#)); do
    case $1 in
    -h | --help)
        usage
        exit 0
        ;;
    --name)
        (($# >= 2)) || die 2 "error: --name needs an interface name" "try '$prog --help'"
        name=$2
        shift 2
        ;;
    --name=*)
        name=${1#--name=}
        shift
        ;;
    *)
        die 2 "error: unknown argument '$1'" "try '$prog --help'"
        ;;
    esac
done
# Linux interface names: 1..15 characters, no '/', no whitespace, not '.' or '..'.
if [[ ! $name =~ ^[A-Za-z0-9_.:-]{1,15}$ || $name == . || $name == .. ]]; then
    die 2 "error: '$name' is not a valid interface name (1-15 of A-Z a-z 0-9 _ . : -)"
fi

[ "$(id -u)" -eq 0 ] || die 3 \
    "error: must be run as root: creating a network interface needs CAP_NET_ADMIN" \
    "fix: sudo $0 --name $name"
command -v ip >/dev/null 2>&1 || die 1 \
    "error: 'ip' not found" "fix: install iproute2 (sudo apt-get install iproute2)"

kernel=$(uname -r)

# Why the kernel has no SocketCAN protocol, or nothing if it has one. /proc/net/can is
# per network namespace and appears once the can module is loaded or built in.
af_can_problem() {
    if [ -d /proc/net/can ]; then
        return 0
    fi
    if command -v modprobe >/dev/null 2>&1 && [ -e /proc/modules ]; then
        modprobe can >/dev/null 2>&1 || true
        modprobe can_raw >/dev/null 2>&1 || true
        [ -d /proc/net/can ] && return 0
        echo "SocketCAN (AF_CAN) is not available: 'modprobe can can_raw' did not provide it (no /proc/net/can)"
    else
        echo "the kernel has no SocketCAN (AF_CAN) protocol (no /proc/net/can)"
    fi
}

fix_lines() {
    echo "fix: on Ubuntu, install the extra modules of the running kernel, then retry:"
    echo "       sudo apt-get install linux-modules-extra-$kernel && sudo modprobe vcan"
    echo "     on Debian the vcan module ships with linux-image-$kernel; on other kernels"
    echo "     enable CONFIG_CAN, CONFIG_CAN_RAW and CONFIG_CAN_VCAN"
    if [ ! -e /proc/modules ]; then
        echo "     this kernel cannot load modules at all, so no package fixes it on this"
        echo "     machine: boot a kernel with CAN support, or run the CAN tests on"
        echo "     python-can's 'virtual' interface, which needs no kernel support"
    fi
}

bring_up() {
    local err
    if ! err=$(ip link set up dev "$name" 2>&1); then
        die 1 "error: 'ip link set up dev $name' failed: $err"
    fi
}

check_af_can() {
    local problem
    problem=$(af_can_problem)
    if [ -n "$problem" ]; then
        local lines=()
        mapfile -t lines < <(fix_lines)
        die 4 "error: $name is up, but $problem: CAN sockets cannot be opened" "${lines[@]}"
    fi
}

if [ -e "/sys/class/net/$name" ]; then
    if ip -details link show dev "$name" 2>/dev/null | grep -qw vcan; then
        bring_up
        check_af_can
        echo "$prog: $name already exists (vcan); it is up"
        exit 0
    fi
    die 6 "error: $name exists but is not a vcan interface:" \
        "$(ip -details link show dev "$name" 2>&1 | head -n 3)" \
        "fix: pick another name with --name, or remove it: sudo ip link del dev $name"
fi

modprobe_note=""
if [ ! -e /proc/modules ]; then
    modprobe_note="this kernel was built without loadable module support (no /proc/modules): vcan cannot be loaded, it would have to be built in (CONFIG_CAN_VCAN=y)"
elif ! command -v modprobe >/dev/null 2>&1; then
    modprobe_note="modprobe is not installed (package kmod), so vcan was not loaded"
elif [ ! -d "/lib/modules/$kernel" ]; then
    modprobe_note="no modules are installed for the running kernel (/lib/modules/$kernel is missing)"
elif ! out=$(modprobe vcan 2>&1); then
    modprobe_note="'modprobe vcan' failed: ${out:-no message}"
fi

if ! err=$(ip link add dev "$name" type vcan 2>&1); then
    case $err in
    *"Unknown device type"* | *"Operation not supported"* | *"not supported"*)
        lines=()
        [ -n "$modprobe_note" ] && lines+=("$modprobe_note")
        problem=$(af_can_problem)
        [ -n "$problem" ] && lines+=("$problem")
        mapfile -t -O "${#lines[@]}" lines < <(fix_lines)
        die 4 "error: no vcan module: the running kernel ($kernel) cannot create vcan interfaces ('ip link add dev $name type vcan': $err)" \
            "${lines[@]}"
        ;;
    *"Operation not permitted"*)
        die 1 "error: 'ip link add dev $name type vcan' was refused: $err" \
            "fix: this needs CAP_NET_ADMIN; in a container, run it privileged or with --cap-add NET_ADMIN"
        ;;
    *)
        die 1 "error: 'ip link add dev $name type vcan' failed: $err"
        ;;
    esac
fi
bring_up
check_af_can
echo "$prog: $name is up (vcan)"
