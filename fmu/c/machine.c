/* The machine FMU: a virtual multi-axis machine for co-simulation.
 *
 * Axis commands in; the real tool edge position and tool direction in the real workpiece frame
 * out (the same forward model as mtcomp.kinematics.forward), plus the actual axis positions and
 * the machine temperature.  Per axis, in this order (docs/model-loop.md, "The machine FMU's
 * dynamics"; mtcomp.model.machine_ref is the Python reference, held to it by tests):
 *   1. transport delay: the axis acts on the command given `delay` s earlier (linear between
 *      the commands of the steps; before the start, the first command);
 *   2. a first-order servo (velocity gain kv, 1/s; kv = 0 is an ideal servo that reaches the
 *      command by the end of the step), its command held over the step (servo.interpolation = 0)
 *      or linear from the previous step's command (1: ramp invariant, no half-step shift);
 *   3. backlash: a play of the given width centred on the servo position; a negative width -|b|
 *      (an over-compensated backlash) is the mirror of the play of width |b| about the servo
 *      position, out = 2 servo - play (the error leads the command by |b|/2);
 *   4. friction at reversals (stick-slip): after the motion reverses, static friction holds the
 *      slide until the drive has wound up by the breakaway distance, then the slide catches up
 *      with a time constant, to a lag of the Coulomb distance against the motion;
 *   5. quadrant glitch (the spike form): after the drive's motion reverses at t_r, the slide
 *      lags by height * s exp(1 - s), s = (t - t_r)/time, against the new direction (the
 *      diagnosis' quadrant_glitch, peak `height` at `time` after the reversal);
 *   6. velocity friction (a velocity-mode axis with a proportional velocity loop): the axis'
 *      actual velocity is the drive's less coulomb tanh(v/vs) + viscous v (v the drive's mean
 *      velocity over the step), output as v.<AXIS>; the position follows its integral (the
 *      deficit accumulates on the actual position);
 *   7. encoder cyclic error (the encoder interface): r(p) = sum_{h=1,2} a_h sin(2 pi h p / period
 *      + phase_h) is added to the actual position, p the axis position that elements 1..6 give
 *      (the diagnosis' encoder_cyclic_error takes p from the recorded position, which differs
 *      from it by r itself: a second-order difference, |r| |dr/dp|); period 0: off.
 * A first-order thermal model (driver: spindle speed, a logged temperature, or none) moves the
 * tool edge by drift * (T - T_reference) in the tool frame.  Gaussian sensor noise with a seed
 * is added to the tool edge output.  docs/fmu.md lists the variables.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "common.h"

#define VR_SPINDLE 9      /* spindle speed input, 1/min */
#define VR_KV 100         /* 100..108 servo gain per axis, 1/s (0: ideal) */
#define VR_BACKLASH 110   /* 110..118 backlash per axis, mm or deg */
#define VR_TAU 120        /* thermal time constant, s */
#define VR_GAIN 121       /* steady temperature rise per spindle speed, K per 1/min */
#define VR_AMBIENT 122    /* ambient temperature, degC */
#define VR_DRIFT 123      /* 123..125 tool edge drift per kelvin in the tool frame, mm/K */
#define VR_NOISE 126      /* standard deviation of the tool edge sensor noise, mm */
#define VR_TIN 127        /* logged temperature input (thermal driver 1), degC */
#define VR_EXCESS 128     /* initial temperature above ambient, K */
#define VR_TREF 129       /* temperature at which the drift is zero, degC */
#define VR_P 130          /* 130..132 tool edge in the workpiece frame, mm */
#define VR_V 133          /* 133..135 tool direction (unit vector) */
#define VR_TEMP 136       /* machine temperature, degC */
#define VR_ACT 140        /* 140..148 actual axis positions, mm or deg */
#define VR_DELAY 150      /* transport delay of the commands, s */
#define VR_BREAK 160      /* 160..168 friction breakaway distance per axis, mm or deg */
#define VR_COULOMB 170    /* 170..178 Coulomb lag distance per axis, mm or deg */
#define VR_FTAU 180       /* 180..188 friction catch-up time constant per axis, s */
#define VR_GH 190         /* 190..198 quadrant glitch height per axis, mm or deg */
#define VR_GT 200         /* 200..208 quadrant glitch time (reversal to peak) per axis, s */
#define VR_VFC 210        /* 210..218 velocity friction: Coulomb velocity loss per axis, mm/s or deg/s */
#define VR_VFB 220        /* 220..228 velocity friction: viscous loss per unit velocity (1) */
#define VR_VFS 230        /* 230..238 velocity friction: tanh smoothing speed, mm/s or deg/s */
#define VR_VEL 240        /* 240..248 actual axis velocities, mm/s or deg/s */
#define VR_EP 250         /* 250..258 encoder signal period per axis, mm or deg (0: no cyclic error) */
#define VR_EA1 260        /* 260..268 encoder cyclic error, first harmonic amplitude, mm or deg */
#define VR_EPH1 270       /* 270..278 its phase, deg */
#define VR_EA2 280        /* 280..288 second harmonic amplitude, mm or deg */
#define VR_EPH2 290       /* 290..298 its phase, deg */
#define IVR_SEED 0        /* noise seed */
#define IVR_DRIVER 1      /* thermal driver: 0 spindle speed, 1 temperature input, 2 none (time) */
#define IVR_INTERP 2      /* servo command: 0 held over the step, 1 linear from the previous one */

/* Internal states in st.x */
#define X_SERVO 0         /* 0..8 servo positions */
#define X_PLAY 10         /* 10..18 play states (width |backlash|; backlash_out gives the position) */
#define X_TEMP 20         /* temperature */
#define X_NOISE 21        /* 21..23 current noise sample, mm */
#define X_TIN0 24         /* temperature input at the start, degC */
#define X_SLIDE 30        /* 30..38 slide positions after friction (the actual positions) */
#define X_FERR 40         /* 40..48 backlash output - slide while slipping, mm or deg */
#define X_FDIR 50         /* 50..58 direction of the last motion (+1, -1; 0: not moved yet) */
#define X_FSTUCK 60       /* 60..68 1 while static friction holds the slide */
#define X_HIST_N 70       /* number of commands in the history */
#define X_HIST_HEAD 71    /* index of the newest one */
#define X_GDIR 80         /* 80..88 direction of the drive's last motion (+1, -1; 0: not moved yet) */
#define X_GREV 90         /* 90..98 time of its last reversal, s (while X_GDIR is 0 or before one: none) */
#define X_GON 100         /* 100..108 1 once a reversal has happened */
#define X_VEL 110         /* 110..118 actual velocity over the last step, mm/s or deg/s */
#define X_VDEF 120        /* 120..128 integral of the velocity friction's deficit, mm or deg */
#define X_HIST 130        /* history of the commands: entries (time, command[MTK_MAX_AXES]) */
#define HIST_W (1 + MTK_MAX_AXES)
#define HIST_CAP ((MODEL_NX - X_HIST) / HIST_W)

const uint32_t MODEL_MAGIC = 0x6d746d0fu;  /* "mtm" + layout version 15 */

static int n_axes(const Instance *inst) { return inst->kin ? inst->kin->n_axes : 0; }

void model_defaults(Instance *inst)
{
    common_defaults(inst);
    inst->st.r[VR_TAU] = 600.0;
    inst->st.r[VR_AMBIENT] = 20.0;
    inst->st.r[VR_TEMP] = 20.0;
    inst->st.r[VR_TIN] = 20.0;
    inst->st.r[VR_TREF] = 20.0;
    inst->st.i[IVR_SEED] = 1;
    common_start_values(inst);
}

int model_real_kind(const Instance *inst, unsigned vr)
{
    int n = n_axes(inst);
    if (vr == VR_SPINDLE || vr == VR_TIN) return VAR_INPUT;
    if (vr >= VR_KV && vr < VR_KV + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_BACKLASH && vr < VR_BACKLASH + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_TAU && vr <= VR_NOISE) return VAR_PARAM_FIXED;
    if (vr == VR_EXCESS || vr == VR_TREF || vr == VR_DELAY) return VAR_PARAM_FIXED;
    if (vr >= VR_BREAK && vr < VR_BREAK + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_COULOMB && vr < VR_COULOMB + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_FTAU && vr < VR_FTAU + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_GH && vr < VR_GH + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_GT && vr < VR_GT + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_VFC && vr < VR_VFC + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_VFB && vr < VR_VFB + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_VFS && vr < VR_VFS + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_VEL && vr < VR_VEL + (unsigned)n) return VAR_OUTPUT;
    if (vr >= VR_EP && vr < VR_EPH2 + 10 && (vr - VR_EP) % 10 < (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_P && vr <= VR_TEMP) return VAR_OUTPUT;
    if (vr >= VR_ACT && vr < VR_ACT + (unsigned)n) return VAR_OUTPUT;
    return common_real_kind(vr, n);
}

int model_int_kind(const Instance *inst, unsigned vr)
{
    (void)inst;
    return vr == IVR_SEED || vr == IVR_DRIVER || vr == IVR_INTERP ? VAR_PARAM_FIXED : VAR_NONE;
}

int model_string_kind(const Instance *inst, unsigned vr)
{
    (void)inst;
    return vr == SVR_TABLES ? VAR_PARAM_FIXED : VAR_NONE;
}

/* Range check of a per-axis parameter; its name is formatted only for a rejected value. */
static fmi2Status check_axis_param(Instance *inst, const char *what, int axis, double value, double lo, double hi)
{
    char name[64];
    if (value >= lo && value <= hi) return fmi2OK;
    snprintf(name, sizeof name, "%s.%c", what, inst->kin ? inst->kin->axis_name[axis] : '?');
    return check_range(inst, name, value, lo, hi);
}

fmi2Status model_check_real(Instance *inst, unsigned vr, double value)
{
    if (vr == VR_SPINDLE) return check_range(inst, "spindle_speed", value, 0.0, 1e6);
    if (vr >= VR_KV && vr < VR_KV + MTK_MAX_AXES)
        return check_axis_param(inst, "servo.kv", (int)(vr - VR_KV), value, 0.0, 1e4);
    if (vr >= VR_BACKLASH && vr < VR_BACKLASH + MTK_MAX_AXES)
        return check_axis_param(inst, "backlash", (int)(vr - VR_BACKLASH), value, -1.0, 1.0);
    if (vr == VR_TAU) return check_range(inst, "thermal.time_constant", value, 1e-3, 1e6);
    if (vr == VR_GAIN) return check_range(inst, "thermal.gain", value, 0.0, 1.0);
    if (vr == VR_AMBIENT) return check_range(inst, "thermal.ambient", value, -50.0, 100.0);
    if (vr >= VR_DRIFT && vr < VR_DRIFT + 3) return check_range(inst, "thermal.drift", value, -1.0, 1.0);
    if (vr == VR_NOISE) return check_range(inst, "noise.sigma", value, 0.0, 1.0);
    if (vr == VR_TIN) return check_range(inst, "temperature_input", value, -50.0, 200.0);
    if (vr == VR_EXCESS) return check_range(inst, "thermal.initial_excess", value, -100.0, 100.0);
    if (vr == VR_TREF) return check_range(inst, "thermal.reference", value, -50.0, 100.0);
    if (vr == VR_DELAY) return check_range(inst, "delay", value, 0.0, 1.0);
    if (vr >= VR_BREAK && vr < VR_BREAK + MTK_MAX_AXES)
        return check_axis_param(inst, "friction.breakaway", (int)(vr - VR_BREAK), value, 0.0, 1.0);
    if (vr >= VR_COULOMB && vr < VR_COULOMB + MTK_MAX_AXES)
        return check_axis_param(inst, "friction.coulomb", (int)(vr - VR_COULOMB), value, 0.0, 1.0);
    if (vr >= VR_FTAU && vr < VR_FTAU + MTK_MAX_AXES)
        return check_axis_param(inst, "friction.tau", (int)(vr - VR_FTAU), value, 0.0, 100.0);
    if (vr >= VR_GH && vr < VR_GH + MTK_MAX_AXES)
        return check_axis_param(inst, "glitch.height", (int)(vr - VR_GH), value, -1.0, 1.0);
    if (vr >= VR_GT && vr < VR_GT + MTK_MAX_AXES)
        return check_axis_param(inst, "glitch.time", (int)(vr - VR_GT), value, 0.0, 100.0);
    if (vr >= VR_VFC && vr < VR_VFC + MTK_MAX_AXES)
        return check_axis_param(inst, "velfriction.coulomb", (int)(vr - VR_VFC), value, -1e4, 1e4);
    if (vr >= VR_VFB && vr < VR_VFB + MTK_MAX_AXES)
        return check_axis_param(inst, "velfriction.viscous", (int)(vr - VR_VFB), value, -1.0, 1.0);
    if (vr >= VR_VFS && vr < VR_VFS + MTK_MAX_AXES)
        return check_axis_param(inst, "velfriction.vs", (int)(vr - VR_VFS), value, 0.0, 1e6);
    if (vr >= VR_EP && vr < VR_EP + MTK_MAX_AXES)
        return check_axis_param(inst, "encoder.period", (int)(vr - VR_EP), value, 0.0, 1000.0);
    if (vr >= VR_EA1 && vr < VR_EA1 + MTK_MAX_AXES)
        return check_axis_param(inst, "encoder.a1", (int)(vr - VR_EA1), value, -1.0, 1.0);
    if (vr >= VR_EPH1 && vr < VR_EPH1 + MTK_MAX_AXES)
        return check_axis_param(inst, "encoder.phase1", (int)(vr - VR_EPH1), value, -720.0, 720.0);
    if (vr >= VR_EA2 && vr < VR_EA2 + MTK_MAX_AXES)
        return check_axis_param(inst, "encoder.a2", (int)(vr - VR_EA2), value, -1.0, 1.0);
    if (vr >= VR_EPH2 && vr < VR_EPH2 + MTK_MAX_AXES)
        return check_axis_param(inst, "encoder.phase2", (int)(vr - VR_EPH2), value, -720.0, 720.0);
    return common_check_real(inst, vr, value);
}

fmi2Status model_check_int(Instance *inst, unsigned vr, int value)
{
    /* the noise seed takes any value */
    if (vr == IVR_DRIVER && (value < 0 || value > 2)) {
        inst_log(inst, fmi2Error, "logError", "thermal.driver = %d: expected 0 (spindle speed), 1 (temperature "
                 "input) or 2 (none: the initial excess relaxes over time)", value);
        return fmi2Error;
    }
    if (vr == IVR_INTERP && (value < 0 || value > 1)) {
        inst_log(inst, fmi2Error, "logError", "servo.interpolation = %d: expected 0 (command held over the "
                 "step) or 1 (linear from the previous command)", value);
        return fmi2Error;
    }
    return fmi2OK;
}

/* xorshift128+ seeded by splitmix64: small, fast, and its state is part of the FMU state. */
static uint64_t splitmix(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static double uniform(uint64_t r[2])
{
    uint64_t a = r[0], b = r[1];
    r[0] = b;
    a ^= a << 23;
    r[1] = a ^ b ^ (a >> 17) ^ (b >> 26);
    return ((r[1] + b) >> 11) * (1.0 / 9007199254740992.0);
}

static double normal(uint64_t r[2])
{
    double u1 = uniform(r), u2 = uniform(r);
    if (u1 < 1e-300) u1 = 1e-300;
    return sqrt(-2.0 * log(u1)) * cos(2.0 * 3.14159265358979323846 * u2);
}

static void draw_noise(Instance *inst)
{
    int k;
    double sigma = inst->st.r[VR_NOISE];
    for (k = 0; k < 3; k++) inst->st.x[X_NOISE + k] = sigma > 0.0 ? sigma * normal(inst->st.rng) : 0.0;
}

/* Backlash as a play operator: the output moves only when the input leaves the band
 * [out - b/2, out + b/2]. */
static double play(double in, double out, double b)
{
    if (in - out > 0.5 * b) return in - 0.5 * b;
    if (in - out < -0.5 * b) return in + 0.5 * b;
    return out;
}

/* The position after the backlash element of width b from the servo position and the play
 * state (a play of width |b|): b >= 0 the play itself; b < 0 (an over-compensated backlash, ISO
 * 230-2 reversal value negative) its mirror about the servo position, which leads the command
 * by |b|/2 where the play lags it. */
static double backlash_out(double servo, double play_state, double b)
{
    return b < 0.0 ? 2.0 * servo - play_state : play_state;
}

static int friction_on(const Instance *inst, int i)
{
    return inst->st.r[VR_BREAK + i] > 0.0 || inst->st.r[VR_COULOMB + i] > 0.0;
}

/* The quadrant glitch of axis i at time t: -height d s exp(1 - s), s = (t - t_r)/time after the
 * drive's last reversal at t_r, d the direction since; 0 before any reversal or with time = 0. */
static double glitch(const Instance *inst, int i, double t)
{
    double tg = inst->st.r[VR_GT + i], s;
    if (!(tg > 0.0) || inst->st.x[X_GON + i] == 0.0) return 0.0;
    s = (t - inst->st.x[X_GREV + i]) / tg;
    if (s <= 0.0 || s > 700.0) return 0.0;
    return -inst->st.r[VR_GH + i] * inst->st.x[X_GDIR + i] * s * exp(1.0 - s);
}

/* The actual velocity of a velocity-mode axis whose drive moves at v: v - c tanh(v/vs) - b v
 * (vs = 0: the sign of v, 0 at rest). */
static double velfriction(double v, double c, double b, double vs)
{
    double s = vs > 0.0 ? tanh(v / vs) : (v > 0.0) - (v < 0.0);
    return v - c * s - b * v;
}

/* The encoder cyclic error of axis i at axis position p: sum_h a_h sin(2 pi h p / period +
 * phase_h), h = 1, 2; 0 with period 0. */
static double encoder_cyclic(const Instance *inst, int i, double p)
{
    const double *r = inst->st.r;
    double P = r[VR_EP + i], w, d = 3.14159265358979323846 / 180.0;
    if (!(P > 0.0)) return 0.0;
    w = 2.0 * 3.14159265358979323846 * p / P;
    return r[VR_EA1 + i] * sin(w + r[VR_EPH1 + i] * d) + r[VR_EA2 + i] * sin(2.0 * w + r[VR_EPH2 + i] * d);
}

/* exp(-t/tau), 0 for tau = 0 (an instantaneous catch-up). */
static double decay(double t, double tau)
{
    return tau > 0.0 ? exp(-t / tau) : 0.0;
}

/* Append the commands given at time t to the history (replacing an entry of the same time). */
static void history_push(Instance *inst, double t, double tol)
{
    double *x = inst->st.x;
    int cnt = (int)x[X_HIST_N], head = (int)x[X_HIST_HEAD], k, n = n_axes(inst);
    if (!(cnt > 0 && fabs(x[X_HIST + head * HIST_W] - t) <= tol)) {
        head = cnt > 0 ? (head + 1) % HIST_CAP : 0;
        if (cnt < HIST_CAP) cnt++;
    }
    x[X_HIST + head * HIST_W] = t;
    for (k = 0; k < n; k++) x[X_HIST + head * HIST_W + 1 + k] = inst->st.r[VR_CMD + k];
    x[X_HIST_N] = cnt;
    x[X_HIST_HEAD] = head;
}

/* The commands at time `when`: linear between the history's entries, the newest after it, the
 * first before the start (the machine rested there).  Returns 0 when `when` lies before a
 * history that has already dropped entries (a delay longer than the history). */
static int history_at(const Instance *inst, double when, double tol, double *c)
{
    const double *x = inst->st.x;
    int cnt = (int)x[X_HIST_N], head = (int)x[X_HIST_HEAD], j, k, n = n_axes(inst);
    for (j = 0; j < cnt; j++) {
        int idx = (head - j + HIST_CAP) % HIST_CAP;
        const double *e = x + X_HIST + idx * HIST_W;
        if (e[0] <= when + tol) {
            if (j == 0 || e[0] >= when - tol) {
                for (k = 0; k < n; k++) c[k] = e[1 + k];
            } else {
                const double *nx = x + X_HIST + ((idx + 1) % HIST_CAP) * HIST_W;
                double f = (when - e[0]) / (nx[0] - e[0]);
                for (k = 0; k < n; k++) c[k] = e[1 + k] + f * (nx[1 + k] - e[1 + k]);
            }
            return 1;
        }
    }
    if (cnt < HIST_CAP && cnt > 0) {
        const double *e = x + X_HIST + ((head - cnt + 1 + HIST_CAP) % HIST_CAP) * HIST_W;
        for (k = 0; k < n; k++) c[k] = e[1 + k];
        return 1;
    }
    return 0;
}

/* First-order servo over one step of length h from x0, its command linear from c0 (start) to c1
 * (end; c0 = c1: held).  Exact solution of x' = kv (c - x).  *xm: the position where the motion
 * reverses inside the step (the ramp can turn it once), else the end position. */
static double servo_step(double x0, double c0, double c1, double kv, double h, double *xm)
{
    double a, g, end;
    if (!(kv > 0.0)) {
        *xm = c1;
        return c1;
    }
    a = kv * h;
    g = -expm1(-a);
    if (c0 == c1) {
        end = x0 + (c1 - x0) * g;
        *xm = end;
        return end;
    }
    /* e = c - x obeys e' = m - kv e: e(t) = m/kv + (e0 - m/kv) exp(-kv t), m = (c1 - c0)/h */
    end = c1 - (c1 - c0) * g / a - (c0 - x0) * (1.0 - g);
    *xm = end;
    {
        double m = (c1 - c0) / h, e0 = c0 - x0, den = m - kv * e0;
        if (den != 0.0) {
            double E = m / den;   /* exp(-kv t*) where x' = kv e = 0 */
            if (E > 1.0 - g && E < 1.0) {
                double ts = -log(E) / kv;
                *xm = c0 + m * ts;   /* e(t*) = 0: the slide is at the command */
            }
        }
    }
    return end;
}

/* Friction at reversals on axis i, over a step in which the backlash output moved from s0 to s1. */
static void friction_step(Instance *inst, int i, double s0, double s1, double h)
{
    double *x = inst->st.x;
    double brk = inst->st.r[VR_BREAK + i], cou = inst->st.r[VR_COULOMB + i], tau = inst->st.r[VR_FTAU + i];
    double d = x[X_FDIR + i], ds = s1 - s0;
    if (fabs(ds) > 1e-12) {
        double nd = ds > 0.0 ? 1.0 : -1.0;
        if (d != 0.0 && nd != d) x[X_FSTUCK + i] = 1.0;   /* reversal: the slide sticks where it is */
        d = nd;
        x[X_FDIR + i] = d;
    }
    if (x[X_FSTUCK + i] != 0.0) {
        double stick = x[X_SLIDE + i], D1 = d * (s1 - stick);
        if (D1 >= brk) {   /* breakaway inside this step, where the wind-up crosses brk (linear) */
            double D0 = d * (s0 - stick), f = D1 > D0 ? (brk - D0) / (D1 - D0) : 1.0;
            if (f < 0.0) f = 0.0;
            if (f > 1.0) f = 1.0;
            x[X_FSTUCK + i] = 0.0;
            x[X_FERR + i] = d * (cou + (brk - cou) * decay((1.0 - f) * h, tau));
            x[X_SLIDE + i] = s1 - x[X_FERR + i];
        }
        return;
    }
    {
        double target = d * cou;
        x[X_FERR + i] = target + (x[X_FERR + i] - target) * decay(h, tau);
        x[X_SLIDE + i] = s1 - x[X_FERR + i];
    }
}

/* The machine refuses to move an axis beyond its travel, as a control's software limits do
 * (half a resolution step of tolerance, like mtcomp.kinematics.check_limits). */
static fmi2Status check_travel(Instance *inst)
{
    const mtk_model *m = inst->kin;
    int i;
    for (i = 0; i < m->n_axes; i++) {
        double c = inst->st.r[VR_CMD + i];
        if (c < m->lo[i] - m->slack[i] || c > m->hi[i] + m->slack[i]) {
            inst_log(inst, fmi2Error, "logError", "t = %g s: command.%c = %.6f %s is outside the travel [%g, %g]",
                     inst->st.time, m->axis_name[i], c, m->rotary[i] ? "deg" : "mm", m->lo[i], m->hi[i]);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

fmi2Status model_update(Instance *inst)
{
    mtk_errors e;
    double q[MTK_MAX_AXES], p[3], R[9], dT;
    char err[MTK_ERRLEN];
    int i, k, n = n_axes(inst);
    if (!inst->kin) return fmi2Error;
    /* Outputs are functions of the states only (no direct feed-through from the commands:
     * ModelStructure declares no dependencies), so a master sees no algebraic loop. */
    for (i = 0; i < n; i++) {
        double sv = inst->st.x[X_SERVO + i], b = inst->st.r[VR_BACKLASH + i];
        q[i] = friction_on(inst, i) ? inst->st.x[X_SLIDE + i]
                                    : backlash_out(sv, play(sv, inst->st.x[X_PLAY + i], fabs(b)), b);
        q[i] += glitch(inst, i, inst->st.time) + inst->st.x[X_VDEF + i];
        q[i] += encoder_cyclic(inst, i, q[i]);
        inst->st.r[VR_ACT + i] = q[i];
        inst->st.r[VR_VEL + i] = inst->st.x[X_VEL + i];
    }
    common_errors(inst, &e);
    dT = inst->st.x[X_TEMP] - inst->st.r[VR_TREF];
    for (k = 0; k < 3; k++) e.tool[k] += inst->st.r[VR_DRIFT + k] * dT;
    if (mtk_forward(inst->kin, &e, q, p, R, err) != MTK_OK) {
        inst_log(inst, fmi2Error, "logError", "t = %g s: %s", inst->st.time, err);
        return fmi2Error;
    }
    for (k = 0; k < 3; k++) {
        const double *a = inst->kin->tool_axis;
        inst->st.r[VR_P + k] = p[k] + inst->st.x[X_NOISE + k];
        inst->st.r[VR_V + k] = R[3 * k] * a[0] + R[3 * k + 1] * a[1] + R[3 * k + 2] * a[2];
    }
    inst->st.r[VR_TEMP] = inst->st.x[X_TEMP];
    return fmi2OK;
}

fmi2Status model_exit_init(Instance *inst)
{
    int i, n;
    uint64_t seed;
    if (common_load(inst) != fmi2OK) return fmi2Error;
    if (check_travel(inst) != fmi2OK) return fmi2Error;
    n = n_axes(inst);
    /* Start at rest at the commanded position, at ambient temperature plus the initial excess. */
    for (i = 0; i < n; i++) {
        inst->st.x[X_SERVO + i] = inst->st.r[VR_CMD + i];
        inst->st.x[X_PLAY + i] = inst->st.r[VR_CMD + i];
        inst->st.x[X_SLIDE + i] = inst->st.r[VR_CMD + i];
        inst->st.x[X_FERR + i] = 0.0;
        inst->st.x[X_FDIR + i] = 0.0;
        inst->st.x[X_FSTUCK + i] = 0.0;
        inst->st.x[X_GDIR + i] = 0.0;
        inst->st.x[X_GREV + i] = 0.0;
        inst->st.x[X_GON + i] = 0.0;
        inst->st.x[X_VEL + i] = 0.0;
        inst->st.x[X_VDEF + i] = 0.0;
    }
    inst->st.x[X_HIST_N] = 0.0;
    inst->st.x[X_HIST_HEAD] = 0.0;
    history_push(inst, inst->st.time, 0.0);
    inst->st.x[X_TEMP] = inst->st.r[VR_AMBIENT] + inst->st.r[VR_EXCESS];
    inst->st.x[X_TIN0] = inst->st.r[VR_TIN];
    seed = (uint64_t)(uint32_t)inst->st.i[IVR_SEED];
    inst->st.rng[0] = splitmix(&seed);
    inst->st.rng[1] = splitmix(&seed);
    draw_noise(inst);
    return model_update(inst);
}

fmi2Status model_do_step(Instance *inst, double t, double h)
{
    int i, n = n_axes(inst), driver = inst->st.i[IVR_DRIVER];
    double target, delay = inst->st.r[VR_DELAY], tol = 1e-9 * h;
    double c1[MTK_MAX_AXES], c0[MTK_MAX_AXES];
    if (check_travel(inst) != fmi2OK) return fmi2Error;
    history_push(inst, t, tol);
    /* the command the servo follows over [t, t + h]: given `delay` earlier; held, or linear
     * from the one a step before */
    if (!history_at(inst, t - delay, tol, c1)
        || (inst->st.i[IVR_INTERP] ? !history_at(inst, t - h - delay, tol, c0) : 0)) {
        inst_log(inst, fmi2Error, "logError", "t = %g s: delay = %g s reaches back beyond the %d steps of "
                 "commands the FMU keeps", t, delay, HIST_CAP);
        return fmi2Error;
    }
    for (i = 0; i < n; i++) {
        double kv = inst->st.r[VR_KV + i], bs = inst->st.r[VR_BACKLASH + i], b = fabs(bs);
        double start = inst->st.x[X_SERVO + i], end, mid, s0;
        double cs = inst->st.i[IVR_INTERP] ? c0[i] : c1[i];
        /* The servo's motion within the step is monotonic but for at most one reversal (at
         * `mid`), so the play operator applied there and at both ends of the step is exact. */
        end = servo_step(start, cs, c1[i], kv, h, &mid);
        inst->st.x[X_PLAY + i] = play(start, inst->st.x[X_PLAY + i], b);
        s0 = backlash_out(start, inst->st.x[X_PLAY + i], bs);
        inst->st.x[X_PLAY + i] = play(mid, inst->st.x[X_PLAY + i], b);
        inst->st.x[X_PLAY + i] = play(end, inst->st.x[X_PLAY + i], b);
        inst->st.x[X_SERVO + i] = end;
        /* the drive's motion over the step, resolved to the step: a reversal starts the glitch
         * at the step's start (where a held command turns the motion) */
        if (fabs(end - start) > 1e-12) {
            double nd = end > start ? 1.0 : -1.0;
            if (inst->st.x[X_GDIR + i] != 0.0 && nd != inst->st.x[X_GDIR + i]) {
                inst->st.x[X_GREV + i] = t;
                inst->st.x[X_GON + i] = 1.0;
            }
            inst->st.x[X_GDIR + i] = nd;
        }
        if (friction_on(inst, i)) friction_step(inst, i, s0, backlash_out(end, inst->st.x[X_PLAY + i], bs), h);
        /* the drive's mean velocity over the step; a velocity-mode axis loses to friction what
         * its proportional velocity loop cannot hold, and its position integrates the loss */
        {
            double vd = (end - start) / h;
            double va = velfriction(vd, inst->st.r[VR_VFC + i], inst->st.r[VR_VFB + i], inst->st.r[VR_VFS + i]);
            inst->st.x[X_VEL + i] = va;
            inst->st.x[X_VDEF + i] += (va - vd) * h;
        }
    }
    target = inst->st.r[VR_AMBIENT];
    if (driver == 0) target += inst->st.r[VR_GAIN] * inst->st.r[VR_SPINDLE];
    else if (driver == 1) target += inst->st.r[VR_TIN] - inst->st.x[X_TIN0];
    inst->st.x[X_TEMP] += (target - inst->st.x[X_TEMP]) * (-expm1(-h / inst->st.r[VR_TAU]));
    draw_noise(inst);
    inst->st.dirty = 1;
    return fmi2OK;
}
