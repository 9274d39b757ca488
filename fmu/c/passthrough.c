/* The do-nothing FMU: the compensator's interface (command.<AXIS> in, compensated.<AXIS> out)
 * with the outputs equal to the inputs.  It runs the same FMI wrapper (fmi2_base.c) and no
 * kinematics: the baseline of benchmarks/bench_fmu.py, whose difference to the compensator is
 * the cost of the compensation itself. */
#include <math.h>
#include <string.h>

#include "model.h"

#define VR_CMD 0          /* 0..8 inputs */
#define VR_OUT 10         /* 10..18 outputs = inputs */

const uint32_t MODEL_MAGIC = 0x6d74700bu;  /* "mtp" + layout version 11 */

void model_defaults(Instance *inst) { (void)inst; }

int model_real_kind(const Instance *inst, unsigned vr)
{
    (void)inst;
    if (vr < VR_CMD + MTK_MAX_AXES) return VAR_INPUT;
    if (vr >= VR_OUT && vr < VR_OUT + MTK_MAX_AXES) return VAR_OUTPUT;
    return VAR_NONE;
}

int model_int_kind(const Instance *inst, unsigned vr) { (void)inst; (void)vr; return VAR_NONE; }
int model_string_kind(const Instance *inst, unsigned vr) { (void)inst; (void)vr; return VAR_NONE; }

fmi2Status model_check_real(Instance *inst, unsigned vr, double value)
{
    if (vr < VR_CMD + MTK_MAX_AXES && !isfinite(value)) {
        inst_log(inst, fmi2Error, "logStatusError", "value reference %u: axis commands must be finite", vr);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status model_check_int(Instance *inst, unsigned vr, int value)
{
    (void)inst; (void)vr; (void)value;
    return fmi2OK;
}

fmi2Status model_update(Instance *inst)
{
    memcpy(inst->st.r + VR_OUT, inst->st.r + VR_CMD, MTK_MAX_AXES * sizeof(double));
    return fmi2OK;
}

fmi2Status model_exit_init(Instance *inst) { return model_update(inst); }

fmi2Status model_do_step(Instance *inst, double t, double h)
{
    (void)t;
    (void)h;
    if (inst->st.dirty) {
        model_update(inst);
        inst->st.dirty = 0;
    }
    return fmi2OK;
}
