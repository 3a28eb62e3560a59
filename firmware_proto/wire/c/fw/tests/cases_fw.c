/*
 * Cases of the firmware core that the varied-plant fuzzer (fuzz_fw_plant.c) is about,
 * each spelt out with a plain plant: tests/firmware_proto/test_fw.py builds this with
 * ASan and UBSan (-fno-sanitize-recover=all) and runs one case per process:
 *
 *   cases_fw int32_min   encoder counts and wheel speeds at INT32_MIN, on both sides and
 *                        both polarities: no undefined behaviour, frames that decode;
 *   cases_fw wrap        a 1 m FWD step, then a 1 m REV step, whose encoder counters wrap
 *                        half-way: each completes with travel 23000, having driven 1 m;
 *   cases_fw config      fw_init refuses a zero tick, acceleration or rate (and every
 *                        other configuration its arithmetic cannot take) with its error
 *                        code, and the refused core stays silent and still.
 *
 * Prints `ok CASE`, or `FAIL CASE: what` and exits 1.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../fw.h"

/* ------------------------------------------------------------------ plant and HAL */

static int32_t wheel_cmd[2], speed_reading[2];
static int64_t travel_um[2];   /* motor frame, integrated from the commands */
static uint32_t count_base[2]; /* the counter's value when travel_um was 0 */
static bool speeds_follow = true;
static rp_decoder_t out_dec;
static unsigned frames_out;
static rp_msg_t last_status;
static bool have_status;

/* v as a two's-complement int32, without an implementation-defined conversion. */
static int32_t as_i32(uint32_t v)
{
    return v < 0x80000000u ? (int32_t)v : -(int32_t)(0xFFFFFFFFu - v) - 1;
}

static int32_t count(int side)
{
    const int64_t units = travel_um[side] * 23 / 1000;
    return as_i32(count_base[side] + (uint32_t)(uint64_t)units);
}

void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    wheel_cmd[0] = left_um_s;
    wheel_cmd[1] = right_um_s;
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = count(0);
    *right = count(1);
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = speeds_follow ? wheel_cmd[0] : speed_reading[0];
    *right_um_s = speeds_follow ? wheel_cmd[1] : speed_reading[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    (void)out;
    return 0;
}

void fw_hal_pose_sample(void) {}

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    (void)out;
    return 0;
}

uint16_t fw_hal_boot_nonce(void) { return 0xCA5Eu; }

static const char *failed_case;

static void fail(const char *what)
{
    printf("FAIL %s: %s\n", failed_case, what);
    exit(1);
}

static void require(bool ok, const char *what)
{
    if (!ok) {
        fail(what);
    }
}

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    rp_frame_t f;
    while (rp_decoder_feed(&out_dec, &bytes, &n, &f)) {
        frames_out++;
        if (f.msg.id == RP_MSG_STATUS) {
            last_status = f.msg;
            have_status = true;
        }
    }
    require(rp_counters_rejected(&out_dec.counters) == 0u, "a frame the core wrote decodes");
}

void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len)
{
    (void)can_id;
    (void)data;
    (void)len;
    fail("the serial core sent a CAN frame");
}

static void plant_step(uint32_t tick_us)
{
    int side;
    for (side = 0; side < 2; side++) {
        travel_um[side] += (int64_t)wheel_cmd[side] * tick_us / 1000000;
    }
}

/* ------------------------------------------------------------------ host */

static fw_t c;
static uint64_t now;

static void reset_plant(uint32_t left_count, uint32_t right_count)
{
    memset(wheel_cmd, 0, sizeof wheel_cmd);
    memset(travel_um, 0, sizeof travel_um);
    count_base[0] = left_count;
    count_base[1] = right_count;
    speeds_follow = true;
    rp_decoder_init(&out_dec);
    frames_out = 0u;
    have_status = false;
    now = 1000u;
}

static void send(const rp_msg_t *m)
{
    uint8_t wire[RP_MAX_WIRE_BYTES];
    const int n = rp_encode_message(m, 0u, false, wire, sizeof wire);
    require(n > 0, "the host's frame encodes");
    fw_on_bytes(&c, now, wire, (size_t)n);
}

static void hello(void)
{
    rp_msg_t m;
    m.id = RP_MSG_HELLO;
    m.body.hello.protocol_version = (uint8_t)RP_PROTOCOL_VERSION;
    m.body.hello.schema_hash = (uint16_t)RP_SCHEMA_HASH;
    send(&m);
}

static void motion(uint16_t seq, uint8_t command, uint16_t distance)
{
    rp_msg_t m;
    m.id = RP_MSG_MOTION;
    m.body.motion.seq = seq;
    m.body.motion.command = command;
    m.body.motion.speed = 60u;
    m.body.motion.distance = distance;
    send(&m);
}

/* Ticks with a host heartbeat every 50, until the step seq ends or max_ticks pass;
 * true if it completed. */
static bool run_step(uint16_t seq, uint32_t max_ticks)
{
    uint32_t k;
    for (k = 0u; k < max_ticks; k++) {
        if (k % 50u == 0u) {
            rp_msg_t m;
            m.id = RP_MSG_HOST_HEARTBEAT;
            m.body.host_heartbeat.counter = (uint16_t)k;
            send(&m);
        }
        have_status = false;
        now += c.cfg.tick_us;
        fw_control(&c, now);
        plant_step(c.cfg.tick_us);
        fw_sense(&c, now);
        if (have_status && last_status.body.status.seq == seq &&
            last_status.body.status.state != RP_STEP_STATE_STARTED) {
            return last_status.body.status.state == RP_STEP_STATE_COMPLETED;
        }
    }
    return false;
}

/* ------------------------------------------------------------------ the cases */

static void case_int32_min(void)
{
    int polarity;
    for (polarity = 0; polarity < 4; polarity++) {
        fw_config_t cfg;
        uint32_t k;
        fw_default_config(&cfg);
        cfg.left_sign = (polarity & 1) != 0 ? -1 : 1;
        cfg.right_sign = (polarity & 2) != 0 ? -1 : 1;
        reset_plant(0x80000000u, 0x80000000u);
        require(fw_init(&c, &cfg, now) == FW_OK, "the default configuration is taken");
        speeds_follow = false;
        speed_reading[0] = speed_reading[1] = INT32_MIN;
        hello();
        motion(1u, RP_COMMAND_FWD, 2300u);
        for (k = 0u; k < 200u; k++) {
            now += cfg.tick_us;
            fw_tick(&c, now);
            plant_step(cfg.tick_us);
        }
        require(frames_out > 20u, "the core kept talking");
    }
}

static void case_wrap(void)
{
    fw_config_t cfg;
    int32_t before[2];
    fw_default_config(&cfg);
    /* Motor frame: forward, the left counter (polarity -1) counts down through INT32_MIN
     * and the right one up through INT32_MAX, 0.5 m into the step. */
    reset_plant(0x80000000u + 11500u, 0x7FFFFFFFu - 11500u);
    require(fw_init(&c, &cfg, now) == FW_OK, "the default configuration is taken");
    hello();
    before[0] = count(0);
    before[1] = count(1);
    motion(1u, RP_COMMAND_FWD, 23000u);
    require(run_step(1u, 10000u), "FWD 1 m across the wrap completes");
    require(last_status.body.status.travel == 23000u, "its travel is 23000");
    require(travel_um[0] <= -999000 && travel_um[0] >= -1001000, "the left wheel drove 1 m");
    require(travel_um[1] >= 999000 && travel_um[1] <= 1001000, "the right wheel drove 1 m");
    require(count(0) > 0 && before[0] < 0 && count(1) < 0 && before[1] > 0, "both wrapped");
    motion(2u, RP_COMMAND_REV, 23000u);
    require(run_step(2u, 10000u), "REV 1 m back across the wrap completes");
    require(last_status.body.status.travel == 23000u, "its travel is 23000");
    require(travel_um[0] > -1000 && travel_um[0] < 1000, "the left wheel came back");
    require(travel_um[1] > -1000 && travel_um[1] < 1000, "the right wheel came back");
}

static void refused(const fw_config_t *cfg, fw_error_t expected, const char *what)
{
    uint32_t k;
    reset_plant(0u, 0u);
    require(fw_init(&c, cfg, now) == expected, what);
    hello();
    motion(1u, RP_COMMAND_FWD, 2300u);
    for (k = 0u; k < 2000u; k++) {
        now += 1000u;
        fw_tick(&c, now);
        plant_step(1000u);
        require(wheel_cmd[0] == 0 && wheel_cmd[1] == 0, "a refused core drives nothing");
    }
    require(frames_out == 0u, "a refused core sends nothing");
}

static void case_config(void)
{
    fw_config_t cfg;
    fw_default_config(&cfg);
    cfg.tick_us = 0u;
    refused(&cfg, FW_ERR_TICK, "tick_us 0 is refused (FW_ERR_TICK)");
    fw_default_config(&cfg);
    cfg.accel_um_s2 = 0u;
    refused(&cfg, FW_ERR_ACCEL, "accel_um_s2 0 is refused (FW_ERR_ACCEL)");
    fw_default_config(&cfg);
    cfg.accel_um_s2 = 999u; /* under 1 um/s per 1 ms tick */
    refused(&cfg, FW_ERR_ACCEL, "an acceleration that changes no speed in a tick is refused");
    fw_default_config(&cfg);
    cfg.telemetry_hz = 0u;
    refused(&cfg, FW_ERR_RATE, "telemetry_hz 0 is refused (FW_ERR_RATE)");
    fw_default_config(&cfg);
    cfg.pose_hz = 0u;
    refused(&cfg, FW_ERR_RATE, "pose_hz 0 is refused (FW_ERR_RATE)");
    fw_default_config(&cfg);
    cfg.heartbeat_hz = 0u;
    refused(&cfg, FW_ERR_RATE, "heartbeat_hz 0 is refused (FW_ERR_RATE)");
    /* The rest that would divide by zero or overflow the step profile. */
    fw_default_config(&cfg);
    cfg.timeout_scale_permille = 0u;
    refused(&cfg, FW_ERR_TIMEOUT_SCALE, "timeout_scale_permille 0 is refused");
    fw_default_config(&cfg);
    cfg.distance_units_per_m = 0u;
    refused(&cfg, FW_ERR_UNITS, "distance_units_per_m 0 is refused");
    fw_default_config(&cfg);
    cfg.accel_um_s2 = 0xFFFFFFFFu;
    refused(&cfg, FW_ERR_ACCEL, "a speed change per tick above the top speed is refused");
    fw_default_config(&cfg);
    cfg.speed_um_s_per_unit = FW_SPEED_UM_S_MAX / cfg.max_speed + 1u;
    refused(&cfg, FW_ERR_SPEED, "a top speed above FW_SPEED_UM_S_MAX is refused");
    fw_default_config(&cfg);
    cfg.speed_um_s_per_unit = FW_SPEED_UM_S_MAX / cfg.max_speed;
    cfg.tick_us = 1000000u;
    cfg.accel_um_s2 = 1u; /* 4,500 km of braking from 3 m/s */
    refused(&cfg, FW_ERR_BRAKING, "a braking distance beyond 64-bit arithmetic is refused");
    /* Edges that are taken: a 3 m/s top speed, 1 Hz rates, one unit per metre, scale 1. */
    fw_default_config(&cfg);
    cfg.speed_um_s_per_unit = FW_SPEED_UM_S_MAX / cfg.max_speed;
    cfg.accel_um_s2 = 1000000u;
    cfg.telemetry_hz = cfg.pose_hz = cfg.heartbeat_hz = 1u;
    cfg.distance_units_per_m = 1u;
    cfg.timeout_scale_permille = 1u;
    reset_plant(0u, 0u);
    require(fw_init(&c, &cfg, now) == FW_OK && frames_out == 1u, "the edges are taken");
}

int main(int argc, char **argv)
{
    static const struct {
        const char *name;
        void (*run)(void);
    } cases[] = {{"int32_min", case_int32_min}, {"wrap", case_wrap}, {"config", case_config}};
    size_t k;
    if (argc != 2) {
        fprintf(stderr, "usage: cases_fw int32_min|wrap|config\n");
        return 2;
    }
    for (k = 0u; k < sizeof cases / sizeof cases[0]; k++) {
        if (strcmp(argv[1], cases[k].name) == 0) {
            failed_case = cases[k].name;
            cases[k].run();
            printf("ok %s\n", cases[k].name);
            return 0;
        }
    }
    fprintf(stderr, "cases_fw: unknown case %s\n", argv[1]);
    return 2;
}
