/**
 * @file fw_hal.h
 * @brief The hardware abstraction layer the motor-controller core needs: what a port
 *        implements (README.md in this folder shows how).
 *
 * Every function is called from the thread (or ISR) that calls fw_tick, fw_control,
 * fw_sense, fw_on_bytes or fw_on_can; none is called re-entrantly. None may block.
 *
 * Frames: speeds are wheel surface speeds in micrometres per second in the *motor*
 * frame (the core applies the mounting polarity, fw_config_t.left_sign/right_sign);
 * encoder counts are distance units (23000 per metre of wheel travel by default) in
 * the motor frame, since boot, as a signed 32-bit counter that may wrap.
 *
 * The encoder counter's contract: zero at boot, it counts up and down and wraps modulo
 * 2^32 (one past INT32_MAX reads INT32_MIN, and back). The core only ever takes the
 * difference of two readings modulo 2^32, so a step, a stall check or a STOPPED distance
 * is right across a wrap as long as the counter moves less than 2^31 units (93 km at
 * 23000 units/m) between two readings of it (the core reads it every tick). A port whose
 * hardware counter is narrower (16 bits) extends it to 32 in software, as
 * port_bare/main.c extends its 32-bit clock: passed as is, its wrap would read as a jump
 * of 65536 units. Any int32 is a valid reading, INT32_MIN included; so is any wheel speed
 * (the core negates speeds with saturation).
 */
#ifndef FW_HAL_H
#define FW_HAL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** One IMU sample in the protocol's raw units (IMU message). */
typedef struct {
    int16_t yaw_rate_mrad_s; /**< counter-clockwise yaw rate, mrad/s */
    int16_t accel_x_mm_s2;   /**< body-frame forward acceleration, mm/s^2 */
    int16_t accel_y_mm_s2;   /**< body-frame left acceleration, mm/s^2 */
} fw_imu_sample_t;

/** One ground-seeing pose measurement (POSE message), with when it was taken. */
typedef struct {
    int32_t x_mm;      /**< map frame, mm (clamped to the 20-bit wire range by the core) */
    int32_t y_mm;      /**< map frame, mm */
    int16_t yaw_ddeg;  /**< map frame, 0.1 deg, -1800..1799 */
    uint8_t sigma_cm;  /**< 1-sigma position error, cm, 1..15; 0 = no fix */
    uint64_t taken_us; /**< fw clock (the now_us the core is given) when it was taken */
} fw_pose_sample_t;

/**
 * Apply wheel surface speed commands, um/s, motor frame (polarity applied). Called once
 * per fw_control; the values are already ramped at the acceleration limit.
 */
void fw_hal_set_wheels(int32_t left_um_s, int32_t right_um_s);

/** Encoder counts since boot, distance units, motor frame, wrapping modulo 2^32 (above). */
void fw_hal_read_encoders(int32_t *left, int32_t *right);

/** Measured wheel surface speeds, um/s, motor frame (truncated toward zero). */
void fw_hal_read_wheel_speeds(int32_t *left_um_s, int32_t *right_um_s);

/** An IMU sample; return 0 when there is none (no IMU, or a dropout). Optional: return 0. */
int fw_hal_read_imu(fw_imu_sample_t *out);

/** Take a pose measurement now (called at the POSE rate). Optional: do nothing. */
void fw_hal_pose_sample(void);

/**
 * A pose measurement whose latency has elapsed, oldest first; return 0 when none is due.
 * Called every fw_sense until it returns 0. Optional: return 0.
 */
int fw_hal_pose_read(fw_pose_sample_t *out);

/** 16 bits of entropy for the boot nonce (called once per fw_init / fw_reboot). */
uint16_t fw_hal_boot_nonce(void);

/**
 * Serial port: write n bytes (one whole frame with its delimiters, at most 15 bytes).
 * Must not block: queue them (a 64-byte ring per 1 ms tick covers the telemetry).
 */
void fw_hal_write(const uint8_t *bytes, size_t n);

/** CAN port: send one classic frame (11-bit id, len <= 8). Must not block. */
void fw_hal_can_send(uint16_t can_id, const uint8_t *data, uint8_t len);

#ifdef __cplusplus
}
#endif

#endif /* FW_HAL_H */
