"""``CancelOnSignal``: the first SIGINT/SIGTERM calls ``on_signal`` on a thread of its
own, the next raises ``KeyboardInterrupt``; nothing of it runs in the handler, so a
signal handled while the main thread waits on the very event ``on_signal`` sets cannot
hang it.

Each case runs in a child process of its own (signals are its main thread's), whose
waits are far longer than the test's limit: a wait that the signal did not end fails the
test by its time limit, not by a clock."""

from __future__ import annotations

from tests.procs import run_snippet

HEADER = """import json, os, signal, threading
from planner.ground.interrupt import CancelOnSignal"""


def test_the_first_signal_sets_the_cancel_even_inside_that_events_own_wait() -> None:
    # The mission loop waits on `cancel`; Python may run the handler just after that
    # wait took the event's lock. There, a handler that set the event itself hung.
    got = run_snippet(
        HEADER,
        """
        cancel = threading.Event()
        threads = []
        def on_signal(signum):
            threads.append(threading.current_thread().name)
            cancel.set()
        with CancelOnSignal(on_signal) as signals:
            with cancel._cond:  # as inside cancel.wait(), before it sleeps
                signal.raise_signal(signal.SIGTERM)
                held = sum(range(10))  # the handler runs here
            woke = cancel.wait(600)
        print(json.dumps({"woke": woke, "threads": threads, "status": signals.exit_status}))
        """,
    )
    assert got == {"woke": True, "threads": ["signal-dispatch"], "status": 143}


def test_the_second_signal_raises_keyboard_interrupt_in_the_main_thread() -> None:
    got = run_snippet(
        HEADER,
        """
        calls = []
        with CancelOnSignal(calls.append) as signals:
            signal.raise_signal(signal.SIGINT)
            try:
                signal.raise_signal(signal.SIGINT)
                second = "nothing"
            except KeyboardInterrupt as exc:
                second = str(exc)
        print(json.dumps({"calls": calls, "second": second, "signum": signals.signum}))
        """,
    )
    assert got == {"calls": [2], "second": "signal SIGINT received twice", "signum": 2}


def test_an_on_signal_that_raises_keyboard_interrupt_interrupts_the_main_thread() -> None:
    # `rover demo` before its mission runs: nothing needs a STOP, the start-up ends.
    got = run_snippet(
        HEADER,
        """
        def on_signal(signum):
            raise KeyboardInterrupt("nothing to stop yet")
        try:
            with CancelOnSignal(on_signal):
                os.kill(os.getpid(), signal.SIGTERM)
                threading.Event().wait(600)
            got = "not interrupted"
        except KeyboardInterrupt as exc:
            got = str(exc)
        print(json.dumps({"got": got}))
        """,
    )
    assert got == {"got": "nothing to stop yet"}


def test_leaving_puts_back_the_handlers_and_ends_the_dispatch_thread() -> None:
    got = run_snippet(
        HEADER,
        """
        def mine(signum, frame):
            pass
        signal.signal(signal.SIGTERM, mine)
        sigint = signal.getsignal(signal.SIGINT)  # as inherited (ignored in a background job)
        calls = []
        with CancelOnSignal(calls.append):
            inside = {t.name for t in threading.enumerate()}
            signal.raise_signal(signal.SIGTERM)
        after = {t.name for t in threading.enumerate()}
        print(json.dumps({
            "inside": "signal-dispatch" in inside,
            "after": "signal-dispatch" in after,
            "calls": calls,  # run before the context ended
            "handler": signal.getsignal(signal.SIGTERM) is mine,
            "sigint": signal.getsignal(signal.SIGINT) is sigint,
        }))
        """,
    )
    assert got == {"inside": True, "after": False, "calls": [15], "handler": True, "sigint": True}
