/**
 * @file pil_plant.c
 * @brief The kinematic wheel and encoder model of pil_plant.h (FW_PIL builds only).
 */
#include "pil_plant.h"

#ifndef FW_PIL_TURN_PERMILLE
#define FW_PIL_TURN_PERMILLE 1000
#endif
#define PI_URAD 3141593
#define TWO_PI_URAD 6283185

/* sin(k degrees) in Q15, k = 0..90. */
static const int16_t SIN_Q15[91] = {
    0,     572,   1144,  1715,  2286,  2856,  3425,  3993,  4560,  5126,  5690,  6252,  6813,
    7371,  7927,  8481,  9032,  9580,  10126, 10668, 11207, 11743, 12275, 12803, 13328, 13848,
    14365, 14876, 15384, 15886, 16384, 16877, 17364, 17847, 18324, 18795, 19261, 19720, 20174,
    20622, 21063, 21498, 21926, 22348, 22763, 23170, 23571, 23965, 24351, 24730, 25102, 25466,
    25822, 26170, 26510, 26842, 27166, 27482, 27789, 28088, 28378, 28660, 28932, 29197, 29452,
    29698, 29935, 30163, 30382, 30592, 30792, 30983, 31164, 31336, 31499, 31651, 31795, 31928,
    32052, 32166, 32270, 32365, 32449, 32524, 32588, 32643, 32688, 32723, 32748, 32763, 32767};

/* sin of an angle in millidegrees 0..90000, Q15. */
static int32_t sin_quadrant(int32_t mdeg)
{
    const int32_t k = mdeg / 1000;
    const int32_t f = mdeg - k * 1000;
    if (k >= 90) {
        return SIN_Q15[90];
    }
    return SIN_Q15[k] + (int32_t)(((int32_t)(SIN_Q15[k + 1] - SIN_Q15[k]) * f) / 1000);
}

/* sin of an angle in millidegrees, any value in -180000..180000, Q15. */
static int32_t sin_mdeg(int32_t mdeg)
{
    if (mdeg < 0) {
        return -sin_mdeg(-mdeg);
    }
    if (mdeg > 90000) {
        mdeg = 180000 - mdeg;
    }
    return sin_quadrant(mdeg);
}

static int32_t cos_mdeg(int32_t mdeg)
{
    int32_t a = mdeg + 90000;
    if (a > 180000) {
        a -= 360000;
    }
    return sin_mdeg(a);
}

static int32_t urad_to_mdeg(int32_t urad)
{
    return (int32_t)(((int64_t)urad * 57296) / 1000000);
}

void pil_plant_init(pil_plant_t *p, const fw_config_t *cfg, uint32_t track_um,
                    const volatile pil_world_t *world)
{
    uint8_t i;
    p->sign[0] = cfg->left_sign;
    p->sign[1] = cfg->right_sign;
    p->units_per_m = cfg->distance_units_per_m;
    p->track_um = track_um;
    for (i = 0u; i < 2u; i++) {
        p->cmd[i] = 0;
        p->speed[i] = 0;
        p->enc[i] = 0;
        p->reported[i] = 0;
        p->frac[i] = 0;
    }
    p->x_um = 0;
    p->y_um = 0;
    p->yaw_urad = 0;
    if (world->magic == PIL_WORLD_MAGIC) {
        p->x_um = (int64_t)world->x_mm * 1000;
        p->y_um = (int64_t)world->y_mm * 1000;
        p->yaw_urad = (int32_t)(((int64_t)world->yaw_ddeg * PI_URAD) / 1800);
        p->travel_um = (uint64_t)world->travel_mm * 1000u;
    }
    p->yaw_rate_mrad_s = 0;
    p->accel_mm_s2 = 0;
    p->v_um_s = 0;
    p->travel_um = 0u;
}

void pil_plant_step(pil_plant_t *p, const volatile pil_hooks_t *hooks, uint32_t dt_us)
{
    int32_t ground[2];
    int32_t v, omega_urad_s;
    int32_t mdeg;
    uint8_t i;
    for (i = 0u; i < 2u; i++) {
        uint16_t slip = hooks->slip_permille[i];
        p->speed[i] = hooks->stall[i] ? 0 : p->cmd[i];
        {
            int64_t whole;
            /* um/s * us * units/m = units * 1e-12 */
            p->frac[i] += (int64_t)p->speed[i] * (int64_t)dt_us * (int64_t)p->units_per_m;
            whole = p->frac[i] / 1000000000000LL;
            p->frac[i] -= whole * 1000000000000LL;
            p->enc[i] = (int32_t)(uint32_t)((uint32_t)p->enc[i] + (uint32_t)(int32_t)whole);
        }
        /* A dropped-out encoder repeats its last good count; the wheel's travel is still
         * there to be counted when it comes back. */
        if (hooks->encoder_dropout[i] == 0u) {
            p->reported[i] = p->enc[i];
        }
        if (slip == 0u || slip > 1000u) {
            slip = 1000u;
        }
        /* rover frame (polarity undone), then the share that reaches the ground */
        ground[i] = (int32_t)(((int64_t)p->sign[i] * p->speed[i] * slip) / 1000);
    }
    v = (ground[0] + ground[1]) / 2;
    /* A skid-steer rover yaws less than its wheel arcs say (its wheels slip sideways in a
     * turn): FW_PIL_TURN_PERMILLE of it, the description's turn_efficiency. */
    omega_urad_s = (int32_t)(((int64_t)(ground[1] - ground[0]) * 1000 * FW_PIL_TURN_PERMILLE) /
                             (int64_t)p->track_um);
    p->accel_mm_s2 = (int32_t)(((int64_t)(v - p->v_um_s) * 1000) / (int64_t)dt_us);
    p->v_um_s = v;
    p->travel_um += (uint64_t)(v < 0 ? -(int64_t)v : v) * dt_us / 1000000u;
    p->yaw_rate_mrad_s = omega_urad_s / 1000;
    mdeg = urad_to_mdeg(p->yaw_urad);
    /* um/s * us / 1e6 = um; Q15 */
    p->x_um += ((int64_t)v * dt_us / 1000000 * cos_mdeg(mdeg)) / 32768;
    p->y_um += ((int64_t)v * dt_us / 1000000 * sin_mdeg(mdeg)) / 32768;
    p->yaw_urad += (int32_t)(((int64_t)omega_urad_s * dt_us) / 1000000);
    if (p->yaw_urad >= PI_URAD) {
        p->yaw_urad -= TWO_PI_URAD;
    } else if (p->yaw_urad < -PI_URAD) {
        p->yaw_urad += TWO_PI_URAD;
    }
}

void pil_plant_pose(const pil_plant_t *p, int32_t *x_mm, int32_t *y_mm, int16_t *yaw_ddeg)
{
    int32_t ddeg = (int32_t)(((int64_t)p->yaw_urad * 1800) / PI_URAD);
    if (ddeg >= 1800) {
        ddeg -= 3600;
    }
    *x_mm = (int32_t)(p->x_um / 1000);
    *y_mm = (int32_t)(p->y_um / 1000);
    *yaw_ddeg = (int16_t)ddeg;
}

void pil_plant_keep(const pil_plant_t *p, volatile pil_world_t *world)
{
    int32_t x, y;
    int16_t yaw;
    pil_plant_pose(p, &x, &y, &yaw);
    world->x_mm = x;
    world->y_mm = y;
    world->yaw_ddeg = yaw;
    world->travel_mm = (uint32_t)(p->travel_um / 1000u);
    world->magic = PIL_WORLD_MAGIC;
}
