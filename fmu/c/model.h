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

#include "mtcomp_fmi.h"   /* written by the build: MTCOMP_FMI_VERSION, the FMI version of this binary */
#if MTCOMP_FMI_VERSION == 3
/* An FMI 3.0 binary runs the FMI 2.0 layer (fmi2_base.c) internally: its functions are declared
 * here without the export attribute fmi2Functions.h gives them, so that the binary exports only
 * fmi3* functions (a DLL exports only what is marked dllexport; -fvisibility=hidden on ELF). */
#include "fmi2TypesPlatform.h"
#include "fmi2FunctionTypes.h"
#define fmi2Version "2.0"
#if defined(__GNUC__) && !defined(_WIN32)
#define FMI2_INTERNAL __attribute__((visibility("hidden")))
#else
#define FMI2_INTERNAL
#endif
FMI2_INTERNAL fmi2GetTypesPlatformTYPE fmi2GetTypesPlatform;
FMI2_INTERNAL fmi2GetVersionTYPE fmi2GetVersion;
FMI2_INTERNAL fmi2SetDebugLoggingTYPE fmi2SetDebugLogging;
FMI2_INTERNAL fmi2InstantiateTYPE fmi2Instantiate;
FMI2_INTERNAL fmi2FreeInstanceTYPE fmi2FreeInstance;
FMI2_INTERNAL fmi2SetupExperimentTYPE fmi2SetupExperiment;
FMI2_INTERNAL fmi2EnterInitializationModeTYPE fmi2EnterInitializationMode;
FMI2_INTERNAL fmi2ExitInitializationModeTYPE fmi2ExitInitializationMode;
FMI2_INTERNAL fmi2TerminateTYPE fmi2Terminate;
FMI2_INTERNAL fmi2ResetTYPE fmi2Reset;
FMI2_INTERNAL fmi2GetRealTYPE fmi2GetReal;
FMI2_INTERNAL fmi2GetIntegerTYPE fmi2GetInteger;
FMI2_INTERNAL fmi2GetBooleanTYPE fmi2GetBoolean;
FMI2_INTERNAL fmi2GetStringTYPE fmi2GetString;
FMI2_INTERNAL fmi2SetRealTYPE fmi2SetReal;
FMI2_INTERNAL fmi2SetIntegerTYPE fmi2SetInteger;
FMI2_INTERNAL fmi2SetBooleanTYPE fmi2SetBoolean;
FMI2_INTERNAL fmi2SetStringTYPE fmi2SetString;
FMI2_INTERNAL fmi2GetFMUstateTYPE fmi2GetFMUstate;
FMI2_INTERNAL fmi2SetFMUstateTYPE fmi2SetFMUstate;
FMI2_INTERNAL fmi2FreeFMUstateTYPE fmi2FreeFMUstate;
FMI2_INTERNAL fmi2SerializedFMUstateSizeTYPE fmi2SerializedFMUstateSize;
FMI2_INTERNAL fmi2SerializeFMUstateTYPE fmi2SerializeFMUstate;
FMI2_INTERNAL fmi2DeSerializeFMUstateTYPE fmi2DeSerializeFMUstate;
FMI2_INTERNAL fmi2GetDirectionalDerivativeTYPE fmi2GetDirectionalDerivative;
FMI2_INTERNAL fmi2SetRealInputDerivativesTYPE fmi2SetRealInputDerivatives;
FMI2_INTERNAL fmi2GetRealOutputDerivativesTYPE fmi2GetRealOutputDerivatives;
FMI2_INTERNAL fmi2DoStepTYPE fmi2DoStep;
FMI2_INTERNAL fmi2CancelStepTYPE fmi2CancelStep;
FMI2_INTERNAL fmi2GetStatusTYPE fmi2GetStatus;
FMI2_INTERNAL fmi2GetRealStatusTYPE fmi2GetRealStatus;
FMI2_INTERNAL fmi2GetIntegerStatusTYPE fmi2GetIntegerStatus;
FMI2_INTERNAL fmi2GetBooleanStatusTYPE fmi2GetBooleanStatus;
FMI2_INTERNAL fmi2GetStringStatusTYPE fmi2GetStringStatus;
#else
#include "fmi2Functions.h"
#endif
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
    const char *api;           /* "fmi2" or "fmi3": the prefix of the function names in log messages */
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
