/*
 * Fuzz target for the firmware core's receive path (fw_on_bytes) and its state machine,
 * with a small ideal plant behind the HAL (libFuzzer entry point).
 *
 *   clang -std=c99 -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all \
 *       -I../.. ../fw.c ../../rover_msgs.c ../../rover_proto.c fuzz_fw.c -o fuzz_fw
 *   ./fuzz_fw -seed=1 -runs=100000 new_corpus/ corpus_fw/
 *
 * (make -C firmware_proto/wire/c fuzz-fw; tests/firmware_proto/test_libfuzzer.py runs it.)
 * Without -fno-sanitize-recover=all UBSan only prints, and undefined behaviour passes.
 *
 * Built with -DFW_FUZZ_MAIN (gcc with the sanitizers: tests/firmware_proto/test_fw.py)
 * it is a plain program that runs the same checks over the files named on its command
 * line.
 *
 * The same input, cut differently, is also fed as CAN frames to a second controller on
 * node 1 (fw_on_can), whose every sent frame must decode as its own; a matching HELLO
 * opens a session there whenever it has none, every 50 ms.
 *
 * Input: a sequence of records; byte 0 of each: bits 0..5 the chunk length (0..63) fed
 * to fw_on_bytes, bits 6..7 what happens after it (0, 1: a tick of 1 ms; 2: 50 ticks;
 * 3: a fault raised or cleared, or a reboot, chosen by the next byte). Checks, beyond
 * "no crash, no out-of-bounds access, no undefined behaviour" (the sanitizers): every
 * frame the core writes decodes cleanly; the queue never exceeds its depth; while the
 * latch is set the wheel targets are zero; every STOP frame is answered by a STOP_ACK
 * in the call that received it.
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

/* ------------------------------------------------------------------ plant and HAL */

static int32_t wheel_cmd[2], enc[2];
static int64_t enc_um[2];
static uint16_t nonce = 1u;
static rp_decoder_t out_dec;
static unsigned frames_out, stop_acks_out;

void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    wheel_cmd[0] = left_um_s;
    wheel_cmd[1] = right_um_s;
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = enc[0];
    *right = enc[1];
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = wheel_cmd[0];
    *right_um_s = wheel_cmd[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    out->yaw_rate_mrad_s = 1;
    out->accel_x_mm_s2 = 2;
    out->accel_y_mm_s2 = 3;
    return 1;
}

static int pose_pending;

void fw_hal_pose_sample(void) { pose_pending++; }

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    if (pose_pending == 0) {
        return 0;
    }
    pose_pending--;
    out->x_mm = 600000; /* outside the 20-bit range: the core clamps */
    out->y_mm = -12;
    out->yaw_ddeg = 5;
    out->sigma_cm = 1;
    out->taken_us = 0u;
    return 1;
}

uint16_t fw_hal_boot_nonce(void) { return nonce++; }

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    const uint8_t *p = bytes;
    size_t len = n;
    rp_frame_t f;
    require(n <= RP_MAX_WIRE_BYTES);
    while (rp_decoder_feed(&out_dec, &p, &len, &f)) {
        frames_out++;
        if (f.msg.id == RP_MSG_STOP_ACK) {
            stop_acks_out++;
        }
    }
    require(rp_counters_rejected(&out_dec.counters) == 0u);
}

static unsigned can_out;

void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len)
{
    rp_can_decoder_t d;
    rp_can_frame_t f;
    rp_can_decoder_init(&d);
    /* Every frame the core sends is a valid controller-to-host frame of its node. */
    require(rp_can_decode(&d, can_id, false, false, data, len, &f));
    require(f.node == 1u);
    can_out++;
}

static void plant_step(uint32_t tick_us)
{
    int side;
    for (side = 0; side < 2; side++) {
        enc_um[side] += (int64_t)wheel_cmd[side] * tick_us / 1000000;
        enc[side] = (int32_t)(enc_um[side] * 23 / 1000);
    }
}

/* ------------------------------------------------------------------ the target */

static unsigned stops_in(const uint8_t *data, size_t len)
{
    rp_decoder_t d;
    rp_frame_t f;
    unsigned n = 0u;
    rp_decoder_init(&d);
    /* Bytes before the chunk's first delimiter continue the core's open run. */
    while (len > 0u && *data != 0u) {
        data++;
        len--;
    }
    while (rp_decoder_feed(&d, &data, &len, &f)) {
        n += f.msg.id == RP_MSG_STOP;
    }
    return n;
}

static void check(const fw_t *c)
{
    require(fw_queue_depth(c) <= c->cfg.queue_depth);
    if (c->latch != 0u) {
        require(c->setpoint[0] == 0 && c->setpoint[1] == 0);
    }
    require(c->state <= RP_CONTROLLER_STATE_FAULT);
}

/* The same bytes as CAN frames to a controller on node 1: byte 0 and 1 make the 11-bit
 * identifier (node 1, 0 or another), byte 2 the flags and length, then the data. */
static void fuzz_can(const uint8_t *data, size_t size)
{
    static fw_t can;
    fw_config_t cfg;
    uint64_t t = 0u;
    size_t i = 0u;
    rp_msg_t hello;
    uint32_t hello_id = 0u;
    uint8_t hello_data[RP_MAX_PAYLOAD_BYTES];
    int n;
    fw_default_config(&cfg);
    cfg.transport = FW_TRANSPORT_CAN;
    fw_init(&can, &cfg, t);
    /* A host that opens a session, and a new one every 50 ms while it has none (as the
     * bridge does): without one the core sends no sensor samples and refuses every
     * MOTION, and the random frames end sessions (a mismatched HELLO) far more often
     * than they open one. */
    hello.id = RP_MSG_HELLO;
    hello.body.hello.protocol_version = (uint8_t)RP_PROTOCOL_VERSION;
    hello.body.hello.schema_hash = (uint16_t)RP_SCHEMA_HASH;
    n = rp_can_encode(&hello, 1u, true, &hello_id, hello_data);
    require(n >= 0);
    while (i + 3u <= size) {
        if (!can.handshake_ok && t % 50000u == 0u) {
            fw_on_can(&can, t, hello_id, false, false, hello_data, (size_t)n);
            require(can.handshake_ok);
        }
        const uint32_t msg_id = data[i] & 0x7Fu;
        const uint32_t node = (data[i + 1] & 3u) == 0u ? 0u : ((data[i + 1] & 3u) == 1u ? 2u : 1u);
        const uint8_t flags = data[i + 2];
        size_t len = flags & 0x0Fu;
        i += 3u;
        if (len > size - i) {
            len = size - i;
        }
        fw_on_can(&can, t, msg_id << 4 | node, (flags & 0x40u) != 0u && (flags & 0x30u) == 0x30u,
                  (flags & 0x80u) != 0u && (flags & 0x20u) != 0u, data + i, len);
        i += len;
        check(&can);
        t += cfg.tick_us;
        fw_tick(&can, t);
        plant_step(cfg.tick_us);
        check(&can);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static fw_t c;
    fw_config_t cfg;
    uint64_t now = 0u;
    size_t i = 0u;
    fw_default_config(&cfg);
    memset(wheel_cmd, 0, sizeof wheel_cmd);
    memset(enc, 0, sizeof enc);
    memset(enc_um, 0, sizeof enc_um);
    rp_decoder_init(&out_dec);
    pose_pending = 0;
    fw_init(&c, &cfg, now);
    while (i < size) {
        const uint8_t op = data[i++];
        size_t len = op & 0x3Fu;
        unsigned stops, acks_before;
        if (len > size - i) {
            len = size - i;
        }
        /* Every STOP frame that starts in this chunk is acknowledged in this call. */
        stops = stops_in(data + i, len);
        acks_before = stop_acks_out;
        fw_on_bytes(&c, now, data + i, len);
        require(stop_acks_out - acks_before >= stops);
        i += len;
        check(&c);
        switch (op >> 6) {
        case 2: {
            int k;
            for (k = 0; k < 50; k++) {
                now += cfg.tick_us;
                fw_control(&c, now);
                plant_step(cfg.tick_us);
                fw_sense(&c, now);
                check(&c);
            }
            break;
        }
        case 3: {
            const uint8_t arg = i < size ? data[i++] : 0u;
            if (arg < 16u) {
                fw_reboot(&c, now);
            } else if (arg < 128u) {
                fw_raise_fault(&c, now, (uint8_t)(arg % 9u), arg, (arg & 1u) != 0u);
            } else {
                fw_clear_fault(&c, (uint8_t)(arg % 9u));
            }
            check(&c);
            break;
        }
        default:
            now += cfg.tick_us;
            fw_tick(&c, now);
            plant_step(cfg.tick_us);
            check(&c);
            break;
        }
    }
    fuzz_can(data, size);
    return 0;
}

#ifdef FW_FUZZ_MAIN
#include <stdio.h>

int main(int argc, char **argv)
{
    int k;
    for (k = 1; k < argc; k++) {
        FILE *f = fopen(argv[k], "rb");
        static uint8_t buf[1u << 22];
        size_t n;
        require(f != NULL);
        n = fread(buf, 1u, sizeof buf, f);
        fclose(f);
        LLVMFuzzerTestOneInput(buf, n);
    }
    printf("fuzz_fw: %u frames out, %u STOP_ACK, %u CAN frames out\n", frames_out, stop_acks_out,
           can_out);
    return 0;
}
#endif
