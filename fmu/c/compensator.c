/* The compensator FMU: nominal axis commands in, compensated axis commands out.
 *
 * An algebraic (direct feed-through) block: the outputs are mtcomp.kinematics.retarget of the
 * current inputs under the setting, location and table errors given as parameters and
 * resources.  Value references: common.h plus the ones below (docs/fmu.md).
 */
#include <math.h>
#include <string.h>

#include "common.h"

#define VR_OUT 10         /* 10..18 compensated commands, mm or deg */
#define VR_TOL 30         /* step tolerance of the iteration, mm or deg */
#define VR_RESIDUAL 31    /* largest remaining residual, mm */
#define IVR_MAXIT 0       /* iteration limit */
#define IVR_ITERS 1       /* iterations used at the last evaluation */

const uint32_t MODEL_MAGIC = 0x6d74630bu;  /* "mtc" + layout version 11 */

static int n_axes(const Instance *inst) { return inst->kin ? inst->kin->n_axes : 0; }

void model_defaults(Instance *inst)
{
    common_defaults(inst);
    inst->st.r[VR_TOL] = 1e-10;
    inst->st.i[IVR_MAXIT] = 60;
    common_start_values(inst);
}

int model_real_kind(const Instance *inst, unsigned vr)
{
    int n = n_axes(inst);
    if (vr >= VR_OUT && vr < VR_OUT + (unsigned)n) return VAR_OUTPUT;
    if (vr == VR_RESIDUAL) return VAR_OUTPUT;
    if (vr == VR_TOL) return VAR_PARAM_TUNABLE;
    return common_real_kind(vr, n);
}

int model_int_kind(const Instance *inst, unsigned vr)
{
    (void)inst;
    if (vr == IVR_MAXIT) return VAR_PARAM_TUNABLE;
    if (vr == IVR_ITERS) return VAR_OUTPUT;
    return VAR_NONE;
}

int model_string_kind(const Instance *inst, unsigned vr)
{
    (void)inst;
    return vr == SVR_TABLES ? VAR_PARAM_FIXED : VAR_NONE;
}

fmi2Status model_check_real(Instance *inst, unsigned vr, double value)
{
    if (vr == VR_TOL) return check_range(inst, "tolerance", value, 1e-15, 1e-3);
    return common_check_real(inst, vr, value);
}

fmi2Status model_check_int(Instance *inst, unsigned vr, int value)
{
    if (vr == IVR_MAXIT && (value < 1 || value > 1000)) {
        inst_log(inst, fmi2Error, "logStatusError", "max_iterations = %d is out of range [1, 1000]", value);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status model_update(Instance *inst)
{
    mtk_errors e;
    double q[MTK_MAX_AXES], res = 0.0;
    char err[MTK_ERRLEN];
    int iters = 0, i, n = n_axes(inst), rc;
    if (!inst->kin) return fmi2Error;
    if (inst->st.i[IVR_MAXIT] < 1 || inst->st.i[IVR_MAXIT] > 1000) {
        inst_log(inst, fmi2Error, "logStatusError", "max_iterations = %d is out of range [1, 1000]",
                 inst->st.i[IVR_MAXIT]);
        return fmi2Error;
    }
    common_errors(inst, &e);
    rc = mtk_retarget(inst->kin, &e, inst->st.r + VR_CMD, q, inst->st.r[VR_TOL], inst->st.i[IVR_MAXIT],
                      &iters, &res, err);
    inst->st.i[IVR_ITERS] = iters;
    inst->st.r[VR_RESIDUAL] = res;
    if (rc != MTK_OK) {
        inst_log(inst, fmi2Error, "logError", "t = %g s: %s", inst->st.time, err);
        return fmi2Error;
    }
    for (i = 0; i < n; i++) inst->st.r[VR_OUT + i] = q[i];
    return fmi2OK;
}

fmi2Status model_exit_init(Instance *inst)
{
    if (common_load(inst) != fmi2OK) return fmi2Error;
    return model_update(inst);
}

fmi2Status model_do_step(Instance *inst, double t, double h)
{
    (void)t;
    (void)h;
    /* No states: outputs follow the inputs; evaluate now so a failure is reported by doStep. */
    if (inst->st.dirty) {
        fmi2Status s = model_update(inst);
        if (s > fmi2Warning) return s;
        inst->st.dirty = 0;
    }
    return fmi2OK;
}
