/* Parameters and resources shared by the compensator and the machine FMU (see common.h). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common.h"

static const char COMP[] = "XYZABC";

int common_real_kind(unsigned vr, int n_axes)
{
    if (vr < VR_CMD + (unsigned)n_axes) return VAR_INPUT;
    if (vr >= VR_TOOL && vr < VR_WP_A + 3) return VAR_PARAM_TUNABLE;
    if (vr >= VR_LOC && vr < VR_LOC + 6u * (unsigned)n_axes) return VAR_PARAM_FIXED;
    return VAR_NONE;
}

void common_vr_name(unsigned vr, const mtk_model *m, char *buf, size_t cap)
{
    static const char *xyz[] = {"x", "y", "z"}, *abc[] = {"a", "b", "c"};
    if (m && vr < VR_CMD + (unsigned)m->n_axes) snprintf(buf, cap, "command.%c", m->axis_name[vr]);
    else if (vr >= VR_TOOL && vr < VR_TOOL + 3) snprintf(buf, cap, "tool_setting.offset.%s", xyz[vr - VR_TOOL]);
    else if (vr >= VR_WP_T && vr < VR_WP_T + 3) snprintf(buf, cap, "workpiece_setting.translation.%s", xyz[vr - VR_WP_T]);
    else if (vr >= VR_WP_A && vr < VR_WP_A + 3) snprintf(buf, cap, "workpiece_setting.angle.%s", abc[vr - VR_WP_A]);
    else if (m && vr >= VR_LOC && vr < VR_LOC + 6u * (unsigned)m->n_axes)
        snprintf(buf, cap, "location.E%c0%c", COMP[(vr - VR_LOC) % 6], m->axis_name[(vr - VR_LOC) / 6]);
    else snprintf(buf, cap, "value reference %u", vr);
}

fmi2Status check_range(Instance *inst, const char *what, double value, double lo, double hi)
{
    if (isnan(value)) {
        inst_log(inst, fmi2Error, "logStatusError", "%s: NaN is not a valid value", what);
        return fmi2Error;
    }
    if (!(value >= lo && value <= hi)) {
        inst_log(inst, fmi2Error, "logStatusError", "%s = %g is out of range [%g, %g]", what, value, lo, hi);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status common_check_real(Instance *inst, unsigned vr, double value)
{
    char name[96];
    common_vr_name(vr, inst->kin, name, sizeof name);
    if (vr < VR_CMD + MTK_MAX_AXES) {
        if (!isfinite(value)) {
            inst_log(inst, fmi2Error, "logStatusError", "%s = %g: axis commands must be finite", name, value);
            return fmi2Error;
        }
        return fmi2OK;
    }
    if (vr >= VR_TOOL && vr < VR_TOOL + 3) return check_range(inst, name, value, -MAX_TOOL_OFFSET, MAX_TOOL_OFFSET);
    if (vr >= VR_WP_T && vr < VR_WP_T + 3) return check_range(inst, name, value, -MAX_WP_TRANSLATION, MAX_WP_TRANSLATION);
    if (vr >= VR_WP_A && vr < VR_WP_A + 3) return check_range(inst, name, value, -MAX_WP_ANGLE, MAX_WP_ANGLE);
    if (vr >= VR_LOC && vr < VR_LOC_END) {
        if ((vr - VR_LOC) % 6 < 3) return check_range(inst, name, value, -MAX_LOC_LINEAR, MAX_LOC_LINEAR);
        return check_range(inst, name, value, -MAX_LOC_ANGLE, MAX_LOC_ANGLE);
    }
    return fmi2OK;
}

static fmi2Status load_machine(Instance *inst)
{
    char path[sizeof inst->resources + 64], err[MTK_ERRLEN];
    mtk_free(inst->kin);
    inst->kin = NULL;
    if (!inst->resources[0]) {
        /* no (usable) resource location: never fall back to a machine.txt in the working folder */
        inst_log(inst, fmi2Error, "logError", "no usable fmuResourceLocation: cannot read %s", MACHINE_RESOURCE);
        return fmi2Error;
    }
    snprintf(path, sizeof path, "%s%s", inst->resources, MACHINE_RESOURCE);
    if (mtk_load_machine(path, &inst->kin, err) != MTK_OK) {
        inst_log(inst, fmi2Error, "logError", "%s", err);
        return fmi2Error;
    }
    return fmi2OK;
}

void common_defaults(Instance *inst)
{
    strcpy(inst->st.s[SVR_TABLES], "");
    /* The machine description fixes the number of axes (the structure of the FMU), so it is
     * read at instantiation; a failure is reported again when initialisation ends. */
    load_machine(inst);
}

/* Start values of the parameters, written by the builder from the same list as the start
 * attributes of modelDescription.xml, so the FMU's defaults equal its declared start values.
 * Lines: "r VR VALUE", "i VR VALUE" or "s VR TEXT". */
void common_start_values(Instance *inst)
{
    char path[sizeof inst->resources + 64], line[MODEL_SLEN + 64];
    FILE *f;
    if (!inst->resources[0]) return;
    snprintf(path, sizeof path, "%s%s", inst->resources, START_RESOURCE);
    f = fopen(path, "r");
    if (!f) return;
    while (fgets(line, sizeof line, f)) {
        char kind;
        unsigned vr;
        int used = 0;
        if (line[0] == '#' || sscanf(line, " %c %u %n", &kind, &vr, &used) < 2) continue;
        if (kind == 'r' && vr < MODEL_NR) inst->st.r[vr] = strtod(line + used, NULL);
        else if (kind == 'i' && vr < MODEL_NI) inst->st.i[vr] = atoi(line + used);
        else if (kind == 's' && vr < MODEL_NS) {
            char *v = line + used;
            v[strcspn(v, "\r\n")] = 0;
            snprintf(inst->st.s[vr], MODEL_SLEN, "%s", v);
        }
    }
    fclose(f);
}

fmi2Status common_load(Instance *inst)
{
    char spec[MODEL_SLEN], err[MTK_ERRLEN], *item, *save = NULL;
    if (load_machine(inst) != fmi2OK) return fmi2Error;
    strcpy(spec, inst->st.s[SVR_TABLES]);
    for (item = mtk_tok(spec, ";", &save); item; item = mtk_tok(NULL, ";", &save)) {
        char path[sizeof inst->resources + MODEL_SLEN], *colon;
        while (*item == ' ') item++;
        if (!*item) continue;
        colon = strchr(item, ':');
        if (!colon || colon == item) {
            inst_log(inst, fmi2Error, "logError",
                     "geometric_tables: expected 'AXIS:resource/path.csv' items separated by ';', got '%s'", item);
            return fmi2Error;
        }
        *colon = 0;
        if (strstr(colon + 1, "..")) {
            inst_log(inst, fmi2Error, "logError", "geometric_tables: '%s' must stay inside the resources folder", colon + 1);
            return fmi2Error;
        }
        snprintf(path, sizeof path, "%s%s", inst->resources, colon + 1);
        if (mtk_load_table(inst->kin, item, path, err) != MTK_OK) {
            inst_log(inst, fmi2Error, "logError", "geometric_tables: %s", err);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

void common_errors(const Instance *inst, mtk_errors *e)
{
    int i, k;
    mtk_errors_zero(e);
    for (k = 0; k < 3; k++) {
        e->tool[k] = inst->st.r[VR_TOOL + k];
        e->wp_t[k] = inst->st.r[VR_WP_T + k];
        e->wp_a[k] = inst->st.r[VR_WP_A + k];
    }
    for (i = 0; i < inst->kin->n_axes; i++)
        for (k = 0; k < 6; k++) e->loc[i][k] = inst->st.r[VR_LOC + 6 * i + k];
}
