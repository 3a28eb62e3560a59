"""Admission by cost on its own (pure bookkeeping): what a request costs, the cap of one
request, a client's share, the gate's whole budget; what is released."""

from __future__ import annotations

import math

import pytest

from gate.admission import (
    CALL_WORK_S,
    SAMPLE_STEP_WORK_S,
    STEP_WORK_S,
    Admission,
    Cost,
    Limits,
)
from gate.errors import OptionError, OverloadedError, TooManyRequestsError

DT_S = 0.01
SLOWEST_S = 3131.0
"""Twin seconds of the slowest valid plan (12 steps of 30000 units at speed 1)."""


def test_a_cost_counts_the_nominal_playback_and_every_sample() -> None:
    single = Cost.of(55.0, DT_S, 1, 0)
    assert single.calls == 1 and single.samples == 0
    assert single.work_s == pytest.approx(5500 * STEP_WORK_S + CALL_WORK_S)
    many = Cost.of(55.0, DT_S, 200, 2)
    assert many.calls == 3 and many.samples == 200
    assert many.work_s == pytest.approx(
        5500 * STEP_WORK_S + 200 * 5500 * SAMPLE_STEP_WORK_S + 3 * CALL_WORK_S
    )


def test_a_request_over_a_clients_share_is_refused_for_good_naming_samples() -> None:
    limits = Limits.for_gate(workers=2, queue_depth=16, request_timeout_s=60.0)
    assert (limits.capacity, limits.client_count) == (18, 16)
    assert (limits.budget_s, limits.share_s) == (120.0, 60.0)
    admission = Admission(limits)
    worst = Cost.of(SLOWEST_S, DT_S, 2000, 20)
    with pytest.raises(OptionError) as info:
        admission.check_request(worst, DT_S)
    assert info.value.parameter == "samples"
    most = worst.most_samples(limits.share_s, DT_S)
    assert f"at most {most} samples" in str(info.value)
    fits = Cost.of(SLOWEST_S, DT_S, most, 2)
    admission.check_request(fits, DT_S)
    with pytest.raises(OptionError):
        admission.check_request(Cost.of(SLOWEST_S, DT_S, most + 1, 2), DT_S)
    admission.check_request(Cost.of(55.0, DT_S, 2000, 20), DT_S)  # an ordinary plan may


def test_a_client_holding_its_share_waits_while_others_are_served() -> None:
    admission = Admission(Limits.for_gate(workers=2, queue_depth=2, request_timeout_s=10.0))
    big = Cost.of(SLOWEST_S, DT_S, 1, 0)  # 3.1 s of its 10 s share
    tickets = [admission.admit("a", big) for _ in range(3)]
    with pytest.raises(TooManyRequestsError) as info:
        admission.admit("a", big)  # over a's share of the work
    assert info.value.status == 429 and int(info.value.headers["Retry-After"]) >= 1
    small = Cost.of(5.0, DT_S, 1, 0)
    admission.admit("b", small)  # b is served meanwhile
    with pytest.raises(OverloadedError):
        admission.admit("c", small)  # 4 of 4 places taken: the gate is full
    admission.release(tickets[0])
    admission.release(tickets[0])  # idempotent
    assert admission.in_flight == 3 and admission.clients == 2
    with pytest.raises(TooManyRequestsError, match="while others have some"):
        admission.admit("a", small)  # a has capacity - workers = 2 places, b is here
    assert admission.admit("c", small).client == "c"


def test_a_client_alone_may_fill_the_queue_and_the_budget_bounds_everyone() -> None:
    admission = Admission(Limits.for_gate(workers=1, queue_depth=2, request_timeout_s=4.0))
    small = Cost.of(5.0, DT_S, 1, 0)
    held = [admission.admit("a", small) for _ in range(3)]  # alone: every place
    with pytest.raises(OverloadedError, match="queued"):
        admission.admit("a", small)
    for ticket in held:
        admission.release(ticket)
    assert admission.in_flight == 0 and admission.work_s == 0.0 and admission.clients == 0
    half = Cost(twin_s=0.0, samples=0, calls=1, work_s=1.9)
    admission.admit("a", half)
    admission.admit("b", half)
    with pytest.raises(OverloadedError, match="within the deadline") as info:
        admission.admit("c", half)  # 5.7 s of work over the 4 s budget
    assert info.value.status == 503 and int(info.value.headers["Retry-After"]) >= 1


def test_a_calibrated_twins_step_error_is_weighed_on_every_chunk() -> None:
    """Each chunk of a calibrated twin's uncertainty plays the nominal twin twice more
    (at the gate's step and at the step error's finer one): admission weighs it, and
    the most samples a plan may ask for shrinks with it."""
    plain = Cost.of(55.0, DT_S, 200, 2)
    calibrated = Cost.of(55.0, DT_S, 200, 2, fine_dt_s=0.002)
    steps = math.ceil(55.0 / DT_S)
    per_chunk = (steps + math.ceil(55.0 / 0.002)) * STEP_WORK_S
    assert calibrated.chunk_extra_s == pytest.approx(per_chunk)
    assert calibrated.work_s == pytest.approx(plain.work_s + 2 * per_chunk)
    assert Cost.of(55.0, DT_S, 1, 0, fine_dt_s=0.002).work_s == Cost.of(55.0, DT_S, 1, 0).work_s
    cap = 10.0
    most = calibrated.most_samples(cap, DT_S)
    assert 0 < most < plain.most_samples(cap, DT_S)
    chunks = math.ceil(most / 100)
    assert Cost.of(55.0, DT_S, most, max(2, chunks), fine_dt_s=0.002).work_s <= cap
