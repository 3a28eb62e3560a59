"""The C reference codec agrees with the Python codec byte for byte and counter for counter.

Both are checked against the shared vectors (``firmware_proto/wire/vectors/``): the Python side
always (so a drift of either the vectors or the codec is caught without a compiler), the
C side when gcc is there (tests marked ``cc``). The C library and its pipe harness are
built once per session with warnings as errors and AddressSanitizer + UBSan; random and
hypothesis-generated streams must never upset the sanitizers and must give the same
frames and counters as the Python decoder fed the same chunks.
"""

from __future__ import annotations

import binascii
import itertools
import json
import os
import platform
import random
import re
import shutil
import subprocess
import sys
import types
from functools import cache
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_proto.errors import EncodeError
from firmware_proto.wire import cobs
from firmware_proto.wire.canmap import CanDecoder, encode_can
from firmware_proto.wire.codegen import REPO_ROOT
from firmware_proto.wire.codegen.vectors import COUNTER_NAMES, ReferenceDecoder, frame_bytes
from firmware_proto.wire.framing import FrameDecoder, encode_frame, encode_raw_frame
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import BY_NAME, MESSAGE_TYPES
from firmware_proto.wire.spec import load_spec

from .c_harness import (
    C_DIR,
    LIBRARY_SOURCES,
    SANITIZER_ENV,
    SANITIZERS,
    WARNINGS,
    Tool,
    build_tool,
    compile_c,
    compiler,
    frame_dict,
    parse_decode,
    parse_fields,
    python_decode,
    xorshift_chunks,
)

VECTORS = REPO_ROOT / "firmware_proto" / "wire" / "vectors"
GENERAL_REGS_ONLY = {"x86_64", "AMD64", "i386", "i686", "aarch64", "arm64"}
"""Machines whose gcc takes ``-mgeneral-regs-only``."""
SPEC = load_spec()


@cache
def _vectors(name: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((VECTORS / name).read_text(encoding="utf-8"))
    return data


def _messages() -> list[dict[str, Any]]:
    return list(_vectors("messages.json")["messages"])


def _encode_errors() -> list[dict[str, Any]]:
    return list(_vectors("messages.json")["encode_errors"])


def _streams() -> list[dict[str, Any]]:
    return list(_vectors("serial_streams.json")["streams"])


def _can_cases() -> list[dict[str, Any]]:
    return list(_vectors("can_frames.json")["cases"])


def _message(vector: dict[str, Any]) -> Message:
    return BY_NAME[vector["name"]](**vector["fields"])


def _field_line(head: str, vector: dict[str, Any]) -> str:
    fields = " ".join(f"{k}={v}" for k, v in vector["fields"].items())
    strict = "" if vector["strict"] else " strict=0"
    return f"{head}{strict} {fields}".rstrip()


def _python_encode(vector: dict[str, Any]) -> object:
    msg = _message(vector)
    if vector["transport"] == "can":
        return encode_can(msg, vector["node"], vector["strict"])
    return encode_frame(msg, 0, vector["strict"])


def _chunks(stream: dict[str, Any]) -> list[bytes]:
    return [bytes.fromhex(c) for c in stream["chunks"]]


# ------------------------------------------------------------------ the vectors themselves


def test_vectors_match_the_spec_they_were_made_from() -> None:
    for name in ("messages.json", "serial_streams.json", "can_frames.json"):
        doc = _vectors(name)
        assert doc["schema_hash"] == SPEC.schema_hash, name
        assert doc["protocol_version"] == SPEC.protocol_version, name
        assert "do not edit" in doc["_generated"].lower()


def test_vectors_cover_every_message_extreme_and_drop_reason() -> None:
    messages = _messages()
    for spec in SPEC.messages:
        mine = [v for v in messages if v["name"] == spec.name]
        assert len(mine) >= 4, spec.name
        for f in spec.public_fields:
            values = {v["fields"][f.name] for v in mine}
            assert {f.min, f.max} <= values, f"{spec.name}.{f.name}"
            if f.limit:
                assert set(f.limit) <= values, f"{spec.name}.{f.name} limit"
        assert {c["node"] for v in mine for c in v["can"]} >= {1}
        assert len({c["node"] for v in mine for c in v["can"]}) >= 2
    serial_reasons = set(COUNTER_NAMES) - {"not_classic"}
    seen = {k for s in _streams() for k, v in s["counters"].items() if v}
    assert seen >= serial_reasons
    can_reasons = {"frames", "unknown_id", "bad_length", "out_of_range", "not_classic"}
    assert {k for c in _can_cases() for k, v in c["counters"].items() if v} >= can_reasons
    kinds = {(e["transport"], e["kind"]) for e in _encode_errors()}
    assert kinds >= {("serial", "range"), ("serial", "limit"), ("can", "node")}
    assert ("can", "broadcast") in kinds


def test_python_codec_encodes_every_message_vector() -> None:
    for v in _messages():
        msg = _message(v)
        assert msg.pack(v["strict"]).hex() == v["payload"], v
        assert encode_frame(msg, v["seq"], v["strict"]).hex() == v["serial"], v
        for can in v["can"]:
            can_id, data = encode_can(msg, can["node"], v["strict"])
            assert (can_id, data.hex()) == (can["can_id"], can["data"]), v


def test_python_codec_decodes_every_message_vector() -> None:
    decoder = FrameDecoder()
    can = CanDecoder()
    for v in _messages():
        (frame,) = decoder.feed(bytes.fromhex(v["serial"]))
        assert frame_dict(frame) == {"id": v["id"], "seq": v["seq"], "fields": v["fields"]}
        for c in v["can"]:
            got = can.decode(c["can_id"], bytes.fromhex(c["data"]))
            assert got is not None, v
            assert (got.node, got.message.to_dict()) == (c["node"], v["fields"])
    assert decoder.counters.rejected == can.counters.rejected == 0


def test_python_codec_refuses_every_encode_error_vector() -> None:
    for e in _encode_errors():
        with pytest.raises(EncodeError) as caught:
            _python_encode(e)
        assert caught.value.field == e["field"], e
        if e["kind"] in ("range", "limit"):
            assert f"outside its {e['kind']}" in str(caught.value), e


@pytest.mark.parametrize("stream", _streams(), ids=lambda s: s["label"])
def test_python_decoder_matches_stream_vector(stream: dict[str, Any]) -> None:
    frames, counters = python_decode(_chunks(stream))
    assert frames == stream["frames"]
    assert counters == stream["counters"]


@pytest.mark.parametrize("case", _can_cases(), ids=lambda c: c["label"])
def test_python_can_decoder_matches_can_vector(case: dict[str, Any]) -> None:
    decoder = CanDecoder()
    decoded = []
    for f in case["frames"]:
        got = decoder.decode(
            f["can_id"], bytes.fromhex(f["data"]), is_extended=f["extended"], is_remote=f["remote"]
        )
        decoded.append(
            None
            if got is None
            else {"node": got.node, "id": got.message.MSG_ID, "fields": got.message.to_dict()}
        )
    assert decoded == case["decoded"]
    assert decoder.counters.as_dict() == case["counters"]


@given(
    st.lists(st.binary(max_size=40), max_size=8),
    st.lists(st.integers(0, 300), max_size=6),
    st.randoms(use_true_random=False),
)
def test_vector_model_decoder_agrees_with_python_decoder(
    noise: list[bytes], cuts: list[int], rng: random.Random
) -> None:
    """The model the vectors are made with is the Python decoder's behaviour, chunked or not."""
    parts = []
    for k, junk in enumerate(noise):
        msg = rng.choice(SPEC.messages)
        values = {f.name: rng.randint(f.min, f.max) for f in msg.public_fields}
        payload = BY_NAME[msg.name](**values).pack(strict=False)
        parts += [frame_bytes(msg.id, rng.choice((k, 7)), payload), junk]
    stream = b"".join(parts)
    edges = sorted({0, len(stream), *(c % (len(stream) + 1) for c in cuts)})
    chunks = [stream[a:b] for a, b in itertools.pairwise(edges)]
    model = ReferenceDecoder(SPEC)
    model_frames = [f for chunk in chunks for f in model.feed(chunk)]
    assert python_decode(chunks) == (model_frames, model.counters)


# ------------------------------------------------------------------ the C codec


@pytest.fixture(scope="session")
def rp_tool(tmp_path_factory: pytest.TempPathFactory) -> Tool:
    """The harness, built once per session; skips (saying why) without a compiler."""
    if compiler() is None:
        pytest.skip("gcc not found (set CC): the C reference codec cannot be built here")
    return build_tool(tmp_path_factory.mktemp("ccodec"))


@pytest.mark.cc
def test_c_selftest(rp_tool: Tool) -> None:
    assert rp_tool.run("selftest", b"") == ["ok selftest"]


@pytest.mark.cc
def test_c_library_is_freestanding_float_free_and_warning_free(tmp_path: Path) -> None:
    """No libc, no heap, no stdio, no floating point: what the firmware can link."""
    if compiler() is None:
        pytest.skip("gcc not found (set CC)")
    if shutil.which("nm") is None:
        pytest.skip("nm (binutils) not found: the library's undefined symbols are not listed")
    # Where gcc has it, -mgeneral-regs-only makes any float or double operation an error.
    no_fpu = ("-mgeneral-regs-only",) if platform.machine() in GENERAL_REGS_ONLY else ()
    extra = (
        *no_fpu,
        "-O2",
        "-ffreestanding",
        "-Wcast-qual",
        "-Wstrict-prototypes",
        "-Wmissing-prototypes",
        "-Wundef",
        "-Wdouble-promotion",
        "-Wvla",
        "-Wswitch-enum",
        "-Wstack-usage=256",
    )
    objects = []
    for source in LIBRARY_SOURCES:
        obj = tmp_path / (source.stem + ".o")
        compile_c([*WARNINGS, *extra, "-c", source, "-o", obj])
        objects.append(obj)
    done = subprocess.run(
        ["nm", "-u", *map(str, objects)], capture_output=True, text=True, timeout=60, check=True
    )
    ours = {"rp_msg_info", "rp_msg_pack", "rp_msg_unpack"}
    undefined = {line.split()[-1] for line in done.stdout.splitlines() if " U " in line}
    # Compilers may emit memcpy/memset for struct copies; every freestanding runtime has them.
    assert undefined - ours <= {"memcpy", "memset"}
    for source in (*LIBRARY_SOURCES, C_DIR / "rover_msgs.h", C_DIR / "rover_proto.h"):
        code = re.sub(r"/\*.*?\*/|//[^\n]*", "", source.read_text(encoding="utf-8"), flags=re.S)
        for banned in ("stdio.h", "stdlib.h", "malloc", "float", "double", "printf"):
            assert not re.search(rf"\b{re.escape(banned)}\b", code), f"{banned} in {source.name}"


@pytest.mark.cc
def test_c_headers_compile_as_cpp(tmp_path: Path) -> None:
    if shutil.which("g++") is None:
        pytest.skip("g++ not found: C++ inclusion of the headers not checked")
    probe = tmp_path / "probe.cpp"
    probe.write_text('#include "rover_proto.h"\nint main() { return RP_MSG_COUNT == 0; }\n')
    done = subprocess.run(
        ["g++", "-std=c++11", "-Wall", "-Wextra", "-Werror", "-I", str(C_DIR), "-c", str(probe)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        check=False,
    )
    assert done.returncode == 0, done.stderr


@pytest.mark.cc
def test_c_decodes_every_python_encoded_message(rp_tool: Tool) -> None:
    vectors = _messages()
    wire = [encode_frame(_message(v), v["seq"], v["strict"]) for v in vectors]
    frames, counters = parse_decode(rp_tool.lines("decode", [w.hex() for w in wire]))
    assert frames == [{"id": v["id"], "seq": v["seq"], "fields": v["fields"]} for v in vectors]
    assert counters == python_decode(wire)[1]
    assert counters["frames"] == len(vectors)


@pytest.mark.cc
def test_c_encodes_every_message_like_python(rp_tool: Tool) -> None:
    vectors = _messages()
    out = rp_tool.lines("encode", [_field_line(f"{v['name']} {v['seq']}", v) for v in vectors])
    assert len(out) == len(vectors)
    decoder = FrameDecoder()
    for v, line in zip(vectors, out, strict=True):
        assert line == f"ok {v['serial']}", v
        (frame,) = decoder.feed(bytes.fromhex(line.split()[1]))
        assert frame.message == _message(v)
        assert frame.seq == v["seq"]


@pytest.mark.cc
def test_c_refuses_every_encode_error_like_python(rp_tool: Tool) -> None:
    errors = _encode_errors()
    serial = [e for e in errors if e["transport"] == "serial"]
    can = [e for e in errors if e["transport"] == "can"]
    out = rp_tool.lines("encode", [_field_line(f"{e['name']} 0", e) for e in serial])
    out += rp_tool.lines("can-encode", [_field_line(f"{e['name']} {e['node']}", e) for e in can])
    for e, line in zip(serial + can, out, strict=True):
        word, _code, kind, field = line.split()
        assert word == "error", e
        if e["kind"] in ("range", "limit"):
            assert (kind, field) == (e["kind"], e["field"]), e
        else:
            assert kind == "other", e


@pytest.mark.cc
def test_c_can_encodes_every_message_like_python(rp_tool: Tool) -> None:
    lines, expected = [], []
    for v in _messages():
        for c in v["can"]:
            lines.append(_field_line(f"{v['name']} {c['node']}", v))
            expected.append(f"ok {c['can_id']:03x} {c['data']}")
    assert rp_tool.lines("can-encode", lines) == expected


@pytest.mark.cc
def test_c_can_decodes_every_message_vector(rp_tool: Tool) -> None:
    lines, expected = [], []
    for v in _messages():
        for c in v["can"]:
            lines.append(f"{c['can_id']:x} 0 0 {c['data'] or '-'}")
            fields = " ".join(f"{k}={x}" for k, x in v["fields"].items())
            expected.append(f"frame {c['node']} {v['id']} {fields}".rstrip())
    out = rp_tool.lines("can-decode", lines)
    assert out[:-1] == expected
    assert parse_fields(out[-1].split()[1:])["frames"] == len(expected)


@pytest.mark.cc
@pytest.mark.parametrize("case", _can_cases(), ids=lambda c: c["label"])
def test_c_can_decoder_matches_can_vector(rp_tool: Tool, case: dict[str, Any]) -> None:
    lines = [
        f"{f['can_id']:x} {int(f['extended'])} {int(f['remote'])} {f['data'] or '-'}"
        for f in case["frames"]
    ]
    out = rp_tool.lines("can-decode", lines)
    decoded: list[dict[str, Any] | None] = []
    for line in out[:-1]:
        if line == "drop":
            decoded.append(None)
        else:
            _, node, msg_id, *fields = line.split()
            decoded.append({"node": int(node), "id": int(msg_id), "fields": parse_fields(fields)})
    assert decoded == case["decoded"]
    assert parse_fields(out[-1].split()[1:]) == case["counters"]


@pytest.mark.cc
@pytest.mark.parametrize("stream", _streams(), ids=lambda s: s["label"])
def test_c_decoder_matches_stream_vector(rp_tool: Tool, stream: dict[str, Any]) -> None:
    frames, counters = parse_decode(rp_tool.lines("decode", stream["chunks"]))
    assert frames == stream["frames"]
    assert counters == stream["counters"]


@pytest.mark.cc
def test_c_cobs_and_crc_match_python(rp_tool: Tool) -> None:
    rng = random.Random(0xC0B5)
    blocks = [b"", b"\x00", b"\x00\x00", bytes(range(1, 255)), bytes(range(1, 256)) * 2]
    blocks += [bytes([7]) * n for n in (253, 254, 255, 508, 509)]
    for _ in range(300):
        n = rng.choice((rng.randrange(16), rng.randrange(600)))
        zeros = rng.random()
        blocks.append(bytes(0 if rng.random() < zeros else rng.randrange(1, 256) for _ in range(n)))
    hexes = [b.hex() for b in blocks]
    assert rp_tool.lines("cobs-encode", hexes) == [f"ok {cobs.encode(b).hex()}" for b in blocks]
    assert rp_tool.lines("crc", hexes) == [f"ok {binascii.crc_hqx(b, 0xFFFF):04x}" for b in blocks]
    encoded = [cobs.encode(b) for b in blocks]
    garbage = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))) for _ in range(300)]
    inputs = encoded + garbage
    out = rp_tool.lines("cobs-decode", [b.hex() for b in inputs])
    for data, line in zip(inputs, out, strict=True):
        want = cobs.decode(data)
        assert line == ("error -7" if want is None else f"ok {want.hex()}"), data.hex()


def _noisy_stream(rng: random.Random, size: int) -> bytes:
    """Valid frames of every type mixed with flips, cuts, garbage and long runs."""
    parts: list[bytes] = []
    total = seq = 0
    while total < size:
        roll = rng.random()
        if roll < 0.6:
            spec = rng.choice(SPEC.messages)
            values = {f.name: rng.randint(f.min, f.max) for f in spec.public_fields}
            part = encode_frame(BY_NAME[spec.name](**values), seq, strict=False)
            seq += rng.choice((1, 1, 1, 2, 0))
            if rng.random() < 0.1:
                hit = bytearray(part)
                hit[rng.randrange(len(hit))] ^= 1 << rng.randrange(8)
                part = bytes(hit)
            elif rng.random() < 0.05:
                part = part[: rng.randrange(1, len(part))]
        elif roll < 0.7:
            msg_id = rng.randrange(256)
            part = encode_raw_frame(msg_id, seq, bytes(rng.randrange(256) for _ in range(8)))
        elif roll < 0.9:
            part = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 20)))
        else:
            part = bytes(rng.randrange(1, 256) for _ in range(rng.randrange(10, 120)))
        parts.append(part)
        total += len(part)
    return b"".join(parts)


FUZZ_INPUTS = [
    ("uniform", 1),
    ("uniform", 2),
    ("zero_rich", 3),
    ("noisy_frames", 4),
    ("noisy_frames", 5),
]
FUZZ_BYTES = 1 << 20


def _fuzz_input(kind: str, seed: int) -> bytes:
    rng = random.Random(seed)
    if kind == "uniform":
        return rng.randbytes(FUZZ_BYTES)
    if kind == "zero_rich":
        raw = bytearray(rng.randbytes(FUZZ_BYTES))
        for k in range(0, FUZZ_BYTES, 11):
            raw[k] = 0
        return bytes(raw)
    return _noisy_stream(rng, FUZZ_BYTES)


@pytest.mark.cc
@pytest.mark.parametrize(("kind", "seed"), FUZZ_INPUTS, ids=[f"{k}-{s}" for k, s in FUZZ_INPUTS])
def test_c_decoder_survives_a_megabyte_and_agrees_with_python(
    rp_tool: Tool, kind: str, seed: int
) -> None:
    """1 MiB per case in random chunks: no sanitizer report, same frames, same counters."""
    data = _fuzz_input(kind, seed)
    chunk_seed = 0x9E3779B9 ^ seed
    frames, counters = parse_decode(rp_tool.run("fuzz", data, str(chunk_seed), "64"))
    assert (frames, counters) == python_decode(xorshift_chunks(data, chunk_seed, 64))
    assert counters["bytes"] == len(data)
    if kind == "noisy_frames":
        assert counters["frames"] > 10_000
        assert all(counters[k] for k in ("framing", "crc", "oversize", "unknown_id", "lost"))


@st.composite
def _hypothesis_stream(draw: st.DrawFn) -> list[bytes]:
    parts: list[bytes] = []
    for _ in range(draw(st.integers(0, 8))):
        spec = SPEC.messages[draw(st.integers(0, len(SPEC.messages) - 1))]
        values = {f.name: draw(st.integers(f.min, f.max)) for f in spec.public_fields}
        frame = encode_frame(BY_NAME[spec.name](**values), draw(st.integers(0, 255)), False)
        flip = draw(st.one_of(st.none(), st.tuples(st.integers(0, 14), st.integers(0, 7))))
        if flip is not None:
            hit = bytearray(frame)
            hit[flip[0] % len(hit)] ^= 1 << flip[1]
            frame = bytes(hit)
        parts += [frame, draw(st.binary(max_size=24))]
    stream = b"".join(parts)
    cuts = draw(st.lists(st.integers(0, max(0, len(stream))), max_size=6))
    edges = sorted({0, len(stream), *cuts})
    return [stream[a:b] for a, b in itertools.pairwise(edges)]


@pytest.mark.cc
@settings(max_examples=60)
@given(_hypothesis_stream())
def test_c_decoder_agrees_with_python_on_generated_streams(
    rp_tool: Tool, chunks: list[bytes]
) -> None:
    out = rp_tool.lines("decode", [c.hex() for c in chunks])
    assert parse_decode(out) == python_decode(chunks)


@pytest.mark.cc
@settings(max_examples=30)
@given(st.lists(st.sampled_from(sorted(MESSAGE_TYPES)), min_size=1, max_size=20), st.data())
def test_c_round_trips_generated_messages(
    rp_tool: Tool, ids: list[int], data: st.DataObject
) -> None:
    msgs = []
    for msg_id in ids:
        spec = next(m for m in SPEC.messages if m.id == msg_id)
        values = {f.name: data.draw(st.integers(f.min, f.max)) for f in spec.public_fields}
        msgs.append(BY_NAME[spec.name](**values))
    lines = [
        " ".join([m.NAME, str(k), "strict=0", *(f"{n}={v}" for n, v in m.to_dict().items())])
        for k, m in enumerate(msgs)
    ]
    out = rp_tool.lines("encode", lines)
    assert out == [f"ok {encode_frame(m, k, strict=False).hex()}" for k, m in enumerate(msgs)]
    frames, _ = parse_decode(rp_tool.lines("decode", [line.split()[1] for line in out]))
    assert [f["fields"] for f in frames] == [m.to_dict() for m in msgs]


@pytest.mark.cc
def test_c_fuzz_target_runs_over_the_vectors_and_random_inputs(tmp_path: Path) -> None:
    """The libFuzzer target, built as a plain program, over a seeded corpus."""
    if compiler() is None:
        pytest.skip("gcc not found (set CC)")
    binary = tmp_path / "fuzz_decoder"
    compile_c(
        [
            *WARNINGS,
            *SANITIZERS,
            "-DRP_FUZZ_MAIN",
            "-I",
            C_DIR,
            *LIBRARY_SOURCES,
            C_DIR / "tests" / "fuzz_decoder.c",
            "-o",
            binary,
        ]
    )
    rng = random.Random(0xF022)
    corpus = []
    for k, stream in enumerate(_streams()):
        path = tmp_path / f"stream{k}"
        path.write_bytes(bytes([k]) + b"".join(_chunks(stream)))
        corpus.append(str(path))
    for k in range(40):
        path = tmp_path / f"random{k}"
        path.write_bytes(_noisy_stream(rng, rng.randrange(1, 20_000)))
        corpus.append(str(path))
    done = subprocess.run(
        [str(binary), *corpus],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **SANITIZER_ENV},
        check=False,
    )
    assert (done.returncode, done.stderr) == (0, ""), done.stderr[-4000:]
    assert done.stdout.strip() == f"ok {len(corpus)} inputs"


def _pack_or_error(msg: Message, strict: bool) -> tuple[bytes, EncodeError | None]:
    try:
        return msg.pack(strict), None
    except EncodeError as exc:
        return b"", exc


EDGE_MESSAGES = """
[[message]]
name = "EDGE_WIDE"
id = 100
direction = "host_to_controller"
priority = "config"
fields = [
  { name = "big", type = "u32", min = 5, max = 4000000000, limit = [10, 20] },
  { name = "neg", type = "i24", min = -8388608, max = 0 },
  { name = "flag", type = "u1" },
  { name = "small", type = "i7", min = -64, max = 62 },
]

[[message]]
name = "EDGE_EMPTY"
id = 101
direction = "controller_to_host"
priority = "config"
fields = []

[[message]]
name = "EDGE_I32"
id = 102
direction = "controller_to_host"
priority = "config"
fields = [
  { name = "lo", type = "i32", min = -2147483648, max = 7 },
  { name = "_pad", type = "u3", reserved = true },
  { name = "odd", type = "u13", max = 8000, limit = [1, 8000] },
  { name = "w", type = "i16", limit = [-3, 3] },
]
"""


@pytest.mark.cc
def test_c_generator_handles_edge_case_layouts(tmp_path: Path) -> None:
    """Widths 1..32, narrowed u32/i32 ranges, padding, an empty message: the generated C
    compiles clean and packs and unpacks exactly like the Python generated from the same spec."""
    if compiler() is None:
        pytest.skip("gcc not found (set CC)")
    from firmware_proto.wire.codegen.c import render_c_header, render_c_source
    from firmware_proto.wire.codegen.python import render_python
    from firmware_proto.wire.spec import DEFAULT_SPEC_PATH

    spec_file = tmp_path / "protocol.toml"
    spec_file.write_text(DEFAULT_SPEC_PATH.read_text(encoding="utf-8") + EDGE_MESSAGES)
    spec = load_spec(spec_file)
    (tmp_path / "rover_msgs.h").write_text(render_c_header(spec))
    (tmp_path / "rover_msgs.c").write_text(render_c_source(spec))
    for name in ("rover_proto.h", "rover_proto.c"):
        shutil.copy(C_DIR / name, tmp_path / name)
    compile_c([*WARNINGS, "-O2", "-c", tmp_path / "rover_msgs.c", "-o", tmp_path / "m.o"])
    binary = tmp_path / "rp_tool"
    compile_c(
        [
            *WARNINGS,
            *SANITIZERS,
            "-I",
            tmp_path,
            tmp_path / "rover_msgs.c",
            tmp_path / "rover_proto.c",
            C_DIR / "tests" / "rp_tool.c",
            "-o",
            binary,
        ]
    )
    tool = Tool(binary)
    # The Python codec of the same spec, as a throwaway module (dataclasses need it in
    # sys.modules while the class bodies run to resolve their ClassVar annotations).
    module = types.ModuleType("edge_messages")
    sys.modules[module.__name__] = module
    try:
        exec(compile(render_python(spec), "edge_messages.py", "exec"), module.__dict__)
    finally:
        del sys.modules[module.__name__]
    classes = {cls.NAME: cls for cls in module.MESSAGE_TYPES.values()}
    rng = random.Random(0xED6E)
    cases: list[tuple[str, dict[str, int], bool]] = []
    for m in spec.messages[-3:]:
        for pick in ("min", "max", "random", "random"):
            values = {
                f.name: f.min
                if pick == "min"
                else f.max
                if pick == "max"
                else rng.randint(f.min, f.max)
                for f in m.public_fields
            }
            cases.append((m.name, values, False))
        bad = {f.name: f.max for f in m.public_fields}
        for f in m.public_fields:
            cases.append((m.name, {**bad, f.name: f.max + 1}, True))
            if f.limit and f.limit[1] < f.max:
                cases.append((m.name, {**bad, f.name: f.limit[1] + 1}, True))
    lines = [
        " ".join(
            [
                name,
                "3",
                *(["strict=0"] if not strict else []),
                *(f"{k}={v}" for k, v in values.items()),
            ]
        )
        for name, values, strict in cases
    ]
    out = tool.lines("encode", lines)
    for (name, values, strict), line in zip(cases, out, strict=True):
        msg = classes[name](**values)
        payload, error = _pack_or_error(msg, strict)
        if error is not None:
            kind = "limit" if "limit" in str(error) else "range"
            assert line.split()[2:] == [kind, error.field], (name, values)
            continue
        raw = bytes((msg.MSG_ID, 3)) + payload
        raw += binascii.crc_hqx(raw, 0xFFFF).to_bytes(2, "big")
        assert line == f"ok 00{cobs.encode(raw).hex()}00", (name, values)
        frames, _ = parse_decode(tool.lines("decode", [line.split()[1]]))
        assert frames == [{"id": msg.MSG_ID, "seq": 3, "fields": values}]
