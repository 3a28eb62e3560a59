/*
 * Fuzz target for the firmware core behind a VARIED plant (libFuzzer entry point): where
 * fuzz_fw.c feeds bytes to a core with an ideal plant and the default configuration,
 * this one draws the configuration, the encoder counters' start (near the wrap and at
 * INT32_MIN included), encoder gain and glitches, wheel speed readings (INT32_MIN, any
 * int32), IMU and pose samples, time jumps of up to 71 minutes, faults and reboots, with
 * well-formed host messages (so that steps actually run) and raw bytes in between.
 *
 *   clang -std=c99 -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all \
 *       -I../.. ../fw.c ../../rover_msgs.c ../../rover_proto.c fuzz_fw_plant.c -o fuzz_fw_plant
 *   ./fuzz_fw_plant -seed=1 -runs=100000 corpus/ corpus_fw_plant/
 *
 * Built with -DFW_FUZZ_MAIN (gcc with the sanitizers) it is a plain program that runs
 * the same checks over the files named on its command line.
 *
 * Input: 16 bytes of configuration and plant (missing bytes read as 0), then records of
 * an op byte and its arguments (see run_op). Invariants, checked inside, beyond "no
 * undefined behaviour and no memory error" (the sanitizers):
 *   - fw_init refuses a configuration it cannot run with, and a refused core sends
 *     nothing and keeps the wheels at zero whatever it is fed;
 *   - every frame the core writes decodes cleanly;
 *   - the queue never exceeds its depth; while the latch is set the wheel targets are 0;
 *   - a STOP frame is answered by STOP_ACK in the call that received it, and the wheel
 *     targets are zero when that call returns;
 *   - the wheel commands stay within the top speed and change by at most the
 *     acceleration limit per fw_control (a reboot stops them at once);
 *   - a step never drives far beyond its distance: while the plant is ideal (exact
 *     counting, no glitch, no time jump) since the step started, each side's counted
 *     travel along its direction, taken modulo 2^32, stays within the distance plus the
 *     cruise distance from the top speed plus 2 units.
 */
#include <stdlib.h>
#include <string.h>

#include "../fw.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void require(bool ok)
{
    if (!ok) {
        abort();
    }
}

/* ------------------------------------------------------------------ input */

static const uint8_t *in_data;
static size_t in_size, in_pos;

static uint8_t take8(void) { return in_pos < in_size ? in_data[in_pos++] : 0u; }

static uint16_t take16(void) { return (uint16_t)(take8() | (uint16_t)take8() << 8); }

static uint32_t take32(void) { return (uint32_t)take16() | (uint32_t)take16() << 16; }

/* A value from table (index b % n), or, for b >= 0xF0, four raw bytes. */
static uint32_t pick(const uint32_t *table, size_t n)
{
    const uint8_t b = take8();
    return b >= 0xF0u ? take32() : table[b % n];
}

#define PICK(table) pick(table, sizeof table / sizeof table[0])

/* ------------------------------------------------------------------ plant and HAL */

static int32_t as_i32(uint32_t v)
{
    return v < 0x80000000u ? (int32_t)v : -(int32_t)(0xFFFFFFFFu - v) - 1;
}

static int32_t wheel[2];        /* last fw_hal_set_wheels, motor frame, um/s */
static uint32_t counter[2];     /* encoder counters, motor frame */
static double counter_frac[2];  /* counts not yet whole, and the gain's rounding */
static uint8_t gain[2];         /* counts per travel, x/128: 128 counts exactly */
static uint8_t speed_mode[2];   /* 0: the command; 1: speed_value */
static int32_t speed_value[2];
static fw_imu_sample_t imu;
static int imu_on;
static int pose_pending;
static fw_pose_sample_t pose;
static uint64_t now;
static uint16_t nonce;

static rp_decoder_t out_dec;
static unsigned frames_out, stop_acks_out;
static unsigned long total_frames, total_completed, total_watched, total_refused;
static bool step_started;       /* a STATUS STARTED in the current call */
static uint16_t started_seq;

/* What the harness knows of the configuration the core took. */
static bool accepted;
static int64_t top_um_s, a_dt;
static double upm, bound_units;
static bool allow_jump;         /* the next fw_hal_set_wheels may jump (init, reboot) */

/* The step the harness watches. */
static bool tracking, ideal;
static uint16_t track_seq;
static int8_t track_dir[2];
static int64_t track_limit;
static int32_t track_start[2];  /* rover-frame counts when it started */

void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    const int32_t w[2] = {left_um_s, right_um_s};
    int side;
    for (side = 0; side < 2; side++) {
        if (!accepted) {
            require(w[side] == 0);
        } else {
            require(w[side] <= top_um_s && w[side] >= -top_um_s);
            if (!allow_jump) {
                const int64_t d = (int64_t)w[side] - wheel[side];
                require(d <= a_dt && d >= -a_dt);
            }
        }
        wheel[side] = w[side];
    }
    allow_jump = false;
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = as_i32(counter[0]);
    *right = as_i32(counter[1]);
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = speed_mode[0] != 0u ? speed_value[0] : wheel[0];
    *right_um_s = speed_mode[1] != 0u ? speed_value[1] : wheel[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    *out = imu;
    return imu_on;
}

void fw_hal_pose_sample(void)
{
    if (pose_pending < 4) {
        pose_pending++;
    }
}

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    if (pose_pending == 0) {
        return 0;
    }
    pose_pending--;
    *out = pose;
    /* Taken in the past (the HAL's contract), any time ago. */
    out->taken_us = pose.taken_us <= now ? now - pose.taken_us : 0u;
    return 1;
}

uint16_t fw_hal_boot_nonce(void) { return nonce++; }

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    rp_frame_t f;
    require(accepted);
    require(n <= RP_MAX_WIRE_BYTES);
    while (rp_decoder_feed(&out_dec, &bytes, &n, &f)) {
        frames_out++;
        total_frames++;
        if (f.msg.id == RP_MSG_STOP_ACK) {
            stop_acks_out++;
        } else if (f.msg.id == RP_MSG_STATUS) {
            const rp_status_t *s = &f.msg.body.status;
            if (s->state == RP_STEP_STATE_STARTED) {
                step_started = true;
                started_seq = s->seq;
            } else if (step_started && s->seq == started_seq) {
                step_started = false; /* started and ended in one call */
            } else if (tracking && s->seq == track_seq) {
                tracking = false;
                total_watched += ideal;
            }
            total_completed += s->state == RP_STEP_STATE_COMPLETED;
        }
    }
    require(rp_counters_rejected(&out_dec.counters) == 0u);
}

void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len)
{
    (void)can_id;
    (void)data;
    (void)len;
    require(false); /* a serial core */
}

static int32_t rover_count(const fw_t *c, int side)
{
    const int8_t sign = side == 0 ? c->cfg.left_sign : c->cfg.right_sign;
    return as_i32(sign < 0 ? 0u - counter[side] : counter[side]);
}

/* The wheels turn at their command for dt_us; the counters count it, times the gain. */
static void plant_step(uint64_t dt_us)
{
    int side;
    const double dt = (double)(dt_us > 0x7FFFFFFFu ? 0x7FFFFFFFu : dt_us);
    for (side = 0; side < 2; side++) {
        double units = counter_frac[side] + (double)wheel[side] * dt / 1e6 * upm / 1e6 *
                                                (double)gain[side] / 128.0;
        const double wraps = (double)(int64_t)(units / 4294967296.0);
        int64_t whole;
        units -= wraps * 4294967296.0;
        whole = (int64_t)units;
        counter_frac[side] = units - (double)whole;
        counter[side] += (uint32_t)whole;
        if (gain[side] != 128u) {
            ideal = false;
        }
    }
}

/* ------------------------------------------------------------------ checks */

static void check(const fw_t *c)
{
    if (!accepted) {
        require(frames_out == 0u && wheel[0] == 0 && wheel[1] == 0);
        return;
    }
    require(fw_queue_depth(c) <= c->cfg.queue_depth);
    require(c->state <= RP_CONTROLLER_STATE_FAULT);
    if (c->latch != 0u) {
        require(c->setpoint[0] == 0 && c->setpoint[1] == 0);
    }
}

/* After fw_control: watch a step that started in it. */
static void after_control(const fw_t *c)
{
    int side;
    if (step_started && c->running && c->run.seq == started_seq) {
        const bool moving =
            c->run.command != RP_COMMAND_STOP && c->run.speed > 0u && c->run.distance > 0u;
        tracking = moving;
        ideal = true;
        track_seq = c->run.seq;
        track_limit = (int64_t)c->run.distance + (int64_t)bound_units;
        for (side = 0; side < 2; side++) {
            track_start[side] = rover_count(c, side);
        }
        switch (c->run.command) {
        case RP_COMMAND_FWD: track_dir[0] = 1; track_dir[1] = 1; break;
        case RP_COMMAND_REV: track_dir[0] = -1; track_dir[1] = -1; break;
        case RP_COMMAND_LEFT: track_dir[0] = -1; track_dir[1] = 1; break;
        default: track_dir[0] = 1; track_dir[1] = -1; break;
        }
    }
    step_started = false;
}

/* After a plant step: the step the harness watches has not driven far beyond. */
static void check_travel(const fw_t *c)
{
    int side;
    if (!tracking || !ideal) {
        return;
    }
    for (side = 0; side < 2; side++) {
        const uint32_t d = (uint32_t)rover_count(c, side) - (uint32_t)track_start[side];
        const int64_t moved = (int64_t)as_i32(d) * track_dir[side];
        require(moved <= track_limit);
    }
}

/* ------------------------------------------------------------------ host */

static void feed(fw_t *c, const uint8_t *bytes, size_t len)
{
    rp_decoder_t d;
    rp_frame_t f;
    const uint8_t *p = bytes;
    size_t left = len;
    unsigned stops = 0u;
    const unsigned acks_before = stop_acks_out;
    rp_decoder_init(&d);
    /* Bytes before the chunk's first delimiter continue the core's open run. */
    while (left > 0u && *p != 0u) {
        p++;
        left--;
    }
    while (rp_decoder_feed(&d, &p, &left, &f)) {
        stops += f.msg.id == RP_MSG_STOP;
    }
    fw_on_bytes(c, now, bytes, len);
    check(c);
    if (accepted && stops > 0u) {
        require(stop_acks_out - acks_before >= stops);
        require(c->setpoint[0] == 0 && c->setpoint[1] == 0);
    }
}

static void send(fw_t *c, const rp_msg_t *m)
{
    uint8_t wire[RP_MAX_WIRE_BYTES];
    const int n = rp_encode_message(m, 0u, false, wire, sizeof wire);
    if (n > 0) {
        feed(c, wire, (size_t)n);
    }
}

static void host_message(fw_t *c)
{
    static const uint32_t distances[] = {23000u, 2300u, 0u, 1u, 30000u, 65535u, 11500u, 100u};
    static const uint32_t values[] = {250u, 50u, 200u, 1u, 0u, 10000u, 0x80000000u, 60u};
    const uint8_t kind = take8();
    rp_msg_t m;
    memset(&m, 0, sizeof m);
    switch (kind % 8u) {
    case 0:
    case 1:
        m.id = RP_MSG_HELLO;
        m.body.hello.protocol_version = (uint8_t)RP_PROTOCOL_VERSION;
        m.body.hello.schema_hash = (uint16_t)(kind < 0xF0u ? RP_SCHEMA_HASH : take16());
        break;
    case 2:
    case 3:
        m.id = RP_MSG_MOTION;
        m.body.motion.seq = (uint16_t)(take8() % 16u);
        m.body.motion.command = (uint8_t)(take8() % 6u);
        m.body.motion.speed = take8();
        m.body.motion.distance = (uint16_t)PICK(distances);
        break;
    case 4:
        m.id = RP_MSG_STOP;
        m.body.stop.stop_id = (uint16_t)(1u + take8() % 8u);
        m.body.stop.source = (uint8_t)(take8() % 5u);
        break;
    case 5:
        m.id = RP_MSG_CLEAR_STOP;
        m.body.clear_stop.stop_id = (uint16_t)(1u + take8() % 8u);
        break;
    case 6:
        m.id = RP_MSG_SET_PARAM;
        m.body.set_param.param = (uint8_t)(take8() % 6u);
        m.body.set_param.value = as_i32(PICK(values));
        break;
    default:
        m.id = RP_MSG_HOST_HEARTBEAT;
        m.body.host_heartbeat.counter = take16();
        break;
    }
    send(c, &m);
}

static void heartbeat(fw_t *c)
{
    rp_msg_t m;
    m.id = RP_MSG_HOST_HEARTBEAT;
    m.body.host_heartbeat.counter = 1u;
    send(c, &m);
}

/* One control period: fw_control, the plant, fw_sense (the emulator's order); a period
 * longer than the core was told (jump) is not an ideal plant, for a step that started
 * in it too. */
static void tick(fw_t *c, uint64_t dt_us, bool jump)
{
    fw_control(c, now);
    check(c);
    after_control(c);
    if (jump) {
        ideal = false;
    }
    now += dt_us;
    plant_step(dt_us);
    check_travel(c);
    fw_sense(c, now);
    check(c);
}

static unsigned ticks_left;

static void run_op(fw_t *c)
{
    static const uint32_t glitches[] = {0u, 0x80000000u, 0x7FFFFFFFu, 0xFFFFFFFFu, 1u, 0x7FFF0000u};
    static const uint32_t speeds[] = {0u, 0x80000000u, 0x7FFFFFFFu, 99u, 100u, 0xFFFFFF9Cu};
    const uint8_t op = take8();
    const uint8_t arg = take8();
    switch (op % 8u) {
    case 0:
    case 1:
        host_message(c);
        break;
    case 2:
    case 3: {
        /* 1 to 4096 ticks, with host heartbeats every 50 if bit 4 is set. */
        unsigned n = 1u << (arg & 0x0Fu);
        unsigned k;
        if (n > 4096u) {
            n = 4096u;
        }
        for (k = 0u; k < n && ticks_left > 0u; k++, ticks_left--) {
            if ((arg & 0x10u) != 0u && k % 50u == 0u) {
                heartbeat(c);
            }
            tick(c, c->cfg.tick_us, false);
        }
        break;
    }
    case 4: {
        /* A time jump: the control loop did not run for that long; the wheels did. */
        tick(c, take32(), true);
        break;
    }
    case 5: {
        const int side = arg & 1;
        switch ((arg >> 1) % 4u) {
        case 0: gain[side] = take8(); break;
        case 1:
            counter[side] = PICK(glitches);
            ideal = false;
            break;
        case 2:
            speed_mode[side] = 1u;
            speed_value[side] = as_i32(PICK(speeds));
            break;
        default: speed_mode[side] = 0u; break;
        }
        break;
    }
    case 6:
        if (arg < 16u) {
            allow_jump = true;
            tracking = false;
            fw_reboot(c, now);
            allow_jump = false;
        } else if (arg < 128u) {
            fw_raise_fault(c, now, (uint8_t)(arg % 10u), take32(), (arg & 1u) != 0u);
        } else {
            fw_clear_fault(c, (uint8_t)(arg % 10u));
        }
        check(c);
        break;
    default:
        if (arg < 64u) {
            const size_t len = arg < in_size - in_pos ? arg : in_size - in_pos;
            feed(c, in_data + in_pos, len);
            in_pos += len;
        } else {
            imu_on = (arg & 1u) != 0u;
            imu.yaw_rate_mrad_s = (int16_t)take16();
            imu.accel_x_mm_s2 = (int16_t)take16();
            imu.accel_y_mm_s2 = (int16_t)take16();
            pose.x_mm = as_i32(take32());
            pose.y_mm = as_i32(take32());
            pose.yaw_ddeg = (int16_t)take16();
            pose.sigma_cm = take8();
            pose.taken_us = take32();
        }
        break;
    }
}

/* ------------------------------------------------------------------ the target */

static void configure(fw_config_t *cfg)
{
    static const uint32_t ticks[] = {1000u, 500u, 2000u, 10000u, 100u, 1u, 0u, 1000000u};
    static const uint32_t accels[] = {800000u, 100000u, 2000000u, 1000u, 999u, 0u, 0xFFFFFFFFu};
    static const uint32_t per_unit[] = {5000u, 1000u, 20000u, 1u, 0u, 50000u, 50001u};
    static const uint32_t top[] = {60u, 60u, 30u, 255u, 0u, 1u};
    static const uint32_t units[] = {23000u, 1000u, 100000u, 1u, 0u, 4000000000u};
    static const uint32_t rates[] = {50u, 10u, 5u, 1u, 200u, 255u, 0u};
    static const uint32_t scales[] = {1000u, 4000u, 1u, 0u, 1000000u};
    static const uint32_t watchdogs[] = {250u, 50u, 10000u, 0u};
    static const uint32_t counters[] = {0u, 0x80000000u, 0x7FFFFFFFu - 11500u,
                                        0x80000000u + 11500u, 0xFFFFFFFFu, 0x7FFFFFFFu};
    uint8_t bits;
    fw_default_config(cfg);
    cfg->tick_us = PICK(ticks);
    cfg->accel_um_s2 = PICK(accels);
    cfg->speed_um_s_per_unit = PICK(per_unit);
    cfg->max_speed = (uint8_t)PICK(top);
    cfg->distance_units_per_m = PICK(units);
    cfg->telemetry_hz = (uint8_t)PICK(rates);
    cfg->pose_hz = (uint8_t)PICK(rates);
    cfg->heartbeat_hz = (uint8_t)PICK(rates);
    cfg->timeout_scale_permille = PICK(scales);
    cfg->watchdog_ms = (uint16_t)PICK(watchdogs);
    cfg->stall_timeout_ms = take16();
    cfg->queue_depth = take8();
    bits = take8();
    cfg->left_sign = (bits & 1u) != 0u ? 1 : -1;
    cfg->right_sign = (bits & 2u) != 0u ? -1 : 1;
    counter[0] = PICK(counters);
    counter[1] = PICK(counters);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static fw_t c;
    fw_config_t cfg;
    fw_error_t err;
    in_data = data;
    in_size = size;
    in_pos = 0u;
    memset(wheel, 0, sizeof wheel);
    memset(counter_frac, 0, sizeof counter_frac);
    memset(speed_mode, 0, sizeof speed_mode);
    memset(&imu, 0, sizeof imu);
    memset(&pose, 0, sizeof pose);
    gain[0] = gain[1] = 128u;
    imu_on = 0;
    pose_pending = 0;
    now = 0u;
    nonce = 1u;
    rp_decoder_init(&out_dec);
    frames_out = stop_acks_out = 0u;
    step_started = tracking = false;
    ticks_left = 10000u;
    configure(&cfg);
    {
        /* What fw_init must take: every divisor non-zero, every product in 64 bits. */
        const uint64_t dv = (uint64_t)cfg.accel_um_s2 * cfg.tick_us / 1000000u;
        const uint64_t top = (uint64_t)cfg.max_speed * cfg.speed_um_s_per_unit;
        double cruise_pm = 0.0;
        const bool divides = cfg.tick_us != 0u && dv != 0u && dv <= FW_SPEED_UM_S_MAX &&
                             cfg.telemetry_hz != 0u && cfg.pose_hz != 0u &&
                             cfg.heartbeat_hz != 0u && cfg.timeout_scale_permille != 0u &&
                             cfg.distance_units_per_m != 0u && top <= FW_SPEED_UM_S_MAX;
        bool ok = divides;
        if (ok) {
            cruise_pm = (double)top * (double)top * 1e6 / (2.0 * cfg.accel_um_s2) +
                        (double)top * cfg.tick_us + (double)dv * cfg.tick_us;
            /* fw_init refuses these (FW_ERR_BRAKING); near the edge it may go either way
             * (integer against double): the harness only requires what follows. */
            ok = cruise_pm * cfg.distance_units_per_m < 4e18 && cruise_pm < 5e17;
        }
        top_um_s = (int64_t)top;
        a_dt = (int64_t)dv;
        upm = (double)cfg.distance_units_per_m;
        bound_units = cruise_pm * upm / 1e12 + 3.0;
        accepted = true; /* until fw_init says otherwise: IDENT may be written */
        allow_jump = true;
        err = fw_init(&c, &cfg, now);
        allow_jump = false;
        if (ok) {
            require(err == FW_OK);
        }
        if (!divides) {
            require(err != FW_OK);
        }
        accepted = err == FW_OK;
        total_refused += !accepted;
        if (!accepted) {
            require(frames_out == 0u && wheel[0] == 0 && wheel[1] == 0);
        } else {
            require(frames_out == 1u);
        }
    }
    while (in_pos < in_size) {
        run_op(&c);
    }
    return 0;
}

#ifdef FW_FUZZ_MAIN
#include <stdio.h>

int main(int argc, char **argv)
{
    int k;
    for (k = 1; k < argc; k++) {
        FILE *f = fopen(argv[k], "rb");
        static uint8_t buf[1u << 20];
        size_t n;
        require(f != NULL);
        n = fread(buf, 1u, sizeof buf, f);
        fclose(f);
        LLVMFuzzerTestOneInput(buf, n);
    }
    /* Steps watched: those the plant stayed ideal for, from their start to their end. */
    printf("fuzz_fw_plant: %d inputs, %lu refused, %lu frames out, %lu steps completed, "
           "%lu watched\n",
           argc - 1, total_refused, total_frames, total_completed, total_watched);
    return 0;
}
#endif
