/**
 * @file pil_plant.h
 * @brief A kinematic wheel and encoder model inside the image (FW_PIL builds only): the
 *        plant of a port that runs alone in an emulator (the nRF51 image under qemu),
 *        where no outside twin drives the encoder pins.
 *
 * Each wheel turns at the speed the core last commanded (fw_hal_set_wheels, motor frame,
 * um/s) unless the runner locked it (pil_hooks.stall); its encoder counts that travel,
 * 23000 units per metre by default, as a wrapping 32-bit counter, unless it dropped out
 * (pil_hooks.encoder_dropout: the reported count holds its last good value while the wheel
turns on, and reports its true count again when the dropout ends, as docs/protocol.md
asks of an ENCODER fault's end). The ground travel of each side is the
 * wheel travel times pil_hooks.slip_permille / 1000, so the pose (integer, um and urad)
 * and the IMU yaw rate see slip where the encoders cannot. No floating point: a sine table
 * of 91 entries (Q15, whole degrees) with linear interpolation.
 */
#ifndef PIL_PLANT_H
#define PIL_PLANT_H

#include <stdint.h>

#include "../fw.h"
#include "pil_port.h"

typedef struct {
    int8_t sign[2];          /**< motor polarity, as fw_config_t.left_sign/right_sign */
    uint32_t units_per_m;    /**< encoder units per metre of wheel travel */
    uint32_t track_um;       /**< distance between the wheel lines, um */
    int32_t cmd[2];          /**< commanded wheel surface speed, motor frame, um/s */
    int32_t speed[2];        /**< measured wheel surface speed, motor frame, um/s */
    int32_t enc[2];          /**< the wheels' true counts, motor frame, wrapping */
    int32_t reported[2];     /**< what the encoders report: enc, or held in a dropout */
    int64_t frac[2];         /**< encoder travel not yet counted, units * 1e-12 */
    int64_t x_um, y_um;      /**< ground truth, map frame */
    int32_t yaw_urad;        /**< ground truth heading, -pi..pi, urad */
    int32_t yaw_rate_mrad_s; /**< last step's yaw rate, mrad/s */
    int32_t accel_mm_s2;     /**< last step's forward acceleration, mm/s^2 */
    int32_t v_um_s;          /**< last step's forward ground speed, um/s */
    uint64_t travel_um;      /**< ground travel of the centre (kept in pil_world), um */
} pil_plant_t;

/** At rest, counters 0; at `world`'s pose when it holds one (PIL_WORLD_MAGIC), else at the
 * origin, heading 0. */
void pil_plant_init(pil_plant_t *p, const fw_config_t *cfg, uint32_t track_um,
                    const volatile pil_world_t *world);

/** Write the pose into `world` (to be found again after a reset). */
void pil_plant_keep(const pil_plant_t *p, volatile pil_world_t *world);

/** Advance dt_us with the faults in `hooks`. */
void pil_plant_step(pil_plant_t *p, const volatile pil_hooks_t *hooks, uint32_t dt_us);

/** The pose as the POSE message carries it (mm, 0.1 deg). */
void pil_plant_pose(const pil_plant_t *p, int32_t *x_mm, int32_t *y_mm, int16_t *yaw_ddeg);

#endif /* PIL_PLANT_H */
