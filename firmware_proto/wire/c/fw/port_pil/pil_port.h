/**
 * @file pil_port.h
 * @brief What every processor-in-the-loop port exposes to its host-side runner
 *        (`rover pil`, docs/firmware.md "Processor in the loop"): its counters, and under
 *        FW_PIL the hooks a runner writes into RAM to inject faults.
 *
 * A port keeps one `pil_stats` and (FW_PIL) one `pil_hooks` at global scope under these
 * names; the runner finds them by symbol in the ELF image and reads or writes them (the
 * qemu gdbstub for the nRF51, libsimavr's RAM for the ATmega2560). A lab's port keeps the
 * counters (they cost 28 bytes) and drops the hooks with the PIL flag.
 */
#ifndef PIL_PORT_H
#define PIL_PORT_H

#include <stdint.h>

#include "../fw.h"

/** The port's own counters, since boot. Read by the runner; written only by the port. */
typedef struct {
    uint32_t ticks;        /**< fw_tick calls */
    uint32_t tick_last;    /**< duration of the last fw_tick, in `tick_unit` */
    uint32_t tick_max;     /**< longest fw_tick since boot, in `tick_unit` */
    uint32_t late_ticks;   /**< ticks run late: the next grid point had passed already */
    uint32_t rx_overflows; /**< bytes the UART delivered into a full receive ring (lost) */
    uint32_t tx_drops;     /**< frames dropped whole because the transmit ring was full */
    uint32_t tick_unit_hz; /**< counts per second of the durations here (the CPU clock) */
    uint32_t stop_ack_last; /**< last STOP: its last byte received -> STOP_ACK queued (the
                                 wheel targets zero), in tick_unit_hz */
    uint32_t stop_ack_max;  /**< the longest of those since boot */
    uint32_t ident_last;    /**< last HELLO: its last byte received -> IDENT queued */
} pil_stats_t;


/**
 * The pose of an in-image plant's world, kept in RAM that the start-up does not clear
 * (.noinit), so that a reset of the MCU does not move the rover: the runner writes the
 * map's start pose with the magic before the first instruction; the plant starts from it
 * at every boot and writes its pose back every tick.
 */
typedef struct {
    uint32_t magic;   /**< PIL_WORLD_MAGIC once written */
    int32_t x_mm, y_mm;
    int16_t yaw_ddeg;
    uint16_t reserved;
    uint32_t travel_mm; /**< ground travel of the rover's centre since the runner started */
} pil_world_t;

#define PIL_WORLD_MAGIC 0x57524C44u /* "WRLD" */

/** Faults a runner injects (FW_PIL builds only); each field read once per tick. */
typedef struct {
    uint8_t stall[2];          /**< 1: that wheel is locked (left, right) */
    uint8_t encoder_dropout[2];/**< 1: that encoder stops counting and flags an error */
    uint16_t slip_permille[2]; /**< ground travel per wheel travel, per mille (0: 1000) */
} pil_hooks_t;

/**
 * What the controller is doing, copied from fw_t after every tick for the runner's
 * `status` (the same layout on 8- and 32-bit targets: little-endian, no padding).
 */
typedef struct {
    int32_t commanded_um_s[2]; /**< ramped wheel commands, rover frame, um/s */
    int32_t speed_um_s[2];     /**< measured wheel speeds, motor frame, um/s */
    int32_t x_mm, y_mm;        /**< ground truth of an in-image plant (else 0), mm */
    int16_t yaw_ddeg;          /**< ground truth heading of an in-image plant, 0.1 deg */
    uint16_t boot_nonce;
    uint16_t rx_errors;        /**< fw_t.rx_errors, 16 bits */
    uint8_t state;             /**< rp_controller_state_t */
    uint8_t latch;             /**< FW_LATCH_* bits */
    uint8_t faults;            /**< active fault conditions, bit (code - 1) */
    uint8_t queue_depth;       /**< steps queued, the running one included */
    uint8_t reserved[2];
    uint32_t travel_mm;        /**< ground travel of an in-image plant's centre since the
                                    runner started it (else 0), mm */
} pil_view_t;

/**
 * The sensors of a port whose plant is outside the MCU (the ATmega2560 under simavr, the
 * twin in the harness): the count registers of an external quadrature decoder and its
 * error line, the measured wheel speeds, the latest IMU sample and the latest pose fix,
 * as the harness posts them. Its layout is the same on every target (no padding).
 *
 * The harness changes it between two instructions and adds 1 to `seq` each time; a port
 * copies it whole and copies again while `seq` moved (pil_sensors_copy), so that no
 * multi-byte field is read half old, half new.
 */
typedef struct {
    uint8_t seq;           /**< +1 per update by the harness */
    uint8_t encoder_error; /**< the decoder's error line per side: bit 0 left, bit 1 right */
    uint8_t imu_valid;     /**< 1: imu[] is a sample; 0: no IMU (a dropout) */
    uint8_t pose_seq;      /**< +1 per new pose fix */
    int32_t enc[2];        /**< encoder counts, motor frame, wrapping */
    int32_t speed_um_s[2]; /**< measured wheel speeds, motor frame, um/s */
    int16_t imu[3];        /**< yaw rate mrad/s, accel x and y mm/s^2 */
    uint8_t pose_sigma_cm; /**< 0: no fix */
    uint8_t reserved;
    int32_t pose_x_mm, pose_y_mm;
    int16_t pose_yaw_ddeg;
    uint32_t pose_age_us;  /**< how long ago the fix was taken, when posted */
} pil_sensors_t;

extern volatile pil_stats_t pil_stats;
extern volatile pil_view_t pil_view;

/**
 * Note an answer the core writes: call from fw_hal_write with the frame and how long ago
 * (tick_unit_hz counts) the last received byte came in; keeps STOP_ACK's and IDENT's.
 */
void pil_note_answer(const uint8_t *frame, size_t n, uint32_t spent);

/** A consistent copy of a harness-posted pil_sensors_t (retries while it changes). */
void pil_sensors_copy(pil_sensors_t *out, const volatile pil_sensors_t *in);

/** Copy what the runner shows from the core (after each tick): pil_view. */
void pil_view_update(const fw_t *c, int32_t speed_left_um_s, int32_t speed_right_um_s);

#endif /* PIL_PORT_H */
