/**
 * @file port_host.c
 * @brief The host port of the firmware core: a shared library that a simulator drives
 *        (emulator/firmware.py loads it with ctypes; tests/fw_replay.c links it).
 *
 * The plant is the caller's: it pushes the sensor readings (encoder counts and wheel
 * speeds, motor frame) with fw_host_set_sensors after every plant step, reads the
 * wheel commands with fw_host_wheels after fw_control, and answers the IMU, pose and
 * boot-nonce callbacks (optional: NULL means none). Every frame the core writes lands
 * in the instance's output buffer, drained with fw_host_take. One instance per thread
 * at a time (the HAL finds it in a thread-local pointer set around each call).
 */
#include <stdlib.h>
#include <string.h>

#include "fw.h"

#define FW_HOST_OUT_BYTES 8192u

typedef int (*fw_host_imu_cb)(fw_imu_sample_t *out);
typedef void (*fw_host_pose_sample_cb)(void);
typedef int (*fw_host_pose_read_cb)(fw_pose_sample_t *out);
typedef uint16_t (*fw_host_nonce_cb)(void);

typedef struct {
    fw_t fw;
    int32_t enc[2], speed[2], wheels[2];
    fw_host_imu_cb imu;
    fw_host_pose_sample_cb pose_sample;
    fw_host_pose_read_cb pose_read;
    fw_host_nonce_cb nonce;
    uint8_t out[FW_HOST_OUT_BYTES];
    size_t out_len;
    uint32_t out_dropped;
    uint64_t stop_ns_last; /**< unused by the core; see fw_host_rx_timed */
} fw_host_t;

/** Flat status for the simulator (fw_t itself is not part of the ABI). */
typedef struct {
    uint8_t state, handshake_ok, latch, faults, queue_depth, running;
    uint16_t boot_nonce, running_seq, watchdog_ms;
    uint8_t telemetry_hz, pose_hz, heartbeat_hz, latch_gen;
    uint32_t rx_errors;
    int32_t setpoint[2], commanded[2];
} fw_host_status_t;

static __thread fw_host_t *current;

/* ------------------------------------------------------------------ the HAL */

void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s)
{
    current->wheels[0] = left_um_s;
    current->wheels[1] = right_um_s;
}

void fw_hal_read_encoders(int32_t *left, int32_t *right)
{
    *left = current->enc[0];
    *right = current->enc[1];
}

void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s)
{
    *left_um_s = current->speed[0];
    *right_um_s = current->speed[1];
}

int fw_hal_read_imu(fw_imu_sample_t *out)
{
    return current->imu != NULL ? current->imu(out) : 0;
}

void fw_hal_pose_sample(void)
{
    if (current->pose_sample != NULL) {
        current->pose_sample();
    }
}

int fw_hal_pose_read(fw_pose_sample_t *out)
{
    return current->pose_read != NULL ? current->pose_read(out) : 0;
}

uint16_t fw_hal_boot_nonce(void)
{
    return current->nonce != NULL ? current->nonce() : 0x1234u;
}

void fw_hal_write(const uint8_t *bytes, size_t n)
{
    if (current->out_len + n > sizeof current->out) {
        current->out_dropped++;
        return;
    }
    memcpy(current->out + current->out_len, bytes, n);
    current->out_len += n;
}

void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len)
{
    (void)can_id;
    (void)data;
    (void)len;
    current->out_dropped++; /* the host port speaks serial */
}

/* ------------------------------------------------------------------ the API */

size_t fw_host_sizeof_fw(void) { return sizeof(fw_t); }

void fw_host_default_config(fw_config_t *cfg) { fw_default_config(cfg); }

size_t fw_host_sizeof_config(void) { return sizeof(fw_config_t); }

/** The name of an fw_error_t, and what to change. */
const char *fw_host_error_name(int error)
{
    switch (error) {
    case FW_OK: return "FW_OK";
    case FW_ERR_TICK: return "FW_ERR_TICK: tick_us is 0";
    case FW_ERR_ACCEL:
        return "FW_ERR_ACCEL: the speed change per tick (accel_um_s2 * tick_us / 1e6) is 0 "
               "or above 3 m/s";
    case FW_ERR_RATE: return "FW_ERR_RATE: a telemetry, pose or heartbeat rate is 0";
    case FW_ERR_TIMEOUT_SCALE: return "FW_ERR_TIMEOUT_SCALE: timeout_scale_permille is 0";
    case FW_ERR_UNITS: return "FW_ERR_UNITS: distance_units_per_m is 0";
    case FW_ERR_SPEED:
        return "FW_ERR_SPEED: the top wheel speed (max_speed * speed_um_s_per_unit) is above "
               "3 m/s";
    case FW_ERR_BRAKING:
        return "FW_ERR_BRAKING: the braking distance from the top speed is too long for the "
               "core's 64-bit arithmetic";
    default: return "unknown fw_error_t";
    }
}

/**
 * A core on this port, initialised (fw_init) with cfg and these first sensor readings.
 * NULL if out of memory (*error FW_OK) or if fw_init refused cfg (*error says why).
 */
fw_host_t *fw_host_new(const fw_config_t *cfg, fw_host_imu_cb imu, fw_host_pose_sample_cb ps,
                       fw_host_pose_read_cb pr, fw_host_nonce_cb nonce, const int32_t enc[2],
                       const int32_t speed[2], uint64_t now_us, int *error)
{
    fw_host_t *h = (fw_host_t *)calloc(1u, sizeof *h);
    fw_host_t *saved = current;
    *error = FW_OK;
    if (h == NULL) {
        return NULL;
    }
    h->imu = imu;
    h->pose_sample = ps;
    h->pose_read = pr;
    h->nonce = nonce;
    h->enc[0] = enc[0];
    h->enc[1] = enc[1];
    h->speed[0] = speed[0];
    h->speed[1] = speed[1];
    current = h;
    *error = (int)fw_init(&h->fw, cfg, now_us);
    current = saved;
    if (*error != FW_OK) {
        free(h);
        return NULL;
    }
    return h;
}

void fw_host_free(fw_host_t *h) { free(h); }

void fw_host_set_sensors(fw_host_t *h, const int32_t enc[2], const int32_t speed[2])
{
    h->enc[0] = enc[0];
    h->enc[1] = enc[1];
    h->speed[0] = speed[0];
    h->speed[1] = speed[1];
}

#define ENTER(h)                         \
    fw_host_t *saved_ = current;         \
    current = (h)
#define LEAVE() current = saved_

void fw_host_rx(fw_host_t *h, uint64_t now_us, const uint8_t *data, size_t len)
{
    ENTER(h);
    fw_on_bytes(&h->fw, now_us, data, len);
    LEAVE();
}

void fw_host_control(fw_host_t *h, uint64_t now_us)
{
    ENTER(h);
    fw_control(&h->fw, now_us);
    LEAVE();
}

void fw_host_sense(fw_host_t *h, uint64_t now_us)
{
    ENTER(h);
    fw_sense(&h->fw, now_us);
    LEAVE();
}

void fw_host_reboot(fw_host_t *h, uint64_t now_us)
{
    ENTER(h);
    fw_reboot(&h->fw, now_us);
    LEAVE();
}

void fw_host_raise_fault(fw_host_t *h, uint64_t now_us, uint8_t code, uint32_t detail,
                         int condition)
{
    ENTER(h);
    fw_raise_fault(&h->fw, now_us, code, detail, condition != 0);
    LEAVE();
}

void fw_host_clear_fault(fw_host_t *h, uint8_t code)
{
    ENTER(h);
    fw_clear_fault(&h->fw, code);
    LEAVE();
}

void fw_host_add_rx_errors(fw_host_t *h, uint32_t count) { fw_add_rx_errors(&h->fw, count); }

void fw_host_wheels(const fw_host_t *h, int32_t out[2])
{
    out[0] = h->wheels[0];
    out[1] = h->wheels[1];
}

size_t fw_host_take(fw_host_t *h, uint8_t *out, size_t cap)
{
    size_t n = h->out_len < cap ? h->out_len : cap;
    memcpy(out, h->out, n);
    memmove(h->out, h->out + n, h->out_len - n);
    h->out_len -= n;
    return n;
}

uint32_t fw_host_out_dropped(const fw_host_t *h) { return h->out_dropped; }

void fw_host_status(const fw_host_t *h, fw_host_status_t *s)
{
    const fw_t *c = &h->fw;
    s->state = c->state;
    s->handshake_ok = c->handshake_ok ? 1u : 0u;
    s->latch = c->latch;
    s->faults = c->faults;
    s->queue_depth = fw_queue_depth(c);
    s->running = c->running ? 1u : 0u;
    s->boot_nonce = c->boot_nonce;
    s->running_seq = c->running ? c->run.seq : 0u;
    s->watchdog_ms = c->watchdog_ms;
    s->telemetry_hz = c->telemetry_hz;
    s->pose_hz = c->pose_hz;
    s->heartbeat_hz = c->heartbeat_hz;
    s->latch_gen = c->latch_gen;
    s->rx_errors = c->rx_errors;
    s->setpoint[0] = c->setpoint[0];
    s->setpoint[1] = c->setpoint[1];
    s->commanded[0] = c->commanded[0];
    s->commanded[1] = c->commanded[1];
}
