"""The PIL images: the same fw.c with each MCU's port, built with warnings as errors; their
flash and RAM against the part they run on; the port's structures as the runner reads them."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from emulator.pil.images import C_DIR, IMAGES, build_image
from emulator.pil.plant import SENSORS
from emulator.pil.view import HOOKS, STATS, VIEW

from .pil_helpers import require_target


@pytest.mark.parametrize("target", list(IMAGES))
@pytest.mark.parametrize("pil", [True, False], ids=["pil", "lab"])
def test_the_image_builds_and_fits_its_part(target: str, pil: bool) -> None:
    require_target(target)
    image = build_image(target, pil=pil)
    spec = image.spec
    print(f"\n{image.line()} (text {image.text}, data {image.data}, bss {image.bss})")
    assert image.text > 10_000  # the core and the codec are in there
    assert image.flash_bytes <= spec.flash_bytes
    assert image.ram_bytes + 1024 <= spec.ram_bytes  # a stack of 1 KiB on top
    assert {"pil_stats", "pil_view"} <= set(image.symbols)
    if pil:
        assert ("pil_hooks" if target == "microbit" else "pil_sensors") in image.symbols


def test_the_image_is_cached_by_content(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    require_target("microbit")
    monkeypatch.setenv("ROVER_FIRMWARE_CACHE", str(tmp_path))
    first = build_image("microbit")
    mtime = first.elf.stat().st_mtime_ns
    again = build_image("microbit")
    assert again.elf == first.elf and again.elf.stat().st_mtime_ns == mtime
    assert first.elf.parent == tmp_path


def test_the_structures_have_the_runners_layout(tmp_path: Path) -> None:
    """pil_port.h's structures, as the host compiler lays them out, are the sizes the
    runner decodes (no padding, the same on the 8- and 32-bit targets)."""
    cc = shutil.which("gcc")
    if cc is None:
        pytest.skip("gcc not found")
    src = tmp_path / "layout.c"
    src.write_text(
        '#include <stdio.h>\n#include "fw/port_pil/pil_port.h"\n'
        'int main(void) { printf("%zu %zu %zu %zu\\n", sizeof(pil_stats_t), '
        "sizeof(pil_view_t), sizeof(pil_hooks_t), sizeof(pil_sensors_t)); return 0; }\n"
    )
    exe = tmp_path / "layout"
    subprocess.run([cc, "-std=c99", f"-I{C_DIR}", str(src), "-o", str(exe)], check=True)
    sizes = [
        int(w)
        for w in subprocess.run(
            [str(exe)], capture_output=True, text=True, check=True
        ).stdout.split()
    ]
    assert sizes[:3] == [STATS.size, VIEW.size, HOOKS.size]
    # pil_sensors_t on a 32-bit host pads after pose_yaw_ddeg; the AVR (the only target that
    # posts it) does not: the runner's layout is the AVR's.
    assert SENSORS.size == 42 and sizes[3] in (42, 44)


def test_an_avr_sensor_layout_is_unpadded(tmp_path: Path) -> None:
    require_target("atmega2560")
    src = tmp_path / "sensors.c"
    src.write_text(
        '#include "fw/port_pil/pil_port.h"\n'
        "typedef char size_is_42[sizeof(pil_sensors_t) == 42 ? 1 : -1];\n"
        "typedef char view_is_40[sizeof(pil_view_t) == 40 ? 1 : -1];\n"
    )
    subprocess.run(
        [
            "avr-gcc",
            "-mmcu=atmega2560",
            "-std=c99",
            f"-I{C_DIR}",
            "-c",
            str(src),
            "-o",
            str(tmp_path / "s.o"),
        ],
        check=True,
    )
