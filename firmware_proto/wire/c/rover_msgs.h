/* GENERATED from firmware_proto/wire/protocol.toml by firmware_proto/wire/codegen/c.py
 * (`rover frame generate`). Do not edit: edit the spec and regenerate. */

/**
 * @file rover_msgs.h
 * @brief Messages of the rover motor-controller protocol, version 4.
 *
 * Payloads are bit-packed least significant bit first, little-endian (DBC Intel);
 * fields hold raw integers (docs/protocol.md gives units and scales). Every
 * function is reentrant, allocation-free and float-free; errors are negative
 * return codes (RP_ERR_*), never asserts. Framing, COBS, CRC and the stream and CAN
 * decoders are in rover_proto.h.
 */
#ifndef ROVER_MSGS_H
#define ROVER_MSGS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------ protocol constants */

#define RP_PROTOCOL_VERSION 4u /**< sent in HELLO and IDENT */
#define RP_SCHEMA_HASH 0x75E0u /**< CRC-16 of the wire-relevant spec; compared at HELLO */
#define RP_MAX_PAYLOAD_BYTES 8u /**< largest payload (one classic CAN frame) */
#define RP_DELIMITER 0x00u /**< serial frame delimiter */
#define RP_CAN_NODE_BITS 4u /**< CAN identifier = id << RP_CAN_NODE_BITS | node */
#define RP_BROADCAST_NODE 0u /**< CAN node of host-to-controller broadcasts */
#define RP_DEFAULT_NODE 1u /**< default controller node id */
#define RP_MSG_COUNT 20u /**< number of message types */

/* Timing (docs/protocol.md, 'Timing'). */
#define RP_HOST_HEARTBEAT_PERIOD_MS 100u
#define RP_CONTROLLER_HEARTBEAT_PERIOD_MS 100u
#define RP_WATCHDOG_MS 250u
#define RP_LINK_LOST_HEARTBEATS 3u
#define RP_ACK_TIMEOUT_MS 50u
#define RP_MOTION_RETRIES 3u
#define RP_STOP_REPEAT_MS 10u
#define RP_MOTION_QUEUE_DEPTH 8u
#define RP_STALL_TIMEOUT_MS 1000u
#define RP_ENCODERS_RATE_HZ 50u
#define RP_WHEEL_SPEEDS_RATE_HZ 50u
#define RP_IMU_RATE_HZ 50u
#define RP_POSE_RATE_HZ 10u

/* Priority classes: inclusive message id ranges, lower ids win CAN arbitration. */
#define RP_PRIORITY_EMERGENCY_FIRST 0u
#define RP_PRIORITY_EMERGENCY_LAST 7u
#define RP_PRIORITY_MOTION_FIRST 8u
#define RP_PRIORITY_MOTION_LAST 31u
#define RP_PRIORITY_STATUS_FIRST 32u
#define RP_PRIORITY_STATUS_LAST 63u
#define RP_PRIORITY_TELEMETRY_FIRST 64u
#define RP_PRIORITY_TELEMETRY_LAST 95u
#define RP_PRIORITY_CONFIG_FIRST 96u
#define RP_PRIORITY_CONFIG_LAST 127u

/* ------------------------------------------------------------ result codes */

#define RP_OK 0 /**< success */
#define RP_ERR_NULL (-1) /**< a required pointer was NULL */
#define RP_ERR_UNKNOWN_ID (-2) /**< message id not in the protocol */
#define RP_ERR_LENGTH (-3) /**< payload length differs from the message's */
#define RP_ERR_BUFFER (-4) /**< output buffer too small */
#define RP_ERR_NODE (-5) /**< CAN node id outside 0..15 */
#define RP_ERR_BROADCAST (-6) /**< controller-to-host message to the broadcast node */
#define RP_ERR_FRAMING (-7) /**< input is not valid COBS */
#define RP_ERR_FIELD_BASE (-100) /**< see RP_ERR_FIELD() */
#define RP_ERR_LIMIT_BASE (-200) /**< see RP_ERR_LIMIT() */
/** Field with index i (RP_F_*) outside its wire range, or not representable. */
#define RP_ERR_FIELD(i) (RP_ERR_FIELD_BASE - (int)(i))
/** Field with index i (RP_F_*) outside its semantic limit (strict pack only). */
#define RP_ERR_LIMIT(i) (RP_ERR_LIMIT_BASE - (int)(i))

/** Index of the field named by an RP_ERR_FIELD/RP_ERR_LIMIT code, else -1. */
int rp_err_field_index(int err);
/** True if err is an RP_ERR_LIMIT code (a semantic limit, not the wire range). */
bool rp_err_is_limit(int err);

/* ------------------------------------------------------------ enumerations */

/** Command: Motion command codes (docs/architecture.md, contract 2). */
typedef enum {
    RP_COMMAND_STOP = 0,
    RP_COMMAND_FWD = 1,
    RP_COMMAND_REV = 2,
    RP_COMMAND_LEFT = 3,
    RP_COMMAND_RIGHT = 4
} rp_command_t;

/** StopSource: Who asked for an emergency stop. */
typedef enum {
    RP_STOP_SOURCE_OPERATOR = 0,
    RP_STOP_SOURCE_PLAN_STEP = 1,
    RP_STOP_SOURCE_DRIFT = 2,
    RP_STOP_SOURCE_HOST_FAULT = 3,
    RP_STOP_SOURCE_BENCH = 4
} rp_stop_source_t;

/**
 * AckResult: Answer to a MOTION request. ACCEPTED and DUPLICATE both mean: stop
 * retransmitting.
 */
typedef enum {
    RP_ACK_RESULT_ACCEPTED = 0,
    RP_ACK_RESULT_OUT_OF_RANGE = 1,
    RP_ACK_RESULT_QUEUE_FULL = 2,
    RP_ACK_RESULT_STOP_LATCHED = 3,
    RP_ACK_RESULT_DUPLICATE = 4,
    RP_ACK_RESULT_NOT_READY = 5,
    RP_ACK_RESULT_FAULT_ACTIVE = 6
} rp_ack_result_t;

/** AckField: Which MOTION field was out of range (NONE for other results). */
typedef enum {
    RP_ACK_FIELD_NONE = 0,
    RP_ACK_FIELD_COMMAND = 1,
    RP_ACK_FIELD_SPEED = 2,
    RP_ACK_FIELD_DISTANCE = 3
} rp_ack_field_t;

/** StepState: Progress of one MOTION step. */
typedef enum {
    RP_STEP_STATE_STARTED = 0,
    RP_STEP_STATE_COMPLETED = 1,
    RP_STEP_STATE_ABORTED = 2
} rp_step_state_t;

/**
 * AbortReason: Why a step ended early (NONE unless STATUS state is ABORTED): STOP for a
 * STOP frame or a MOTION with command STOP, WATCHDOG for the watchdog, STALL for a stall
 * fault, FAULT for any other stopping fault, SESSION for a new session (HELLO).
 */
typedef enum {
    RP_ABORT_REASON_NONE = 0,
    RP_ABORT_REASON_STOP = 1,
    RP_ABORT_REASON_WATCHDOG = 2,
    RP_ABORT_REASON_STALL = 3,
    RP_ABORT_REASON_FAULT = 4,
    RP_ABORT_REASON_SESSION = 5
} rp_abort_reason_t;

/** ControllerState: Controller state machine (docs/protocol.md, 'State machine'). */
typedef enum {
    RP_CONTROLLER_STATE_BOOT = 0,
    RP_CONTROLLER_STATE_IDLE = 1,
    RP_CONTROLLER_STATE_EXECUTING = 2,
    RP_CONTROLLER_STATE_STOP_LATCHED = 3,
    RP_CONTROLLER_STATE_FAULT = 4
} rp_controller_state_t;

/**
 * ClearResult: Answer to CLEAR_STOP: CLEARED (the latch is released), NOT_LATCHED (there
 * was no latch; nothing changes), FAULT_PERSISTS (a stopping fault's condition is still
 * active; the latch holds), LATCH_CHANGED (the latch gained a cause since the generation
 * the request names; the latch holds). A repeat of the last request answered gets the same
 * answer and changes nothing.
 */
typedef enum {
    RP_CLEAR_RESULT_CLEARED = 0,
    RP_CLEAR_RESULT_NOT_LATCHED = 1,
    RP_CLEAR_RESULT_FAULT_PERSISTS = 2,
    RP_CLEAR_RESULT_LATCH_CHANGED = 3
} rp_clear_result_t;

/**
 * FaultCode: Fault codes; bit (code - 1) of HEARTBEAT.fault_bits is set while the fault's
 * condition is active (from FAULT active = 1 to FAULT active = 0). WATCHDOG, STALL_*,
 * ENCODER, DRIVER and INTERNAL stop the rover and latch; IMU and POSE only report.
 */
typedef enum {
    RP_FAULT_CODE_WATCHDOG = 1,
    RP_FAULT_CODE_STALL_LEFT = 2,
    RP_FAULT_CODE_STALL_RIGHT = 3,
    RP_FAULT_CODE_ENCODER = 4,
    RP_FAULT_CODE_IMU = 5,
    RP_FAULT_CODE_POSE = 6,
    RP_FAULT_CODE_DRIVER = 7,
    RP_FAULT_CODE_INTERNAL = 8
} rp_fault_code_t;

/** Param: Run-time parameters settable with SET_PARAM. */
typedef enum {
    RP_PARAM_WATCHDOG_MS = 1,
    RP_PARAM_TELEMETRY_HZ = 2,
    RP_PARAM_POSE_HZ = 3,
    RP_PARAM_HEARTBEAT_HZ = 4
} rp_param_t;

/**
 * ParamResult: Answer to SET_PARAM. OK: the value is in force; UNKNOWN_PARAM: no such
 * parameter (value 0); OUT_OF_RANGE: refused, value is the one still in force.
 */
typedef enum {
    RP_PARAM_RESULT_OK = 0,
    RP_PARAM_RESULT_UNKNOWN_PARAM = 1,
    RP_PARAM_RESULT_OUT_OF_RANGE = 2
} rp_param_result_t;

/* ------------------------------------------------------------ messages */

/* -------- STOP -------------------------------------------------------------------------- */

/**
 * STOP (id 0, host to controller, class emergency, 3 bytes). Emergency stop: preempts
 * everything, purges the queue, latches until CLEAR_STOP. Idempotent. Sent: on demand;
 * repeated every stop_repeat_ms until STOP_ACK.
 */
typedef struct {
    /**
     * u16 range 1..65535: host's request id, echoed in STOP_ACK and STOPPED; 0 is reserved
     * for stops the controller starts itself (a STOP frame with 0 is outside the wire
     * range: dropped and counted, not obeyed).
     */
    uint16_t stop_id;
    /** u8 (rp_stop_source_t) range 0..4: who asked. */
    uint8_t source;
} rp_stop_t;

#define RP_MSG_STOP 0u /**< message id of STOP */
#define RP_MSG_STOP_LEN 3u /**< payload bytes of STOP */
#define RP_MSG_STOP_NAME "STOP"
#define RP_F_STOP_STOP_ID 0 /**< field index of stop_id */
#define RP_F_STOP_SOURCE 1 /**< field index of source */

/**
 * Pack a STOP payload into out[0..3). Checks every field's wire range in wire order, then,
 * if strict, every semantic limit. Returns the payload length (3) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 3), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_STOP_*); out is untouched on error.
 */
int rp_stop_pack(const rp_stop_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a STOP payload of exactly 3 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_stop_unpack(rp_stop_t *msg, const uint8_t *payload, size_t len);

/* -------- STOP_ACK ---------------------------------------------------------------------- */

/**
 * STOP_ACK (id 1, controller to host, class emergency, 4 bytes). STOP received; wheel
 * targets are already zero and the queue purged. Sent for every STOP frame, repeats
 * included. Sent: once per STOP received.
 */
typedef struct {
    /** u16: echo of STOP.stop_id. */
    uint16_t stop_id;
    /**
     * u8 (rp_controller_state_t) range 0..4: state after the STOP (STOP_LATCHED, or FAULT).
     */
    uint8_t state;
    /** u8: the latch generation after the STOP (docs/protocol.md, 'Latch and faults'). */
    uint8_t latch_gen;
} rp_stop_ack_t;

#define RP_MSG_STOP_ACK 1u /**< message id of STOP_ACK */
#define RP_MSG_STOP_ACK_LEN 4u /**< payload bytes of STOP_ACK */
#define RP_MSG_STOP_ACK_NAME "STOP_ACK"
#define RP_F_STOP_ACK_STOP_ID 0 /**< field index of stop_id */
#define RP_F_STOP_ACK_STATE 1 /**< field index of state */
#define RP_F_STOP_ACK_LATCH_GEN 2 /**< field index of latch_gen */

/**
 * Pack a STOP_ACK payload into out[0..4). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (4) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 4), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_STOP_ACK_*); out is untouched on error.
 */
int rp_stop_ack_pack(const rp_stop_ack_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a STOP_ACK payload of exactly 4 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_stop_ack_unpack(rp_stop_ack_t *msg, const uint8_t *payload, size_t len);

/* -------- CLEAR_STOP -------------------------------------------------------------------- */

/**
 * CLEAR_STOP (id 2, host to controller, class emergency, 3 bytes). Explicit unlatch:
 * releases the latch (whatever set it: STOP, watchdog, fault) if it is still the latch of
 * the generation named and no stopping fault's condition is active. Sent: on demand;
 * repeated every stop_repeat_ms until CLEAR_ACK.
 */
typedef struct {
    /** u16 range 1..65535: host's request id, echoed in CLEAR_ACK. */
    uint16_t stop_id;
    /**
     * u8: the latch generation the request releases: the last one the host reported to
     * whoever asked for the clear (its operator, or its own automatic clear).
     */
    uint8_t latch_gen;
} rp_clear_stop_t;

#define RP_MSG_CLEAR_STOP 2u /**< message id of CLEAR_STOP */
#define RP_MSG_CLEAR_STOP_LEN 3u /**< payload bytes of CLEAR_STOP */
#define RP_MSG_CLEAR_STOP_NAME "CLEAR_STOP"
#define RP_F_CLEAR_STOP_STOP_ID 0 /**< field index of stop_id */
#define RP_F_CLEAR_STOP_LATCH_GEN 1 /**< field index of latch_gen */

/**
 * Pack a CLEAR_STOP payload into out[0..3). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (3) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 3), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_CLEAR_STOP_*); out is untouched on error.
 */
int rp_clear_stop_pack(const rp_clear_stop_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a CLEAR_STOP payload of exactly 3 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_clear_stop_unpack(rp_clear_stop_t *msg, const uint8_t *payload, size_t len);

/* -------- CLEAR_ACK --------------------------------------------------------------------- */

/**
 * CLEAR_ACK (id 3, controller to host, class emergency, 4 bytes). Answer to CLEAR_STOP.
 * Sent: once per CLEAR_STOP received.
 */
typedef struct {
    /** u16: echo of CLEAR_STOP.stop_id. */
    uint16_t stop_id;
    /** u8 (rp_clear_result_t) range 0..3. */
    uint8_t result;
    /** u8: the latch generation after the answer. */
    uint8_t latch_gen;
} rp_clear_ack_t;

#define RP_MSG_CLEAR_ACK 3u /**< message id of CLEAR_ACK */
#define RP_MSG_CLEAR_ACK_LEN 4u /**< payload bytes of CLEAR_ACK */
#define RP_MSG_CLEAR_ACK_NAME "CLEAR_ACK"
#define RP_F_CLEAR_ACK_STOP_ID 0 /**< field index of stop_id */
#define RP_F_CLEAR_ACK_RESULT 1 /**< field index of result */
#define RP_F_CLEAR_ACK_LATCH_GEN 2 /**< field index of latch_gen */

/**
 * Pack a CLEAR_ACK payload into out[0..4). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (4) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 4), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_CLEAR_ACK_*); out is untouched on error.
 */
int rp_clear_ack_pack(const rp_clear_ack_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a CLEAR_ACK payload of exactly 4 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_clear_ack_unpack(rp_clear_ack_t *msg, const uint8_t *payload, size_t len);

/* -------- MOTION ------------------------------------------------------------------------ */

/**
 * MOTION (id 8, host to controller, class motion, 6 bytes). Queue one motion step. The
 * controller answers ACK; a repeated seq is acknowledged DUPLICATE and never executed
 * twice. Checks in this order: session, duplicate, command, (command STOP: emergency stop),
 * speed, distance, fault, latch, queue. Sent: one per plan step; retransmitted after
 * ack_timeout_ms, at most motion_retries times.
 */
typedef struct {
    /** u16: host step sequence number, wraps; new per step, kept across retransmissions. */
    uint16_t seq;
    /**
     * u8 (rp_command_t) limit 0..4: STOP/FWD/REV/LEFT/RIGHT; STOP here acts as an emergency
     * stop (speed and distance ignored).
     */
    uint8_t command;
    /**
     * u8 limit 0..60: speed units; wheel angular speed = speed * k rad/s, surface speed =
     * speed * k * wheel_radius m/s (docs/protocol.md, Units).
     */
    uint8_t speed;
    /**
     * u16 limit 0..30000: distance units of encoder travel per side, each side along its
     * own direction of travel (23000 per metre).
     */
    uint16_t distance;
} rp_motion_t;

#define RP_MSG_MOTION 8u /**< message id of MOTION */
#define RP_MSG_MOTION_LEN 6u /**< payload bytes of MOTION */
#define RP_MSG_MOTION_NAME "MOTION"
#define RP_F_MOTION_SEQ 0 /**< field index of seq */
#define RP_F_MOTION_COMMAND 1 /**< field index of command */
#define RP_F_MOTION_SPEED 2 /**< field index of speed */
#define RP_F_MOTION_DISTANCE 3 /**< field index of distance */

/**
 * Pack a MOTION payload into out[0..6). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (6) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 6), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_MOTION_*); out is untouched on error.
 */
int rp_motion_pack(const rp_motion_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a MOTION payload of exactly 6 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_motion_unpack(rp_motion_t *msg, const uint8_t *payload, size_t len);

/* -------- ACK --------------------------------------------------------------------------- */

/**
 * ACK (id 9, controller to host, class motion, 5 bytes). Acknowledgement (result ACCEPTED
 * or DUPLICATE) or refusal (any other result) of a MOTION. Sent: once per MOTION received.
 */
typedef struct {
    /** u16: echo of MOTION.seq. */
    uint16_t seq;
    /** u8 (rp_ack_result_t) range 0..6. */
    uint8_t result;
    /** u8 (rp_ack_field_t) range 0..3: for OUT_OF_RANGE: the offending field. */
    uint8_t field;
    /** u8: steps queued after this request, the running one included. */
    uint8_t queue_depth;
} rp_ack_t;

#define RP_MSG_ACK 9u /**< message id of ACK */
#define RP_MSG_ACK_LEN 5u /**< payload bytes of ACK */
#define RP_MSG_ACK_NAME "ACK"
#define RP_F_ACK_SEQ 0 /**< field index of seq */
#define RP_F_ACK_RESULT 1 /**< field index of result */
#define RP_F_ACK_FIELD 2 /**< field index of field */
#define RP_F_ACK_QUEUE_DEPTH 3 /**< field index of queue_depth */

/**
 * Pack a ACK payload into out[0..5). Checks every field's wire range in wire order, then,
 * if strict, every semantic limit. Returns the payload length (5) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 5), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_ACK_*); out is untouched on error.
 */
int rp_ack_pack(const rp_ack_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a ACK payload of exactly 5 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_ack_unpack(rp_ack_t *msg, const uint8_t *payload, size_t len);

/* -------- STATUS ------------------------------------------------------------------------ */

/**
 * STATUS (id 32, controller to host, class status, 6 bytes). Progress of one step: STARTED,
 * then COMPLETED when both sides' encoder travel reached the distance and the wheels are at
 * rest, or ABORTED with a reason. A step with speed 0 or distance 0 is STARTED and
 * COMPLETED in the same control tick, travel 0, when the wheels are at rest; started while
 * a wheel still turns (after a new session or a clear before rest), it first brakes them to
 * rest as a STOP does. Sent: when a step starts and when it ends.
 */
typedef struct {
    /** u16: MOTION.seq of the step. */
    uint16_t seq;
    /** u8 (rp_step_state_t) range 0..2. */
    uint8_t state;
    /** u8 (rp_abort_reason_t) range 0..5. */
    uint8_t reason;
    /** u16: distance units travelled so far, mean of both sides' encoders. */
    uint16_t travel;
} rp_status_t;

#define RP_MSG_STATUS 32u /**< message id of STATUS */
#define RP_MSG_STATUS_LEN 6u /**< payload bytes of STATUS */
#define RP_MSG_STATUS_NAME "STATUS"
#define RP_F_STATUS_SEQ 0 /**< field index of seq */
#define RP_F_STATUS_STATE 1 /**< field index of state */
#define RP_F_STATUS_REASON 2 /**< field index of reason */
#define RP_F_STATUS_TRAVEL 3 /**< field index of travel */

/**
 * Pack a STATUS payload into out[0..6). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (6) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 6), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_STATUS_*); out is untouched on error.
 */
int rp_status_pack(const rp_status_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a STATUS payload of exactly 6 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_status_unpack(rp_status_t *msg, const uint8_t *payload, size_t len);

/* -------- STOPPED ----------------------------------------------------------------------- */

/**
 * STOPPED (id 33, controller to host, class status, 6 bytes). The wheels are at rest after
 * a STOP (or a stop the controller started itself, stop_id 0: MOTION with command STOP,
 * watchdog, stopping fault). Every new stop_id gets its own STOPPED, also while already
 * latched and at rest (then distance 0); a repeat of a stop_id seen since the latch was
 * last cleared gets none. Sent: once per stop_id new to the latch (a repeat gets none),
 * when both wheels have come to rest; one owed is sent after CLEARED too.
 */
typedef struct {
    /** u16: the STOP being reported; 0 for watchdog and fault stops. */
    uint16_t stop_id;
    /** u16 mm: wheel travel from STOP arrival to rest, mean of both sides. */
    uint16_t distance_mm;
    /** u16 ms: time from STOP arrival to rest. */
    uint16_t duration_ms;
} rp_stopped_t;

#define RP_MSG_STOPPED 33u /**< message id of STOPPED */
#define RP_MSG_STOPPED_LEN 6u /**< payload bytes of STOPPED */
#define RP_MSG_STOPPED_NAME "STOPPED"
#define RP_F_STOPPED_STOP_ID 0 /**< field index of stop_id */
#define RP_F_STOPPED_DISTANCE_MM 1 /**< field index of distance_mm */
#define RP_F_STOPPED_DURATION_MS 2 /**< field index of duration_ms */

/**
 * Pack a STOPPED payload into out[0..6). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (6) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 6), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_STOPPED_*); out is untouched on error.
 */
int rp_stopped_pack(const rp_stopped_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a STOPPED payload of exactly 6 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_stopped_unpack(rp_stopped_t *msg, const uint8_t *payload, size_t len);

/* -------- FAULT ------------------------------------------------------------------------- */

/**
 * FAULT (id 34, controller to host, class status, 5 bytes). A fault's condition became
 * active (active = 1) or went away (active = 0). A stopping fault's latch outlives its
 * condition: it holds until CLEAR_STOP. Sent: when a fault is raised or cleared.
 */
typedef struct {
    /** u8 (rp_fault_code_t) range 1..8. */
    uint8_t code;
    /** u1. */
    uint8_t active;
    /**
     * u16: code-specific with active = 1: WATCHDOG ms since the last valid frame; STALL_*
     * distance units still to go; ENCODER the failed side (1 left, 2 right, 3 both);
     * DRIVER, INTERNAL, IMU, POSE 0 or a vendor code; always 0 with active = 0.
     */
    uint16_t detail;
    /**
     * u8: the latch generation after this FAULT (a stopping fault's active = 1 raises it).
     */
    uint8_t latch_gen;
} rp_fault_t;

#define RP_MSG_FAULT 34u /**< message id of FAULT */
#define RP_MSG_FAULT_LEN 5u /**< payload bytes of FAULT */
#define RP_MSG_FAULT_NAME "FAULT"
#define RP_F_FAULT_CODE 0 /**< field index of code */
#define RP_F_FAULT_ACTIVE 1 /**< field index of active */
#define RP_F_FAULT_DETAIL 2 /**< field index of detail */
#define RP_F_FAULT_LATCH_GEN 3 /**< field index of latch_gen */

/**
 * Pack a FAULT payload into out[0..5). Checks every field's wire range in wire order, then,
 * if strict, every semantic limit. Returns the payload length (5) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 5), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_FAULT_*); out is untouched on error.
 */
int rp_fault_pack(const rp_fault_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a FAULT payload of exactly 5 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_fault_unpack(rp_fault_t *msg, const uint8_t *payload, size_t len);

/* -------- HEARTBEAT --------------------------------------------------------------------- */

/**
 * HEARTBEAT (id 64, controller to host, class telemetry, 8 bytes). Controller liveness and
 * summary state. A changed boot_nonce means the controller rebooted. The latch_* bits say
 * what holds the latch; fault_bits say which fault conditions are active now. Sent: every
 * controller_heartbeat_period_ms.
 */
typedef struct {
    /** u3 (rp_controller_state_t) range 0..4. */
    uint8_t state;
    /**
     * u1: motion inhibited until CLEAR_STOP: latch_stop OR latch_watchdog OR latch_fault.
     */
    uint8_t stop_latched;
    /** u1: a session is open: the last HELLO since boot matched version and schema hash. */
    uint8_t handshake_ok;
    /**
     * u1: the latch was set (or set again) by a STOP frame or a MOTION with command STOP
     * since the last CLEARED.
     */
    uint8_t latch_stop;
    /** u1: the latch was set (or set again) by the watchdog since the last CLEARED. */
    uint8_t latch_watchdog;
    /**
     * u1: the latch was set (or set again) by a stopping fault other than WATCHDOG since
     * the last CLEARED.
     */
    uint8_t latch_fault;
    /**
     * u8: bit (FaultCode - 1) set while that fault's condition is active (not the latch it
     * left).
     */
    uint8_t fault_bits;
    /** u8: steps queued, the running one included. */
    uint8_t queue_depth;
    /** u16: random per boot, as in IDENT. */
    uint16_t boot_nonce;
    /**
     * u16: frames the controller dropped, for any reason of docs/protocol.md 'Receive
     * errors', wrapping.
     */
    uint16_t rx_errors;
    /**
     * u8: the latch generation: raised by every new latch cause (docs/protocol.md, 'Latch
     * and faults'), wrapping.
     */
    uint8_t latch_gen;
} rp_heartbeat_t;

#define RP_MSG_HEARTBEAT 64u /**< message id of HEARTBEAT */
#define RP_MSG_HEARTBEAT_LEN 8u /**< payload bytes of HEARTBEAT */
#define RP_MSG_HEARTBEAT_NAME "HEARTBEAT"
#define RP_F_HEARTBEAT_STATE 0 /**< field index of state */
#define RP_F_HEARTBEAT_STOP_LATCHED 1 /**< field index of stop_latched */
#define RP_F_HEARTBEAT_HANDSHAKE_OK 2 /**< field index of handshake_ok */
#define RP_F_HEARTBEAT_LATCH_STOP 3 /**< field index of latch_stop */
#define RP_F_HEARTBEAT_LATCH_WATCHDOG 4 /**< field index of latch_watchdog */
#define RP_F_HEARTBEAT_LATCH_FAULT 5 /**< field index of latch_fault */
#define RP_F_HEARTBEAT_FAULT_BITS 6 /**< field index of fault_bits */
#define RP_F_HEARTBEAT_QUEUE_DEPTH 7 /**< field index of queue_depth */
#define RP_F_HEARTBEAT_BOOT_NONCE 8 /**< field index of boot_nonce */
#define RP_F_HEARTBEAT_RX_ERRORS 9 /**< field index of rx_errors */
#define RP_F_HEARTBEAT_LATCH_GEN 10 /**< field index of latch_gen */

/**
 * Pack a HEARTBEAT payload into out[0..8). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (8) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 8), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_HEARTBEAT_*); out is untouched on error.
 */
int rp_heartbeat_pack(const rp_heartbeat_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a HEARTBEAT payload of exactly 8 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_heartbeat_unpack(rp_heartbeat_t *msg, const uint8_t *payload, size_t len);

/* -------- HOST_HEARTBEAT ---------------------------------------------------------------- */

/**
 * HOST_HEARTBEAT (id 65, host to controller, class telemetry, 2 bytes). Host liveness; any
 * valid host-to-controller frame feeds the controller's watchdog, this one when nothing
 * else is sent. Sent: every host_heartbeat_period_ms.
 */
typedef struct {
    /** u16: increments per heartbeat, wraps. */
    uint16_t counter;
} rp_host_heartbeat_t;

#define RP_MSG_HOST_HEARTBEAT 65u /**< message id of HOST_HEARTBEAT */
#define RP_MSG_HOST_HEARTBEAT_LEN 2u /**< payload bytes of HOST_HEARTBEAT */
#define RP_MSG_HOST_HEARTBEAT_NAME "HOST_HEARTBEAT"
#define RP_F_HOST_HEARTBEAT_COUNTER 0 /**< field index of counter */

/**
 * Pack a HOST_HEARTBEAT payload into out[0..2). Checks every field's wire range in wire
 * order, then, if strict, every semantic limit. Returns the payload length (2) or
 * RP_ERR_NULL, RP_ERR_BUFFER (cap < 2), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first
 * offending field index i (RP_F_HOST_HEARTBEAT_*); out is untouched on error.
 */
int rp_host_heartbeat_pack(const rp_host_heartbeat_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a HOST_HEARTBEAT payload of exactly 2 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_host_heartbeat_unpack(rp_host_heartbeat_t *msg, const uint8_t *payload, size_t len);

/* -------- ENCODERS ---------------------------------------------------------------------- */

/**
 * ENCODERS (id 66, controller to host, class telemetry, 8 bytes). Absolute wheel encoder
 * counts since boot, polarity applied (forward positive on both sides), wrapping modulo
 * 2^24; the host unwraps. They restart at 0 after a reboot: the host re-bases on the new
 * boot nonce. Sent: encoders_rate_hz.
 */
typedef struct {
    /** u16 ms: controller clock, wraps every 65.536 s. */
    uint16_t t_ms;
    /** i24: left side counts (distance units). */
    int32_t left;
    /** i24: right side counts (distance units). */
    int32_t right;
} rp_encoders_t;

#define RP_MSG_ENCODERS 66u /**< message id of ENCODERS */
#define RP_MSG_ENCODERS_LEN 8u /**< payload bytes of ENCODERS */
#define RP_MSG_ENCODERS_NAME "ENCODERS"
#define RP_F_ENCODERS_T_MS 0 /**< field index of t_ms */
#define RP_F_ENCODERS_LEFT 1 /**< field index of left */
#define RP_F_ENCODERS_RIGHT 2 /**< field index of right */

/**
 * Pack a ENCODERS payload into out[0..8). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (8) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 8), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_ENCODERS_*); out is untouched on error.
 */
int rp_encoders_pack(const rp_encoders_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a ENCODERS payload of exactly 8 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_encoders_unpack(rp_encoders_t *msg, const uint8_t *payload, size_t len);

/* -------- WHEEL_SPEEDS ------------------------------------------------------------------ */

/**
 * WHEEL_SPEEDS (id 67, controller to host, class telemetry, 8 bytes). Measured and target
 * wheel surface speeds, polarity applied. Sent: wheel_speeds_rate_hz.
 */
typedef struct {
    /** u16 ms. */
    uint16_t t_ms;
    /** i12 mm/s. */
    int16_t left_mm_s;
    /** i12 mm/s. */
    int16_t right_mm_s;
    /** i12 mm/s. */
    int16_t left_target_mm_s;
    /** i12 mm/s. */
    int16_t right_target_mm_s;
} rp_wheel_speeds_t;

#define RP_MSG_WHEEL_SPEEDS 67u /**< message id of WHEEL_SPEEDS */
#define RP_MSG_WHEEL_SPEEDS_LEN 8u /**< payload bytes of WHEEL_SPEEDS */
#define RP_MSG_WHEEL_SPEEDS_NAME "WHEEL_SPEEDS"
#define RP_F_WHEEL_SPEEDS_T_MS 0 /**< field index of t_ms */
#define RP_F_WHEEL_SPEEDS_LEFT_MM_S 1 /**< field index of left_mm_s */
#define RP_F_WHEEL_SPEEDS_RIGHT_MM_S 2 /**< field index of right_mm_s */
#define RP_F_WHEEL_SPEEDS_LEFT_TARGET_MM_S 3 /**< field index of left_target_mm_s */
#define RP_F_WHEEL_SPEEDS_RIGHT_TARGET_MM_S 4 /**< field index of right_target_mm_s */

/**
 * Pack a WHEEL_SPEEDS payload into out[0..8). Checks every field's wire range in wire
 * order, then, if strict, every semantic limit. Returns the payload length (8) or
 * RP_ERR_NULL, RP_ERR_BUFFER (cap < 8), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first
 * offending field index i (RP_F_WHEEL_SPEEDS_*); out is untouched on error.
 */
int rp_wheel_speeds_pack(const rp_wheel_speeds_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a WHEEL_SPEEDS payload of exactly 8 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_wheel_speeds_unpack(rp_wheel_speeds_t *msg, const uint8_t *payload, size_t len);

/* -------- IMU --------------------------------------------------------------------------- */

/**
 * IMU (id 68, controller to host, class telemetry, 8 bytes). Body yaw rate (counter-
 * clockwise positive) and planar acceleration in the body frame. Sent: imu_rate_hz.
 */
typedef struct {
    /** u16 ms. */
    uint16_t t_ms;
    /** i16 x0.001 rad/s. */
    int16_t yaw_rate_mrad_s;
    /** i16 x0.001 m/s^2. */
    int16_t accel_x_mm_s2;
    /** i16 x0.001 m/s^2. */
    int16_t accel_y_mm_s2;
} rp_imu_t;

#define RP_MSG_IMU 68u /**< message id of IMU */
#define RP_MSG_IMU_LEN 8u /**< payload bytes of IMU */
#define RP_MSG_IMU_NAME "IMU"
#define RP_F_IMU_T_MS 0 /**< field index of t_ms */
#define RP_F_IMU_YAW_RATE_MRAD_S 1 /**< field index of yaw_rate_mrad_s */
#define RP_F_IMU_ACCEL_X_MM_S2 2 /**< field index of accel_x_mm_s2 */
#define RP_F_IMU_ACCEL_Y_MM_S2 3 /**< field index of accel_y_mm_s2 */

/**
 * Pack a IMU payload into out[0..8). Checks every field's wire range in wire order, then,
 * if strict, every semantic limit. Returns the payload length (8) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 8), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_IMU_*); out is untouched on error.
 */
int rp_imu_pack(const rp_imu_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a IMU payload of exactly 8 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_imu_unpack(rp_imu_t *msg, const uint8_t *payload, size_t len);

/* -------- POSE -------------------------------------------------------------------------- */

/**
 * POSE (id 69, controller to host, class telemetry, 8 bytes). Pose from a sensor that sees
 * the ground (visual odometry or lab tracking) in the map frame: the frame of the map the
 * gate plans on, x and y from its origin, never re-zeroed at boot; unlike the encoders it
 * shows slip. Optional: a controller without such a sensor never sends it. Sent:
 * pose_rate_hz.
 */
typedef struct {
    /** i20 x0.001 m. */
    int32_t x_mm;
    /** i20 x0.001 m. */
    int32_t y_mm;
    /** i12 x0.1 deg range -1800..1800: counter-clockwise from the map x axis. */
    int16_t yaw_ddeg;
    /**
     * u4 x0.01 m: 1-sigma position error; 0 = no fix, ignore the pose; 15 = 15 cm or worse.
     */
    uint8_t sigma_cm;
    /** u8 x4 ms: age of the measurement when sent. */
    uint8_t age_4ms;
} rp_pose_t;

#define RP_MSG_POSE 69u /**< message id of POSE */
#define RP_MSG_POSE_LEN 8u /**< payload bytes of POSE */
#define RP_MSG_POSE_NAME "POSE"
#define RP_F_POSE_X_MM 0 /**< field index of x_mm */
#define RP_F_POSE_Y_MM 1 /**< field index of y_mm */
#define RP_F_POSE_YAW_DDEG 2 /**< field index of yaw_ddeg */
#define RP_F_POSE_SIGMA_CM 3 /**< field index of sigma_cm */
#define RP_F_POSE_AGE_4MS 4 /**< field index of age_4ms */

/**
 * Pack a POSE payload into out[0..8). Checks every field's wire range in wire order, then,
 * if strict, every semantic limit. Returns the payload length (8) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 8), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_POSE_*); out is untouched on error.
 */
int rp_pose_pack(const rp_pose_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a POSE payload of exactly 8 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_pose_unpack(rp_pose_t *msg, const uint8_t *payload, size_t len);

/* -------- PROGRESS ---------------------------------------------------------------------- */

/**
 * PROGRESS (id 70, controller to host, class telemetry, 8 bytes). The last step that ended
 * in this session and how many have ended, so a host that lost a STATUS frame on a noisy
 * link can still settle every step. Sent: with every HEARTBEAT.
 */
typedef struct {
    /**
     * u16: MOTION.seq of the last step that ended; while ended_count is 0 every field is 0
     * and the host ignores them.
     */
    uint16_t ended_seq;
    /** u8 (rp_step_state_t) range 0..2: COMPLETED or ABORTED. */
    uint8_t ended_state;
    /** u8 (rp_abort_reason_t) range 0..5. */
    uint8_t ended_reason;
    /**
     * u16: steps ended in this session, wrapping; 0 after HELLO (the steps that HELLO
     * aborted belong to the old session and are not counted).
     */
    uint16_t ended_count;
    /** u16: distance units the last ended step travelled. */
    uint16_t travel;
} rp_progress_t;

#define RP_MSG_PROGRESS 70u /**< message id of PROGRESS */
#define RP_MSG_PROGRESS_LEN 8u /**< payload bytes of PROGRESS */
#define RP_MSG_PROGRESS_NAME "PROGRESS"
#define RP_F_PROGRESS_ENDED_SEQ 0 /**< field index of ended_seq */
#define RP_F_PROGRESS_ENDED_STATE 1 /**< field index of ended_state */
#define RP_F_PROGRESS_ENDED_REASON 2 /**< field index of ended_reason */
#define RP_F_PROGRESS_ENDED_COUNT 3 /**< field index of ended_count */
#define RP_F_PROGRESS_TRAVEL 4 /**< field index of travel */

/**
 * Pack a PROGRESS payload into out[0..8). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (8) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 8), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_PROGRESS_*); out is untouched on error.
 */
int rp_progress_pack(const rp_progress_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a PROGRESS payload of exactly 8 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_progress_unpack(rp_progress_t *msg, const uint8_t *payload, size_t len);

/* -------- HELLO ------------------------------------------------------------------------- */

/**
 * HELLO (id 96, host to controller, class config, 3 bytes). Handshake: the host's protocol
 * version and schema hash. The controller answers every HELLO with IDENT; a matching one
 * opens a new session and arms the watchdog, a mismatched one closes any session. Sent: at
 * connection, until IDENT.
 */
typedef struct {
    /** u8. */
    uint8_t protocol_version;
    /** u16. */
    uint16_t schema_hash;
} rp_hello_t;

#define RP_MSG_HELLO 96u /**< message id of HELLO */
#define RP_MSG_HELLO_LEN 3u /**< payload bytes of HELLO */
#define RP_MSG_HELLO_NAME "HELLO"
#define RP_F_HELLO_PROTOCOL_VERSION 0 /**< field index of protocol_version */
#define RP_F_HELLO_SCHEMA_HASH 1 /**< field index of schema_hash */

/**
 * Pack a HELLO payload into out[0..3). Checks every field's wire range in wire order, then,
 * if strict, every semantic limit. Returns the payload length (3) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 3), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_HELLO_*); out is untouched on error.
 */
int rp_hello_pack(const rp_hello_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a HELLO payload of exactly 3 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_hello_unpack(rp_hello_t *msg, const uint8_t *payload, size_t len);

/* -------- IDENT ------------------------------------------------------------------------- */

/**
 * IDENT (id 97, controller to host, class config, 8 bytes). Controller identity: protocol
 * version and schema hash (compare with the host's), firmware version and a random boot
 * nonce. Sent once at boot (unsolicited) and otherwise only in answer to HELLO. Sent: at
 * boot and in answer to HELLO.
 */
typedef struct {
    /** u8. */
    uint8_t protocol_version;
    /** u8. */
    uint8_t firmware_major;
    /** u8. */
    uint8_t firmware_minor;
    /** u8. */
    uint8_t firmware_patch;
    /** u16. */
    uint16_t schema_hash;
    /** u16. */
    uint16_t boot_nonce;
} rp_ident_t;

#define RP_MSG_IDENT 97u /**< message id of IDENT */
#define RP_MSG_IDENT_LEN 8u /**< payload bytes of IDENT */
#define RP_MSG_IDENT_NAME "IDENT"
#define RP_F_IDENT_PROTOCOL_VERSION 0 /**< field index of protocol_version */
#define RP_F_IDENT_FIRMWARE_MAJOR 1 /**< field index of firmware_major */
#define RP_F_IDENT_FIRMWARE_MINOR 2 /**< field index of firmware_minor */
#define RP_F_IDENT_FIRMWARE_PATCH 3 /**< field index of firmware_patch */
#define RP_F_IDENT_SCHEMA_HASH 4 /**< field index of schema_hash */
#define RP_F_IDENT_BOOT_NONCE 5 /**< field index of boot_nonce */

/**
 * Pack a IDENT payload into out[0..8). Checks every field's wire range in wire order, then,
 * if strict, every semantic limit. Returns the payload length (8) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 8), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_IDENT_*); out is untouched on error.
 */
int rp_ident_pack(const rp_ident_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a IDENT payload of exactly 8 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_ident_unpack(rp_ident_t *msg, const uint8_t *payload, size_t len);

/* -------- SET_PARAM --------------------------------------------------------------------- */

/**
 * SET_PARAM (id 98, host to controller, class config, 5 bytes). Set a run-time parameter;
 * the controller answers PARAM_VALUE. Sent: on demand.
 */
typedef struct {
    /** u8 (rp_param_t). */
    uint8_t param;
    /** i32. */
    int32_t value;
} rp_set_param_t;

#define RP_MSG_SET_PARAM 98u /**< message id of SET_PARAM */
#define RP_MSG_SET_PARAM_LEN 5u /**< payload bytes of SET_PARAM */
#define RP_MSG_SET_PARAM_NAME "SET_PARAM"
#define RP_F_SET_PARAM_PARAM 0 /**< field index of param */
#define RP_F_SET_PARAM_VALUE 1 /**< field index of value */

/**
 * Pack a SET_PARAM payload into out[0..5). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (5) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 5), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_SET_PARAM_*); out is untouched on error.
 */
int rp_set_param_pack(const rp_set_param_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a SET_PARAM payload of exactly 5 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_set_param_unpack(rp_set_param_t *msg, const uint8_t *payload, size_t len);

/* -------- PARAM_VALUE ------------------------------------------------------------------- */

/**
 * PARAM_VALUE (id 99, controller to host, class config, 6 bytes). Answer to SET_PARAM:
 * param echoed; value in force (OK, OUT_OF_RANGE) or 0 (UNKNOWN_PARAM). Sent: once per
 * SET_PARAM.
 */
typedef struct {
    /** u8. */
    uint8_t param;
    /** u8 (rp_param_result_t) range 0..2. */
    uint8_t result;
    /** i32. */
    int32_t value;
} rp_param_value_t;

#define RP_MSG_PARAM_VALUE 99u /**< message id of PARAM_VALUE */
#define RP_MSG_PARAM_VALUE_LEN 6u /**< payload bytes of PARAM_VALUE */
#define RP_MSG_PARAM_VALUE_NAME "PARAM_VALUE"
#define RP_F_PARAM_VALUE_PARAM 0 /**< field index of param */
#define RP_F_PARAM_VALUE_RESULT 1 /**< field index of result */
#define RP_F_PARAM_VALUE_VALUE 2 /**< field index of value */

/**
 * Pack a PARAM_VALUE payload into out[0..6). Checks every field's wire range in wire order,
 * then, if strict, every semantic limit. Returns the payload length (6) or RP_ERR_NULL,
 * RP_ERR_BUFFER (cap < 6), RP_ERR_FIELD(i) / RP_ERR_LIMIT(i) for the first offending field
 * index i (RP_F_PARAM_VALUE_*); out is untouched on error.
 */
int rp_param_value_pack(const rp_param_value_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a PARAM_VALUE payload of exactly 6 bytes into *msg. Returns RP_OK, RP_ERR_NULL,
 * RP_ERR_LENGTH, or RP_ERR_FIELD(i) for the first field outside its wire range (the frame
 * must then be dropped); *msg is untouched on error.
 */
int rp_param_value_unpack(rp_param_value_t *msg, const uint8_t *payload, size_t len);

/* ------------------------------------------------------------ any message */

/** Any message: its id and the matching member of body. */
typedef struct {
    uint8_t id; /**< message id (RP_MSG_*), selects the member of body */
    /** The message's fields; only the member named after id is meaningful. */
    union {
        rp_stop_t stop;
        rp_stop_ack_t stop_ack;
        rp_clear_stop_t clear_stop;
        rp_clear_ack_t clear_ack;
        rp_motion_t motion;
        rp_ack_t ack;
        rp_status_t status;
        rp_stopped_t stopped;
        rp_fault_t fault;
        rp_heartbeat_t heartbeat;
        rp_host_heartbeat_t host_heartbeat;
        rp_encoders_t encoders;
        rp_wheel_speeds_t wheel_speeds;
        rp_imu_t imu;
        rp_pose_t pose;
        rp_progress_t progress;
        rp_hello_t hello;
        rp_ident_t ident;
        rp_set_param_t set_param;
        rp_param_value_t param_value;
    } body;
} rp_msg_t;

/** Direction of a message. */
typedef enum {
    RP_DIR_HOST_TO_CONTROLLER = 0,
    RP_DIR_CONTROLLER_TO_HOST = 1
} rp_direction_t;

/** Static description of one public field. */
typedef struct {
    const char *name; /**< field name as in protocol.toml */
    uint8_t bits; /**< wire width */
    bool is_signed; /**< two's complement */
    int64_t min; /**< wire range, inclusive */
    int64_t max; /**< wire range, inclusive */
    bool has_limit; /**< a semantic limit is checked by strict pack */
    int64_t limit_lo; /**< semantic limit, inclusive (if has_limit) */
    int64_t limit_hi; /**< semantic limit, inclusive (if has_limit) */
} rp_field_info_t;

/** Static description of one message type. */
typedef struct {
    uint8_t id; /**< message id */
    uint8_t length; /**< payload bytes */
    rp_direction_t direction; /**< who sends it */
    const char *name; /**< protocol name, e.g. "MOTION" */
    uint8_t n_fields; /**< public fields (reserved padding excluded) */
    const rp_field_info_t *fields; /**< n_fields entries, in wire order */
} rp_msg_info_t;

/** Every message type, sorted by id. */
extern const rp_msg_info_t rp_msg_table[RP_MSG_COUNT];

/** Description of message id, or NULL if the id is not in the protocol. O(1). */
const rp_msg_info_t *rp_msg_info(uint32_t id);
/** Description of the message called name (NUL-terminated), or NULL. */
const rp_msg_info_t *rp_msg_by_name(const char *name);

/**
 * Pack msg->body per msg->id into out (capacity cap). Returns the payload length or
 * a negative RP_ERR_* code (RP_ERR_UNKNOWN_ID, and those of the per-message pack).
 */
int rp_msg_pack(const rp_msg_t *msg, bool strict, uint8_t *out, size_t cap);
/**
 * Unpack a payload of message id into *msg (msg->id set on success). Returns RP_OK
 * or RP_ERR_UNKNOWN_ID, RP_ERR_LENGTH, RP_ERR_FIELD(i), RP_ERR_NULL; *msg is
 * untouched on error.
 */
int rp_msg_unpack(rp_msg_t *msg, uint32_t id, const uint8_t *payload, size_t len);
/** Value of public field index of *msg into *value. RP_OK or a negative code. */
int rp_msg_get_field(const rp_msg_t *msg, unsigned index, int64_t *value);
/**
 * Set public field index of *msg (msg->id must be set). Returns RP_OK, or
 * RP_ERR_FIELD(index) if the struct member cannot hold value (the wire range is
 * checked by pack, not here), RP_ERR_UNKNOWN_ID, RP_ERR_NULL.
 */
int rp_msg_set_field(rp_msg_t *msg, unsigned index, int64_t value);

#ifdef __cplusplus
}
#endif

#endif /* ROVER_MSGS_H */
