/**
 * @file fw.c
 * @brief The motor controller's firmware core (see fw.h). The reference behaviour is
 *        emulator/controller.py (ControllerModel); the comments name its methods.
 *
 * Integer arithmetic only: speeds in um/s, travel in encoder units, lengths in the
 * braking law in picometres (int64), time in microseconds (uint64). No undefined or
 * implementation-defined behaviour for any reading the HAL gives: encoder counts are
 * compared only through count_delta (they wrap modulo 2^32), wheel speeds are negated
 * with saturation, and fw_init refuses a configuration whose arithmetic could divide by
 * zero or overflow (fw_error_t).
 */
#include "fw.h"

/* ------------------------------------------------------------------ helpers */

#define FW_REST_UM_S 100           /* a side is at rest below 1e-4 m/s */
#define FW_STALL_MIN_TARGET_UM_S 2500 /* stall detection watches ramped commands from
                                        2.5 mm/s, half of speed 1: every step */

/** v as a two's-complement int32 (no implementation-defined conversion). */
static int32_t as_i32(uint32_t v)
{
    return v < 0x80000000u ? (int32_t)v : -(int32_t)(0xFFFFFFFFu - v) - 1;
}

/**
 * Travel between two readings of a counter that wraps modulo 2^32 (fw_hal.h): after -
 * before in -2^31..2^31-1, right across a wrap while the counter moved less than 2^31
 * units (93 km at 23000 units/m) in between.
 */
static int32_t count_delta(int32_t after, int32_t before)
{
    return as_i32((uint32_t)after - (uint32_t)before);
}

/** -v, INT32_MIN giving INT32_MAX (a speed reading, not a counter). */
static int32_t neg_sat32(int32_t v) { return v == INT32_MIN ? INT32_MAX : -v; }

static int64_t abs64(int64_t v) { return v < 0 ? -v : v; }

/** num / den rounded half to even (Python's round), den > 0. */
static int64_t div_round(int64_t num, int64_t den)
{
    int64_t q = num / den;
    int64_t r = num % den;
    if (r < 0) {
        r = -r;
    }
    if (2 * r > den || (2 * r == den && (q & 1) != 0)) {
        q += num < 0 ? -1 : 1;
    }
    return q;
}

static int32_t clamp32(int64_t v, int32_t lo, int32_t hi)
{
    return v < lo ? lo : (v > hi ? hi : (int32_t)v);
}

static int32_t ramp32(int32_t current, int32_t target, int32_t max_delta)
{
    if (target > current) {
        return (int64_t)current + max_delta < target ? current + max_delta : target;
    }
    return (int64_t)current - max_delta > target ? current - max_delta : target;
}

static bool stopping_fault(uint8_t code)
{
    return code == RP_FAULT_CODE_WATCHDOG || code == RP_FAULT_CODE_STALL_LEFT ||
           code == RP_FAULT_CODE_STALL_RIGHT || code == RP_FAULT_CODE_ENCODER ||
           code == RP_FAULT_CODE_DRIVER || code == RP_FAULT_CODE_INTERNAL;
}

static uint8_t stopping_mask(void)
{
    uint8_t m = 0u;
    uint8_t code;
    for (code = 1u; code <= 8u; code++) {
        if (stopping_fault(code)) {
            m = (uint8_t)(m | (1u << (code - 1u)));
        }
    }
    return m;
}

/**
 * drive.StepProfile's cruise_m in picometres for a top speed of vmax um/s: the braking
 * distance vmax^2 / 2a plus a tick at vmax and one at a_dt. Needs vmax <= FW_SPEED_UM_S_MAX
 * and a configuration fw_init took (fw_check).
 */
static int64_t cruise_pm(const fw_t *c, int64_t vmax)
{
    const int64_t tick = (int64_t)c->cfg.tick_us;
    return vmax * vmax * 1000000LL / (2 * (int64_t)c->cfg.accel_um_s2) + vmax * tick +
           (int64_t)c->a_dt * tick;
}

/** Scaled time-out in microseconds for ms milliseconds. */
static uint64_t scaled_us(const fw_t *c, uint32_t ms)
{
    return (uint64_t)ms * c->cfg.timeout_scale_permille;
}

/* ------------------------------------------------------------------ transmit */

static void send(fw_t *c, const rp_msg_t *msg)
{
    if (c->cfg.transport == FW_TRANSPORT_CAN) {
        uint32_t id = 0u;
        uint8_t data[RP_MAX_PAYLOAD_BYTES];
        const int n = rp_can_encode(msg, c->cfg.can_node, false, &id, data);
        if (n >= 0) {
            fw_hal_can_send((uint16_t)id, data, (uint8_t)n);
        }
        return;
    }
    {
        uint8_t wire[RP_MAX_WIRE_BYTES];
        const int n = rp_encode_message(msg, c->tx_seq, false, wire, sizeof wire);
        if (n > 0) {
            c->tx_seq = (uint8_t)(c->tx_seq + 1u);
            fw_hal_write(wire, (size_t)n);
        }
    }
}

static void send_ident(fw_t *c)
{
    rp_msg_t m;
    m.id = RP_MSG_IDENT;
    m.body.ident.protocol_version = c->cfg.protocol_version;
    m.body.ident.firmware_major = c->cfg.fw_major;
    m.body.ident.firmware_minor = c->cfg.fw_minor;
    m.body.ident.firmware_patch = c->cfg.fw_patch;
    m.body.ident.schema_hash = c->cfg.schema_hash;
    m.body.ident.boot_nonce = c->boot_nonce;
    send(c, &m);
}

static void send_fault(fw_t *c, uint8_t code, uint8_t active, uint32_t detail)
{
    rp_msg_t m;
    m.id = RP_MSG_FAULT;
    m.body.fault.code = code;
    m.body.fault.active = active;
    m.body.fault.detail = (uint16_t)(detail > 0xFFFFu ? 0xFFFFu : detail);
    m.body.fault.latch_gen = c->latch_gen;
    send(c, &m);
}

/* ------------------------------------------------------------------ sensors */

/** Rover-frame encoder counts (polarity applied: negated modulo 2^32, like the counter). */
static void read_travel(fw_t *c, int32_t travel[2])
{
    int32_t l = 0, r = 0;
    fw_hal_read_encoders(&l, &r);
    travel[0] = c->cfg.left_sign < 0 ? count_delta(0, l) : l;
    travel[1] = c->cfg.right_sign < 0 ? count_delta(0, r) : r;
}

static void read_speeds(fw_t *c, int32_t speed[2])
{
    int32_t l = 0, r = 0;
    fw_hal_read_wheel_speeds(&l, &r);
    speed[0] = c->cfg.left_sign < 0 ? neg_sat32(l) : l;
    speed[1] = c->cfg.right_sign < 0 ? neg_sat32(r) : r;
}

/** -limit < v < limit. */
static bool below(int32_t v, int32_t limit) { return v > -limit && v < limit; }

/* ------------------------------------------------------------------ state */

uint8_t fw_queue_depth(const fw_t *c)
{
    return (uint8_t)(c->q_len + (c->running ? 1u : 0u));
}

void fw_default_config(fw_config_t *cfg)
{
    cfg->fw_major = 1u;
    cfg->fw_minor = 0u;
    cfg->fw_patch = 0u;
    cfg->protocol_version = (uint8_t)RP_PROTOCOL_VERSION;
    cfg->schema_hash = (uint16_t)RP_SCHEMA_HASH;
    cfg->transport = FW_TRANSPORT_SERIAL;
    cfg->can_node = (uint8_t)RP_DEFAULT_NODE;
    cfg->queue_depth = (uint8_t)RP_MOTION_QUEUE_DEPTH;
    cfg->left_sign = -1;
    cfg->right_sign = 1;
    cfg->watchdog_ms = (uint16_t)RP_WATCHDOG_MS;
    cfg->telemetry_hz = (uint8_t)RP_ENCODERS_RATE_HZ;
    cfg->pose_hz = (uint8_t)RP_POSE_RATE_HZ;
    cfg->heartbeat_hz = (uint8_t)(1000u / RP_CONTROLLER_HEARTBEAT_PERIOD_MS);
    cfg->stall_timeout_ms = (uint16_t)RP_STALL_TIMEOUT_MS;
    cfg->timeout_scale_permille = 1000u;
    cfg->tick_us = 1000u;
    cfg->distance_units_per_m = 23000u;
    cfg->speed_um_s_per_unit = 5000u;
    cfg->accel_um_s2 = 800000u;
    cfg->max_speed = 60u;
    cfg->max_distance = 30000u;
}

static void reset_progress(fw_t *c)
{
    c->ended.ended_seq = 0u;
    c->ended.ended_state = (uint8_t)RP_STEP_STATE_STARTED;
    c->ended.ended_reason = (uint8_t)RP_ABORT_REASON_NONE;
    c->ended.ended_count = 0u;
    c->ended.travel = 0u;
}

static void sched_init(fw_sched_t *s, uint8_t hz, uint64_t now_us)
{
    s->base_ns = s->next_ns = now_us * 1000u;
    s->k = 0u;
    s->hz = hz;
}

/** ControllerModel._init_params and _init_state. */
static void init_state(fw_t *c, uint64_t now_us)
{
    c->watchdog_ms = c->cfg.watchdog_ms;
    c->telemetry_hz = c->cfg.telemetry_hz;
    c->pose_hz = c->cfg.pose_hz;
    c->heartbeat_hz = c->cfg.heartbeat_hz;
    c->state = (uint8_t)RP_CONTROLLER_STATE_BOOT;
    {
        /* A boot's nonce differs from the one before (docs/protocol.md, Handshake 1). A
         * reset of the MCU loses fw_t: its port's fw_hal_boot_nonce keeps that promise
         * across one (docs/firmware.md); fw_reboot keeps it here. */
        const uint16_t nonce = fw_hal_boot_nonce();
        c->boot_nonce = (c->booted && nonce == c->boot_nonce) ? (uint16_t)(nonce + 1u) : nonce;
        c->booted = true;
    }
    c->boot_us = now_us;
    c->now_us = now_us;
    c->handshake_ok = false;
    c->latch = 0u;
    c->faults = 0u;
    c->momentary = 0u;
    c->q_head = 0u;
    c->q_len = 0u;
    c->running = false;
    c->acc_head = 0u;
    c->acc_len = 0u;
    c->setpoint[0] = c->setpoint[1] = 0;
    c->commanded[0] = c->commanded[1] = 0;
    c->n_pending = 0u;
    c->n_reported = 0u;
    c->reported_head = 0u;
    c->clears = 0u;
    c->latch_gen = 0u;
    c->have_last_clear = false;
    c->last_clear_id = 0u;
    c->last_clear_gen = 0u;
    c->last_clear_result = 0u;
    /* A reset MCU's UART: the frame counter restarts at 0 (the boot IDENT is seq 0) and
     * a partial frame is gone. */
    c->tx_seq = 0u;
    rp_decoder_init(&c->dec);
    rp_can_decoder_init(&c->can_dec);
    c->dec_rejected_seen = 0u;
    reset_progress(c);
    c->have_rx = false;
    c->wd_tripped = false;
    c->stalling[0] = c->stalling[1] = false;
    c->stall_ref[0] = c->stall_ref[1] = 0;
    sched_init(&c->tel, c->telemetry_hz, now_us);
    sched_init(&c->pose, c->pose_hz, now_us);
    sched_init(&c->hb, c->heartbeat_hz, now_us);
}

/**
 * What fw_init says of c->cfg; sets c->a_dt. The bounds keep every product of the step
 * profile inside 64 bits and every divisor non-zero (fw.h, fw_error_t).
 */
static fw_error_t fw_check(fw_t *c)
{
    const fw_config_t *k = &c->cfg;
    const uint64_t a_dt = (uint64_t)k->accel_um_s2 * k->tick_us / 1000000u;
    const uint64_t top = (uint64_t)k->max_speed * k->speed_um_s_per_unit;
    int64_t pm;
    c->a_dt = 0;
    if (k->tick_us == 0u) {
        return FW_ERR_TICK;
    }
    if (a_dt == 0u || a_dt > FW_SPEED_UM_S_MAX) {
        return FW_ERR_ACCEL;
    }
    if (k->telemetry_hz == 0u || k->pose_hz == 0u || k->heartbeat_hz == 0u) {
        return FW_ERR_RATE;
    }
    if (k->timeout_scale_permille == 0u) {
        return FW_ERR_TIMEOUT_SCALE;
    }
    if (k->distance_units_per_m == 0u) {
        return FW_ERR_UNITS;
    }
    if (top > FW_SPEED_UM_S_MAX) {
        return FW_ERR_SPEED;
    }
    c->a_dt = (int32_t)a_dt;
    pm = cruise_pm(c, (int64_t)top);
    /* cruise_units multiplies (pm + 1) by the units per metre (and adds 1e12 - 1); the
     * braking law multiplies pm by 8. */
    if (pm > FW_BRAKING_PM_MAX ||
        pm + 1 > (INT64_MAX - 999999999999LL) / (int64_t)k->distance_units_per_m) {
        return FW_ERR_BRAKING;
    }
    return FW_OK;
}

fw_error_t fw_init(fw_t *c, const fw_config_t *cfg, uint64_t now_us)
{
    c->cfg = *cfg;
    if (c->cfg.queue_depth == 0u || c->cfg.queue_depth > FW_QUEUE_CAP) {
        c->cfg.queue_depth = (uint8_t)FW_QUEUE_CAP;
    }
    c->error = (uint8_t)fw_check(c);
    c->rx_errors = 0u;
    c->booted = false;
    init_state(c, now_us);
    if (c->error != FW_OK) {
        fw_hal_set_wheels(0, 0);
        return (fw_error_t)c->error;
    }
    send_ident(c);
    return FW_OK;
}

void fw_reboot(fw_t *c, uint64_t now_us)
{
    if (c->error != FW_OK) {
        return;
    }
    init_state(c, now_us);
    fw_hal_set_wheels(0, 0); /* the motors stop at once: no braking ramp */
    send_ident(c);
}

void fw_add_rx_errors(fw_t *c, uint32_t count)
{
    c->rx_errors += count;
}

/* ------------------------------------------------------------------ steps */

static int32_t step_travel(fw_t *c)
{
    int32_t t[2];
    int64_t sum;
    if (!c->running) {
        return 0;
    }
    read_travel(c, t);
    sum = abs64(count_delta(t[0], c->run_start[0])) + abs64(count_delta(t[1], c->run_start[1]));
    sum = div_round(sum, 2);
    return sum > 0xFFFF ? 0xFFFF : (int32_t)sum;
}

/** ControllerModel._ended_status: STATUS of a step that ended, remembered for PROGRESS. */
static void ended_status(fw_t *c, uint16_t seq, uint8_t state, uint8_t reason, int32_t travel)
{
    rp_msg_t m;
    c->ended.ended_count = (uint16_t)(c->ended.ended_count + 1u);
    c->ended.ended_seq = seq;
    c->ended.ended_state = state;
    c->ended.ended_reason = reason;
    c->ended.travel = (uint16_t)travel;
    m.id = RP_MSG_STATUS;
    m.body.status.seq = seq;
    m.body.status.state = state;
    m.body.status.reason = reason;
    m.body.status.travel = (uint16_t)travel;
    send(c, &m);
}

static void abort_all(fw_t *c, uint8_t reason)
{
    if (c->running) {
        ended_status(c, c->run.seq, (uint8_t)RP_STEP_STATE_ABORTED, reason, step_travel(c));
        c->running = false;
    }
    while (c->q_len > 0u) {
        const fw_step_t *s = &c->queue[c->q_head];
        ended_status(c, s->seq, (uint8_t)RP_STEP_STATE_ABORTED, reason, 0);
        c->q_head = (uint8_t)((c->q_head + 1u) % FW_QUEUE_CAP);
        c->q_len--;
    }
    if (c->state == RP_CONTROLLER_STATE_EXECUTING) {
        c->state = (uint8_t)RP_CONTROLLER_STATE_IDLE;
    }
}

static bool reported(const fw_t *c, uint16_t stop_id)
{
    uint8_t i;
    for (i = 0u; i < c->n_reported; i++) {
        if (c->reported[i] == stop_id) {
            return true;
        }
    }
    return false;
}

/** The STOPPED owed for ``stop_id``, or NULL. */
static fw_pending_stop_t *pending_of(fw_t *c, uint16_t stop_id)
{
    uint8_t i;
    for (i = 0u; i < c->n_pending; i++) {
        if (c->pending[i].stop_id == stop_id) {
            return &c->pending[i];
        }
    }
    return NULL;
}

/** A host STOP with this id was seen in this latch (its STOPPED is owed or sent): a
 * repeat, which raises no latch generation and gets no STOPPED of its own. One whose
 * STOPPED is owed from a latch a CLEARED released since is new (it latches again, a new
 * cause); the new latch takes that STOPPED owed over, so a copy after it is a repeat. */
static bool stop_is_repeat(fw_t *c, uint16_t stop_id)
{
    fw_pending_stop_t *p;
    if (stop_id == 0u) {
        return false; /* the controller's own stops are never repeats */
    }
    if (reported(c, stop_id)) {
        return true;
    }
    p = pending_of(c, stop_id);
    if (p == NULL) {
        return false;
    }
    if (p->clears == c->clears) {
        return true;
    }
    p->clears = c->clears; /* owed from a released latch: this one takes it over */
    return false;
}

/** ControllerModel._raise_latch_gen: a new latch cause (docs/protocol.md, "Latch and
 * faults"); the caller raises it before it reports the cause. */
static void raise_latch_gen(fw_t *c) { c->latch_gen = (uint8_t)(c->latch_gen + 1u); }

/** ControllerModel._stop: zero the targets now, purge, latch; STOPPED follows at rest.
 * The caller has raised the latch generation if the stop is new. */
static void do_stop(fw_t *c, uint16_t stop_id, uint8_t reason, uint8_t cause)
{
    c->setpoint[0] = c->setpoint[1] = 0;
    abort_all(c, reason);
    c->latch = (uint8_t)(c->latch | cause);
    if (cause != FW_LATCH_STOP) {
        c->state = (uint8_t)RP_CONTROLLER_STATE_FAULT;
    } else if (c->state != RP_CONTROLLER_STATE_FAULT) {
        c->state = (uint8_t)RP_CONTROLLER_STATE_STOP_LATCHED;
    }
    /* One STOPPED per host stop_id until the latch is cleared; own stops (0) each one. */
    if (stop_id != 0u && reported(c, stop_id)) {
        return;
    }
    if (pending_of(c, stop_id) != NULL) {
        return;
    }
    if (c->n_pending < FW_PENDING_STOPS) {
        fw_pending_stop_t *p = &c->pending[c->n_pending++];
        p->stop_id = stop_id;
        p->clears = c->clears;
        p->arrived_us = c->now_us;
        read_travel(c, p->travel);
    }
}

void fw_raise_fault(fw_t *c, uint64_t now_us, uint8_t code, uint32_t detail, bool condition)
{
    uint8_t bit;
    if (code < 1u || code > 8u || c->error != FW_OK) {
        return;
    }
    c->now_us = now_us;
    bit = (uint8_t)(1u << (code - 1u));
    if ((c->faults & bit) != 0u) {
        return;
    }
    c->faults = (uint8_t)(c->faults | bit);
    if (!condition) {
        c->momentary = (uint8_t)(c->momentary | bit);
    }
    if (stopping_fault(code)) {
        raise_latch_gen(c); /* FAULT names the generation its stop raised */
    }
    send_fault(c, code, 1u, detail);
    if (stopping_fault(code)) {
        if (code == RP_FAULT_CODE_WATCHDOG) {
            do_stop(c, 0u, (uint8_t)RP_ABORT_REASON_WATCHDOG, FW_LATCH_WATCHDOG);
        } else if (code == RP_FAULT_CODE_STALL_LEFT || code == RP_FAULT_CODE_STALL_RIGHT) {
            do_stop(c, 0u, (uint8_t)RP_ABORT_REASON_STALL, FW_LATCH_FAULT);
        } else {
            do_stop(c, 0u, (uint8_t)RP_ABORT_REASON_FAULT, FW_LATCH_FAULT);
        }
    }
}

void fw_clear_fault(fw_t *c, uint8_t code)
{
    uint8_t bit;
    if (code < 1u || code > 8u) {
        return;
    }
    bit = (uint8_t)(1u << (code - 1u));
    if ((c->faults & bit) == 0u) {
        return;
    }
    c->faults = (uint8_t)(c->faults & ~bit);
    c->momentary = (uint8_t)(c->momentary & ~bit);
    send_fault(c, code, 0u, 0u);
}

/* ------------------------------------------------------------------ receive */

static void remember(fw_t *c, uint16_t seq)
{
    if (c->acc_len == FW_DEDUP_WINDOW) {
        c->acc_head = (uint8_t)((c->acc_head + 1u) % FW_DEDUP_WINDOW);
        c->acc_len--;
    }
    c->accepted[(c->acc_head + c->acc_len) % FW_DEDUP_WINDOW] = seq;
    c->acc_len++;
}

static bool is_accepted(const fw_t *c, uint16_t seq)
{
    uint8_t i;
    for (i = 0u; i < c->acc_len; i++) {
        if (c->accepted[(c->acc_head + i) % FW_DEDUP_WINDOW] == seq) {
            return true;
        }
    }
    return false;
}

static void send_ack(fw_t *c, uint16_t seq, uint8_t result, uint8_t field)
{
    rp_msg_t m;
    const uint8_t depth = fw_queue_depth(c);
    m.id = RP_MSG_ACK;
    m.body.ack.seq = seq;
    m.body.ack.result = result;
    m.body.ack.field = field;
    m.body.ack.queue_depth = depth;
    send(c, &m);
}

/** ControllerModel._motion: the checks in the normative order. */
static void on_motion(fw_t *c, const rp_motion_t *mo)
{
    if (!c->handshake_ok) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_NOT_READY, (uint8_t)RP_ACK_FIELD_NONE);
        return;
    }
    if (is_accepted(c, mo->seq)) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_DUPLICATE, (uint8_t)RP_ACK_FIELD_NONE);
        return;
    }
    if (mo->command > RP_COMMAND_RIGHT) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_OUT_OF_RANGE, (uint8_t)RP_ACK_FIELD_COMMAND);
        return;
    }
    if (mo->command == RP_COMMAND_STOP) {
        /* An emergency stop whatever its speed and distance. The ACK (queue depth 0,
         * as after the purge) goes ahead of the aborted steps' STATUS. */
        uint8_t saved_len = c->q_len;
        bool saved_running = c->running;
        remember(c, mo->seq);
        c->q_len = 0u;
        c->running = false;
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_ACCEPTED, (uint8_t)RP_ACK_FIELD_NONE);
        c->q_len = saved_len;
        c->running = saved_running;
        raise_latch_gen(c);
        do_stop(c, 0u, (uint8_t)RP_ABORT_REASON_STOP, FW_LATCH_STOP);
        return;
    }
    if (mo->speed > c->cfg.max_speed) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_OUT_OF_RANGE, (uint8_t)RP_ACK_FIELD_SPEED);
        return;
    }
    if (mo->distance > c->cfg.max_distance) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_OUT_OF_RANGE, (uint8_t)RP_ACK_FIELD_DISTANCE);
        return;
    }
    if (c->state == RP_CONTROLLER_STATE_FAULT) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_FAULT_ACTIVE, (uint8_t)RP_ACK_FIELD_NONE);
        return;
    }
    if (c->latch != 0u) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_STOP_LATCHED, (uint8_t)RP_ACK_FIELD_NONE);
        return;
    }
    if (fw_queue_depth(c) >= c->cfg.queue_depth) {
        send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_QUEUE_FULL, (uint8_t)RP_ACK_FIELD_NONE);
        return;
    }
    remember(c, mo->seq);
    {
        fw_step_t *s = &c->queue[(c->q_head + c->q_len) % FW_QUEUE_CAP];
        s->seq = mo->seq;
        s->command = mo->command;
        s->speed = mo->speed;
        s->distance = mo->distance;
        c->q_len++;
    }
    send_ack(c, mo->seq, (uint8_t)RP_ACK_RESULT_ACCEPTED, (uint8_t)RP_ACK_FIELD_NONE);
}

/** ControllerModel._judge_clear: the answer to a new request naming latch_gen. */
static uint8_t judge_clear(const fw_t *c, uint8_t latch_gen)
{
    if (c->latch == 0u) {
        return (uint8_t)RP_CLEAR_RESULT_NOT_LATCHED;
    }
    if (latch_gen != c->latch_gen) {
        return (uint8_t)RP_CLEAR_RESULT_LATCH_CHANGED;
    }
    if ((c->faults & stopping_mask()) != 0u) {
        return (uint8_t)RP_CLEAR_RESULT_FAULT_PERSISTS;
    }
    return (uint8_t)RP_CLEAR_RESULT_CLEARED;
}

/** ControllerModel._clear: the answer to CLEAR_STOP stop_id naming latch_gen. */
static uint8_t do_clear(fw_t *c, uint16_t stop_id, uint8_t latch_gen)
{
    uint8_t result;
    if (c->have_last_clear && stop_id == c->last_clear_id && latch_gen == c->last_clear_gen) {
        return c->last_clear_result; /* a repeat that crossed its answer: nothing changes */
    }
    result = judge_clear(c, latch_gen);
    c->have_last_clear = true;
    c->last_clear_id = stop_id;
    c->last_clear_gen = latch_gen;
    c->last_clear_result = result;
    if (result == RP_CLEAR_RESULT_CLEARED) {
        c->latch = 0u;
        c->n_reported = 0u;
        c->reported_head = 0u;
        c->clears++;
        c->state =
            (uint8_t)(c->handshake_ok ? RP_CONTROLLER_STATE_IDLE : RP_CONTROLLER_STATE_BOOT);
    }
    return result;
}

static void on_hello(fw_t *c, const rp_hello_t *h)
{
    const bool match =
        h->protocol_version == c->cfg.protocol_version && h->schema_hash == c->cfg.schema_hash;
    /* A new session: the previous host's steps and seqs are gone. */
    abort_all(c, (uint8_t)RP_ABORT_REASON_SESSION);
    c->setpoint[0] = c->setpoint[1] = 0;
    c->acc_head = 0u;
    c->acc_len = 0u;
    reset_progress(c);
    c->handshake_ok = match;
    if (match && c->state == RP_CONTROLLER_STATE_BOOT) {
        c->state = (uint8_t)RP_CONTROLLER_STATE_IDLE;
    } else if (!match && (c->state == RP_CONTROLLER_STATE_IDLE ||
                          c->state == RP_CONTROLLER_STATE_EXECUTING)) {
        c->state = (uint8_t)RP_CONTROLLER_STATE_BOOT;
    }
    send_ident(c);
}

static void on_set_param(fw_t *c, const rp_set_param_t *sp)
{
    rp_msg_t m;
    int32_t lo = 0, hi = 0, cur = 0;
    m.id = RP_MSG_PARAM_VALUE;
    m.body.param_value.param = sp->param;
    switch (sp->param) {
    case RP_PARAM_WATCHDOG_MS: lo = 50; hi = 10000; cur = c->watchdog_ms; break;
    case RP_PARAM_TELEMETRY_HZ: lo = 1; hi = 200; cur = c->telemetry_hz; break;
    case RP_PARAM_POSE_HZ: lo = 1; hi = 50; cur = c->pose_hz; break;
    case RP_PARAM_HEARTBEAT_HZ: lo = 1; hi = 50; cur = c->heartbeat_hz; break;
    default:
        m.body.param_value.result = (uint8_t)RP_PARAM_RESULT_UNKNOWN_PARAM;
        m.body.param_value.value = 0;
        send(c, &m);
        return;
    }
    if (sp->value < lo || sp->value > hi) {
        m.body.param_value.result = (uint8_t)RP_PARAM_RESULT_OUT_OF_RANGE;
        m.body.param_value.value = cur;
        send(c, &m);
        return;
    }
    switch (sp->param) {
    case RP_PARAM_WATCHDOG_MS: c->watchdog_ms = (uint16_t)sp->value; break;
    case RP_PARAM_TELEMETRY_HZ: c->telemetry_hz = (uint8_t)sp->value; break;
    case RP_PARAM_POSE_HZ: c->pose_hz = (uint8_t)sp->value; break;
    default: c->heartbeat_hz = (uint8_t)sp->value; break;
    }
    m.body.param_value.result = (uint8_t)RP_PARAM_RESULT_OK;
    m.body.param_value.value = sp->value;
    send(c, &m);
}

static bool host_to_controller(uint8_t id)
{
    const rp_msg_info_t *info = rp_msg_info(id);
    return info != NULL && info->direction == RP_DIR_HOST_TO_CONTROLLER;
}

void fw_handle(fw_t *c, uint64_t now_us, const rp_msg_t *msg)
{
    if (c->error != FW_OK) {
        return;
    }
    c->now_us = now_us;
    if (!host_to_controller(msg->id)) {
        c->rx_errors++; /* an echo on a serial line: counted, does not feed the watchdog */
        return;
    }
    if (msg->id == RP_MSG_STOP) {
        /* The acknowledgement goes first (it is what the host is timing); the state and
         * generation it names are the ones after the stop: FAULT stays FAULT, all else
         * latches. do_stop, below in this call, zeroes the targets: no control tick
         * comes between. */
        rp_msg_t ack;
        if (!stop_is_repeat(c, msg->body.stop.stop_id)) {
            raise_latch_gen(c);
        }
        ack.body.stop_ack.latch_gen = c->latch_gen;
        ack.id = RP_MSG_STOP_ACK;
        ack.body.stop_ack.stop_id = msg->body.stop.stop_id;
        ack.body.stop_ack.state = (uint8_t)(c->state == RP_CONTROLLER_STATE_FAULT
                                                ? RP_CONTROLLER_STATE_FAULT
                                                : RP_CONTROLLER_STATE_STOP_LATCHED);
        send(c, &ack);
    }
    /* Any valid frame feeds the watchdog; the first after a trip ends its condition. */
    c->last_rx_us = now_us;
    c->have_rx = true;
    if (c->wd_tripped) {
        c->wd_tripped = false;
        fw_clear_fault(c, (uint8_t)RP_FAULT_CODE_WATCHDOG);
    }
    switch (msg->id) {
    case RP_MSG_STOP:
        do_stop(c, msg->body.stop.stop_id, (uint8_t)RP_ABORT_REASON_STOP, FW_LATCH_STOP);
        break;
    case RP_MSG_MOTION: on_motion(c, &msg->body.motion); break;
    case RP_MSG_CLEAR_STOP: {
        rp_msg_t m;
        m.id = RP_MSG_CLEAR_ACK;
        m.body.clear_ack.stop_id = msg->body.clear_stop.stop_id;
        m.body.clear_ack.result =
            do_clear(c, m.body.clear_ack.stop_id, msg->body.clear_stop.latch_gen);
        m.body.clear_ack.latch_gen = c->latch_gen;
        send(c, &m);
        break;
    }
    case RP_MSG_HELLO: on_hello(c, &msg->body.hello); break;
    case RP_MSG_SET_PARAM: on_set_param(c, &msg->body.set_param); break;
    default: break; /* HOST_HEARTBEAT: the watchdog only */
    }
}

static void count_decoder_errors(fw_t *c, const rp_counters_t *counters)
{
    const uint32_t rejected = rp_counters_rejected(counters);
    c->rx_errors += rejected - c->dec_rejected_seen;
    c->dec_rejected_seen = rejected;
}

void fw_on_bytes(fw_t *c, uint64_t now_us, const uint8_t *data, size_t len)
{
    rp_frame_t f;
    while (rp_decoder_feed(&c->dec, &data, &len, &f)) {
        count_decoder_errors(c, &c->dec.counters);
        fw_handle(c, now_us, &f.msg);
    }
    count_decoder_errors(c, &c->dec.counters);
}

void fw_on_can(fw_t *c, uint64_t now_us, uint32_t can_id, bool is_extended, bool is_remote,
               const uint8_t *data, size_t len)
{
    rp_can_frame_t f;
    /* As the Python CAN endpoint does: a bad frame is an rx error whoever it was for; a
     * good one for another node, or of our own kind (a controller's frame echoed back),
     * is foreign: ignored, not an error. */
    if (!rp_can_decode(&c->can_dec, can_id, is_extended, is_remote, data, len, &f)) {
        c->rx_errors++;
        return;
    }
    if ((f.node != c->cfg.can_node && f.node != RP_BROADCAST_NODE) ||
        !host_to_controller(f.msg.id)) {
        return;
    }
    fw_handle(c, now_us, &f.msg);
}

/* ------------------------------------------------------------------ step profile */

/** Integer square root, floor. */
static uint64_t isqrt64(uint64_t v)
{
    uint64_t r = 0u, bit = (uint64_t)1u << 62;
    while (bit > v) {
        bit >>= 2;
    }
    while (bit != 0u) {
        if (v >= r + bit) {
            v -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    return r;
}

/**
 * drive._braking_speed: the largest speed (um/s) for this tick from which braking tick by
 * tick covers at most rem_pm picometres; a_dt in um/s per tick.
 */
static int64_t braking_speed(const fw_t *c, int64_t rem_pm, int64_t a_dt)
{
    const int64_t tick = (int64_t)c->cfg.tick_us;
    const int64_t unit = a_dt * tick; /* pm travelled in one tick at a_dt */
    int64_t m = ((int64_t)isqrt64((uint64_t)(1 + 8 * (rem_pm / unit))) - 1) / 2;
    if (m < 0) {
        m = 0;
    }
    while (m > 0 && unit * m * (m + 1) / 2 > rem_pm) {
        m--;
    }
    while (unit * (m + 1) * (m + 2) / 2 <= rem_pm) {
        m++;
    }
    return (rem_pm / tick + a_dt * m * (m + 1) / 2) / (m + 1);
}

/** StepProfile._side: the next target along the direction of travel, and arrival. */
static int32_t profile_side(fw_t *c, int32_t u, int64_t rem_units, int32_t a_dt, bool *arrived)
{
    if (rem_units <= 0) {
        *arrived = true;
        return u > a_dt ? u - a_dt : (u < -a_dt ? u + a_dt : 0);
    }
    *arrived = false;
    {
        const int64_t vmax = c->vmax_um_s;
        int64_t want = vmax;
        /* Beyond the cruise distance the braking curve allows more than cruise speed:
         * rem_units >= cruise_units is rem_pm > cruise_pm without a division per tick. */
        if (rem_units < c->cruise_units) {
            const int64_t rem_pm =
                rem_units * 1000000000000LL / (int64_t)c->cfg.distance_units_per_m;
            const int64_t b = braking_speed(c, rem_pm, a_dt);
            want = b < vmax ? b : vmax;
        }
        if (want > (int64_t)u + a_dt) {
            return u + a_dt;
        }
        if (want < (int64_t)u - a_dt) {
            return u - a_dt;
        }
        return (int32_t)want;
    }
}

/**
 * The cruise distance of a step, as the smallest remaining travel in encoder units whose
 * length in picometres, floor(rem * 1e12 / units_per_m), exceeds
 * vmax^2 / 2a + vmax * dt + a_dt * dt (drive.StepProfile's cruise_m).
 */
static int32_t cruise_units(const fw_t *c)
{
    const int64_t upm = (int64_t)c->cfg.distance_units_per_m;
    return (int32_t)(((cruise_pm(c, c->vmax_um_s) + 1) * upm + 999999999999LL) / 1000000000000LL);
}

static void start_next(fw_t *c, const int32_t travel[2])
{
    const fw_step_t *s = &c->queue[c->q_head];
    const bool moving = s->command != RP_COMMAND_STOP && s->speed > 0u && s->distance > 0u;
    rp_msg_t m;
    c->run = *s;
    c->q_head = (uint8_t)((c->q_head + 1u) % FW_QUEUE_CAP);
    c->q_len--;
    c->running = true;
    c->run_start[0] = travel[0];
    c->run_start[1] = travel[1];
    switch (c->run.command) {
    case RP_COMMAND_FWD: c->dir[0] = 1; c->dir[1] = 1; break;
    case RP_COMMAND_REV: c->dir[0] = -1; c->dir[1] = -1; break;
    case RP_COMMAND_LEFT: c->dir[0] = -1; c->dir[1] = 1; break;
    case RP_COMMAND_RIGHT: c->dir[0] = 1; c->dir[1] = -1; break;
    default: c->dir[0] = 0; c->dir[1] = 0; break;
    }
    c->vmax_um_s = moving ? (int32_t)(s->speed * c->cfg.speed_um_s_per_unit) : 0;
    c->goal_units = moving ? (int32_t)s->distance : 0;
    c->cruise_units = cruise_units(c);
    /* STOP, and a step with nothing to do started while a wheel turns, brake whatever
     * the direction (StepProfile._brakes): along a direction a zero step never arrives. */
    c->stop_profile = !moving;
    if (c->stop_profile) {
        c->u[0] = c->commanded[0];
        c->u[1] = c->commanded[1];
    } else {
        c->u[0] = c->dir[0] != 0 ? c->commanded[0] * c->dir[0] : 0;
        c->u[1] = c->dir[1] != 0 ? c->commanded[1] * c->dir[1] : 0;
    }
    c->run_done = !moving && c->u[0] == 0 && c->u[1] == 0;
    c->arrived[0] = c->arrived[1] = !moving;
    c->stalling[0] = c->stalling[1] = false;
    c->stall_ref[0] = travel[0];
    c->stall_ref[1] = travel[1];
    c->state = (uint8_t)RP_CONTROLLER_STATE_EXECUTING;
    m.id = RP_MSG_STATUS;
    m.body.status.seq = c->run.seq;
    m.body.status.state = (uint8_t)RP_STEP_STATE_STARTED;
    m.body.status.reason = (uint8_t)RP_ABORT_REASON_NONE;
    m.body.status.travel = 0u;
    send(c, &m);
}

/** StepProfile.update: targets (rover frame) for the next tick. */
static void profile_update(fw_t *c, const int32_t travel[2])
{
    const int32_t a_dt = c->a_dt;
    int side;
    if (c->run_done) {
        c->setpoint[0] = c->setpoint[1] = 0;
        return;
    }
    if (c->stop_profile) {
        c->u[0] = ramp32(c->u[0], 0, a_dt);
        c->u[1] = ramp32(c->u[1], 0, a_dt);
        c->run_done = c->u[0] == 0 && c->u[1] == 0;
        c->setpoint[0] = c->u[0];
        c->setpoint[1] = c->u[1];
        return;
    }
    for (side = 0; side < 2; side++) {
        const int64_t moved = count_delta(travel[side], c->run_start[side]);
        const int64_t rem = (int64_t)c->goal_units - c->dir[side] * moved;
        c->u[side] = profile_side(c, c->u[side], rem, a_dt, &c->arrived[side]);
    }
    c->run_done = c->arrived[0] && c->arrived[1] && c->u[0] == 0 && c->u[1] == 0;
    c->setpoint[0] = c->dir[0] * c->u[0];
    c->setpoint[1] = c->dir[1] * c->u[1];
}

/* ------------------------------------------------------------------ control */

static void check_watchdog(fw_t *c)
{
    uint64_t silent;
    if (!c->handshake_ok || !c->have_rx || c->wd_tripped) {
        return;
    }
    silent = c->now_us - c->last_rx_us;
    if (silent > scaled_us(c, c->watchdog_ms)) {
        const uint64_t detail =
            (uint64_t)div_round((int64_t)silent, (int64_t)c->cfg.timeout_scale_permille);
        c->wd_tripped = true;
        fw_raise_fault(c, c->now_us, (uint8_t)RP_FAULT_CODE_WATCHDOG, (uint32_t)detail, true);
    }
}

void fw_control(fw_t *c, uint64_t now_us)
{
    int32_t travel[2];
    const int32_t dv = c->a_dt;
    if (c->error != FW_OK) {
        fw_hal_set_wheels(0, 0);
        return;
    }
    c->now_us = now_us;
    check_watchdog(c);
    read_travel(c, travel);
    /* A STOPPED still owed (a clear came before rest) holds the queue. */
    if (!c->running && c->q_len > 0u && c->latch == 0u && c->n_pending == 0u) {
        start_next(c, travel);
    }
    if (c->running) {
        profile_update(c, travel);
        if (c->run_done) {
            int32_t t = step_travel(c);
            ended_status(c, c->run.seq, (uint8_t)RP_STEP_STATE_COMPLETED,
                         (uint8_t)RP_ABORT_REASON_NONE, t);
            c->running = false;
            if (c->q_len > 0u) {
                start_next(c, travel);
            } else {
                c->state = (uint8_t)RP_CONTROLLER_STATE_IDLE;
            }
        }
    }
    c->commanded[0] = ramp32(c->commanded[0], c->setpoint[0], dv);
    c->commanded[1] = ramp32(c->commanded[1], c->setpoint[1], dv);
    fw_hal_set_wheels(c->cfg.left_sign < 0 ? -c->commanded[0] : c->commanded[0],
                      c->cfg.right_sign < 0 ? -c->commanded[1] : c->commanded[1]);
}

/* ------------------------------------------------------------------ sense */

static void check_stall(fw_t *c, const int32_t travel[2])
{
    int side;
    if (!c->running) {
        c->stalling[0] = c->stalling[1] = false;
        return;
    }
    for (side = 0; side < 2; side++) {
        if (below(c->commanded[side], FW_STALL_MIN_TARGET_UM_S) ||
            count_delta(travel[side], c->stall_ref[side]) != 0) {
            c->stalling[side] = false;
            c->stall_ref[side] = travel[side];
            continue;
        }
        if (!c->stalling[side]) {
            c->stalling[side] = true;
            c->stall_since[side] = c->now_us;
        } else if (c->now_us - c->stall_since[side] > scaled_us(c, c->cfg.stall_timeout_ms)) {
            const int64_t moved = count_delta(travel[side], c->run_start[side]);
            int64_t expected = (int64_t)c->goal_units - c->dir[side] * moved;
            expected = expected < 0 ? 0 : expected;
            fw_raise_fault(c, c->now_us,
                           (uint8_t)(side == 0 ? RP_FAULT_CODE_STALL_LEFT
                                               : RP_FAULT_CODE_STALL_RIGHT),
                           (uint32_t)expected, false);
            return;
        }
    }
}

static void report_stopped(fw_t *c, const int32_t travel[2])
{
    uint8_t i;
    for (i = 0u; i < c->n_pending; i++) {
        const fw_pending_stop_t *p = &c->pending[i];
        const int64_t moved = abs64(count_delta(travel[0], p->travel[0])) +
                              abs64(count_delta(travel[1], p->travel[1]));
        const int64_t mm = div_round(moved * 1000, 2 * (int64_t)c->cfg.distance_units_per_m);
        const int64_t ms =
            div_round((int64_t)(c->now_us - p->arrived_us), (int64_t)c->cfg.timeout_scale_permille);
        rp_msg_t m;
        m.id = RP_MSG_STOPPED;
        m.body.stopped.stop_id = p->stop_id;
        m.body.stopped.distance_mm = (uint16_t)(mm > 0xFFFF ? 0xFFFF : mm);
        m.body.stopped.duration_ms = (uint16_t)(ms > 0xFFFF ? 0xFFFF : ms);
        send(c, &m);
        /* Remembered only within its latch: a CLEARED it predates makes it new again. */
        if (p->stop_id != 0u && p->clears == c->clears) {
            if (c->n_reported < FW_REPORTED_STOPS) {
                c->reported[c->n_reported++] = p->stop_id;
            } else {
                c->reported[c->reported_head] = p->stop_id;
                c->reported_head = (uint8_t)((c->reported_head + 1u) % FW_REPORTED_STOPS);
            }
        }
    }
    c->n_pending = 0u;
}

static void check_stopped(fw_t *c, const int32_t travel[2])
{
    int32_t speed[2];
    uint8_t code;
    if (c->commanded[0] != 0 || c->commanded[1] != 0) {
        return;
    }
    read_speeds(c, speed);
    if (!below(speed[0], FW_REST_UM_S) || !below(speed[1], FW_REST_UM_S)) {
        return;
    }
    report_stopped(c, travel);
    /* Events (a stall) are over once the wheels are at rest: after STOPPED. */
    for (code = 1u; code <= 8u; code++) {
        if ((c->momentary & (1u << (code - 1u))) != 0u) {
            fw_clear_fault(c, code);
        }
    }
}

/**
 * next = max(next + 1/hz, now) on an exact grid in nanoseconds: the k-th deadline after
 * base is base + ceil(k * 1e9 / hz) ns, so no rounding accumulates while the rate holds;
 * a rate change (SET_PARAM) starts a new grid at the current deadline. Every second (k =
 * hz, exactly base + 1e9) the grid moves its base there, so k never wraps. A deadline is due
 * from 1 ns before it (the Python model's float tolerance), so a grid point that falls
 * on a tick, like 18.1 s at 30 Hz, fires on that tick in both.
 */
static void advance(fw_sched_t *s, uint8_t hz, uint64_t now_us)
{
    const uint64_t now_ns = now_us * 1000u;
    if (hz != s->hz) {
        s->base_ns = s->next_ns;
        s->k = 0u;
        s->hz = hz;
    }
    s->k++;
    s->next_ns = s->base_ns + ((uint64_t)s->k * 1000000000u + hz - 1u) / hz;
    if (s->k == hz) {
        s->base_ns = s->next_ns;
        s->k = 0u;
    }
    if (s->next_ns < now_ns) {
        s->base_ns = s->next_ns = now_ns;
        s->k = 0u;
    }
}

static bool due(const fw_sched_t *s, uint64_t now_us)
{
    return now_us * 1000u + 1u >= s->next_ns;
}

static int16_t mm12(int32_t um_s)
{
    return (int16_t)clamp32(div_round(um_s, 1000), -2048, 2047);
}

static int32_t wrap24(int32_t v)
{
    return (int32_t)(((uint32_t)v + 0x800000u) & 0xFFFFFFu) - 0x800000;
}

/**
 * A sensor sample (ENCODERS, WHEEL_SPEEDS, IMU, POSE): sent only in a session
 * (docs/protocol.md, Handshake). The sensors are read on schedule all the same, so the
 * HAL sees the same calls with or without a session.
 */
static void send_sample(fw_t *c, const rp_msg_t *msg)
{
    if (c->handshake_ok) {
        send(c, msg);
    }
}

static void fast_telemetry(fw_t *c)
{
    const uint16_t t_ms = (uint16_t)(((c->now_us - c->boot_us) / 1000u) & 0xFFFFu);
    int32_t travel[2], speed[2];
    fw_imu_sample_t imu;
    rp_msg_t m;
    read_travel(c, travel);
    read_speeds(c, speed);
    m.id = RP_MSG_ENCODERS;
    m.body.encoders.t_ms = t_ms;
    m.body.encoders.left = wrap24(travel[0]);
    m.body.encoders.right = wrap24(travel[1]);
    send_sample(c, &m);
    m.id = RP_MSG_WHEEL_SPEEDS;
    m.body.wheel_speeds.t_ms = t_ms;
    m.body.wheel_speeds.left_mm_s = mm12(speed[0]);
    m.body.wheel_speeds.right_mm_s = mm12(speed[1]);
    m.body.wheel_speeds.left_target_mm_s = mm12(c->setpoint[0]);
    m.body.wheel_speeds.right_target_mm_s = mm12(c->setpoint[1]);
    send_sample(c, &m);
    if (fw_hal_read_imu(&imu)) {
        m.id = RP_MSG_IMU;
        m.body.imu.t_ms = t_ms;
        m.body.imu.yaw_rate_mrad_s = imu.yaw_rate_mrad_s;
        m.body.imu.accel_x_mm_s2 = imu.accel_x_mm_s2;
        m.body.imu.accel_y_mm_s2 = imu.accel_y_mm_s2;
        send_sample(c, &m);
    }
}

static void send_heartbeat(fw_t *c)
{
    rp_msg_t m;
    const uint8_t depth = fw_queue_depth(c);
    m.id = RP_MSG_HEARTBEAT;
    m.body.heartbeat.state = c->state;
    m.body.heartbeat.stop_latched = c->latch != 0u ? 1u : 0u;
    m.body.heartbeat.handshake_ok = c->handshake_ok ? 1u : 0u;
    m.body.heartbeat.latch_stop = (c->latch & FW_LATCH_STOP) != 0u ? 1u : 0u;
    m.body.heartbeat.latch_watchdog = (c->latch & FW_LATCH_WATCHDOG) != 0u ? 1u : 0u;
    m.body.heartbeat.latch_fault = (c->latch & FW_LATCH_FAULT) != 0u ? 1u : 0u;
    m.body.heartbeat.fault_bits = c->faults;
    m.body.heartbeat.queue_depth = depth;
    m.body.heartbeat.boot_nonce = c->boot_nonce;
    m.body.heartbeat.rx_errors = (uint16_t)(c->rx_errors & 0xFFFFu);
    m.body.heartbeat.latch_gen = c->latch_gen;
    send(c, &m);
    m.id = RP_MSG_PROGRESS;
    m.body.progress = c->ended;
    send(c, &m);
}

static void telemetry(fw_t *c)
{
    const uint64_t now = c->now_us;
    fw_pose_sample_t pose;
    if (due(&c->tel, now)) {
        advance(&c->tel, c->telemetry_hz, now);
        fast_telemetry(c);
    }
    if (due(&c->pose, now)) {
        advance(&c->pose, c->pose_hz, now);
        fw_hal_pose_sample();
    }
    while (fw_hal_pose_read(&pose)) {
        /* The age is in the host's time, like the time-outs; a time from the future is 0. */
        const uint64_t age_us = (pose.taken_us < now ? now - pose.taken_us : 0u) * 1000u /
                                c->cfg.timeout_scale_permille;
        const int64_t age = div_round((int64_t)age_us, 4000);
        rp_msg_t m;
        m.id = RP_MSG_POSE;
        m.body.pose.x_mm = clamp32(pose.x_mm, -524288L, 524287L);
        m.body.pose.y_mm = clamp32(pose.y_mm, -524288L, 524287L);
        m.body.pose.yaw_ddeg = pose.yaw_ddeg;
        m.body.pose.sigma_cm = pose.sigma_cm;
        m.body.pose.age_4ms = (uint8_t)(age > 255 ? 255 : age);
        send_sample(c, &m);
    }
    if (due(&c->hb, now)) {
        advance(&c->hb, c->heartbeat_hz, now);
        send_heartbeat(c);
    }
}

void fw_sense(fw_t *c, uint64_t now_us)
{
    int32_t travel[2];
    if (c->error != FW_OK) {
        return;
    }
    c->now_us = now_us;
    read_travel(c, travel);
    check_stall(c, travel);
    check_stopped(c, travel);
    telemetry(c);
}

void fw_tick(fw_t *c, uint64_t now_us)
{
    fw_sense(c, now_us);
    fw_control(c, now_us);
}
