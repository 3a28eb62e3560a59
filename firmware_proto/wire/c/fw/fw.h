/**
 * @file fw.h
 * @brief The motor controller's firmware core: the controller state machine of
 *        docs/protocol.md in portable C99 over the generated codec (rover_msgs.h,
 *        rover_proto.h) and a small HAL (fw_hal.h).
 *
 * One fw_t holds the whole controller (no heap, no stdio, no floating point). A port
 * calls, from one thread of execution:
 *
 *   - fw_init once at power-on (sends IDENT);
 *   - fw_on_bytes with every chunk the UART received (serial), or fw_on_can with every
 *     CAN frame; a STOP has zeroed the wheel targets when the call returns;
 *   - fw_tick(now_us) once per control period (config.tick_us, 1 ms by default).
 *
 * fw_tick is fw_sense (check stall and rest on the sensors, send the telemetry due)
 * followed by fw_control (watchdog, step logic, ramp, fw_hal_set_wheels). A simulator
 * that steps its plant between the two calls them separately: fw_control(t), plant
 * step, fw_sense(t + tick): that is the emulator's order (emulator/firmware.py).
 *
 * Time is a 64-bit microsecond clock that never goes back. Time-outs (watchdog, stall,
 * the STOPPED duration and the POSE age) are scaled by config.timeout_scale_permille / 1000
 * (1000 on hardware; k*1000 in an emulator whose plant runs k times faster than the host).
 */
#ifndef FW_H
#define FW_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "../rover_proto.h"
#include "fw_hal.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Steps queued at most, the running one included (RP_MOTION_QUEUE_DEPTH). */
#define FW_QUEUE_CAP RP_MOTION_QUEUE_DEPTH
/** Accepted MOTION seqs remembered per session (docs/protocol.md, deduplication). */
#define FW_DEDUP_WINDOW 64u
/** Stops waiting for rest before their STOPPED (distinct stop_ids; more are merged). */
#define FW_PENDING_STOPS 8u
/** Host stop_ids already answered with STOPPED, remembered until CLEAR_STOP. */
#define FW_REPORTED_STOPS 16u

/** Latch causes (HEARTBEAT latch_stop, latch_watchdog, latch_fault). */
#define FW_LATCH_STOP 1u
#define FW_LATCH_WATCHDOG 2u
#define FW_LATCH_FAULT 4u

/** Top wheel speed fw_init takes (max_speed * speed_um_s_per_unit), um/s: 3 m/s. */
#define FW_SPEED_UM_S_MAX 3000000u
/** Longest braking distance fw_init takes (cruise distance at the top speed), pm: 576 km. */
#define FW_BRAKING_PM_MAX ((int64_t)1 << 59)

/**
 * What fw_init says of a configuration: FW_OK, or why it refuses to run with it. Each
 * refusal names the first field that would divide by zero or overflow the step profile's
 * 64-bit arithmetic; a refused core stays silent (no IDENT) and keeps the wheels at zero.
 */
typedef enum {
    FW_OK = 0,
    FW_ERR_TICK = 1,          /**< tick_us is 0 */
    FW_ERR_ACCEL = 2,         /**< accel_um_s2 * tick_us / 1e6 (speed change per tick) is 0
                                   or above FW_SPEED_UM_S_MAX */
    FW_ERR_RATE = 3,          /**< telemetry_hz, pose_hz or heartbeat_hz is 0 */
    FW_ERR_TIMEOUT_SCALE = 4, /**< timeout_scale_permille is 0 */
    FW_ERR_UNITS = 5,         /**< distance_units_per_m is 0 */
    FW_ERR_SPEED = 6,         /**< max_speed * speed_um_s_per_unit is above FW_SPEED_UM_S_MAX */
    FW_ERR_BRAKING = 7        /**< the braking distance from the top speed is above
                                   FW_BRAKING_PM_MAX, or times distance_units_per_m above
                                   64 bits (a faster top speed than the acceleration and the
                                   encoder resolution allow) */
} fw_error_t;

/** Transport the core answers on. */
typedef enum { FW_TRANSPORT_SERIAL = 0, FW_TRANSPORT_CAN = 1 } fw_transport_t;

/** Build-time and run-time settings; fw_default_config gives the protocol's defaults. */
typedef struct {
    uint8_t fw_major, fw_minor, fw_patch;  /**< firmware version sent in IDENT */
    uint8_t protocol_version;              /**< RP_PROTOCOL_VERSION (change to impersonate) */
    uint16_t schema_hash;                  /**< RP_SCHEMA_HASH (change to impersonate) */
    uint8_t transport;                     /**< fw_transport_t */
    uint8_t can_node;                      /**< CAN node id 1..15 */
    uint8_t queue_depth;                   /**< 1..FW_QUEUE_CAP */
    int8_t left_sign, right_sign;          /**< motor polarity, +1 or -1 */
    uint16_t watchdog_ms;                  /**< default WATCHDOG_MS parameter */
    uint8_t telemetry_hz, pose_hz, heartbeat_hz; /**< default rate parameters */
    uint16_t stall_timeout_ms;             /**< STALL_TIMEOUT_MS */
    uint32_t timeout_scale_permille;       /**< time-out scale x1000 (1000 on hardware) */
    uint32_t tick_us;                      /**< control period, us (fw_control interval) */
    uint32_t distance_units_per_m;         /**< encoder units per metre (23000) */
    uint32_t speed_um_s_per_unit;          /**< wheel surface speed of one speed unit, um/s */
    uint32_t accel_um_s2;                  /**< wheel acceleration limit, um/s^2 */
    uint8_t max_speed;                     /**< MOTION speed limit (60) */
    uint16_t max_distance;                 /**< MOTION distance limit (30000) */
} fw_config_t;

/** One queued MOTION step. */
typedef struct {
    uint16_t seq;
    uint8_t command, speed;
    uint16_t distance;
} fw_step_t;

/** A stop waiting for both wheels at rest, to be answered with STOPPED. */
typedef struct {
    uint16_t stop_id;
    uint16_t clears;      /**< fw_t.clears when the stop arrived */
    uint64_t arrived_us;
    int32_t travel[2];
} fw_pending_stop_t;

/** A periodic deadline on an exact grid (telemetry, pose, heartbeat). */
typedef struct {
    uint64_t base_ns, next_ns;
    uint32_t k;
    uint8_t hz;
} fw_sched_t;

/** The whole controller. Read the fields freely; change them only through the API. */
typedef struct {
    fw_config_t cfg;
    uint8_t error;        /**< fw_error_t of fw_init; not FW_OK: the core does nothing */
    /* parameters (SET_PARAM), reset at boot */
    uint16_t watchdog_ms;
    uint8_t telemetry_hz, pose_hz, heartbeat_hz;
    /* state machine */
    uint8_t state;        /**< rp_controller_state_t */
    bool handshake_ok;
    uint8_t latch;        /**< FW_LATCH_* bits; 0: not latched */
    uint8_t faults;       /**< active fault conditions, bit (code - 1) */
    uint8_t momentary;    /**< active faults that end at rest (stall) */
    uint16_t boot_nonce;
    bool booted;          /**< boot_nonce holds the nonce of a previous boot (fw_reboot) */
    uint64_t boot_us;
    uint32_t rx_errors;   /**< HEARTBEAT rx_errors (wraps at 16 bits on the wire) */
    /* queue and the running step */
    fw_step_t queue[FW_QUEUE_CAP];
    uint8_t q_head, q_len;
    bool running;
    fw_step_t run;
    int32_t run_start[2]; /**< rover-frame travel when the step started */
    int32_t u[2];         /**< target along each side's direction, um/s */
    int8_t dir[2];
    int32_t vmax_um_s;
    int32_t goal_units;
    int32_t cruise_units; /**< remaining travel from which the step cruises at vmax */
    int32_t a_dt;         /**< speed change per tick at the acceleration limit, um/s */
    bool arrived[2], run_done, stop_profile;
    /* deduplication */
    uint16_t accepted[FW_DEDUP_WINDOW];
    uint8_t acc_head, acc_len;
    /* wheels, rover frame, um/s */
    int32_t setpoint[2], commanded[2];
    /* stops */
    uint16_t clears;          /**< CLEAR_STOPs answered CLEARED since boot (wraps) */
    uint8_t n_pending;
    fw_pending_stop_t pending[FW_PENDING_STOPS];
    uint16_t reported[FW_REPORTED_STOPS];
    uint8_t n_reported, reported_head;
    uint8_t latch_gen;        /**< HEARTBEAT latch_gen: raised by every new latch cause */
    bool have_last_clear;     /**< a CLEAR_STOP was answered since boot */
    uint16_t last_clear_id;   /**< stop_id of the last CLEAR_STOP answered */
    uint8_t last_clear_gen;   /**< its latch_gen */
    uint8_t last_clear_result; /**< its answer (rp_clear_result_t): a repeat gets it again */
    /* PROGRESS of the last ended step */
    rp_progress_t ended;
    /* watchdog and stall */
    uint64_t last_rx_us;
    bool have_rx, wd_tripped;
    uint64_t stall_since[2];
    bool stalling[2];
    int32_t stall_ref[2];
    /* telemetry schedule */
    fw_sched_t tel, pose, hb;
    /* receive and transmit */
    rp_decoder_t dec;
    rp_can_decoder_t can_dec;
    uint32_t dec_rejected_seen;
    uint8_t tx_seq;
    uint64_t now_us;      /**< the time of the call being served */
} fw_t;

/** The protocol's defaults (docs/protocol.md, Timing) and the reference rover's drive. */
void fw_default_config(fw_config_t *cfg);

/**
 * Power-on: state BOOT, parameters at their defaults, a new nonce; sends IDENT. Returns
 * FW_OK, or the fw_error_t of a configuration it refuses: then nothing is sent, the wheels
 * are set to zero, and every other call does nothing (fw_control keeps the wheels at 0).
 */
fw_error_t fw_init(fw_t *c, const fw_config_t *cfg, uint64_t now_us);

/**
 * A reset: everything but the configuration and the rx_errors count is lost (the frame
 * counter restarts at 0, so the IDENT sent is seq 0; the remembered CLEAR_STOP id is
 * forgotten); IDENT.
 */
void fw_reboot(fw_t *c, uint64_t now_us);

/** Serial: feed received bytes; every complete frame is handled before this returns. */
void fw_on_bytes(fw_t *c, uint64_t now_us, const uint8_t *data, size_t len);

/**
 * CAN: one received frame. A frame that fails to decode counts in rx_errors whichever
 * node it was for; a valid frame for another node, or a controller-to-host frame (our
 * own kind echoed), is ignored without counting (the Python endpoint's "foreign").
 */
void fw_on_can(fw_t *c, uint64_t now_us, uint32_t can_id, bool is_extended, bool is_remote,
               const uint8_t *data, size_t len);

/** Handle one decoded message from the host (what fw_on_bytes/fw_on_can call). */
void fw_handle(fw_t *c, uint64_t now_us, const rp_msg_t *msg);

/** One control period: fw_sense then fw_control. */
void fw_tick(fw_t *c, uint64_t now_us);

/** Watchdog, step logic, ramp; calls fw_hal_set_wheels once. */
void fw_control(fw_t *c, uint64_t now_us);

/** Stall and rest detection on the sensors, STOPPED, telemetry due. */
void fw_sense(fw_t *c, uint64_t now_us);

/**
 * A fault's condition became active (FAULT active 1); a stopping fault also stops,
 * latches and enters FAULT. condition: it persists until fw_clear_fault (else it is an
 * event, like a stall, and ends at rest). Nothing happens if it is already active.
 */
void fw_raise_fault(fw_t *c, uint64_t now_us, uint8_t code, uint32_t detail, bool condition);

/** A fault's condition went away: FAULT active 0. The latch holds until CLEAR_STOP. */
void fw_clear_fault(fw_t *c, uint8_t code);

/** Count bad frames dropped before the core (a driver's own checks). */
void fw_add_rx_errors(fw_t *c, uint32_t count);

/** Steps queued, the running one included. */
uint8_t fw_queue_depth(const fw_t *c);

#ifdef __cplusplus
}
#endif

#endif /* FW_H */
