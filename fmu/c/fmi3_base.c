/* FMI 3.0 Co-Simulation interface of the mtcomp FMUs, as a thin layer over the FMI 2.0 wrapper.
 *
 * Written by hand: the FMI 3.0 calls map one to one onto the FMI 2.0 implementation in
 * fmi2_base.c (same model, same state machine, same checks); what differs is the value
 * reference space (unique across types in FMI 3.0: Float64 = FMI 2.0 Real reference,
 * Int32 = 1000 + Integer reference, String = 2000 + String reference, time = 3000), the
 * logging callback and the resource path (a plain path).  Everything FMI 3.0 adds that a
 * co-simulation block without events does not use (clocks, event mode, other types,
 * Model Exchange, Scheduled Execution) returns fmi3Error with a log message.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "model.h"
#include "fmi3Functions.h"

#define VR3_INT 1000u
#define VR3_STRING 2000u
#define VR3_TIME 3000u
#define UNUSED(x) (void)(x)

/* The FMI 2.0 callbacks handed to fmi2Instantiate, followed by the FMI 3.0 logger they forward to.
 * Instance.cb points to `fmi2`, the first member, so the wrapper is found from the instance. */
typedef struct {
    fmi2CallbackFunctions fmi2;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
} Callbacks3;

static void forward_log(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                        fmi2String message, ...)
{
    Callbacks3 *w = (Callbacks3 *)env;
    UNUSED(name);
    if (w && w->log) w->log(w->env, (fmi3Status)status, category, message);
}

static Instance *I(fmi3Instance instance) { return (Instance *)instance; }

static fmi3Status unsupported(fmi3Instance instance, const char *what)
{
    inst_log(I(instance), fmi2Error, "logStatusError", "%s is not supported by this FMU", what);
    return fmi3Error;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    return (fmi3Status)fmi2SetDebugLogging(instance, loggingOn, nCategories, categories);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage)
{
    UNUSED(instanceName); UNUSED(instantiationToken); UNUSED(resourcePath); UNUSED(visible);
    UNUSED(loggingOn); UNUSED(instanceEnvironment); UNUSED(logMessage);
    return NULL;  /* Co-Simulation only */
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate)
{
    Callbacks3 *w;
    fmi2Component c;
    char *uri = NULL;
    UNUSED(earlyReturnAllowed); UNUSED(requiredIntermediateVariables); UNUSED(nRequiredIntermediateVariables);
    UNUSED(intermediateUpdate);
    if (eventModeUsed) {
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError", "event mode is not supported by this FMU");
        return NULL;
    }
    w = (Callbacks3 *)calloc(1, sizeof *w);
    if (!w) return NULL;
    w->fmi2.logger = forward_log;
    w->fmi2.componentEnvironment = w;
    w->env = instanceEnvironment;
    w->log = logMessage;
    if (resourcePath) {
        /* FMI 3.0 gives a plain path, the FMI 2.0 wrapper expects a URI: escape '%' so that a
         * folder named like "a%41" is not decoded into another one */
        const char *p;
        char *o;
        uri = (char *)malloc(3 * strlen(resourcePath) + 8);
        if (!uri) {
            free(w);
            return NULL;
        }
        o = uri + sprintf(uri, "file://");
        for (p = resourcePath; *p; p++) {
            if (*p == '%') {
                memcpy(o, "%25", 3);
                o += 3;
            } else {
                *o++ = *p;
            }
        }
        *o = 0;
    }
    c = fmi2Instantiate(instanceName, fmi2CoSimulation, instantiationToken, uri, &w->fmi2, visible, loggingOn);
    free(uri);
    if (!c) free(w);
    else ((Instance *)c)->api = "fmi3";
    return c;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption)
{
    UNUSED(instanceName); UNUSED(instantiationToken); UNUSED(resourcePath); UNUSED(visible); UNUSED(loggingOn);
    UNUSED(instanceEnvironment); UNUSED(logMessage); UNUSED(clockUpdate); UNUSED(lockPreemption);
    UNUSED(unlockPreemption);
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance)
{
    Callbacks3 *w;
    if (!instance) return;
    w = (Callbacks3 *)I(instance)->cb;
    fmi2FreeInstance(instance);
    free(w);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    fmi2Status s = fmi2SetupExperiment(instance, toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime);
    if (s > fmi2Warning) return (fmi3Status)s;
    return (fmi3Status)fmi2EnterInitializationMode(instance);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) { return (fmi3Status)fmi2ExitInitializationMode(instance); }
fmi3Status fmi3EnterEventMode(fmi3Instance instance) { return unsupported(instance, "event mode"); }
fmi3Status fmi3Terminate(fmi3Instance instance) { return (fmi3Status)fmi2Terminate(instance); }
fmi3Status fmi3Reset(fmi3Instance instance) { return (fmi3Status)fmi2Reset(instance); }

/* ---------------------------------------------------------------- values */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues)
{
    size_t k;
    fmi2Status s = fmi2OK;
    if (!instance || nValues < nvr) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        if (vr[k] == VR3_TIME) {
            values[k] = I(instance)->st.time;
        } else {
            fmi2Status sk = fmi2GetReal(instance, &vr[k], 1, &values[k]);
            if (sk > fmi2Warning) return (fmi3Status)sk;
            if (sk > s) s = sk;
        }
    }
    return (fmi3Status)s;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues)
{
    size_t k;
    if (!instance || nValues < nvr) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        fmi2Status s;
        if (vr[k] == VR3_TIME) return unsupported(instance, "setting the independent variable");
        s = fmi2SetReal(instance, &vr[k], 1, &values[k]);
        if (s > fmi2Warning) return (fmi3Status)s;
    }
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues)
{
    size_t k;
    if (!instance || nValues < nvr) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        fmi2ValueReference r = vr[k] >= VR3_INT ? vr[k] - VR3_INT : 0xffffffffu;
        fmi2Integer v;
        fmi2Status s = fmi2GetInteger(instance, &r, 1, &v);
        if (s > fmi2Warning) return (fmi3Status)s;
        values[k] = v;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 values[],
                        size_t nValues)
{
    size_t k;
    if (!instance || nValues < nvr) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        fmi2ValueReference r = vr[k] >= VR3_INT ? vr[k] - VR3_INT : 0xffffffffu;
        fmi2Integer v = values[k];
        fmi2Status s = fmi2SetInteger(instance, &r, 1, &v);
        if (s > fmi2Warning) return (fmi3Status)s;
    }
    return fmi3OK;
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3String values[],
                         size_t nValues)
{
    size_t k;
    if (!instance || nValues < nvr) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        fmi2ValueReference r = vr[k] >= VR3_STRING ? vr[k] - VR3_STRING : 0xffffffffu;
        fmi2Status s = fmi2GetString(instance, &r, 1, &values[k]);
        if (s > fmi2Warning) return (fmi3Status)s;
    }
    return fmi3OK;
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3String values[],
                         size_t nValues)
{
    size_t k;
    if (!instance || nValues < nvr) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        fmi2ValueReference r = vr[k] >= VR3_STRING ? vr[k] - VR3_STRING : 0xffffffffu;
        fmi2Status s = fmi2SetString(instance, &r, 1, &values[k]);
        if (s > fmi2Warning) return (fmi3Status)s;
    }
    return fmi3OK;
}

/* Types this FMU has no variables of: only empty requests succeed. */
#define NO_SUCH_TYPE(NAME, CONSTQ, T)                                                                  \
    fmi3Status NAME(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, CONSTQ T values[], \
                    size_t nValues)                                                                    \
    {                                                                                                  \
        UNUSED(vr); UNUSED(values); UNUSED(nValues);                                                   \
        return nvr == 0 ? fmi3OK : unsupported(instance, #NAME " (the FMU has no such variables)");     \
    }

NO_SUCH_TYPE(fmi3GetFloat32, , fmi3Float32)
NO_SUCH_TYPE(fmi3GetInt8, , fmi3Int8)
NO_SUCH_TYPE(fmi3GetUInt8, , fmi3UInt8)
NO_SUCH_TYPE(fmi3GetInt16, , fmi3Int16)
NO_SUCH_TYPE(fmi3GetUInt16, , fmi3UInt16)
NO_SUCH_TYPE(fmi3GetUInt32, , fmi3UInt32)
NO_SUCH_TYPE(fmi3GetInt64, , fmi3Int64)
NO_SUCH_TYPE(fmi3GetUInt64, , fmi3UInt64)
NO_SUCH_TYPE(fmi3GetBoolean, , fmi3Boolean)
NO_SUCH_TYPE(fmi3SetFloat32, const, fmi3Float32)
NO_SUCH_TYPE(fmi3SetInt8, const, fmi3Int8)
NO_SUCH_TYPE(fmi3SetUInt8, const, fmi3UInt8)
NO_SUCH_TYPE(fmi3SetInt16, const, fmi3Int16)
NO_SUCH_TYPE(fmi3SetUInt16, const, fmi3UInt16)
NO_SUCH_TYPE(fmi3SetUInt32, const, fmi3UInt32)
NO_SUCH_TYPE(fmi3SetInt64, const, fmi3Int64)
NO_SUCH_TYPE(fmi3SetUInt64, const, fmi3UInt64)
NO_SUCH_TYPE(fmi3SetBoolean, const, fmi3Boolean)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues)
{
    UNUSED(vr); UNUSED(valueSizes); UNUSED(values); UNUSED(nValues);
    return nvr == 0 ? fmi3OK : unsupported(instance, "fmi3GetBinary (the FMU has no such variables)");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues)
{
    UNUSED(vr); UNUSED(valueSizes); UNUSED(values); UNUSED(nValues);
    return nvr == 0 ? fmi3OK : unsupported(instance, "fmi3SetBinary (the FMU has no such variables)");
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{
    UNUSED(vr); UNUSED(values);
    return nvr == 0 ? fmi3OK : unsupported(instance, "clocks");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
{
    UNUSED(vr); UNUSED(values);
    return nvr == 0 ? fmi3OK : unsupported(instance, "clocks");
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies)
{
    UNUSED(valueReference); UNUSED(nDependencies);
    return unsupported(instance, "variable dependency information");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies)
{
    UNUSED(dependent); UNUSED(elementIndicesOfDependent); UNUSED(independents);
    UNUSED(elementIndicesOfIndependents); UNUSED(dependencyKinds); UNUSED(nDependencies);
    return unsupported(instance, "variable dependency information");
}

/* ---------------------------------------------------------------- FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)fmi2GetFMUstate(instance, (fmi2FMUstate *)FMUState);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    return (fmi3Status)fmi2SetFMUstate(instance, (fmi2FMUstate)FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return (fmi3Status)fmi2FreeFMUstate(instance, (fmi2FMUstate *)FMUState);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    return (fmi3Status)fmi2SerializedFMUstateSize(instance, (fmi2FMUstate)FMUState, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[], size_t size)
{
    return (fmi3Status)fmi2SerializeFMUstate(instance, (fmi2FMUstate)FMUState, (fmi2Byte *)serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState)
{
    return (fmi3Status)fmi2DeSerializeFMUstate(instance, (const fmi2Byte *)serializedState, size,
                                               (fmi2FMUstate *)FMUState);
}

/* ---------------------------------------------------------------- not provided */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    UNUSED(unknowns); UNUSED(nUnknowns); UNUSED(knowns); UNUSED(nKnowns); UNUSED(seed); UNUSED(nSeed);
    UNUSED(sensitivity); UNUSED(nSensitivity);
    return unsupported(instance, "directional derivatives");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    UNUSED(unknowns); UNUSED(nUnknowns); UNUSED(knowns); UNUSED(nKnowns); UNUSED(seed); UNUSED(nSeed);
    UNUSED(sensitivity); UNUSED(nSensitivity);
    return unsupported(instance, "adjoint derivatives");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) { return unsupported(instance, "configuration mode"); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) { return unsupported(instance, "configuration mode"); }

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(intervals); UNUSED(qualifiers);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(counters); UNUSED(resolutions); UNUSED(qualifiers);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 shifts[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(shifts);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(counters); UNUSED(resolutions);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(intervals);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(counters); UNUSED(resolutions);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(shifts);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    UNUSED(vr); UNUSED(nvr); UNUSED(counters); UNUSED(resolutions);
    return unsupported(instance, "clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) { return unsupported(instance, "event mode"); }

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime)
{
    UNUSED(discreteStatesNeedUpdate); UNUSED(terminateSimulation); UNUSED(nominalsOfContinuousStatesChanged);
    UNUSED(valuesOfContinuousStatesChanged); UNUSED(nextEventTimeDefined); UNUSED(nextEventTime);
    return unsupported(instance, "event mode");
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) { return unsupported(instance, "Model Exchange"); }

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    UNUSED(noSetFMUStatePriorToCurrentPoint); UNUSED(enterEventMode); UNUSED(terminateSimulation);
    return unsupported(instance, "Model Exchange");
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    UNUSED(time);
    return unsupported(instance, "Model Exchange");
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 x[], size_t nx)
{
    UNUSED(x); UNUSED(nx);
    return unsupported(instance, "Model Exchange");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[], size_t nx)
{
    UNUSED(derivatives); UNUSED(nx);
    return unsupported(instance, "Model Exchange");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t ni)
{
    UNUSED(eventIndicators); UNUSED(ni);
    return unsupported(instance, "Model Exchange");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t nx)
{
    UNUSED(x); UNUSED(nx);
    return unsupported(instance, "Model Exchange");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[], size_t nx)
{
    UNUSED(nominals); UNUSED(nx);
    return unsupported(instance, "Model Exchange");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *n)
{
    UNUSED(instance);
    *n = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *n)
{
    UNUSED(instance);
    *n = 0;
    return fmi3OK;
}

/* ---------------------------------------------------------------- co-simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    UNUSED(instance);
    return fmi3OK;  /* without event mode the FMU is in step mode after initialisation */
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
{
    UNUSED(vr); UNUSED(nvr); UNUSED(orders); UNUSED(values); UNUSED(nValues);
    return unsupported(instance, "output derivatives");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    fmi2Status s = fmi2DoStep(instance, currentCommunicationPoint, communicationStepSize,
                              noSetFMUStatePriorToCurrentPoint);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime && instance) *lastSuccessfulTime = I(instance)->st.time;
    return (fmi3Status)s;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    UNUSED(clockReference); UNUSED(activationTime);
    return unsupported(instance, "Scheduled Execution");
}
