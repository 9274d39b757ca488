/* Interface between the generic FMI 2.0 Co-Simulation wrapper (fmi2_base.c) and one model
 * (compensator.c or machine.c).
 *
 * Every value an importer can see lives in the plain-old-data ModelState, indexed by value
 * reference, so that FMU state get/set/serialize is a byte copy of that struct.  Anything loaded
 * from the resources (machine description, error tables) is read-only after initialisation and
 * lives in the Instance, outside the state.
 */
#ifndef MTCOMP_MODEL_H
#define MTCOMP_MODEL_H

#include <stddef.h>
#include <stdint.h>

#include "fmi2Functions.h"
#include "mtk.h"

#define MODEL_NR 320      /* Real value references 0..319 */
#define MODEL_NI 16       /* Integer value references 0..15 */
#define MODEL_NS 4        /* String value references 0..3 */
#define MODEL_SLEN 512    /* capacity of one String variable, bytes */
#define MODEL_NX 2048     /* model-internal states (servo, backlash, temperature, command history ...) */
#define MODEL_GUIDLEN 64  /* capacity of the GUID text, bytes */

/* What an importer may do with a value reference (FMI 2.0 causality/variability rules). */
enum { VAR_NONE = 0, VAR_PARAM_FIXED, VAR_PARAM_TUNABLE, VAR_INPUT, VAR_OUTPUT };

enum { MODE_INSTANTIATED = 0, MODE_INIT, MODE_STEP, MODE_TERMINATED, MODE_ERROR };

typedef struct {
    uint32_t magic;            /* identifies a serialized state of this model and layout */
    uint32_t size;
    char guid[MODEL_GUIDLEN];  /* GUID of the FMU the state was taken from: states of another
                                * build (another machine, other errors) are refused */
    int mode;
    double time;
    double r[MODEL_NR];
    int i[MODEL_NI];
    char s[MODEL_NS][MODEL_SLEN];
    double x[MODEL_NX];
    uint64_t rng[2];
    int dirty;                 /* outputs must be recomputed from the inputs */
} ModelState;

typedef struct Instance {
    ModelState st;
    char name[128];
    char resources[2048];      /* resource directory as a plain path, with trailing '/' */
    char guid[MODEL_GUIDLEN];  /* this FMU's GUID as written in resources/start.txt ("": unknown) */
    const fmi2CallbackFunctions *cb;
    int logging;
    mtk_model *kin;            /* loaded at exit of initialisation, read-only afterwards */
} Instance;

/* Implemented by the generic wrapper. */
void inst_log(Instance *inst, fmi2Status status, const char *category, const char *fmt, ...);

/* Implemented by each model. */
extern const uint32_t MODEL_MAGIC;
void model_defaults(Instance *inst);
int model_real_kind(const Instance *inst, unsigned vr);
int model_int_kind(const Instance *inst, unsigned vr);
int model_string_kind(const Instance *inst, unsigned vr);
/* Validate a real value before it is stored (NaN, range); returns fmi2OK or fmi2Error. */
fmi2Status model_check_real(Instance *inst, unsigned vr, double value);
/* Validate an integer value before it is stored (range); returns fmi2OK or fmi2Error. */
fmi2Status model_check_int(Instance *inst, unsigned vr, int value);
/* Load resources, validate all parameters and compute initial outputs. */
fmi2Status model_exit_init(Instance *inst);
/* Recompute the outputs that depend directly on inputs (called when outputs are read). */
fmi2Status model_update(Instance *inst);
fmi2Status model_do_step(Instance *inst, double t, double h);

#endif
