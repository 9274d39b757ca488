/* Generic FMI 2.0 Co-Simulation wrapper shared by the mtcomp FMUs.
 *
 * Written by hand because it is the thin, model-independent part every native FMU needs: the
 * state machine of the FMI 2.0 standard, value access by reference with causality checks,
 * logging through the importer's callback, and FMU state get/set/serialize as a byte copy of
 * ModelState.  The model (compensator.c, machine.c) supplies the hooks declared in model.h.
 */
#include <ctype.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "model.h"

#define UNUSED(x) (void)(x)

static fmi2Status check_parameters(Instance *inst);
static int state_is_valid(Instance *inst, const ModelState *st);

void inst_log(Instance *inst, fmi2Status status, const char *category, const char *fmt, ...)
{
    char msg[1024];
    va_list ap;
    size_t k;
    if (!inst || !inst->cb || !inst->cb->logger) return;
    /* Warnings and errors are always reported; info only with debug logging on. */
    if (status == fmi2OK && !inst->logging) return;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    /* The importer treats the message as a printf format: neutralise '%'. */
    for (k = 0; msg[k]; k++)
        if (msg[k] == '%') msg[k] = ' ';
    inst->cb->logger(inst->cb->componentEnvironment, inst->name, status, category, msg);
}

static int uri_to_path(const char *uri, char *out, size_t cap)
{
    const char *p = uri;
    size_t n = 0;
    if (!uri) return 0;
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        /* file://localhost/path or file:///path */
        if (strncmp(p, "localhost/", 10) == 0) p += 9;
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
    }
#ifdef _WIN32
    if (p[0] == '/' && isalpha((unsigned char)p[1]) && p[2] == ':') p++;
#endif
    while (*p && n + 2 < cap) {
        if (p[0] == '%' && isxdigit((unsigned char)p[1]) && isxdigit((unsigned char)p[2])) {
            char hex[3] = {p[1], p[2], 0};
            out[n++] = (char)strtol(hex, NULL, 16);
            p += 3;
        } else {
            out[n++] = *p++;
        }
    }
    if (*p) {            /* longer than the buffer: a truncated path would name another file */
        out[0] = 0;
        return 0;
    }
    if (n > 0 && out[n - 1] != '/') out[n++] = '/';
    out[n] = 0;
    return 1;
}

/* ---------------------------------------------------------------- inquiry, logging */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    Instance *inst = (Instance *)c;
    UNUSED(nCategories);
    UNUSED(categories);
    if (!inst) return fmi2Error;
    inst->logging = loggingOn ? 1 : 0;
    inst->api = "fmi2";
    return fmi2OK;
}

/* ---------------------------------------------------------------- life cycle */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance *inst;
    UNUSED(visible);
    if (fmuType != fmi2CoSimulation) return NULL;  /* Co-Simulation only */
    inst = (Instance *)calloc(1, sizeof(Instance));
    if (!inst) return NULL;
    snprintf(inst->name, sizeof inst->name, "%s", instanceName ? instanceName : "mtcomp");
    inst->cb = functions;
    inst->logging = loggingOn ? 1 : 0;
    if (!fmuResourceLocation || !uri_to_path(fmuResourceLocation, inst->resources, sizeof inst->resources))
        inst->resources[0] = 0;
    inst->st.magic = MODEL_MAGIC;
    inst->st.size = (uint32_t)sizeof(ModelState);
    inst->st.mode = MODE_INSTANTIATED;
    model_defaults(inst);
    /* The importer passes the GUID of the modelDescription.xml it read; the resources carry the
     * GUID of the build they belong to.  A mismatch means parts of two different FMUs. */
    if (inst->guid[0] && (!fmuGUID || strcmp(fmuGUID, inst->guid) != 0)) {
        inst_log(inst, fmi2Error, "logError",
                 "fmuGUID '%s' is not the GUID of this FMU ('%s'): modelDescription.xml and resources "
                 "come from different builds", fmuGUID ? fmuGUID : "(none)", inst->guid);
        mtk_free(inst->kin);
        free(inst);
        return NULL;
    }
    snprintf(inst->st.guid, sizeof inst->st.guid, "%s", fmuGUID ? fmuGUID : "");
    inst->st.dirty = 1;
    inst_log(inst, fmi2OK, "logAll", "instantiated, resources at '%s'", inst->resources);
    return inst;
}

void fmi2FreeInstance(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!inst) return;
    mtk_free(inst->kin);
    free(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    Instance *inst = (Instance *)c;
    UNUSED(toleranceDefined);
    UNUSED(tolerance);
    UNUSED(stopTimeDefined);
    UNUSED(stopTime);
    if (!inst) return fmi2Error;
    if (inst->st.mode != MODE_INSTANTIATED) {
        inst_log(inst, fmi2Error, "logStatusError", "%s", inst->api[3] == '3' ? "fmi3EnterInitializationMode called twice or too late"
                 : "fmi2SetupExperiment is only allowed after fmi2Instantiate");
        return fmi2Error;
    }
    if (!isfinite(startTime)) {
        inst_log(inst, fmi2Error, "logStatusError", "start time must be finite, got %g", startTime);
        return fmi2Error;
    }
    inst->st.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    if (inst->st.mode != MODE_INSTANTIATED) {
        inst_log(inst, fmi2Error, "logStatusError", "%sEnterInitializationMode called twice or too late", inst->api);
        return fmi2Error;
    }
    inst->st.mode = MODE_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    fmi2Status s;
    if (!inst) return fmi2Error;
    if (inst->st.mode != MODE_INIT) {
        inst_log(inst, fmi2Error, "logStatusError", "%sExitInitializationMode outside initialization mode", inst->api);
        return fmi2Error;
    }
    s = check_parameters(inst);
    if (s == fmi2OK) s = model_exit_init(inst);
    if (s > fmi2Warning) {
        inst->st.mode = MODE_ERROR;
        return s;
    }
    inst->st.mode = MODE_STEP;
    inst->st.dirty = 1;
    return s;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    inst->st.mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    char guid[MODEL_GUIDLEN];
    if (!inst) return fmi2Error;
    mtk_free(inst->kin);
    inst->kin = NULL;
    memcpy(guid, inst->st.guid, sizeof guid);
    memset(&inst->st, 0, sizeof inst->st);
    memcpy(inst->st.guid, guid, sizeof guid);
    inst->st.magic = MODEL_MAGIC;
    inst->st.size = (uint32_t)sizeof(ModelState);
    inst->st.mode = MODE_INSTANTIATED;
    model_defaults(inst);
    inst->st.dirty = 1;
    return fmi2OK;
}

/* ---------------------------------------------------------------- values */

/* Every Real parameter through the model's range checks: start values come from
 * resources/start.txt, which fmi2SetReal never saw. */
static fmi2Status check_parameters(Instance *inst)
{
    unsigned vr;
    for (vr = 0; vr < MODEL_NR; vr++) {
        int kind = model_real_kind(inst, vr);
        if ((kind == VAR_PARAM_FIXED || kind == VAR_PARAM_TUNABLE) &&
            model_check_real(inst, vr, inst->st.r[vr]) != fmi2OK)
            return fmi2Error;
    }
    for (vr = 0; vr < MODEL_NI; vr++) {
        int kind = model_int_kind(inst, vr);
        if ((kind == VAR_PARAM_FIXED || kind == VAR_PARAM_TUNABLE) &&
            model_check_int(inst, vr, inst->st.i[vr]) != fmi2OK)
            return fmi2Error;
    }
    return fmi2OK;
}

static fmi2Status refresh(Instance *inst)
{
    fmi2Status s = fmi2OK;
    if (inst->st.mode == MODE_STEP && inst->st.dirty) {
        s = model_update(inst);
        if (s <= fmi2Warning) inst->st.dirty = 0;
    } else if (inst->st.mode == MODE_INIT && inst->st.dirty) {
        /* Initial outputs requested in initialization mode: initialise with what is set so
         * far (repeated, with the final values, when initialization mode ends). */
        s = check_parameters(inst);
        if (s == fmi2OK) s = model_exit_init(inst);
        if (s <= fmi2Warning) inst->st.dirty = 0;
    }
    return s;
}

static int may_set(Instance *inst, int kind, const char *type, unsigned vr)
{
    int mode = inst->st.mode;
    int ok = 0;
    if (kind == VAR_INPUT) ok = (mode != MODE_TERMINATED && mode != MODE_ERROR);
    else if (kind == VAR_PARAM_FIXED) ok = (mode == MODE_INSTANTIATED || mode == MODE_INIT);
    else if (kind == VAR_PARAM_TUNABLE) ok = (mode != MODE_TERMINATED && mode != MODE_ERROR);
    if (!ok)
        inst_log(inst, fmi2Error, "logStatusError",
                 kind == VAR_NONE ? "%s value reference %u does not exist"
                 : kind == VAR_OUTPUT ? "%s value reference %u is an output and cannot be set"
                 : "%s value reference %u cannot be set in the current state", type, vr);
    return ok;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    fmi2Status s;
    size_t k;
    if (!inst) return fmi2Error;
    s = refresh(inst);
    for (k = 0; k < nvr; k++) {
        if (vr[k] >= MODEL_NR || model_real_kind(inst, vr[k]) == VAR_NONE) {
            inst_log(inst, fmi2Error, "logStatusError", "Real value reference %u does not exist", vr[k]);
            return fmi2Error;
        }
        value[k] = inst->st.r[vr[k]];
    }
    return s;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    Instance *inst = (Instance *)c;
    fmi2Status s;
    size_t k;
    if (!inst) return fmi2Error;
    s = refresh(inst);
    for (k = 0; k < nvr; k++) {
        if (vr[k] >= MODEL_NI || model_int_kind(inst, vr[k]) == VAR_NONE) {
            inst_log(inst, fmi2Error, "logStatusError", "Integer value reference %u does not exist", vr[k]);
            return fmi2Error;
        }
        value[k] = inst->st.i[vr[k]];
    }
    return s;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    Instance *inst = (Instance *)c;
    UNUSED(value);
    if (!inst) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    inst_log(inst, fmi2Error, "logStatusError", "Boolean value reference %u does not exist", vr[0]);
    return fmi2Error;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!inst) return fmi2Error;
    for (k = 0; k < nvr; k++) {
        if (vr[k] >= MODEL_NS || model_string_kind(inst, vr[k]) == VAR_NONE) {
            inst_log(inst, fmi2Error, "logStatusError", "String value reference %u does not exist", vr[k]);
            return fmi2Error;
        }
        value[k] = inst->st.s[vr[k]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!inst) return fmi2Error;
    for (k = 0; k < nvr; k++) {
        int kind = vr[k] < MODEL_NR ? model_real_kind(inst, vr[k]) : VAR_NONE;
        if (!may_set(inst, kind, "Real", vr[k])) return fmi2Error;
        if (model_check_real(inst, vr[k], value[k]) != fmi2OK) return fmi2Error;
        inst->st.r[vr[k]] = value[k];
        inst->st.dirty = 1;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!inst) return fmi2Error;
    for (k = 0; k < nvr; k++) {
        int kind = vr[k] < MODEL_NI ? model_int_kind(inst, vr[k]) : VAR_NONE;
        if (!may_set(inst, kind, "Integer", vr[k])) return fmi2Error;
        if (model_check_int(inst, vr[k], value[k]) != fmi2OK) return fmi2Error;
        inst->st.i[vr[k]] = value[k];
        inst->st.dirty = 1;
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    Instance *inst = (Instance *)c;
    UNUSED(value);
    if (!inst) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    inst_log(inst, fmi2Error, "logStatusError", "Boolean value reference %u does not exist", vr[0]);
    return fmi2Error;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!inst) return fmi2Error;
    for (k = 0; k < nvr; k++) {
        int kind = vr[k] < MODEL_NS ? model_string_kind(inst, vr[k]) : VAR_NONE;
        if (!may_set(inst, kind, "String", vr[k])) return fmi2Error;
        if (!value[k] || strlen(value[k]) >= MODEL_SLEN) {
            inst_log(inst, fmi2Error, "logStatusError", "String value reference %u: value missing or longer than %d bytes",
                     vr[k], MODEL_SLEN - 1);
            return fmi2Error;
        }
        strcpy(inst->st.s[vr[k]], value[k]);
        inst->st.dirty = 1;
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------- FMU state */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    Instance *inst = (Instance *)c;
    ModelState *copy;
    if (!inst || !state) return fmi2Error;
    copy = (ModelState *)(*state ? *state : malloc(sizeof(ModelState)));
    if (!copy) return fmi2Error;
    memcpy(copy, &inst->st, sizeof(ModelState));
    *state = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state)
{
    Instance *inst = (Instance *)c;
    const ModelState *src = (const ModelState *)state;
    if (!inst || !src) return fmi2Error;
    if (!state_is_valid(inst, src)) return fmi2Error;
    /* The kinematic model loaded from the resources is not part of the state: a state taken
     * before initialisation cannot be applied to an initialised instance and vice versa. */
    if ((src->mode == MODE_STEP) != (inst->st.mode == MODE_STEP) || (src->mode == MODE_STEP && !inst->kin)) {
        inst_log(inst, fmi2Error, "logStatusError",
                 "FMU state and instance must both be initialised (or both not) to restore a state");
        return fmi2Error;
    }
    memcpy(&inst->st, src, sizeof(ModelState));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    UNUSED(c);
    if (state && *state) {
        free(*state);
        *state = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size)
{
    UNUSED(state);
    if (!size) {
        inst_log((Instance *)c, fmi2Error, "logStatusError", "%sSerializedFMUstateSize: size is NULL", c ? ((Instance *)c)->api : "fmi2");
        return fmi2Error;
    }
    *size = sizeof(ModelState);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size)
{
    Instance *inst = (Instance *)c;
    if (!inst || !state) return fmi2Error;
    if (size < sizeof(ModelState)) {
        inst_log(inst, fmi2Error, "logStatusError", "buffer too small to serialize the FMU state");
        return fmi2Error;
    }
    memcpy(bytes, state, sizeof(ModelState));
    return fmi2OK;
}

/* A state from outside (de-serialized bytes, or a state handed back by the importer) is used
 * only if it belongs to this FMU (magic, size, GUID) and every value in it is one the FMU
 * would have accepted through its setters: a valid mode, terminated String values, finite
 * numbers, parameters and inputs within their ranges.  Logs what is wrong. */
static int state_is_valid(Instance *inst, const ModelState *st)
{
    unsigned vr;
    int k;
    if (st->magic != MODEL_MAGIC || st->size != sizeof(ModelState)) {
        inst_log(inst, fmi2Error, "logStatusError", "FMU state belongs to another model or build");
        return 0;
    }
    if (!memchr(st->guid, 0, MODEL_GUIDLEN) || strcmp(st->guid, inst->st.guid) != 0) {
        char shown[MODEL_GUIDLEN];   /* the bytes come from outside: log printable ASCII only */
        for (k = 0; k < MODEL_GUIDLEN - 1 && st->guid[k]; k++)
            shown[k] = (st->guid[k] >= 32 && st->guid[k] < 127) ? st->guid[k] : '?';
        shown[k] = 0;
        inst_log(inst, fmi2Error, "logStatusError", "FMU state was taken from another FMU (GUID '%s', this FMU '%s')",
                 shown, inst->st.guid);
        return 0;
    }
    if (st->mode < MODE_INSTANTIATED || st->mode > MODE_ERROR) {
        inst_log(inst, fmi2Error, "logStatusError", "FMU state is corrupt: unknown mode %d", st->mode);
        return 0;
    }
    for (k = 0; k < MODEL_NS; k++)
        if (!memchr(st->s[k], 0, MODEL_SLEN)) {
            inst_log(inst, fmi2Error, "logStatusError", "FMU state is corrupt: String value %d is not terminated", k);
            return 0;
        }
    if (!isfinite(st->time)) {
        inst_log(inst, fmi2Error, "logStatusError", "FMU state is corrupt: time is not finite");
        return 0;
    }
    for (k = 0; k < MODEL_NX; k++)
        if (!isfinite(st->x[k])) {
            inst_log(inst, fmi2Error, "logStatusError", "FMU state is corrupt: internal state %d is not finite", k);
            return 0;
        }
    for (vr = 0; vr < MODEL_NR; vr++) {
        int kind = model_real_kind(inst, vr);
        if (kind == VAR_NONE) continue;
        if (kind != VAR_OUTPUT && model_check_real(inst, vr, st->r[vr]) != fmi2OK) {
            inst_log(inst, fmi2Error, "logStatusError", "FMU state refused: value reference %u out of range", vr);
            return 0;
        }
        if (!isfinite(st->r[vr])) {
            inst_log(inst, fmi2Error, "logStatusError", "FMU state is corrupt: output %u is not finite", vr);
            return 0;
        }
    }
    for (vr = 0; vr < MODEL_NI; vr++) {
        int kind = model_int_kind(inst, vr);
        if (kind != VAR_NONE && kind != VAR_OUTPUT && model_check_int(inst, vr, st->i[vr]) != fmi2OK) {
            inst_log(inst, fmi2Error, "logStatusError",
                     "FMU state refused: Integer value reference %u out of range", vr);
            return 0;
        }
    }
    return 1;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state)
{
    Instance *inst = (Instance *)c;
    ModelState tmp;
    if (!inst || !state) return fmi2Error;
    if (size != sizeof(ModelState)) {
        inst_log(inst, fmi2Error, "logStatusError", "serialized FMU state has %lu bytes, expected %lu",
                 (unsigned long)size, (unsigned long)sizeof(ModelState));
        return fmi2Error;
    }
    memcpy(&tmp, bytes, sizeof tmp);
    /* The bytes come from outside: checked here, and again when the state is set. */
    if (!state_is_valid(inst, &tmp)) return fmi2Error;
    if (!*state) *state = malloc(sizeof(ModelState));
    if (!*state) return fmi2Error;
    memcpy(*state, &tmp, sizeof tmp);
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    UNUSED(vUnknown_ref); UNUSED(nUnknown); UNUSED(vKnown_ref); UNUSED(nKnown);
    UNUSED(dvKnown); UNUSED(dvUnknown);
    inst_log((Instance *)c, fmi2Error, "logStatusError", "directional derivatives are not provided");
    return fmi2Error;
}

/* ---------------------------------------------------------------- co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(order); UNUSED(value);
    inst_log((Instance *)c, fmi2Error, "logStatusError", "input derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(order); UNUSED(value);
    inst_log((Instance *)c, fmi2Error, "logStatusError", "output derivatives are not supported");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    Instance *inst = (Instance *)c;
    fmi2Status s;
    UNUSED(noSetFMUStatePriorToCurrentPoint);
    if (!inst) return fmi2Error;
    if (inst->st.mode != MODE_STEP) {
        inst_log(inst, fmi2Error, "logStatusError", "%sDoStep outside step mode (initialisation failed or not done)", inst->api);
        return fmi2Error;
    }
    if (!(communicationStepSize > 0.0) || !isfinite(communicationStepSize)) {
        inst_log(inst, fmi2Error, "logStatusError", "communication step size must be positive and finite");
        return fmi2Error;
    }
    if (!isfinite(currentCommunicationPoint)) {
        inst_log(inst, fmi2Error, "logStatusError", "communication point must be finite, got %g",
                 currentCommunicationPoint);
        return fmi2Error;
    }
    if (fabs(currentCommunicationPoint - inst->st.time) > 1e-9 * (1.0 + fabs(inst->st.time))) {
        inst_log(inst, fmi2Error, "logStatusError", "%sDoStep at t=%g but the FMU is at t=%g", inst->api,
                 currentCommunicationPoint, inst->st.time);
        return fmi2Error;
    }
    s = model_do_step(inst, currentCommunicationPoint, communicationStepSize);
    if (s > fmi2Warning) {
        inst->st.mode = MODE_ERROR;
        return s;
    }
    /* The model marks its outputs dirty if they change with time. */
    inst->st.time = currentCommunicationPoint + communicationStepSize;
    return s;
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    UNUSED(c);
    return fmi2Error;  /* doStep always completes synchronously */
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    UNUSED(c); UNUSED(s); UNUSED(value);
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    if (s == fmi2LastSuccessfulTime) {
        *value = inst->st.time;
        return fmi2OK;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    UNUSED(c); UNUSED(s); UNUSED(value);
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    UNUSED(c); UNUSED(s); UNUSED(value);
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    UNUSED(c); UNUSED(s); UNUSED(value);
    return fmi2Discard;
}
