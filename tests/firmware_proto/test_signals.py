"""``ShutdownSignals``: SIGINT and SIGTERM end a program's main-loop wait, whichever
thread they land in and whatever lock the main thread holds when Python runs the handler.

Each case runs in a child process of its own (signals are its main thread's), whose
waits are far longer than the test's limit: a wait that a signal did not end fails the
test by its time limit, not by a clock."""

from __future__ import annotations

import pytest

from tests.procs import run_snippet

HEADER = """import json, os, signal, threading
from firmware_proto.runtime import ShutdownSignals"""


def _run(body: str) -> dict[str, object]:
    """Run ``body`` (``ShutdownSignals``, ``signal``, ``threading``, ``os`` and ``json``
    imported) in a child; the JSON it prints last."""
    return run_snippet(HEADER, body)


def test_a_signal_to_the_process_ends_the_wait_and_is_remembered() -> None:
    got = _run(
        """
        with ShutdownSignals() as signals:
            assert not signals.received and not signals.wait(0.01)
            threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGTERM)).start()
            woke = signals.wait(600)
            again = signals.wait(600)  # a signal received stays received
        print(json.dumps({"woke": woke, "again": again, "signum": signals.signum}))
        """
    )
    assert got == {"woke": True, "again": True, "signum": 15}


def test_a_signal_handled_while_the_main_thread_holds_a_lock_does_not_hang_it() -> None:
    # The old handlers called Event.set(); run while the main thread held that event's
    # lock (inside its own Event.wait), it waited for ever for itself (rover gate, after
    # SIGTERM). Here the handler runs with the lock held and takes none.
    got = _run(
        """
        event = threading.Event()
        with ShutdownSignals() as signals:
            with event._cond:  # the lock Event.wait holds around its checks
                signal.raise_signal(signal.SIGINT)
                held = sum(range(10))  # the handler runs here, between two bytecodes
            print(json.dumps({"woke": signals.wait(600), "signum": signals.signum}))
        """
    )
    assert got == {"woke": True, "signum": 2}


def test_a_signal_that_lands_in_another_thread_wakes_the_main_threads_wait() -> None:
    # Python runs handlers only in the main thread; one blocked in a wait is woken by the
    # interpreter's wake-up descriptor, which the C-level handler writes in any thread.
    got = _run(
        """
        with ShutdownSignals() as signals:
            def hit_me() -> None:
                signal.pthread_kill(threading.get_ident(), signal.SIGTERM)
            threading.Timer(0.05, hit_me).start()
            print(json.dumps({"woke": signals.wait(600), "signum": signals.signum}))
        """
    )
    assert got == {"woke": True, "signum": 15}


def test_another_signal_wakes_nothing_and_counts_for_nothing() -> None:
    got = _run(
        """
        seen = []
        signal.signal(signal.SIGUSR1, lambda *_: seen.append(1))
        with ShutdownSignals() as signals:
            threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGUSR1)).start()
            threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
            woke = signals.wait(600)
        print(json.dumps({"woke": woke, "signum": signals.signum, "usr1": len(seen)}))
        """
    )
    assert got == {"woke": True, "signum": 2, "usr1": 1}


def test_while_interrupting_a_signal_raises_keyboard_interrupt_and_is_received() -> None:
    got = _run(
        """
        with ShutdownSignals(interrupt=True) as signals:
            try:
                signal.raise_signal(signal.SIGTERM)
                raised = False
            except KeyboardInterrupt:
                raised = True
            signals.interrupt = False
            signal.raise_signal(signal.SIGINT)  # no longer raises; the first one stays
            woke = signals.wait(600)
        print(json.dumps({"raised": raised, "woke": woke, "signum": signals.signum}))
        """
    )
    assert got == {"raised": True, "woke": True, "signum": 15}


def test_leaving_puts_back_the_handlers_and_the_wakeup_descriptor() -> None:
    got = _run(
        """
        def mine(signum, frame):
            pass
        signal.signal(signal.SIGTERM, mine)
        sigint = signal.getsignal(signal.SIGINT)  # as inherited (ignored in a background job)
        r, w = os.pipe()
        os.set_blocking(w, False)
        signal.set_wakeup_fd(w)
        with ShutdownSignals():
            inside = signal.getsignal(signal.SIGTERM) is not mine
        print(json.dumps({
            "inside": inside,
            "handler": signal.getsignal(signal.SIGTERM) is mine,
            "sigint": signal.getsignal(signal.SIGINT) is sigint,
            "fd": signal.set_wakeup_fd(-1) == w,
        }))
        """
    )
    assert got == {"inside": True, "handler": True, "sigint": True, "fd": True}


@pytest.mark.parametrize("timeout_s", [0.0, 0.02])
def test_outside_the_main_thread_it_changes_nothing_and_only_times_out(
    timeout_s: float,
) -> None:
    got = _run(
        f"""
        out = {{}}
        sigint = signal.getsignal(signal.SIGINT)  # as inherited (ignored in a background job)
        def other() -> None:
            with ShutdownSignals() as signals:
                out["woke"] = signals.wait({timeout_s})
                out["handler"] = signal.getsignal(signal.SIGINT) is sigint
        t = threading.Thread(target=other)
        t.start()
        t.join(60)
        print(json.dumps(out))
        """
    )
    assert got == {"woke": False, "handler": True}
