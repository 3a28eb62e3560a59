"""Which tests run in which lane (README, "Tests"): one list, applied at collection by
tests/conftest.py.

- **fast lane** (``-m "not slow"``): the edit-test loop. :data:`SLOW_MODULES` are whole
  modules of real time, real processes or real DDS; their tests are marked ``slow`` as
  well as those marked so where they are written.
- **the test command** (``.ci/test``): everything but ``extended``. Of it, the fast lane
  and the tests marked ``virtual`` (slow, but needing no wall clock: the wire
  simulator's soak, :data:`VIRTUAL_MODULES` and :data:`HEAVY`) run beside the real-time
  tests, at a lower priority (docs/testing.md).
- **extended** (``-m extended``): wall-time tests whose behaviour the test command checks
  otherwise: in virtual time against both controllers (the wire simulator, tests/sim),
  or by a test of the same path kept in the command. Each entry of :data:`EXTENDED`
  says where. They still run, on demand (README), and before a release.
"""

from __future__ import annotations

import pytest

__all__ = [
    "EXTENDED",
    "HEAVY",
    "IDLE",
    "SLOW_MODULES",
    "SOAK_LONGEST_FIRST",
    "VIRTUAL_MODULES",
    "VIRTUAL_TESTS",
    "keeps_wall_time",
    "lane_marks",
    "soak_rank",
]

SLOW_MODULES = (
    "tests/bridge/test_cli_bridge.py",
    "tests/bridge/test_conformance.py",
    "tests/bridge/test_conformance_probe.py",
    "tests/bridge/test_inprocess.py",
    "tests/bridge/test_latch_recovery.py",
    "tests/bridge/test_link.py",
    "tests/bridge/test_link_rules.py",
    "tests/bridge/test_linklines.py",
    "tests/bridge/test_node.py",
    "tests/bridge/test_onboard_mission.py",
    "tests/bridge/test_port.py",
    "tests/bridge/test_process_port.py",
    "tests/bridge/test_rclpy_backend.py",
    "tests/bridge/test_ros2_contract.py",
    "tests/bridge/test_ros_package.py",
    "tests/bridge/test_socketcan.py",
    "tests/bridge/test_stop_lane.py",
    "tests/bridge/test_stop_write_path.py",
    "tests/bridge/test_stopbench.py",
    "tests/bridge/test_traffic.py",
    "tests/bridge/test_transport_threads.py",
    "tests/bridge/test_transports.py",
    "tests/emulator/test_calibration.py",
    "tests/emulator/test_campaign.py",
    "tests/emulator/test_emulator_main.py",
    "tests/emulator/test_firmware.py",
    "tests/emulator/test_late.py",
    "tests/emulator/test_pil.py",
    "tests/emulator/test_pil_demo.py",
    "tests/emulator/test_pil_images.py",
    "tests/emulator/test_pil_lockstep.py",
    "tests/emulator/test_served.py",
    "tests/firmware_proto/test_c_codec.py",
    "tests/firmware_proto/test_cli.py",
    "tests/firmware_proto/test_fw.py",
    "tests/firmware_proto/test_http.py",
    "tests/firmware_proto/test_libfuzzer.py",
    "tests/firmware_proto/test_runtime.py",
    "tests/firmware_proto/test_signals.py",
    "tests/firmware_proto/test_values.py",
    "tests/gate/test_cli.py",
    "tests/gate/test_hostile.py",
    "tests/planner/test_calibrate_real.py",
    "tests/planner/test_console.py",
    "tests/planner/test_console_browser.py",
    "tests/planner/test_console_server.py",
    "tests/planner/test_demo.py",
    "tests/planner/test_executor.py",
    "tests/planner/test_foxlive.py",
    "tests/planner/test_interrupt.py",
    "tests/planner/test_mission.py",
    "tests/planner/test_orphans.py",
    "tests/planner/test_relay_ros2.py",
    "tests/planner/test_view.py",
    "tests/planner/test_view_browser.py",
    "tests/planner/test_view_hostile.py",
    "tests/planner/test_walkthrough.py",
    "tests/test_benchmarks.py",
    "tests/test_lanes.py",
    "tests/test_require_socketcan.py",
    "tests/test_timeouts.py",
    "tests/test_vcan_vm.py",
)
"""Modules of real time, subprocesses or DDS: ``slow``, out of the fast lane."""

VIRTUAL_MODULES = (
    "tests/emulator/test_calibration.py",  # lockstep recordings; a gate on port 0
    "tests/emulator/test_campaign.py",  # designed calibrations in lockstep
    "tests/firmware_proto/test_c_codec.py",  # compilers, then vectors
    "tests/emulator/test_firmware.py",  # the C core's build, then lockstep against the model
    "tests/emulator/test_pil_images.py",  # cross builds of the PIL images, a layout check
    "tests/emulator/test_pil_lockstep.py",  # the ATmega2560 and its twin on a lockstep clock
    "tests/firmware_proto/test_fw.py",  # cross builds, simavr and qemu-arm run to the end
    "tests/firmware_proto/test_libfuzzer.py",  # a fixed count of runs, not a duration
    "tests/planner/test_executor.py",  # whole rover sides in virtual time (sim/world.py)
    "tests/planner/test_mission.py",  # the same, with move-and-wait
    "tests/test_lanes.py",  # collections
)
"""Slow modules whose tests need no wall clock (no watchdog, no rate, no deadline but a
generous timeout): marked ``virtual``, so that ``.ci/test`` runs them beside the
real-time tests, at a lower priority."""

VIRTUAL_TESTS = (
    # Benchmarks' quick runs that keep no wall clock: CPU work, figures not asserted.
    "tests/test_benchmarks.py::test_bench_codec_quick",
    "tests/test_benchmarks.py::test_bench_twin_quick",
    "tests/test_benchmarks.py::test_bench_firmware_quick",
    "tests/test_benchmarks.py::test_bench_uncertain_quick",
    "tests/test_benchmarks.py::test_bench_onboard_quick",  # missions in virtual time
    "tests/test_benchmarks.py::test_the_stop_bench_runs_a_trial_again",  # lockstep
    # Lockstep runs of the controllers (virtual time) in modules of real-time tests.
    "tests/bridge/test_conformance.py::test_both_controllers_pass_every_rule_in_lockstep",
    "tests/bridge/test_conformance.py::test_the_c_firmware_passes_every_rule_under_asan",
)
"""Node-id prefixes of tests in :data:`SLOW_MODULES` that need no wall clock: marked
``virtual``, so that they run in the test command's no-wall-clock part, not beside the
real-time tests."""

HEAVY: dict[str, str] = {
    # Node-id prefix -> what the fast lane keeps of it. Each costs seconds of CPU and no
    # wall clock: out of the fast lane (30 s), in the test command's no-wall-clock part.
    "tests/firmware_proto/test_schemacheck.py::test_the_fast_path_agrees_with_jsonschema": (
        "the same property on 150 examples: test_the_fast_path_agrees_on_a_quick_sample"
    ),
    "tests/gate/test_pool.py::": "the gate's answers: tests/gate/test_validator.py",
    "tests/gate/test_concurrency.py::": "the gate's answers: tests/gate/test_validator.py",
    "tests/gate/test_lifecycle.py::test_a_dead_worker_process_is_replaced": (
        "the rest of tests/gate/test_lifecycle.py"
    ),
    "tests/planner/test_orchestrator.py::test_gives_up_after_max_attempts_with_every_verdict": (
        "the repairs that succeed: the rest of tests/planner/test_orchestrator.py"
    ),
    "tests/planner/test_experiment.py::test_experiment_with_random_goals": (
        "test_experiment_on_scn01"
    ),
    "tests/gate/test_uncertainty.py::test_a_batch_twin_plays_as_the_single_twin": (
        "test_the_gate_answers_with_the_documented_uncertainty"
    ),
    "tests/gate/test_uncertainty.py::test_the_summary_says_what_the_samples_did": (
        "test_the_gate_answers_with_the_documented_uncertainty"
    ),
    "tests/bridge/test_mutants.py::test_the_suite_fails_the_mutant_on_the_rule_it_breaks"
    "[no-accel-ramp]": "the mutant stopped-at-once",
    "tests/bridge/test_mutants.py::test_the_suite_fails_the_mutant_on_the_rule_it_breaks"
    "[no-brake-ramp]": "the mutant stopped-at-once",
    "tests/emulator/test_twin.py::test_same_inputs_same_trajectory_across_processes": (
        "test_the_same_run_twice_gives_the_same_trajectory (tests/emulator/test_controller.py)"
    ),
}
"""Tests that need no wall clock but seconds of CPU each: ``slow`` and ``virtual``, so
that the fast lane stays within 30 s (docs/testing.md) while the test command runs
them; each entry says what the fast lane keeps of what it checks."""

_SIM = "tests/sim/test_soak.py (virtual time, both controllers)"
_LATCH = "tests/bridge/test_latch_recovery.py::"
_CONF = "tests/bridge/test_conformance.py::"
_LOCKSTEP = _CONF + "test_both_controllers_pass_every_rule_in_lockstep (both media)"

EXTENDED: dict[str, str] = {
    # Benchmarks: figures, not behaviour; the quick runs of the others stay.
    "tests/test_benchmarks.py::test_bench_console_quick_prints_its_table": (
        "the four console commands through a stack's console socket: tests/planner/"
        "test_console.py::test_a_stack_on_a_real_device_starts_no_emulator; rover stack up "
        "--speed 4 with its emulator: tests/planner/test_walkthrough.py"
    ),
    "tests/test_benchmarks.py::test_bench_calibration_quick_cuts_the_error_on_every_ground": (
        "the fit and the designed calibration: tests/emulator/test_calibration.py and "
        "tests/emulator/test_campaign.py (lockstep), tests/planner/test_calibrate_real.py "
        "(a real stack)"
    ),
    "tests/test_benchmarks.py::test_bench_rosport_small_counts_print_its_tables": (
        "the port's contract on both backends: tests/bridge/test_port.py"
    ),
    "tests/test_benchmarks.py::test_bench_bridge_ros2_case_prints_its_rows": (
        "the bridge's STOP path benchmark: test_bench_bridge_quick_prints_its_table"
    ),
    "tests/test_benchmarks.py::test_bench_socketcan_quick_prints_every_case_beside_the_floor": (
        "STOP over SocketCAN: tests/bridge/test_stop_write_path.py and the STOP bench over a "
        "flooded vcan0 (tests/bridge/test_socketcan.py), in the VM"
    ),
    # The bridge node over a ROS 2 process: two smoke tests stay (steps, STOP lane).
    "tests/bridge/test_node.py::test_bad_input_is_rejected_precisely_and_nothing_is_sent"
    "[rclpy-process": "the same checks on the in-process backend; the node's checks run "
    "before any ROS call",
    "tests/bridge/test_node.py::test_stop_step_on_wheel_instructions_is_an_emergency_stop"
    "[rclpy-process]": "in-process backend; " + _SIM,
    "tests/bridge/test_node.py::test_diagnostics_report_link_and_controller[rclpy-process]": (
        "in-process backend"
    ),
    "tests/bridge/test_node.py::test_odom_is_continuous_across_a_controller_reboot"
    "[rclpy-process]": "in-process backend; the odometry invariant of " + _SIM,
    # The port over a ROS 2 process: these checks are the base class's, before any call
    # to the child, or the child's RclpyPort, which [rclpy] runs in process; the
    # child's own operations (round trips, STOP lane, parameters, QoS, matched
    # publishers, closing readers and writers) stay in their [rclpy-process] tests.
    **{
        f"tests/bridge/test_port.py::{name}[rclpy-process]": "[inprocess] and [rclpy]"
        for name in (
            "test_callbacks_run_on_the_backend_thread",
            "test_a_raising_callback_is_logged_counted_and_survived",
            "test_relative_names_get_the_namespace_absolute_ones_do_not",
            "test_invalid_names_are_refused",
            "test_wrong_types_are_refused",
            "test_closed_things_refuse_work_and_close_is_idempotent",
            "test_subscriptions_closed_while_the_lane_waits_leave_it_delivering",
            "test_waiting_for_subscribers_times_out",
        )
    },
    # The onboard program's rule, in its core; the process's wiring stays in the other
    # onboard mission (its STOP latching the controller).
    "tests/bridge/test_onboard_mission.py::test_a_step_someone_else_publishes_while_a_plan"
    "_runs_ends_the_plan_with_stop": (
        "tests/bridge/test_onboard_core.py::test_a_foreign_step_ends_the_plan_with_stop_instead"
        "_of_advancing_it; tests/bridge/test_onboard_mission.py::test_a_plan_runs_on_board_bad"
        "_uplinks_are_refused_and_the_guard_stops_a_slip"
    ),
    # The link's latch recovery in real time, in process: the invariants auto-clear and
    # never-stuck of the simulator, against both controllers; the bridge process frozen
    # with SIGSTOP stays in the command (only real time shows it).
    _LATCH + "test_outage_the_host_never_sees_is_cleared_by_the_bridge": _SIM,
    _LATCH + "test_outage_longer_than_link_lost_is_cleared_after_the_handshake": _SIM,
    _LATCH + "test_bridge_frozen_in_process_recovers_every_time": _SIM,
    _LATCH + "test_an_operator_stop_is_never_cleared_by_the_bridge": _SIM,
    _LATCH + "test_a_fault_latch_is_left_to_the_operator": _SIM,
    _LATCH + "test_fault_persists_is_over_and_only_a_new_clear_releases": _SIM,
    # The link on the virtual CAN bus and on SocketCAN: tests/sim plays CAN in virtual time;
    # the pty case of each stays, and tests/bridge/test_socketcan.py is SocketCAN's smoke.
    "tests/bridge/test_link.py::test_corrupted_and_dropped_frames_lose_nothing_and_run_nothing"
    "_twice[virtual]": _SIM,
    "tests/bridge/test_link.py::test_corrupted_and_dropped_frames_lose_nothing_and_run_nothing"
    "_twice[socketcan]": _SIM,
    "tests/bridge/test_link.py::test_heartbeat_loss_reports_link_lost_then_recovers[virtual]": _SIM,
    "tests/bridge/test_link.py::test_heartbeat_loss_reports_link_lost_then_recovers"
    "[socketcan]": _SIM,
    "tests/bridge/test_link.py::test_controller_reboot_is_detected_and_nothing_replayed"
    "[virtual]": _SIM,
    "tests/bridge/test_link.py::test_controller_reboot_is_detected_and_nothing_replayed"
    "[socketcan]": _SIM,
    "tests/bridge/test_link.py::test_estop_survives_a_reboot[virtual]": _SIM,
    "tests/bridge/test_link.py::test_estop_survives_a_reboot[socketcan]": _SIM,
    # The conformance suite in real time: one controller per medium (the C core's process
    # over a pty, the Python model on the virtual CAN bus); every rule against both
    # controllers on both media runs in lockstep (virtual time) in the command.
    _CONF + "test_the_emulator_passes_the_smoke_rules_over_a_pty_in_real_time[python]": (
        _LOCKSTEP + "; the pty's smoke on the C core"
    ),
    _CONF + "test_the_emulator_passes_the_smoke_rules_on_a_virtual_can_bus_in_real_time[c]": (
        _LOCKSTEP + "; the virtual bus's smoke on the Python model"
    ),
    _CONF + "test_without_a_control_port_those_rules_are_not_run_never_passed[c]": (
        "the same command against the Python model's process (the rule selection is the "
        "suite's, not the controller's)"
    ),
    # The STOP bench command over SocketCAN, twice (about 40 s of the VM's software CPU):
    # STOP under a flood over SocketCAN, and each malformed frame counted and ignored
    # there, stay in the VM; the bench's malformed flood and its command stay on the host.
    "tests/bridge/test_socketcan.py::test_the_stop_bench_command_over_vcan_flooded_with_valid"
    "_and_malformed_frames": (
        "tests/bridge/test_stopbench.py::test_stop_is_acknowledged_stops_latches_and_clears_under"
        "_load[socketcan] and test_socketcan.py::test_malformed_frames_are_counted_and_ignored_by"
        "_bridge_and_emulator[socketcan] (VM); [virtual-malformed] and "
        "test_rover_bench_stop_cli_records_and_reports (host)"
    ),
    # ROS 2 over SocketCAN in the VM: on a host whose VM ran a Python loop 20 times slower
    # than itself (2026-11-27), the guest's bridge process stalled 0.4-0.9 s now and then
    # and the link was lost: 5 runs of 12 failed there as the test was, and 3 of 4 with 10
    # missed heartbeats allowed (`link_lost_beats=10`, ACK timeout 0.25 s, watchdog 1 s),
    # so the test command could not hold it. Its parts stay, each where the VM's CPU can keep time.
    "tests/bridge/test_ros2_contract.py::test_a_mission_over_real_socketcan_recorded_and"
    "_replayed_by_can_utils": (
        "ROS 2 across processes to a bridge process: tests/bridge/test_node.py::"
        "test_bridge_process_over_ros2 (host); steps, STOP, bus-off and malformed frames over "
        "SocketCAN: tests/bridge/test_link.py, test_stopbench.py, test_transports.py and "
        "test_socketcan.py (VM); candump logs recorded and decoded: "
        "tests/bridge/test_traffic.py (host)"
    ),
    # The page at the real 3 s round trip through a whole demo (about 60 s of wall in the
    # serial part): issue #41's ghost (a step's ``published`` reported three times
    # before the rover acknowledges it) is the view hub's, checked in virtual time through
    # a mission, a STOP and a re-plan; the page over a real stack stays in the STOP test.
    "tests/planner/test_view_browser.py::test_the_ghost_stays_on_the_plan_at_speed_1": (
        "tests/planner/test_view_hub.py::test_the_ghost_stays_on_the_plan_through_a_mission"
        "_a_stop_and_a_replan (virtual time); tests/planner/test_view_browser.py::"
        "test_stop_on_the_page_stops_the_emulated_rover (the page, the ghost, a real stack)"
    ),
    # The nRF51's whole mission (about 110 s of wall in the serial part): its image passes
    # every conformance rule and the STOP bench over its UART in the command, and the
    # ATmega2560's demo (the issue's "done when") stays.
    "tests/emulator/test_pil_demo.py::test_rover_demo_on_the_image_stops_on_drift_and_reaches"
    "_its_goal[microbit]": (
        "tests/emulator/test_pil.py (conformance and STOP bench on the nRF51 image) and "
        "test_pil_demo.py's [atmega2560] mission"
    ),
    # The ATmega2560 image's every rule: in lockstep on the same image and plant; its
    # real-time loop over a pty stays (the STOP bench, the control port, the demo), and
    # the nRF51's every rule in real time (the PIL runner's control port).
    "tests/emulator/test_pil.py::test_the_image_passes_every_conformance_rule_over_its_uart"
    "[atmega2560]": (
        "tests/emulator/test_pil_lockstep.py::test_every_conformance_rule_passes_in_lockstep; "
        "test_pil.py's [microbit] run and [atmega2560] STOP bench and control port"
    ),
    # Whole missions: the demo on the Python model stays; the C core's run of every rule
    # and scenario is tests/bridge/test_conformance.py and tests/sim.
    "tests/planner/test_demo.py::test_rover_demo_plans_detours_stops_on_drift_replans_and"
    "_arrives[c]": "the demo on the Python model; the C core in " + _SIM,
    "tests/planner/test_demo.py::test_rover_go_interrupted_mid_step_stops_the_rover_and_says"
    "_cancelled[SIGTERM]": "the same path with SIGINT (Ctrl-C)",
}
"""Node-id prefixes of the tests out of the test command, and where what they show is
checked in it."""


IDLE = (
    # The mutation score: the conformance suite in lockstep against each mutant (about
    # 40 CPU-seconds in all; 50 before the speed-ups of 2026-11-30).
    "tests/bridge/test_mutants.py::test_the_suite_fails_the_mutant_on_the_rule_it_breaks",
    # Whole simulated rover sides on both controllers and media (about 13 CPU-seconds).
    "tests/sim/test_world.py::test_the_mission_goes_as_it_must",
)
"""Node-id prefixes of tests that, beside the wire simulator's soak, keep no clock, start
no program and take seconds of CPU in all: marked ``soak``, so that the test command
runs them in its soak part, under ``SCHED_IDLE``, on the CPU the others leave, instead
of in its no-wall-clock part, one process that would otherwise end last (docs/testing.md).
The fast lane keeps what it ran of them."""


SOAK_LONGEST_FIRST = (
    # About 10 CPU-seconds each.
    "tests/sim/test_mission.py::test_seeded_missions_keep_every_invariant",
    "tests/sim/test_soak.py::test_thousands_of_seeded_scenarios_keep_every_invariant",
    # 1-1.5 s each.
    "tests/sim/test_world.py::test_the_mission_goes_as_it_must[demo-",
    # About 0.6 s each.
    "tests/bridge/test_mutants.py::test_the_suite_fails_the_mutant_on_the_rule_it_breaks",
)
"""The test command's soak part runs its tests in this order (node-id prefixes, the
longest first; the rest after them, in collection order), handed to its two workers one
or two at a time (``.ci/test``), so that it ends on tests of a second or less: one
worker no longer waits for the other's last long test at the end of the run
(docs/testing.md, "The end of a run")."""


def soak_rank(nodeid: str) -> int:
    """A test's place in the soak part's order (:data:`SOAK_LONGEST_FIRST`): the index of
    the first prefix it starts with, else one past the last."""
    for rank, prefix in enumerate(SOAK_LONGEST_FIRST):
        if nodeid.startswith(prefix):
            return rank
    return len(SOAK_LONGEST_FIRST)


def lane_marks(nodeid: str) -> tuple[bool, bool, bool, bool]:
    """``(slow, extended, virtual, soak)`` for a test's node id (``soak``: one of
    :data:`IDLE`; the soak's own tests are marked where they are written)."""
    path = nodeid.split("::", 1)[0]
    extended = any(nodeid.startswith(prefix) for prefix in EXTENDED)
    heavy = any(nodeid.startswith(prefix) for prefix in HEAVY)
    virtual = path in VIRTUAL_MODULES or heavy or any(nodeid.startswith(p) for p in VIRTUAL_TESTS)
    idle = any(nodeid.startswith(prefix) for prefix in IDLE)
    return path in SLOW_MODULES or extended or heavy, extended, virtual, idle


def keeps_wall_time(item: pytest.Item) -> bool:
    """Whether a collected test keeps wall time: marked ``slow`` and not ``virtual``
    (the test command's host, serial and VM parts; the fast lane has none)."""
    return item.get_closest_marker("slow") is not None and (
        item.get_closest_marker("virtual") is None
    )
