/*
 * The batch twins' traction forces in C (emulator/batch_kernel.py loads this): the forces
 * of emulator/batch.py's _Forces (TractionModel.step_wrench) for play_batch's twins, one
 * physics step at a time, and emulator/moves.py's whole replay loop (each job a free rigid
 * body on four wheels, integrated as pymunk integrates one). Same operations in the same
 * order as the numpy code (no fused multiply-adds: built with -ffp-contract=off), so the
 * two agree to the last bits of tanh, sin and cos (numpy's tanh is its own, not libm's).
 * Units: m, s, rad, N, kg.
 */
#include <math.h>
#include <stdint.h>

#define TINY 1e-9

/* The rover and the step, shared by every job. */
typedef struct {
    double hx, hy;              /* half wheelbase, half track, m */
    double mass, inertia;       /* kg, kg m^2 (the traction model's) */
    double inv_mass, inv_inertia; /* of the rigid body (pymunk's box moment) */
    double inv_vrr;             /* 1 / rolling speed scale, s/m */
    double dt;                  /* physics step, s */
    double probe;               /* region probe radius, m */
    double wheel_x[4], wheel_y[4]; /* contact points, body frame: FL, RL, FR, RR */
} batch_model_t;

/* Each job's ground: arrays of n (side: n x 2, left then right; scales: n x regions). */
typedef struct {
    const double *s0, *kappa, *rr, *mu_long_n, *mu_lat_n, *side, *region_scales;
} batch_grounds_t;

/* The traction regions' convex parts: part p belongs to region part_region[p] and has the
 * edges part_edge[p] .. part_edge[p + 1] - 1 of edges (px, py, dx, dy each, CCW, unit). */
typedef struct {
    int32_t regions, parts;
    const int32_t *part_region, *part_edge;
    const double *edges;
} batch_regions_t;

static double max_nan(double a, double b) { /* np.maximum: NaN wins */
    return (a > b || a != a) ? a : b;
}

/* Each wheel's region scale at this pose: the last region (map order) within the probe of
 * its contact, else 1 (_Forces.place). */
static void place(const batch_model_t *m, const batch_regions_t *g, const double *scales,
                  double x, double y, double c, double s, double out[4]) {
    for (int k = 0; k < 4; k++) {
        out[k] = 1.0;
        if (g->parts == 0) continue;
        double wx = x + c * m->wheel_x[k] - s * m->wheel_y[k];
        double wy = y + s * m->wheel_x[k] + c * m->wheel_y[k];
        int found = -1;
        for (int32_t p = 0; p < g->parts; p++) {
            int32_t r = g->part_region[p];
            if (r <= found) continue;
            int inside = 1;
            for (int32_t e = g->part_edge[p]; e < g->part_edge[p + 1] && inside; e++) {
                const double *d = g->edges + 4 * e;
                double cross = d[2] * (wy - d[1]) - d[3] * (wx - d[0]);
                inside = cross >= -m->probe;
            }
            if (inside) found = r;
        }
        if (found >= 0) out[k] = scales[found];
    }
}

/* Twin i's friction limits per wheel at this pose, N: its side factor times its region
 * scale, times mu N (_Forces._update_limits). */
static void limits(const batch_model_t *m, const batch_grounds_t *g, const batch_regions_t *r,
                   int64_t i, double x, double y, double c, double s, double lx[4],
                   double ly[4]) {
    int32_t nr = r->regions > 0 ? r->regions : 1;
    double region[4];
    place(m, r, g->region_scales + (int64_t)nr * i, x, y, c, s, region);
    for (int k = 0; k < 4; k++) {
        double scale = g->side[2 * i + (k >= 2)] * region[k];
        lx[k] = g->mu_long_n[i] * scale;
        ly[k] = g->mu_lat_n[i] * scale;
    }
}

/* Body-frame force and torque of one step (_Forces.step, for one job). */
static void wrench(const batch_model_t *m, const double lx[4], const double ly[4], double s0,
                   double kappa, double rr, double vx, double vy, double w, double ul,
                   double ur, double out[3]) {
    double hx = m->hx, hy = m->hy, dt = m->dt;
    double inv_sl = 1.0 / (s0 + kappa * fabs(ul));
    double inv_sr = 1.0 / (s0 + kappa * fabs(ur));
    double gl = vx - w * hy, gr = vx + w * hy;
    double lat_f = -(vy + w * hx), lat_b = -(vy - w * hx);
    double inv[4] = {inv_sl, inv_sl, inv_sr, inv_sr};
    double nxl = (ul - gl) * inv_sl, nxr = (ur - gr) * inv_sr;
    double nx[4] = {nxl, nxl, nxr, nxr};
    double ny[4] = {lat_f * inv_sl, lat_b * inv_sl, lat_f * inv_sr, lat_b * inv_sr};
    double fxw[4], fyw[4], dfx[4], dfy[4], cw[4], kxw[4], kyw[4];
    for (int k = 0; k < 4; k++) {
        double nx2 = nx[k] * nx[k];
        double sig2 = max_nan(nx2 + ny[k] * ny[k], TINY * TINY);
        double sig = sqrt(sig2);
        double th = tanh(sig);
        double a = th / sig;
        double b = 1.0 - th * th;
        double cx2 = nx2 / sig2;
        double cxy = nx[k] * ny[k] / sig2;
        double cy2 = 1.0 - cx2;
        double ai = a * inv[k];
        fxw[k] = lx[k] * a * nx[k];
        fyw[k] = ly[k] * a * ny[k];
        dfx[k] = lx[k] * inv[k] * (a * cy2 + b * cx2);
        dfy[k] = ly[k] * inv[k] * (a * cx2 + b * cy2);
        cw[k] = (lx[k] + ly[k]) * inv[k] * (b - a) * cxy;
        kxw[k] = lx[k] * ai;
        kyw[k] = ly[k] * ai;
    }
    double xl = gl * m->inv_vrr, xr = gr * m->inv_vrr;
    double tl = tanh(xl), tr = tanh(xr);
    double fx_l = fxw[0] + fxw[1] - 2.0 * rr * tl;
    double fx_r = fxw[2] + fxw[3] - 2.0 * rr * tr;
    double fy_f = fyw[0] + fyw[2];
    double fy_b = fyw[1] + fyw[3];
    double rr_slope = 2.0 * rr * m->inv_vrr;
    double cx = dfx[0] + dfx[1] + dfx[2] + dfx[3] + rr_slope * ((1.0 - tl * tl) + (1.0 - tr * tr));
    double cy = dfy[0] + dfy[1] + dfy[2] + dfy[3];
    double cross = cw[0] + cw[3] - cw[1] - cw[2];
    double cz = max_nan(hy * hy * cx + hx * hx * cy - hx * hy * cross, 0.0);
    double ratio_l = fabs(xl) > TINY ? tl / xl : 1.0;
    double ratio_r = fabs(xr) > TINY ? tr / xr : 1.0;
    double kx = kxw[0] + kxw[1] + kxw[2] + kxw[3] + rr_slope * (ratio_l + ratio_r);
    double ky = kyw[0] + kyw[1] + kyw[2] + kyw[3];
    double kz = hy * hy * kx + hx * hx * ky;
    double mass = m->mass, inertia = m->inertia;
    cx = max_nan(cx, kx - mass / dt);
    cy = max_nan(cy, ky - mass / dt);
    cz = max_nan(cz, kz - inertia / dt);
    out[0] = (fx_l + fx_r) * mass / (mass + dt * cx);
    out[1] = (fy_f + fy_b) * mass / (mass + dt * cy);
    out[2] = (hy * (fx_r - fx_l) + hx * (fy_f - fy_b)) * inertia / (inertia + dt * cz);
}

/*
 * Play n jobs. Job i starts at start[3i..3i+2] (x, y, yaw) at rest, drives the wheel
 * surface speeds surface[2(offset[i] + t)], t < ticks[i] (left, right, m/s), then
 * stopped wheels until tick end[i], and leaves its pose at that tick in out[3i..3i+2]
 * (yaw unwrapped). Returns 0.
 */
int rover_play_moves(const batch_model_t *m, const batch_grounds_t *grounds,
                     const batch_regions_t *regions, int64_t n, const double *start,
                     const double *surface, const int64_t *offset, const int64_t *ticks,
                     const int64_t *end, double *out) {
    for (int64_t i = 0; i < n; i++) {
        double x = start[3 * i], y = start[3 * i + 1], a = start[3 * i + 2];
        double vx = 0.0, vy = 0.0, w = 0.0;
        double s0 = grounds->s0[i], kappa = grounds->kappa[i], rr = grounds->rr[i];
        const double *speeds = surface + 2 * offset[i];
        double lx[4], ly[4];
        for (int64_t tick = 1; tick <= end[i]; tick++) {
            double c = cos(a), s = sin(a);
            limits(m, grounds, regions, i, x, y, c, s, lx, ly);
            double ul = 0.0, ur = 0.0;
            if (tick <= ticks[i]) {
                ul = speeds[2 * (tick - 1)];
                ur = speeds[2 * (tick - 1) + 1];
            }
            double f[3];
            wrench(m, lx, ly, s0, kappa, rr, c * vx + s * vy, c * vy - s * vx, w, ul, ur, f);
            x = x + vx * m->dt;
            y = y + vy * m->dt;
            a = a + w * m->dt;
            vx = vx + (c * f[0] - s * f[1]) * m->inv_mass * m->dt;
            vy = vy + (s * f[0] + c * f[1]) * m->inv_mass * m->dt;
            w = w + f[2] * m->inv_inertia * m->dt;
        }
        out[3 * i] = x;
        out[3 * i + 1] = y;
        out[3 * i + 2] = a;
    }
    return 0;
}

/*
 * One physics step's forces for emulator/batch.py's play_batch: n twins in one pymunk
 * space, state[6i..6i+5] each one's (x, y, angle, vx, vy in the world frame, angular
 * velocity) as pymunk.batch gives it, offsets[2i..2i+1] where its copy of the map is, the
 * wheel surface speeds ul, ur shared by every twin. Writes twin i's world-frame force and
 * torque to force[3i..3i+2] (the layout pymunk.batch sets them from).
 */
void rover_batch_forces(const batch_model_t *m, const batch_grounds_t *grounds,
                        const batch_regions_t *regions, int64_t n, const double *state,
                        const double *offsets, double ul, double ur, double *force) {
    for (int64_t i = 0; i < n; i++) {
        const double *st = state + 6 * i;
        double c = cos(st[2]), s = sin(st[2]);
        double lx[4], ly[4], f[3];
        limits(m, grounds, regions, i, st[0] - offsets[2 * i], st[1] - offsets[2 * i + 1], c, s,
               lx, ly);
        wrench(m, lx, ly, grounds->s0[i], grounds->kappa[i], grounds->rr[i],
               c * st[3] + s * st[4], c * st[4] - s * st[3], st[5], ul, ur, f);
        force[3 * i] = c * f[0] - s * f[1];
        force[3 * i + 1] = s * f[0] + c * f[1];
        force[3 * i + 2] = f[2];
    }
}
