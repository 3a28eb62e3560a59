"""The firmware images of processor-in-the-loop runs: the same ``fw.c`` as the host
build, with a port for an MCU, cross-compiled and cached by content hash.

Targets (:data:`IMAGES`): ``microbit`` (nRF51822, ``port_microbit/main.c``; the PIL flag
``-DFW_PIL`` puts the kinematic plant and the fault hooks inside the image) and
``atmega2560`` (``port_avr/main.c``; its plant is the twin in the simavr harness, so the
flag only adds the hooks). :func:`build_image` compiles one (warnings as errors) into
:func:`cache_dir` (never the checkout), reports ``size`` and finds the port's symbols.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from emulator import sharedlib
from emulator.pil.errors import PilError, PilToolMissingError
from firmware_proto.model.rover import load_rover

__all__ = ["IMAGES", "Image", "ImageSpec", "build_image", "cache_dir", "require_tool"]

C_DIR = Path(__file__).resolve().parents[2] / "firmware_proto" / "wire" / "c"
"""The C codec; the firmware core and its ports are in ``fw/``."""
_CORE = ("rover_msgs.c", "rover_proto.c", "fw/fw.c", "fw/port_pil/pil_port.c")
_WARN = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wshadow")
_COMMON = (
    "-Os",
    "-DRP_NO_FIELD_INFO",
    "-ffunction-sections",
    "-fdata-sections",
    "-Wl,--gc-sections",
)


@dataclass(frozen=True)
class ImageSpec:
    """How one target's image is built.

    Attributes:
        name: the target's name (``rover pil --target``).
        compiler, size_tool, nm_tool: the cross tools.
        packages: the Debian packages that bring them (named when one is missing).
        flags: the target's compiler and linker flags.
        sources: the port's sources, relative to :data:`C_DIR` (after the core's).
        pil_sources: added with the PIL flag.
        ram_offset: what ``nm`` adds to a data address (AVR: 0x800000).
        flash_bytes, ram_bytes: the part's memories (its datasheet).
    """

    name: str
    compiler: str
    size_tool: str
    nm_tool: str
    packages: str
    flags: tuple[str, ...]
    sources: tuple[str, ...]
    pil_sources: tuple[str, ...]
    ram_offset: int
    flash_bytes: int
    ram_bytes: int


IMAGES: dict[str, ImageSpec] = {
    "microbit": ImageSpec(
        name="microbit",
        compiler="arm-none-eabi-gcc",
        size_tool="arm-none-eabi-size",
        nm_tool="arm-none-eabi-nm",
        packages="gcc-arm-none-eabi libnewlib-arm-none-eabi binutils-arm-none-eabi",
        flags=(
            "-mcpu=cortex-m0",
            "-mthumb",
            "-nostartfiles",
            "--specs=nano.specs",
            "--specs=nosys.specs",
            "-T",
            str(C_DIR / "fw" / "port_microbit" / "nrf51.ld"),
        ),
        sources=("fw/port_microbit/main.c",),
        pil_sources=("fw/port_pil/pil_plant.c",),
        ram_offset=0,
        flash_bytes=256 * 1024,
        ram_bytes=16 * 1024,
    ),
    "atmega2560": ImageSpec(
        name="atmega2560",
        compiler="avr-gcc",
        size_tool="avr-size",
        nm_tool="avr-nm",
        packages="gcc-avr avr-libc binutils-avr",
        flags=("-mmcu=atmega2560", "-DF_CPU=16000000UL"),
        sources=("fw/port_avr/main.c",),
        pil_sources=(),
        ram_offset=0x800000,
        flash_bytes=256 * 1024,
        ram_bytes=8 * 1024,
    ),
}
"""Every target, by name."""


@dataclass(frozen=True)
class Image:
    """A built image: its ELF, ``size``'s sections and the port's symbols."""

    spec: ImageSpec
    elf: Path
    pil: bool
    text: int
    data: int
    bss: int
    symbols: dict[str, int] = field(default_factory=dict)
    """RAM addresses of the port's globals (``pil_stats``, ``pil_view``, ``pil_hooks``)."""

    @property
    def flash_bytes(self) -> int:
        """Flash used: text + data."""
        return self.text + self.data

    @property
    def ram_bytes(self) -> int:
        """Static RAM used: data + bss (the stack comes on top)."""
        return self.data + self.bss

    def line(self) -> str:
        """``IMAGE microbit flash N of 262144 B, static RAM N of 16384 B (PIL) path``."""
        s = self.spec
        return (
            f"IMAGE {s.name} flash {self.flash_bytes} of {s.flash_bytes} B, static RAM "
            f"{self.ram_bytes} of {s.ram_bytes} B{' (PIL)' if self.pil else ''} {self.elf}"
        )


def cache_dir() -> Path:
    """Where built images are kept: the host libraries' cache (:mod:`emulator.sharedlib`)."""
    return sharedlib.cache_dir()


def require_tool(tool: str, packages: str) -> str:
    """The path of ``tool``.

    Raises:
        PilToolMissingError: not on PATH; the message names the packages that bring it.
    """
    path = shutil.which(tool)
    if path is None:
        raise PilToolMissingError(
            f"{tool} not found: apt-get install {packages} (or bash .ci/bootstrap --test)"
        )
    return path


def _sources(spec: ImageSpec, pil: bool) -> list[Path]:
    names = [*_CORE, *spec.sources, *(spec.pil_sources if pil else ())]
    return [C_DIR / n for n in names]


def _headers() -> list[Path]:
    return sorted(C_DIR.glob("*.h")) + sorted((C_DIR / "fw").rglob("*.h"))


def build_image(target: str, *, pil: bool = True, timeout_s: float = 300.0) -> Image:
    """Build (or find in the cache) the image of ``target``.

    Args:
        target: a name of :data:`IMAGES`.
        pil: with the PIL flag; ``False``: the port as a lab flashes it.
        timeout_s: compiler time limit, s.

    Raises:
        PilError: an unknown target (the known ones listed), or the build failed.
        PilToolMissingError: the cross compiler is not installed.
    """
    spec = IMAGES.get(target)
    if spec is None:
        raise PilError(f"unknown PIL target {target!r}; known: {', '.join(IMAGES)}")
    gcc = require_tool(spec.compiler, spec.packages)
    size = require_tool(spec.size_tool, spec.packages)
    nm = require_tool(spec.nm_tool, spec.packages)
    sources = _sources(spec, pil)
    rover = load_rover()
    defines = (
        [
            "-DFW_PIL",
            f"-DFW_PIL_TRACK_UM={round(rover.geometry.track_width_m * 1e6)}",
            f"-DFW_PIL_TURN_PERMILLE={round(rover.traction.turn_efficiency * 1000)}",
        ]
        if pil
        else []
    )
    argv = [*_WARN, *_COMMON, *spec.flags, *defines, f"-I{C_DIR}"]
    digest = hashlib.sha256()
    for part in [
        gcc,
        *argv,
        subprocess.run([gcc, "--version"], capture_output=True, text=True, check=False).stdout,
    ]:
        digest.update(part.encode() + b"\0")
    for path in [*sources, *_headers(), *(Path(a) for a in spec.flags if a.endswith(".ld"))]:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    out_dir = cache_dir()
    out_dir.mkdir(parents=True, exist_ok=True)
    elf = out_dir / f"pil-{spec.name}{'-pil' if pil else ''}-{digest.hexdigest()[:16]}.elf"
    if not elf.exists():
        with tempfile.TemporaryDirectory(dir=out_dir) as tmp:
            tmp_elf = Path(tmp) / elf.name
            done = subprocess.run(
                [gcc, *argv, *map(str, sources), "-o", str(tmp_elf)],
                capture_output=True,
                text=True,
                timeout=timeout_s,
                check=False,
            )
            if done.returncode != 0:
                raise PilError(f"building the {spec.name} image failed:\n{done.stderr}")
            os.replace(tmp_elf, elf)
    row = (
        subprocess.run([size, str(elf)], capture_output=True, text=True, check=True)
        .stdout.splitlines()[1]
        .split()
    )
    symbols: dict[str, int] = {}
    for line in subprocess.run(
        [nm, str(elf)], capture_output=True, text=True, check=True
    ).stdout.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2].startswith("pil_") and parts[1] in "bBdD":
            symbols[parts[2]] = int(parts[0], 16) - spec.ram_offset
    return Image(spec, elf, pil, int(row[0]), int(row[1]), int(row[2]), symbols)
