/*
 * FMI 3.0 Co-Simulation glue for an ODE model  x' = f(t, x, u, p),  y = g(t, x, u, p)
 * (contract: ode_model.h), built on the FMI 2.0 glue ode_glue.c: that file is compiled
 * into this one with its functions renamed ode2_fmi2* (internal), and every
 * FMI 3.0 function below forwards to it. Integration, error control, the FMU state and the
 * directional derivatives are therefore exactly those of the FMI 2.0 ODE FMU.
 *
 * Variables: all Float64 scalars, value references as in ode_model.h (1, 2, ...), plus the
 * independent variable "time" with value reference 0 (FMI 3.0 requires one). Only
 * Co-Simulation is served (no event mode, no early return, no intermediate update);
 * fmi3InstantiateModelExchange and fmi3InstantiateScheduledExecution return NULL. Every
 * other function of the FMI 3.0 API exists (fmpy loads all of them) and fails with a log
 * message when asked for something the model does not have.
 *
 * The FMI 2.0 glue's log messages are passed on through the FMI 3.0 logMessage callback
 * (formatted: FMI 3.0 messages are plain text), with the names of FMI 2.0 calls replaced
 * by those of the FMI 3.0 calls the importer made.
 */
/* fmpy's fmi2Functions.h ignores FMI2_FUNCTION_PREFIX: rename every fmi2 function of
 * ode_glue.c by hand, so that they are internal (hidden) and only fmi3* is exported. */
#include "fmi2Functions.h"
#undef fmi2Instantiate
#define fmi2Instantiate ode2_fmi2Instantiate
#undef fmi2FreeInstance
#define fmi2FreeInstance ode2_fmi2FreeInstance
#undef fmi2SetDebugLogging
#define fmi2SetDebugLogging ode2_fmi2SetDebugLogging
#undef fmi2SetupExperiment
#define fmi2SetupExperiment ode2_fmi2SetupExperiment
#undef fmi2EnterInitializationMode
#define fmi2EnterInitializationMode ode2_fmi2EnterInitializationMode
#undef fmi2ExitInitializationMode
#define fmi2ExitInitializationMode ode2_fmi2ExitInitializationMode
#undef fmi2Terminate
#define fmi2Terminate ode2_fmi2Terminate
#undef fmi2Reset
#define fmi2Reset ode2_fmi2Reset
#undef fmi2GetReal
#define fmi2GetReal ode2_fmi2GetReal
#undef fmi2SetReal
#define fmi2SetReal ode2_fmi2SetReal
#undef fmi2DoStep
#define fmi2DoStep ode2_fmi2DoStep
#undef fmi2GetRealStatus
#define fmi2GetRealStatus ode2_fmi2GetRealStatus
#undef fmi2GetDirectionalDerivative
#define fmi2GetDirectionalDerivative ode2_fmi2GetDirectionalDerivative
#undef fmi2GetFMUstate
#define fmi2GetFMUstate ode2_fmi2GetFMUstate
#undef fmi2SetFMUstate
#define fmi2SetFMUstate ode2_fmi2SetFMUstate
#undef fmi2FreeFMUstate
#define fmi2FreeFMUstate ode2_fmi2FreeFMUstate
#undef fmi2SerializedFMUstateSize
#define fmi2SerializedFMUstateSize ode2_fmi2SerializedFMUstateSize
#undef fmi2SerializeFMUstate
#define fmi2SerializeFMUstate ode2_fmi2SerializeFMUstate
#undef fmi2DeSerializeFMUstate
#define fmi2DeSerializeFMUstate ode2_fmi2DeSerializeFMUstate
#undef fmi2CancelStep
#define fmi2CancelStep ode2_fmi2CancelStep
#undef fmi2CompletedIntegratorStep
#define fmi2CompletedIntegratorStep ode2_fmi2CompletedIntegratorStep
#undef fmi2EnterContinuousTimeMode
#define fmi2EnterContinuousTimeMode ode2_fmi2EnterContinuousTimeMode
#undef fmi2EnterEventMode
#define fmi2EnterEventMode ode2_fmi2EnterEventMode
#undef fmi2GetBoolean
#define fmi2GetBoolean ode2_fmi2GetBoolean
#undef fmi2GetBooleanStatus
#define fmi2GetBooleanStatus ode2_fmi2GetBooleanStatus
#undef fmi2GetContinuousStates
#define fmi2GetContinuousStates ode2_fmi2GetContinuousStates
#undef fmi2GetDerivatives
#define fmi2GetDerivatives ode2_fmi2GetDerivatives
#undef fmi2GetEventIndicators
#define fmi2GetEventIndicators ode2_fmi2GetEventIndicators
#undef fmi2GetInteger
#define fmi2GetInteger ode2_fmi2GetInteger
#undef fmi2GetIntegerStatus
#define fmi2GetIntegerStatus ode2_fmi2GetIntegerStatus
#undef fmi2GetNominalsOfContinuousStates
#define fmi2GetNominalsOfContinuousStates ode2_fmi2GetNominalsOfContinuousStates
#undef fmi2GetRealOutputDerivatives
#define fmi2GetRealOutputDerivatives ode2_fmi2GetRealOutputDerivatives
#undef fmi2GetStatus
#define fmi2GetStatus ode2_fmi2GetStatus
#undef fmi2GetString
#define fmi2GetString ode2_fmi2GetString
#undef fmi2GetStringStatus
#define fmi2GetStringStatus ode2_fmi2GetStringStatus
#undef fmi2GetTypesPlatform
#define fmi2GetTypesPlatform ode2_fmi2GetTypesPlatform
#undef fmi2GetVersion
#define fmi2GetVersion ode2_fmi2GetVersion
#undef fmi2NewDiscreteStates
#define fmi2NewDiscreteStates ode2_fmi2NewDiscreteStates
#undef fmi2SetBoolean
#define fmi2SetBoolean ode2_fmi2SetBoolean
#undef fmi2SetContinuousStates
#define fmi2SetContinuousStates ode2_fmi2SetContinuousStates
#undef fmi2SetInteger
#define fmi2SetInteger ode2_fmi2SetInteger
#undef fmi2SetRealInputDerivatives
#define fmi2SetRealInputDerivatives ode2_fmi2SetRealInputDerivatives
#undef fmi2SetString
#define fmi2SetString ode2_fmi2SetString
#undef fmi2SetTime
#define fmi2SetTime ode2_fmi2SetTime
/* Another FMI 2.0 glue may be wrapped (the exported controllers' fmus/controller/ctrl_glue3.c
 * defines GLUE3_INNER, GLUE3_MODEL_NAME, GLUE3_NX and GLUE3_INT32_AS_FMI2_INTEGER first). */
#ifndef GLUE3_INNER
#define GLUE3_INNER "ode_glue.c"
#define GLUE3_MODEL_NAME ODE_SPEC_MODEL_NAME
#define GLUE3_NX NX
#endif
#include GLUE3_INNER

#include "fmi3Functions.h"

typedef struct {
    fmi2CallbackFunctions cb2; /* handed to the FMI 2.0 glue; componentEnvironment = this */
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi2Component inner;
    char name[128];
} Instance3;

/* ---------------------------------------------------------------------------------------
 * Logging
 * ------------------------------------------------------------------------------------- */

static void say3(fmi3InstanceEnvironment env, fmi3LogMessageCallback log, fmi3Status status,
                 const char *category, const char *msg) {
    if (log) log(env, status, category, msg);
}

/* Copy src to dst (size bytes) replacing the names of FMI 2.0 calls by FMI 3.0 ones. */
static void rename_calls(char *dst, size_t size, const char *src) {
    static const char *const from[] = {"fmi2GetReal", "fmi2SetReal", "fmi2SetupExperiment", "fmi2"};
    static const char *const to[] = {"fmi3GetFloat64", "fmi3SetFloat64",
                                     "fmi3EnterInitializationMode", "fmi3"};
    size_t k = 0;
    while (*src && k + 1 < size) {
        int hit = -1;
        for (int i = 0; i < 4 && hit < 0; i++)
            if (strncmp(src, from[i], strlen(from[i])) == 0) hit = i;
        if (hit < 0) {
            dst[k++] = *src++;
            continue;
        }
        for (const char *t = to[hit]; *t && k + 1 < size; t++) dst[k++] = *t;
        src += strlen(from[hit]);
    }
    dst[k] = '\0';
}

/* The FMI 2.0 logger the inner glue calls: its message is a printf format. */
static void bridge_logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                          fmi2String category, fmi2String message, ...) {
    (void)name;
    const Instance3 *c = (const Instance3 *)env;
    if (!c || !c->log || !message) return;
    char text[4096], renamed[4200];
    va_list ap;
    va_start(ap, message);
    vsnprintf(text, sizeof text, message, ap);
    va_end(ap);
    rename_calls(renamed, sizeof renamed, text);
    say3(c->env, c->log, (fmi3Status)status, category ? category : "", renamed);
}

static void *bridge_alloc(size_t n, size_t size) { return calloc(n, size); }
static void bridge_free(void *p) { free(p); }

static fmi3Status fail3(Instance3 *c, const char *fmt, ...) {
    char msg[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (c) say3(c->env, c->log, fmi3Error, "logStatusError", msg);
    return fmi3Error;
}

#define INNER(instance) (((Instance3 *)(instance))->inner)
#define CHECK3(instance)                                                                  \
    do {                                                                                  \
        if (!(instance)) return fmi3Error;                                                \
    } while (0)
#define WORST(a, b) ((a) > (b) ? (a) : (b))

/* ---------------------------------------------------------------------------------------
 * Common functions
 * ------------------------------------------------------------------------------------- */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2SetDebugLogging(INNER(instance), loggingOn ? fmi2True : fmi2False,
                                                nCategories, categories);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    say3(instanceEnvironment, logMessage, fmi3Error, "logStatusError",
         "fmi3InstantiateModelExchange: this FMI 3.0 FMU serves Co-Simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)earlyReturnAllowed, (void)requiredIntermediateVariables, (void)intermediateUpdate;
    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        say3(instanceEnvironment, logMessage, fmi3Error, "logStatusError",
             "fmi3InstantiateCoSimulation: this FMU has no event mode and no intermediate "
             "variables (hasEventMode=false, providesIntermediateUpdate=false)");
        return NULL;
    }
    Instance3 *c = (Instance3 *)calloc(1, sizeof(Instance3));
    if (!c) {
        say3(instanceEnvironment, logMessage, fmi3Error, "logStatusError",
             "fmi3InstantiateCoSimulation: out of memory");
        return NULL;
    }
    c->env = instanceEnvironment;
    c->log = logMessage;
    c->cb2.logger = bridge_logger;
    c->cb2.allocateMemory = bridge_alloc;
    c->cb2.freeMemory = bridge_free;
    c->cb2.componentEnvironment = c;
    snprintf(c->name, sizeof c->name, "%s", instanceName ? instanceName : GLUE3_MODEL_NAME);
    c->inner = ode2_fmi2Instantiate(c->name, fmi2CoSimulation, instantiationToken,
                                    resourcePath ? resourcePath : "", &c->cb2,
                                    visible ? fmi2True : fmi2False, loggingOn ? fmi2True : fmi2False);
    if (!c->inner) {
        free(c);
        return NULL;
    }
    return c;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    say3(instanceEnvironment, logMessage, fmi3Error, "logStatusError",
         "fmi3InstantiateScheduledExecution: this FMI 3.0 FMU serves Co-Simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    if (!instance) return;
    ode2_fmi2FreeInstance(INNER(instance));
    free(instance);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    CHECK3(instance);
    fmi2Status a = ode2_fmi2SetupExperiment(INNER(instance), toleranceDefined ? fmi2True : fmi2False,
                                            tolerance, startTime,
                                            stopTimeDefined ? fmi2True : fmi2False, stopTime);
    if (a > fmi2Warning) return (fmi3Status)a;
    fmi2Status b = ode2_fmi2EnterInitializationMode(INNER(instance));
    return (fmi3Status)WORST(a, b);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2ExitInitializationMode(INNER(instance));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return fail3((Instance3 *)instance, "fmi3EnterEventMode: this FMU has no event mode");
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2Terminate(INNER(instance));
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2Reset(INNER(instance));
}

/* ---------------------------------------------------------------------------------------
 * Float64 variables (value reference 0: the independent variable time)
 * ------------------------------------------------------------------------------------- */

static int has_time(const fmi3ValueReference vr[], size_t n) {
    for (size_t i = 0; i < n; i++)
        if (vr[i] == 0) return 1;
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    CHECK3(instance);
    if (nValues != nValueReferences)
        return fail3((Instance3 *)instance, "fmi3GetFloat64: nValues = %zu for %zu scalar variables",
                     nValues, nValueReferences);
    if (nValueReferences == 0 || !valueReferences || !has_time(valueReferences, nValueReferences))
        return (fmi3Status)ode2_fmi2GetReal(INNER(instance), valueReferences, nValueReferences, values);
    for (size_t i = 0; i < nValueReferences; i++) {
        fmi2Status s = valueReferences[i] == 0
            ? ode2_fmi2GetRealStatus(INNER(instance), fmi2LastSuccessfulTime, &values[i])
            : ode2_fmi2GetReal(INNER(instance), &valueReferences[i], 1, &values[i]);
        if (s > fmi2Warning) return (fmi3Status)s;
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    CHECK3(instance);
    if (nValues != nValueReferences)
        return fail3((Instance3 *)instance, "fmi3SetFloat64: nValues = %zu for %zu scalar variables",
                     nValues, nValueReferences);
    if (nValueReferences > 0 && valueReferences && has_time(valueReferences, nValueReferences))
        return fail3((Instance3 *)instance, "fmi3SetFloat64: time (value reference 0) cannot be set");
    return (fmi3Status)ode2_fmi2SetReal(INNER(instance), valueReferences, nValueReferences, values);
}

/* ---------------------------------------------------------------------------------------
 * Types this FMU has no variables of
 * ------------------------------------------------------------------------------------- */

#define NO_GET(TYPE, CTYPE)                                                               \
    fmi3Status fmi3Get##TYPE(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             CTYPE values[], size_t nValues) {                            \
        (void)vr, (void)values, (void)nValues;                                            \
        CHECK3(instance);                                                                 \
        if (nvr == 0) return fmi3OK;                                                      \
        return fail3((Instance3 *)instance, "fmi3Get" #TYPE ": this FMU has no " #TYPE " variables"); \
    }
#define NO_SET(TYPE, CTYPE)                                                               \
    fmi3Status fmi3Set##TYPE(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             const CTYPE values[], size_t nValues) {                      \
        (void)vr, (void)values, (void)nValues;                                            \
        CHECK3(instance);                                                                 \
        if (nvr == 0) return fmi3OK;                                                      \
        return fail3((Instance3 *)instance, "fmi3Set" #TYPE ": this FMU has no " #TYPE " variables"); \
    }
#define NO_TYPE(TYPE, CTYPE) NO_GET(TYPE, CTYPE) NO_SET(TYPE, CTYPE)

NO_TYPE(Float32, fmi3Float32)
NO_TYPE(Int8, fmi3Int8)
NO_TYPE(UInt8, fmi3UInt8)
NO_TYPE(Int16, fmi3Int16)
NO_TYPE(UInt16, fmi3UInt16)
#ifdef GLUE3_INT32_AS_FMI2_INTEGER
fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Int32 values[], size_t nValues) {
    CHECK3(instance);
    if (nValues != nvr)
        return fail3((Instance3 *)instance, "fmi3GetInt32: nValues = %zu for %zu scalar variables", nValues, nvr);
    return (fmi3Status)ode2_fmi2GetInteger(INNER(instance), vr, nvr, (fmi2Integer *)values);
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Int32 values[], size_t nValues) {
    CHECK3(instance);
    if (nValues != nvr)
        return fail3((Instance3 *)instance, "fmi3SetInt32: nValues = %zu for %zu scalar variables", nValues, nvr);
    return (fmi3Status)ode2_fmi2SetInteger(INNER(instance), vr, nvr, (const fmi2Integer *)values);
}
#else
NO_TYPE(Int32, fmi3Int32)
#endif
NO_TYPE(UInt32, fmi3UInt32)
NO_TYPE(Int64, fmi3Int64)
NO_TYPE(UInt64, fmi3UInt64)
NO_TYPE(Boolean, fmi3Boolean)
NO_TYPE(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    CHECK3(instance);
    return nvr ? fail3((Instance3 *)instance, "fmi3GetBinary: this FMU has no Binary variables") : fmi3OK;
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    CHECK3(instance);
    return nvr ? fail3((Instance3 *)instance, "fmi3SetBinary: this FMU has no Binary variables") : fmi3OK;
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[]) {
    (void)vr, (void)values;
    CHECK3(instance);
    return nvr ? fail3((Instance3 *)instance, "fmi3GetClock: this FMU has no clocks") : fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
    (void)vr, (void)values;
    CHECK3(instance);
    return nvr ? fail3((Instance3 *)instance, "fmi3SetClock: this FMU has no clocks") : fmi3OK;
}

/* ---------------------------------------------------------------------------------------
 * Dependencies, FMU state, derivatives
 * ------------------------------------------------------------------------------------- */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference, (void)nDependencies;
    return fail3((Instance3 *)instance, "fmi3GetNumberOfVariableDependencies is not supported "
                 "(providesPerElementDependencies=false)");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    (void)dependent, (void)elementIndicesOfDependent, (void)independents;
    (void)elementIndicesOfIndependents, (void)dependencyKinds, (void)nDependencies;
    return fail3((Instance3 *)instance, "fmi3GetVariableDependencies is not supported "
                 "(providesPerElementDependencies=false)");
}

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2GetFMUstate(INNER(instance), (fmi2FMUstate *)FMUState);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2SetFMUstate(INNER(instance), (fmi2FMUstate)FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2FreeFMUstate(INNER(instance), (fmi2FMUstate *)FMUState);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2SerializedFMUstateSize(INNER(instance), (fmi2FMUstate)FMUState, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2SerializeFMUstate(INNER(instance), (fmi2FMUstate)FMUState,
                                                  (fmi2Byte *)serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    CHECK3(instance);
    return (fmi3Status)ode2_fmi2DeSerializeFMUstate(INNER(instance), (const fmi2Byte *)serializedState,
                                                    size, (fmi2FMUstate *)FMUState);
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    CHECK3(instance);
    if (nSeed != nKnowns || nSensitivity != nUnknowns)
        return fail3((Instance3 *)instance, "fmi3GetDirectionalDerivative: nSeed = %zu for %zu knowns, "
                     "nSensitivity = %zu for %zu unknowns (all variables are scalars)", nSeed, nKnowns,
                     nSensitivity, nUnknowns);
    return (fmi3Status)ode2_fmi2GetDirectionalDerivative(INNER(instance), unknowns, nUnknowns, knowns,
                                                         nKnowns, seed, sensitivity);
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed;
    (void)sensitivity, (void)nSensitivity;
    return fail3((Instance3 *)instance, "fmi3GetAdjointDerivative is not supported "
                 "(providesAdjointDerivatives=false)");
}

/* ---------------------------------------------------------------------------------------
 * Configuration mode, clocks, discrete states: not provided
 * ------------------------------------------------------------------------------------- */

#define NOT_PROVIDED(instance, fname)                                                     \
    fail3((Instance3 *)(instance), "%s: not provided by this Co-Simulation FMU (no clocks, no "  \
          "structural parameters, no event mode)", (fname))

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return NOT_PROVIDED(instance, "fmi3EnterConfigurationMode");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return NOT_PROVIDED(instance, "fmi3ExitConfigurationMode");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences, (void)nValueReferences, (void)intervals, (void)qualifiers;
    return NOT_PROVIDED(instance, "fmi3GetIntervalDecimal");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions, (void)qualifiers;
    return NOT_PROVIDED(instance, "fmi3GetIntervalFraction");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences, (void)nValueReferences, (void)shifts;
    return NOT_PROVIDED(instance, "fmi3GetShiftDecimal");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions;
    return NOT_PROVIDED(instance, "fmi3GetShiftFraction");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences, (void)nValueReferences, (void)intervals;
    return NOT_PROVIDED(instance, "fmi3SetIntervalDecimal");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions;
    return NOT_PROVIDED(instance, "fmi3SetIntervalFraction");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences, (void)nValueReferences, (void)shifts;
    return NOT_PROVIDED(instance, "fmi3SetShiftDecimal");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences, (void)nValueReferences, (void)counters, (void)resolutions;
    return NOT_PROVIDED(instance, "fmi3SetShiftFraction");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return NOT_PROVIDED(instance, "fmi3EvaluateDiscreteStates");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate, (void)terminateSimulation, (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged, (void)nextEventTimeDefined, (void)nextEventTime;
    return NOT_PROVIDED(instance, "fmi3UpdateDiscreteStates");
}

/* ---------------------------------------------------------------------------------------
 * Model Exchange: not served by this FMU
 * ------------------------------------------------------------------------------------- */

#define ME_ONLY(instance, fname)                                                          \
    fail3((Instance3 *)(instance), "%s is a Model Exchange function; this FMU serves "    \
          "Co-Simulation only", (fname))

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return ME_ONLY(instance, "fmi3EnterContinuousTimeMode");
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    return ME_ONLY(instance, "fmi3CompletedIntegratorStep");
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return ME_ONLY(instance, "fmi3SetTime");
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates, (void)nContinuousStates;
    return ME_ONLY(instance, "fmi3SetContinuousStates");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives_[],
                                             size_t nContinuousStates) {
    (void)derivatives_, (void)nContinuousStates;
    return ME_ONLY(instance, "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators, (void)nEventIndicators;
    return ME_ONLY(instance, "fmi3GetEventIndicators");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates, (void)nContinuousStates;
    return ME_ONLY(instance, "fmi3GetContinuousStates");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals, (void)nContinuousStates;
    return ME_ONLY(instance, "fmi3GetNominalsOfContinuousStates");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    CHECK3(instance);
    if (!nEventIndicators) return fail3((Instance3 *)instance, "fmi3GetNumberOfEventIndicators: NULL");
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    CHECK3(instance);
    if (!nContinuousStates) return fail3((Instance3 *)instance, "fmi3GetNumberOfContinuousStates: NULL");
    *nContinuousStates = (size_t)GLUE3_NX;
    return fmi3OK;
}

/* ---------------------------------------------------------------------------------------
 * Co-Simulation
 * ------------------------------------------------------------------------------------- */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    return fail3((Instance3 *)instance, "fmi3EnterStepMode: this FMU has no event mode (it is in "
                 "Step Mode after fmi3ExitInitializationMode)");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues) {
    (void)valueReferences, (void)orders, (void)values, (void)nValues;
    CHECK3(instance);
    if (nValueReferences == 0) return fmi3OK;
    return fail3((Instance3 *)instance, "fmi3GetOutputDerivatives is not supported "
                 "(maxOutputDerivativeOrder=0)");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    CHECK3(instance);
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return fail3((Instance3 *)instance, "fmi3DoStep: NULL argument");
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    fmi2Status s = ode2_fmi2DoStep(INNER(instance), currentCommunicationPoint, communicationStepSize,
                                   noSetFMUStatePriorToCurrentPoint ? fmi2True : fmi2False);
    fmi2Real last = currentCommunicationPoint;
    ode2_fmi2GetRealStatus(INNER(instance), fmi2LastSuccessfulTime, &last);
    *lastSuccessfulTime = last;
    return (fmi3Status)s;
}

/* ---------------------------------------------------------------------------------------
 * Scheduled Execution: not served by this FMU
 * ------------------------------------------------------------------------------------- */

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference, (void)activationTime;
    return fail3((Instance3 *)instance, "fmi3ActivateModelPartition is a Scheduled Execution "
                 "function; this FMU serves Co-Simulation only");
}
