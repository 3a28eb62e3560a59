"""Whole lines from any thread (``planner/stack/lines.py``): issue #41's ``[bridge] BRIDGE
... rclpy-processstarting link:``, a part's line and the stack's own run together."""

from __future__ import annotations

import io
import threading

from planner.stack.lines import say


class _Slow(io.StringIO):
    """A stream that hands the interpreter to another thread inside every write, as a
    pipe's write may: two writes of one line would let another line in between."""

    def write(self, text: str) -> int:
        n = super().write(text)
        threading.Event().wait(0.0001)
        return n


def test_lines_said_from_many_threads_come_out_whole() -> None:
    out = _Slow()
    start = threading.Barrier(8)

    def speak(who: int) -> None:
        start.wait(10)
        for i in range(50):
            say(f"[part{who}] line {i} of part {who}", stream=out)

    threads = [threading.Thread(target=speak, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    lines = out.getvalue().splitlines()
    assert len(lines) == 400
    for line in lines:
        who = line[len("[part") : line.index("]")]
        assert line.endswith(f"of part {who}"), line
