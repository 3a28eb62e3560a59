"""The C firmware core (firmware_proto/wire/c/fw/) as C: it builds freestanding with no libc
calls and no floating point, its receive path survives fuzzing under ASan and UBSan (an
ideal plant, and a varied one: fuzz_fw_plant.c built with gcc; test_libfuzzer.py runs
both under libFuzzer), the cases of issue #22 hold (fw/tests/cases_fw.c: INT32_MIN
readings, a step across the encoder counter's wrap, fw_init's refusals), and
it cross-builds for a Cortex-M0+ (within 16 KiB of flash and 2 KiB of RAM) and an
ATmega2560, with -Wall -Wextra -Werror, reporting the sizes ``size`` gives; its self-test
(a scripted host, an ideal plant) passes on the host, on the ATmega2560 under simavr and
on a Cortex-M0 under qemu-system-arm, which also give the cost of fw_tick.

The cross compilers are Debian's ``gcc-arm-none-eabi`` (with ``libnewlib-arm-none-eabi``)
and ``gcc-avr`` (with ``avr-libc``), ``simavr`` and ``qemu-system-arm``, which
``.ci/bootstrap --test`` installs. Without
them these tests skip, saying why; with ``ROVER_REQUIRE_CROSS=1`` (set by CI) a missing
cross compiler fails them instead.
"""

from __future__ import annotations

import os
import random
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.cbuild import compile_cached
from tests.firmware_proto.c_harness import C_DIR, SANITIZER_ENV, SANITIZERS, WARNINGS, compiler
from tests.firmware_proto.fuzz_seeds import CORPORA, fw_traffic

pytestmark = pytest.mark.firmware

FW_DIR = C_DIR / "fw"
CORE = (FW_DIR / "fw.c", C_DIR / "rover_msgs.c", C_DIR / "rover_proto.c")
SELFTEST = FW_DIR / "port_bare" / "selftest.c"
REQUIRE_CROSS_ENV = "ROVER_REQUIRE_CROSS"
M0_FLASH_BYTES = 16 * 1024
M0_RAM_BYTES = 2 * 1024


def _cc() -> str:
    cc = compiler()
    if cc is None:
        pytest.skip("gcc not found (set CC): the firmware core cannot be built here")
    return cc


def _run(cmd: list[str], **kw: object) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False, **kw)  # type: ignore[call-overload]
    assert done.returncode == 0 and not done.stderr.strip(), f"{cmd}\n{done.stdout}{done.stderr}"
    return done  # type: ignore[no-any-return]


def _build(cmd: list[str]) -> None:
    """A compiler command, from the test builds' cache when its inputs are unchanged
    (tests/cbuild.py): it must succeed and print nothing."""
    done = compile_cached(cmd, timeout_s=300)
    assert done.returncode == 0 and not done.stderr.strip(), f"{cmd}\n{done.stdout}{done.stderr}"


def test_the_core_builds_freestanding_without_libc_or_floating_point(tmp_path: Path) -> None:
    cc = _cc()
    objects = []
    for src in CORE:
        obj = tmp_path / (src.stem + ".o")
        # -mgeneral-regs-only: any float or double in the code is a compile error.
        _build(
            [
                cc,
                *WARNINGS,
                "-O2",
                "-ffreestanding",
                "-mgeneral-regs-only",
                "-c",
                str(src),
                "-o",
                str(obj),
            ]
        )
        objects.append(obj)
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("nm (binutils) not found: the undefined symbols are not listed")
    undefined = set(_run([nm, "-u", str(objects[0])]).stdout.split()) - {"U"}
    ours = {s for s in undefined if s.startswith(("fw_hal_", "rp_"))}
    # The HAL and the codec, and nothing else (a struct copy may become memcpy).
    assert undefined - ours <= {"memcpy", "memset"}, undefined - ours
    assert {s for s in ours if s.startswith("fw_hal_")} == {
        "fw_hal_set_wheels",
        "fw_hal_read_encoders",
        "fw_hal_read_wheel_speeds",
        "fw_hal_read_imu",
        "fw_hal_pose_sample",
        "fw_hal_pose_read",
        "fw_hal_boot_nonce",
        "fw_hal_write",
        "fw_hal_can_send",
    }


def test_fuzzing_fw_on_bytes_and_fw_on_can_under_asan_and_ubsan_finds_nothing(
    tmp_path: Path,
) -> None:
    cc = _cc()
    exe = tmp_path / "fuzz_fw"
    _build(
        [
            cc,
            *WARNINGS,
            *SANITIZERS,
            "-DFW_FUZZ_MAIN",
            f"-I{C_DIR}",
            *map(str, CORE),
            str(FW_DIR / "tests" / "fuzz_fw.c"),
            "-o",
            str(exe),
        ]
    )
    inputs = []
    for seed in range(4):
        path = tmp_path / f"corpus{seed}.bin"
        path.write_bytes(fw_traffic(seed, 20_000))
        inputs.append(path)
    noise = tmp_path / "noise.bin"
    noise.write_bytes(random.Random(9).randbytes(300_000))
    done = _run([str(exe), *map(str, inputs), str(noise)], env={**os.environ, **SANITIZER_ENV})
    words = done.stdout.split()
    frames, acks, can_frames = int(words[1]), int(words[4]), int(words[6])
    # The corpus reaches the state machine: thousands of answers, STOPs among them, on
    # serial and on CAN.
    assert frames > 50_000 and acks > 1_000 and can_frames > 10_000, done.stdout


def test_the_varied_plant_harness_over_its_seeds_under_asan_and_ubsan(tmp_path: Path) -> None:
    """fuzz_fw_plant.c as a plain program (gcc), over its checked-in seeds and seeded
    noise: what runs where clang is missing (test_libfuzzer.py runs it under libFuzzer).
    Its invariants abort it; the seeds reach refusals, completed and watched steps."""
    cc = _cc()
    exe = tmp_path / "fuzz_fw_plant"
    _build(
        [
            cc,
            *WARNINGS,
            *SANITIZERS,
            "-DFW_FUZZ_MAIN",
            f"-I{C_DIR}",
            *map(str, CORE),
            str(FW_DIR / "tests" / "fuzz_fw_plant.c"),
            "-o",
            str(exe),
        ]
    )
    seeds = sorted(CORPORA["fw_plant"].iterdir())
    rng = random.Random(22)
    noise = []
    for k in range(40):
        path = tmp_path / f"noise{k}"
        path.write_bytes(rng.randbytes(rng.randrange(16, 400)))
        noise.append(path)
    done = _run([str(exe), *map(str, seeds + noise)], env={**os.environ, **SANITIZER_ENV})
    found = re.search(
        r"(\d+) inputs, (\d+) refused, (\d+) frames out, (\d+) steps completed, (\d+) watched",
        done.stdout,
    )
    assert found, done.stdout
    inputs, refused, frames, completed, watched = map(int, found.groups())
    assert inputs == len(seeds) + len(noise) and refused >= 5, done.stdout
    assert frames > 5_000 and completed >= 10 and watched >= 10, done.stdout


# -- cases (fw/tests/cases_fw.c) ------------------------------------------------------------


@pytest.fixture(scope="module")
def cases_fw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """fw/tests/cases_fw.c built with ASan and UBSan (any error aborts it)."""
    cc = _cc()
    exe = tmp_path_factory.mktemp("cases") / "cases_fw"
    _build(
        [
            cc,
            *WARNINGS,
            *SANITIZERS,
            f"-I{C_DIR}",
            *map(str, CORE),
            str(FW_DIR / "tests" / "cases_fw.c"),
            "-o",
            str(exe),
        ]
    )
    return exe


def _case(exe: Path, name: str) -> None:
    done = subprocess.run(
        [str(exe), name],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **SANITIZER_ENV},
        check=False,
    )
    assert (done.returncode, done.stdout, done.stderr) == (0, f"ok {name}\n", ""), (
        done.stdout + done.stderr[-4000:]
    )


def test_an_int32_min_encoder_count_or_wheel_speed_is_no_undefined_behaviour(
    cases_fw: Path,
) -> None:
    """Both polarities negate the motor-frame readings: INT32_MIN must not overflow."""
    _case(cases_fw, "int32_min")


def test_a_step_across_the_encoder_counter_wrap_completes_at_its_distance(
    cases_fw: Path,
) -> None:
    """fw_hal.h's counter wraps modulo 2^32: a 1 m step whose counters wrap half-way
    completes with travel 23000 having driven 1 m (not 2^32 units on)."""
    _case(cases_fw, "wrap")


def test_fw_init_refuses_a_zero_tick_acceleration_or_rate(cases_fw: Path) -> None:
    """Each would divide by zero; refused with its error code, the core stays silent and
    drives nothing."""
    _case(cases_fw, "config")


# -- cross builds -------------------------------------------------------------------------

TARGETS = {
    "cortex-m0plus": (
        "arm-none-eabi-gcc",
        "arm-none-eabi-size",
        ["-mcpu=cortex-m0plus", "-mthumb", "--specs=nano.specs", "--specs=nosys.specs"],
        "gcc-arm-none-eabi libnewlib-arm-none-eabi",
    ),
    "atmega2560": ("avr-gcc", "avr-size", ["-mmcu=atmega2560"], "gcc-avr avr-libc binutils-avr"),
}


def cross_build(target: str, out_dir: Path) -> dict[str, int]:
    """Build the core with the skeleton port for ``target``; ``size``'s text, data and
    bss of the image, bytes. Skips (or fails under ``ROVER_REQUIRE_CROSS=1``) without the
    cross compiler."""
    gcc, size, flags, packages = TARGETS[target]
    _require(gcc, packages)
    _require(size, packages)
    elf = out_dir / f"fw-{target}.elf"
    _build(
        [
            gcc,
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-Wshadow",
            "-Os",
            "-DRP_NO_FIELD_INFO",
            "-ffunction-sections",
            "-fdata-sections",
            "-Wl,--gc-sections",
            *flags,
            f"-I{C_DIR}",
            *map(str, CORE),
            str(FW_DIR / "port_bare" / "main.c"),
            "-o",
            str(elf),
        ]
    )
    row = _run([size, str(elf)]).stdout.splitlines()[1].split()
    return {"text": int(row[0]), "data": int(row[1]), "bss": int(row[2])}


def _require(tool: str, packages: str) -> str:
    path = shutil.which(tool)
    if path is None:
        reason = f"{tool} not found: apt-get install {packages} (or .ci/bootstrap --test)"
        if os.environ.get(REQUIRE_CROSS_ENV) == "1":
            pytest.fail(f"{REQUIRE_CROSS_ENV}=1 but {reason}")
        pytest.skip(reason)
    return path


def test_the_self_test_passes_on_the_host(tmp_path: Path) -> None:
    cc = _cc()
    exe = tmp_path / "selftest"
    _build(
        [cc, *WARNINGS, *SANITIZERS, f"-I{C_DIR}", *map(str, CORE), str(SELFTEST), "-o", str(exe)]
    )
    out = _run([str(exe)], env={**os.environ, **SANITIZER_ENV}).stdout
    assert "FAIL" not in out and out.splitlines()[-1] == "selftest: ok", out


def test_the_self_test_passes_on_an_atmega2560_under_simavr(tmp_path: Path) -> None:
    """The AVR image runs the scripted host on the simulated MCU (16 MHz) and prints over
    its UART; Timer1 measures fw_tick in CPU cycles."""
    gcc = _require("avr-gcc", "gcc-avr avr-libc binutils-avr")
    simavr = _require("simavr", "simavr")
    elf = tmp_path / "selftest-avr.elf"
    _build(
        [
            gcc,
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-Os",
            "-DRP_NO_FIELD_INFO",
            "-mmcu=atmega2560",
            "-ffunction-sections",
            "-fdata-sections",
            "-Wl,--gc-sections",
            f"-I{C_DIR}",
            *map(str, CORE),
            str(SELFTEST),
            "-o",
            str(elf),
        ]
    )
    done = subprocess.run(
        [simavr, "-m", "atmega2560", "-f", "16000000", str(elf)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    # simavr echoes the UART line by line, in colour, with a trailing dot.
    lines = [
        re.sub(r"\x1b\[[0-9;]*m", "", line).rstrip(".")
        for line in (done.stdout + done.stderr).splitlines()
    ]
    assert "selftest: ok" in lines, "\n".join(lines)
    assert not any(line.startswith("FAIL") for line in lines), "\n".join(lines)
    cycles = next(line for line in lines if line.startswith("fw_tick cycles:"))
    print(f"\natmega2560 @ 16 MHz under simavr: {cycles}")


def test_the_self_test_passes_on_a_cortex_m0_under_qemu(tmp_path: Path) -> None:
    """The image for the BBC micro:bit (nRF51822, Cortex-M0, the ARMv6-M instruction set
    of the M0+) runs the scripted host under qemu-system-arm, printing through
    semihosting. With ``-icount shift=6`` every instruction takes 64 ns of virtual time, so
    the 16 MHz SysTick counts 1.024 per instruction: an instruction count per fw_tick."""
    gcc = _require("arm-none-eabi-gcc", "gcc-arm-none-eabi libnewlib-arm-none-eabi")
    qemu = _require("qemu-system-arm", "qemu-system-arm")
    elf = tmp_path / "selftest-m0.elf"
    _build(
        [
            gcc,
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-Os",
            "-DRP_NO_FIELD_INFO",
            "-DFW_SELFTEST_MICROBIT",
            "-mcpu=cortex-m0",
            "-mthumb",
            "-ffunction-sections",
            "-fdata-sections",
            "-nostartfiles",
            "--specs=nano.specs",
            "--specs=rdimon.specs",
            "-Wl,--gc-sections",
            "-T",
            str(FW_DIR / "port_bare" / "microbit.ld"),
            f"-I{C_DIR}",
            *map(str, CORE),
            str(SELFTEST),
            "-o",
            str(elf),
        ]
    )
    done = subprocess.run(
        [
            qemu,
            "-M",
            "microbit",
            "-nographic",
            "-monitor",
            "none",
            "-serial",
            "none",
            "-semihosting-config",
            "enable=on,target=native",
            "-icount",
            "shift=6",
            "-kernel",
            str(elf),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    lines = done.stdout.splitlines()
    assert done.returncode == 0, done.stdout + done.stderr
    assert "selftest: ok" in lines and not any(line.startswith("FAIL") for line in lines)
    counts = next(line for line in lines if line.startswith("fw_tick SysTick counts:"))
    avg, peak = (int(w) for w in counts.split()[4:7:2])
    print(
        f"\ncortex-m0 under qemu (microbit): about {avg / 1.024:,.0f} instructions per "
        f"fw_tick on average, {peak / 1.024:,.0f} at most ({counts})"
    )


@pytest.mark.parametrize("target", list(TARGETS))
def test_the_core_cross_builds_and_reports_its_size(target: str, tmp_path: Path) -> None:
    sizes = cross_build(target, tmp_path)
    flash = sizes["text"] + sizes["data"]
    ram = sizes["data"] + sizes["bss"]
    print(
        f"\n{target}: text {sizes['text']} data {sizes['data']} bss {sizes['bss']} "
        f"-> flash {flash} B, static RAM {ram} B"
    )
    assert sizes["text"] > 4000  # the core is in there, not optimised away
    if target == "cortex-m0plus":
        assert flash <= M0_FLASH_BYTES, sizes
        assert ram <= M0_RAM_BYTES, sizes
