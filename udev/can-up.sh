#!/usr/bin/env bash
# Configure a real CAN interface (the rover's USB-CAN adapter) at a bitrate and bring it
# up; say exactly what is wrong when it cannot. Run with --help.
set -euo pipefail

prog=$(basename "$0")
name=rovercan0
bitrate=500000
restart_ms=100

usage() {
    cat <<EOF
Usage: $prog [IFACE] [--bitrate BPS] [--restart-ms MS] [-h|--help]

Configure a CAN interface and bring it up, the same as systemd-networkd does with
udev/80-rovercan0.network:
  ip link set dev IFACE down
  ip link set dev IFACE type can bitrate BPS restart-ms MS
  ip link set dev IFACE up
A vcan interface has no bitrate: it is only set up. Needs root (CAP_NET_ADMIN).

Arguments:
  IFACE              interface (default: rovercan0, the name udev/70-rover-can.rules gives)
  --bitrate BPS      bits per second, 10000..1000000; suffixes k and M accepted
                     (default: 500000; every node on the bus must use the same)
  --restart-ms MS    restart the controller MS ms after bus-off; 0 disables (default: 100)
  -h, --help         show this help and exit

Exit status:
  0  IFACE is configured and up
  1  any other failure (the message says which)
  2  usage error
  3  not run as root
  5  IFACE does not exist (the message lists the CAN interfaces there are)
  6  IFACE is not a CAN interface

Examples:
  sudo udev/can-up.sh                          # rovercan0 at 500 kbit/s
  sudo udev/can-up.sh can0 --bitrate 1M --restart-ms 0
EOF
}

die() {
    local status=$1
    shift
    local line
    for line in "$@"; do
        echo "$prog: $line" >&2
    done
    exit "$status"
}

# parse_bitrate TEXT: print bits per second, or fail.
parse_bitrate() {
    local text=$1 number scale=1
    case $text in
    *k | *K) number=${text%[kK]} scale=1000 ;;
    *M) number=${text%M} scale=1000000 ;;
    *) number=$text ;;
    esac
    [[ $number =~ ^[0-9]+$ ]] || return 1
    local value=$((10#$number * scale))
    ((value >= 10000 && value <= 1000000)) || return 1
    echo "$value"
}

name_given=0
while (($#)); do
    case $1 in
    -h | --help)
        usage
        exit 0
        ;;
    --bitrate | --restart-ms)
        (($# >= 2)) || die 2 "error: $1 needs a value" "try '$prog --help'"
        if [ "$1" = --bitrate ]; then
            bitrate=$(parse_bitrate "$2") || die 2 \
                "error: --bitrate '$2' is not a classic CAN bitrate (10000..1000000, e.g. 500000 or 500k)"
        else
            [[ $2 =~ ^[0-9]+$ ]] || die 2 "error: --restart-ms '$2' is not a whole number of milliseconds"
            restart_ms=$2
        fi
        shift 2
        ;;
    -*)
        die 2 "error: unknown option '$1'" "try '$prog --help'"
        ;;
    *)
        ((name_given == 0)) || die 2 "error: more than one interface given ('$name', '$1')"
        name=$1
        name_given=1
        shift
        ;;
    esac
done
if [[ ! $name =~ ^[A-Za-z0-9_.:-]{1,15}$ || $name == . || $name == .. ]]; then
    die 2 "error: '$name' is not a valid interface name (1-15 of A-Z a-z 0-9 _ . : -)"
fi

[ "$(id -u)" -eq 0 ] || die 3 \
    "error: must be run as root: configuring a network interface needs CAP_NET_ADMIN" \
    "fix: sudo $0 $name --bitrate $bitrate"
command -v ip >/dev/null 2>&1 || die 1 \
    "error: 'ip' not found" "fix: install iproute2 (sudo apt-get install iproute2)"

# CAN interfaces present (ARPHRD_CAN = 280), space separated.
can_interfaces() {
    local dev found=()
    for dev in /sys/class/net/*; do
        [ -r "$dev/type" ] && [ "$(cat "$dev/type")" = 280 ] && found+=("${dev##*/}")
    done
    if ((${#found[@]})); then
        echo "${found[*]}"
    else
        echo "none"
    fi
}

if [ ! -e "/sys/class/net/$name" ]; then
    present=$(can_interfaces)
    lines=()
    if [ "$present" != none ]; then
        lines+=("CAN interfaces present: $present")
    else
        lines+=("there are no CAN interfaces at all")
    fi
    if [ ! -d /proc/net/can ] && [ ! -e /proc/modules ]; then
        lines+=("this kernel has no SocketCAN (AF_CAN) and cannot load modules: no USB-CAN adapter can work here")
    fi
    lines+=("check: is the adapter plugged in and powered? 'lsusb' should list it (candleLight 1d50:606f or 1209:2323, PEAK 0c72:000c/0012)")
    lines+=("check: did its driver bind? 'dmesg | grep -i -e gs_usb -e peak_usb'; on Ubuntu these modules are in linux-modules-extra-$(uname -r)")
    lines+=("check: named rovercan0 only once udev/70-rover-can.rules is installed ('rover udev install') and the adapter replugged")
    die 5 "error: interface $name does not exist" "${lines[@]}"
fi

type=$(cat "/sys/class/net/$name/type" 2>/dev/null || echo "?")
if [ "$type" != 280 ]; then
    die 6 "error: $name is not a CAN interface (ARPHRD type $type, CAN is 280)" \
        "CAN interfaces present: $(can_interfaces)"
fi

run() {
    local err
    if ! err=$("$@" 2>&1); then
        local hint=()
        case $err in
        *"Invalid argument"*) hint=("the controller cannot produce $bitrate bit/s from its clock, or rejects restart-ms $restart_ms") ;;
        *"Operation not supported"*) hint=("the driver does not support this setting") ;;
        *"Operation not permitted"*) hint=("needs CAP_NET_ADMIN; in a container, run it privileged or with --cap-add NET_ADMIN") ;;
        *"Device or resource busy"*) hint=("the interface is still up or in use; stop what uses it and retry") ;;
        esac
        die 1 "error: '$*' failed: $err" "${hint[@]}"
    fi
}

if ip -details link show dev "$name" 2>/dev/null | grep -qw vcan; then
    run ip link set dev "$name" up
    echo "$prog: $name is vcan (no bitrate to set); it is up"
    exit 0
fi

echo "$prog: ip link set dev $name down"
run ip link set dev "$name" down
echo "$prog: ip link set dev $name type can bitrate $bitrate restart-ms $restart_ms"
run ip link set dev "$name" type can bitrate "$bitrate" restart-ms "$restart_ms"
echo "$prog: ip link set dev $name up"
run ip link set dev "$name" up
ip -details link show dev "$name"
