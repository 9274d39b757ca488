/* Parameters and resources shared by the compensator and the machine FMU (see common.h). */
#if !defined(_WIN32) && !defined(_POSIX_C_SOURCE)
#define _POSIX_C_SOURCE 200809L   /* newlocale/uselocale: per-thread C numbers while parsing */
#endif
#include <locale.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "common.h"

#if defined(__APPLE__)
#include <xlocale.h>
#endif

static const char COMP[] = "XYZABC";

/* Resources are written with '.' as the decimal point, whatever the locale of the importing
 * process: a host that called setlocale(LC_ALL, "") in a comma-decimal locale would otherwise
 * read "0.35" as 0 through strtod/sscanf (here and in mtk.c).  The parsing runs with the C
 * numeric conventions of this thread only, and the host's locale is restored afterwards. */
typedef struct {
#if defined(_WIN32)
    int per_thread;
    char saved[128];
#else
    locale_t c, old;
#endif
} numeric_scope;

static void c_numbers_begin(numeric_scope *sc)
{
#if defined(_WIN32)
    const char *cur;
    sc->per_thread = _configthreadlocale(_ENABLE_PER_THREAD_LOCALE);
    cur = setlocale(LC_NUMERIC, NULL);
    snprintf(sc->saved, sizeof sc->saved, "%s", cur ? cur : "C");
    setlocale(LC_NUMERIC, "C");
#else
    sc->c = newlocale(LC_NUMERIC_MASK, "C", (locale_t)0);
    sc->old = sc->c ? uselocale(sc->c) : (locale_t)0;
#endif
}

static void c_numbers_end(numeric_scope *sc)
{
#if defined(_WIN32)
    setlocale(LC_NUMERIC, sc->saved);
    _configthreadlocale(sc->per_thread);
#else
    if (sc->c) {
        uselocale(sc->old);
        freelocale(sc->c);
    }
#endif
}

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
    if (value >= lo && value <= hi) return fmi2OK;   /* false for NaN */
    if (isnan(value)) {
        inst_log(inst, fmi2Error, "logStatusError", "%s: NaN is not a valid value", what);
        return fmi2Error;
    }
    inst_log(inst, fmi2Error, "logStatusError", "%s = %g is out of range [%g, %g]", what, value, lo, hi);
    return fmi2Error;
}

/* The check of one value by reference; the variable's name is formatted only for the message
 * of a rejected value (fmi2SetReal runs this for every value it stores). */
static fmi2Status check_vr(Instance *inst, unsigned vr, double value, double lo, double hi)
{
    char name[96];
    if (value >= lo && value <= hi) return fmi2OK;
    common_vr_name(vr, inst->kin, name, sizeof name);
    return check_range(inst, name, value, lo, hi);
}

fmi2Status common_check_real(Instance *inst, unsigned vr, double value)
{
    if (vr < VR_CMD + MTK_MAX_AXES) {
        char name[96];
        if (isfinite(value)) return fmi2OK;
        common_vr_name(vr, inst->kin, name, sizeof name);
        inst_log(inst, fmi2Error, "logStatusError", "%s = %g: axis commands must be finite", name, value);
        return fmi2Error;
    }
    if (vr >= VR_TOOL && vr < VR_TOOL + 3) return check_vr(inst, vr, value, -MAX_TOOL_OFFSET, MAX_TOOL_OFFSET);
    if (vr >= VR_WP_T && vr < VR_WP_T + 3) return check_vr(inst, vr, value, -MAX_WP_TRANSLATION, MAX_WP_TRANSLATION);
    if (vr >= VR_WP_A && vr < VR_WP_A + 3) return check_vr(inst, vr, value, -MAX_WP_ANGLE, MAX_WP_ANGLE);
    if (vr >= VR_LOC && vr < VR_LOC_END) {
        if ((vr - VR_LOC) % 6 < 3) return check_vr(inst, vr, value, -MAX_LOC_LINEAR, MAX_LOC_LINEAR);
        return check_vr(inst, vr, value, -MAX_LOC_ANGLE, MAX_LOC_ANGLE);
    }
    return fmi2OK;
}

static fmi2Status load_machine(Instance *inst)
{
    char path[sizeof inst->resources + 64], err[MTK_ERRLEN];
    numeric_scope sc;
    int rc;
    mtk_free(inst->kin);
    inst->kin = NULL;
    if (!inst->resources[0]) {
        /* no (usable) resource location: never fall back to a machine.txt in the working folder */
        inst_log(inst, fmi2Error, "logError", "no usable fmuResourceLocation: cannot read %s", MACHINE_RESOURCE);
        return fmi2Error;
    }
    snprintf(path, sizeof path, "%s%s", inst->resources, MACHINE_RESOURCE);
    c_numbers_begin(&sc);
    rc = mtk_load_machine(path, &inst->kin, err);
    c_numbers_end(&sc);
    if (rc != MTK_OK) {
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
    numeric_scope sc;
    FILE *f;
    inst->guid[0] = 0;
    if (!inst->resources[0]) return;
    snprintf(path, sizeof path, "%s%s", inst->resources, START_RESOURCE);
    f = fopen(path, "r");
    if (!f) return;
    c_numbers_begin(&sc);
    while (fgets(line, sizeof line, f)) {
        char kind;
        unsigned vr;
        int used = 0;
        if (strncmp(line, "guid ", 5) == 0) {        /* the GUID of the modelDescription */
            snprintf(inst->guid, sizeof inst->guid, "%s", line + 5);
            inst->guid[strcspn(inst->guid, "\r\n")] = 0;
            continue;
        }
        if (line[0] == '#' || sscanf(line, " %c %u %n", &kind, &vr, &used) < 2) continue;
        if (kind == 'r' && vr < MODEL_NR) inst->st.r[vr] = strtod(line + used, NULL);
        else if (kind == 'i' && vr < MODEL_NI) inst->st.i[vr] = atoi(line + used);
        else if (kind == 's' && vr < MODEL_NS) {
            char *v = line + used;
            v[strcspn(v, "\r\n")] = 0;
            snprintf(inst->st.s[vr], MODEL_SLEN, "%s", v);
        }
    }
    c_numbers_end(&sc);
    fclose(f);
}

fmi2Status common_load(Instance *inst)
{
    char spec[MODEL_SLEN], err[MTK_ERRLEN], *item, *save = NULL;
    numeric_scope sc;
    int rc;
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
        c_numbers_begin(&sc);
        rc = mtk_load_table(inst->kin, item, path, err);
        c_numbers_end(&sc);
        if (rc != MTK_OK) {
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
