/*
 * Host benchmark driver of the firmware core (benchmarks/bench_firmware.py runs it).
 *
 *   bench_fw stop N    N trials: a step running at cruise speed with 7 more queued, then
 *                      one STOP frame through fw_on_bytes; prints, per trial, the
 *                      nanoseconds from the call to the wheel targets being zero
 *                      (CLOCK_MONOTONIC around the call; the targets are checked zero
 *                      when it returns) and the frames written.
 *   bench_fw ticks N   N fw_tick calls (N <= 50000) with steps running and telemetry at
 *                      the default rates: the work that `valgrind --tool=callgrind
 *                      --toggle-collect=fw_tick` counts instructions of.
 *
 * The plant is ideal: the wheels follow the commands, the encoders integrate them.
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "../fw.h"

static int32_t wheel_cmd[2], enc[2];
static int64_t enc_um[2];
static unsigned long frames_out;

void fw_hal_set_wheels(int32_t l, int32_t r)
{
    wheel_cmd[0] = l;
    wheel_cmd[1] = r;
}

void fw_hal_read_encoders(int32_t *l, int32_t *r)
{
    *l = enc[0];
    *r = enc[1];
}

void fw_hal_read_wheel_speeds(int32_t *l, int32_t *r)
{
    *l = wheel_cmd[0];
    *r = wheel_cmd[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    out->yaw_rate_mrad_s = 0;
    out->accel_x_mm_s2 = 0;
    out->accel_y_mm_s2 = 0;
    return 1;
}

void fw_hal_pose_sample(void) {}

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    (void)out;
    return 0;
}

uint16_t fw_hal_boot_nonce(void) { return 7u; }

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    (void)bytes;
    (void)n;
    frames_out++;
}

void fw_hal_can_send(uint16_t id, const uint8_t *d, uint8_t len)
{
    (void)id;
    (void)d;
    (void)len;
}

static uint64_t now;
static uint16_t seq;

static void plant_step(uint32_t tick_us)
{
    int side;
    for (side = 0; side < 2; side++) {
        enc_um[side] += (int64_t)wheel_cmd[side] * tick_us / 1000000;
        enc[side] = (int32_t)(enc_um[side] * 23 / 1000);
    }
}

static void tick(fw_t *c)
{
    now += c->cfg.tick_us;
    fw_tick(c, now);
    plant_step(c->cfg.tick_us);
}

static void send(fw_t *c, const rp_msg_t *m)
{
    uint8_t wire[RP_MAX_WIRE_BYTES];
    const int n = rp_encode_message(m, 0u, false, wire, sizeof wire);
    if (n <= 0) {
        abort();
    }
    fw_on_bytes(c, now, wire, (size_t)n);
}

static void motion(fw_t *c, uint16_t distance)
{
    rp_msg_t m;
    m.id = RP_MSG_MOTION;
    m.body.motion.seq = seq++;
    m.body.motion.command = RP_COMMAND_FWD;
    m.body.motion.speed = 40u;
    m.body.motion.distance = distance;
    send(c, &m);
}

static void heartbeat(fw_t *c)
{
    rp_msg_t m;
    m.id = RP_MSG_HOST_HEARTBEAT;
    m.body.host_heartbeat.counter = seq;
    send(c, &m);
}

static void start(fw_t *c)
{
    fw_config_t cfg;
    rp_msg_t m;
    fw_default_config(&cfg);
    fw_init(c, &cfg, now);
    m.id = RP_MSG_HELLO;
    m.body.hello.protocol_version = (uint8_t)RP_PROTOCOL_VERSION;
    m.body.hello.schema_hash = (uint16_t)RP_SCHEMA_HASH;
    send(c, &m);
}

static long long ns_of(const struct timespec *t)
{
    return (long long)t->tv_sec * 1000000000LL + t->tv_nsec;
}

int main(int argc, char **argv)
{
    static fw_t c;
    long n = argc > 2 ? atol(argv[2]) : 1000;
    long i;
    int k;
    if (argc < 2) {
        fprintf(stderr, "usage: bench_fw stop|ticks N\n");
        return 2;
    }
    start(&c);
    if (strcmp(argv[1], "stop") == 0) {
        for (i = 0; i < n; i++) {
            rp_msg_t m;
            uint8_t wire[RP_MAX_WIRE_BYTES];
            int len;
            struct timespec t0, t1;
            unsigned long before;
            m.id = RP_MSG_CLEAR_STOP;
            m.body.clear_stop.stop_id = (uint16_t)(i % 60000 + 1);
            m.body.clear_stop.latch_gen = c.latch_gen; /* the latch it releases (v4) */
            send(&c, &m);
            for (k = 0; k < 8; k++) {
                motion(&c, 30000u);
            }
            for (k = 0; k < 400; k++) { /* up to cruise speed */
                if (k % 50 == 0) {
                    heartbeat(&c);
                }
                tick(&c);
            }
            if (c.setpoint[0] == 0 || fw_queue_depth(&c) != 8u) {
                fprintf(stderr, "not running at trial %ld\n", i);
                return 1;
            }
            m.id = RP_MSG_STOP;
            m.body.stop.stop_id = (uint16_t)(i % 60000 + 1);
            m.body.stop.source = 4u;
            len = rp_encode_message(&m, 0u, false, wire, sizeof wire);
            before = frames_out;
            clock_gettime(CLOCK_MONOTONIC, &t0);
            fw_on_bytes(&c, now, wire, (size_t)len);
            clock_gettime(CLOCK_MONOTONIC, &t1);
            if (c.setpoint[0] != 0 || c.setpoint[1] != 0 || c.latch == 0u) {
                fprintf(stderr, "STOP did not zero the targets\n");
                return 1;
            }
            printf("%lld %lu\n", ns_of(&t1) - ns_of(&t0), frames_out - before);
            while (c.commanded[0] != 0) { /* brake to rest before the next trial */
                heartbeat(&c);
                tick(&c);
            }
        }
        return 0;
    }
    if (strcmp(argv[1], "ticks") == 0) {
        for (k = 0; k < 8; k++) { /* 8 x 1.3 m at 0.2 m/s: 53 s of driving */
            motion(&c, 30000u);
        }
        for (i = 0; i < n; i++) {
            if (i % 50 == 0) {
                heartbeat(&c);
            }
            tick(&c);
        }
        if (c.state != RP_CONTROLLER_STATE_EXECUTING) {
            fprintf(stderr, "the steps ended before the ticks did\n");
            return 1;
        }
        printf("ticks %ld frames %lu\n", n, frames_out);
        return 0;
    }
    return 2;
}
