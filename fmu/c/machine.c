/* The machine FMU: a virtual multi-axis machine for co-simulation.
 *
 * Axis commands in; the real tool edge position and tool direction in the real workpiece frame
 * out (the same forward model as mtcomp.kinematics.forward), plus the actual axis positions and
 * the machine temperature.  Per axis: a first-order servo (velocity gain kv, 1/s; kv = 0 is an
 * ideal servo that reaches the command by the end of the step) followed by backlash (a play of the given width
 * centred on the servo position).  A first-order thermal model driven by the spindle speed input
 * moves the tool edge by drift * (T - T_ambient) in the tool frame.  Gaussian sensor noise with
 * a seed is added to the tool edge output.  docs/fmu.md lists the variables.
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
#define VR_P 130          /* 130..132 tool edge in the workpiece frame, mm */
#define VR_V 133          /* 133..135 tool direction (unit vector) */
#define VR_TEMP 136       /* machine temperature, degC */
#define VR_ACT 140        /* 140..148 actual axis positions, mm or deg */
#define IVR_SEED 0        /* noise seed */

/* Internal states in st.x */
#define X_SERVO 0         /* 0..8 servo positions */
#define X_PLAY 10         /* 10..18 positions after backlash */
#define X_TEMP 20         /* temperature */
#define X_NOISE 21        /* 21..23 current noise sample, mm */

const uint32_t MODEL_MAGIC = 0x6d746d0bu;  /* "mtm" + layout version 11 */

static int n_axes(const Instance *inst) { return inst->kin ? inst->kin->n_axes : 0; }

void model_defaults(Instance *inst)
{
    common_defaults(inst);
    inst->st.r[VR_TAU] = 600.0;
    inst->st.r[VR_AMBIENT] = 20.0;
    inst->st.r[VR_TEMP] = 20.0;
    inst->st.i[IVR_SEED] = 1;
    common_start_values(inst);
}

int model_real_kind(const Instance *inst, unsigned vr)
{
    int n = n_axes(inst);
    if (vr == VR_SPINDLE) return VAR_INPUT;
    if (vr >= VR_KV && vr < VR_KV + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_BACKLASH && vr < VR_BACKLASH + (unsigned)n) return VAR_PARAM_FIXED;
    if (vr >= VR_TAU && vr <= VR_NOISE) return VAR_PARAM_FIXED;
    if (vr >= VR_P && vr <= VR_TEMP) return VAR_OUTPUT;
    if (vr >= VR_ACT && vr < VR_ACT + (unsigned)n) return VAR_OUTPUT;
    return common_real_kind(vr, n);
}

int model_int_kind(const Instance *inst, unsigned vr)
{
    (void)inst;
    return vr == IVR_SEED ? VAR_PARAM_FIXED : VAR_NONE;
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
        return check_axis_param(inst, "backlash", (int)(vr - VR_BACKLASH), value, 0.0, 1.0);
    if (vr == VR_TAU) return check_range(inst, "thermal.time_constant", value, 1e-3, 1e6);
    if (vr == VR_GAIN) return check_range(inst, "thermal.gain", value, 0.0, 1.0);
    if (vr == VR_AMBIENT) return check_range(inst, "thermal.ambient", value, -50.0, 100.0);
    if (vr >= VR_DRIFT && vr < VR_DRIFT + 3) return check_range(inst, "thermal.drift", value, -1.0, 1.0);
    if (vr == VR_NOISE) return check_range(inst, "noise.sigma", value, 0.0, 1.0);
    return common_check_real(inst, vr, value);
}

fmi2Status model_check_int(Instance *inst, unsigned vr, int value)
{
    (void)inst;
    (void)vr;
    (void)value;   /* the noise seed takes any value */
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
        q[i] = play(inst->st.x[X_SERVO + i], inst->st.x[X_PLAY + i], inst->st.r[VR_BACKLASH + i]);
        inst->st.r[VR_ACT + i] = q[i];
    }
    common_errors(inst, &e);
    dT = inst->st.x[X_TEMP] - inst->st.r[VR_AMBIENT];
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
    /* Start at rest at the commanded position, at ambient temperature. */
    for (i = 0; i < n; i++) {
        inst->st.x[X_SERVO + i] = inst->st.r[VR_CMD + i];
        inst->st.x[X_PLAY + i] = inst->st.r[VR_CMD + i];
    }
    inst->st.x[X_TEMP] = inst->st.r[VR_AMBIENT];
    seed = (uint64_t)(uint32_t)inst->st.i[IVR_SEED];
    inst->st.rng[0] = splitmix(&seed);
    inst->st.rng[1] = splitmix(&seed);
    draw_noise(inst);
    return model_update(inst);
}

fmi2Status model_do_step(Instance *inst, double t, double h)
{
    int i, n = n_axes(inst);
    double target;
    (void)t;
    if (check_travel(inst) != fmi2OK) return fmi2Error;
    for (i = 0; i < n; i++) {
        double kv = inst->st.r[VR_KV + i], b = inst->st.r[VR_BACKLASH + i];
        double start = inst->st.x[X_SERVO + i], end;
        /* The first-order response to a held command is monotonic within the step, so the
         * play operator applied at both ends of the step is exact. */
        inst->st.x[X_PLAY + i] = play(start, inst->st.x[X_PLAY + i], b);
        end = kv > 0.0 ? start + (inst->st.r[VR_CMD + i] - start) * (-expm1(-kv * h)) : inst->st.r[VR_CMD + i];
        inst->st.x[X_PLAY + i] = play(end, inst->st.x[X_PLAY + i], b);
        inst->st.x[X_SERVO + i] = end;
    }
    target = inst->st.r[VR_AMBIENT] + inst->st.r[VR_GAIN] * inst->st.r[VR_SPINDLE];
    inst->st.x[X_TEMP] += (target - inst->st.x[X_TEMP]) * (-expm1(-h / inst->st.r[VR_TAU]));
    draw_noise(inst);
    inst->st.dirty = 1;
    return fmi2OK;
}
