/*
 * The FMI 2.0 glue every FMU of ftc-verify shares: logging, the argument and phase checks,
 * the version and debug-logging functions, the checks of fmi2SetupExperiment and
 * fmi2DoStep, fmi2EnterInitializationMode, fmi2Terminate, the status functions and the unsupported
 * input/output derivatives, freeing and serializing FMU states; with FMI2_COMMON_FLAT_STATE
 * also instance creation, fmi2Reset and the other FMU state functions of an instance whose
 * whole state is one flat struct.
 *
 * Included (once, as a part of the glue's translation unit: every function is static or
 * one of the exported fmi2* functions) by
 *   LinearJumpPlant/fmi2_glue.c, ode/ode_glue.c, controller/ctrl_glue.c
 * after the glue has defined:
 *   Instance                        its instance type, with the members
 *                                     fmi2CallbackFunctions cb; name (char * or char[]);
 *                                     int logging_on; unsigned log_categories;
 *   PH_INST, PH_INIT, PH_STEP, PH_TERM, PH_ERROR   its phases (an enum; more are allowed)
 *   PHASE_NAMES                     the phases' names, indexed by phase
 *   FMI2_COMMON_MODEL_NAME          the logger's instance name when none was given
 *   FMI2_COMMON_PHASE(c)            the phase of instance c (an lvalue)
 *   FMI2_COMMON_LAST_TIME(c)        what fmi2GetRealStatus(fmi2LastSuccessfulTime) answers
 * and optionally:
 *   FMI2_COMMON_INTERPOLATE_NOTE    text after "canInterpolateInputs=false" in the message of
 *                                   fmi2SetRealInputDerivatives (default: none)
 *   FMI2_COMMON_TERMINATE_PHASES    the phases fmi2Terminate may be called in (a mask of
 *                                   M_* bits; default: every phase but Instantiated)
 * and either (an FMU state of any layout, its own serialization)
 *   FMI2_COMMON_STATE_SIZE(state)   the size in bytes of the serialization of an fmi2FMUstate
 *   FMI2_COMMON_STATE_BYTES(state)  its first byte
 *   FMI2_COMMON_STATE_FREE(c, p)    frees an fmi2FMUstate p of instance c
 * or (an instance in one allocation whose whole state c->s is one flat struct)
 *   FMI2_COMMON_FLAT_STATE          the type of c->s (members char magic[8],
 *                                     uint32_t endian, char guid[64], phase); then also
 *   FMI2_COMMON_GUID                the GUID (a string)
 *   FMI2_COMMON_STATE_MAGIC         the 8 bytes that start its FMU states (a char array)
 *   FMI2_COMMON_AFTER_SET_STATE(c)  what fmi2SetFMUstate does after restoring c->s
 * and declares before including this file
 *     static void reset_values(Instance *c);
 *     static fmi2Status state_check(Instance *c, const FMI2_COMMON_FLAT_STATE *b,
 *                                   size_t size, const char *fname);
 * (the flat case adds instance creation helpers, fmi2FreeInstance, fmi2Reset and the other
 * three FMU state functions).
 *
 * The FMU archives carry this file in sources/ beside the glue, so a source FMU still
 * compiles alone: cc -I <fmi2 headers> -I sources sources/<glue>.c ...
 */
#ifndef FTC_FMI2_COMMON_H
#define FTC_FMI2_COMMON_H

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#ifndef FMI2_COMMON_INTERPOLATE_NOTE
#define FMI2_COMMON_INTERPOLATE_NOTE ""
#endif
#ifndef FMI2_COMMON_TERMINATE_PHASES
#define FMI2_COMMON_TERMINATE_PHASES (~M_INST) /* every phase but Instantiated */
#endif

enum { LOG_EVENTS = 1, LOG_WARNING = 2, LOG_ERROR = 4, LOG_ALL = 7 };

#define M_INST (1u << PH_INST)
#define M_INIT (1u << PH_INIT)
#define M_STEP (1u << PH_STEP)
#define M_TERM (1u << PH_TERM)
#define M_ERR (1u << PH_ERROR)
#define IN_PHASE(c, mask) ((((unsigned)(mask)) >> FMI2_COMMON_PHASE(c)) & 1u)

/* ---------------------------------------------------------------------------------------
 * Logging
 * ------------------------------------------------------------------------------------- */

/* The logger formats its message like printf: double every '%'. */
static void emit(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                 const char *category, const char *msg) {
    if (!cb || !cb->logger) return;
    char esc[4096];
    size_t k = 0;
    for (const char *p = msg; *p && k + 2 < sizeof esc; p++) {
        if (*p == '%') esc[k++] = '%';
        esc[k++] = *p;
    }
    esc[k] = '\0';
    cb->logger(cb->componentEnvironment, name ? name : FMI2_COMMON_MODEL_NAME, status, category, esc);
}

static void logf_(Instance *c, fmi2Status status, const char *fmt, ...) {
    const char *category = "logEvents";
    unsigned bit = LOG_EVENTS;
    if (status == fmi2Warning) category = "logStatusWarning", bit = LOG_WARNING;
    if (status > fmi2Warning) category = "logStatusError", bit = LOG_ERROR;
    /* errors and warnings are always reported, information only when logging is on */
    if (status == fmi2OK && !(c->logging_on && (c->log_categories & bit))) return;
    char msg[2048];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    emit(&c->cb, c->name, status, category, msg);
}

#define FAIL(c, ...)                                                                      \
    do {                                                                                  \
        logf_((c), fmi2Error, __VA_ARGS__);                                               \
        return fmi2Error;                                                                 \
    } while (0)
#define CHECK_INSTANCE(c)                                                                 \
    do {                                                                                  \
        if (!(c)) return fmi2Error;                                                       \
    } while (0)
#define CHECK_PHASE(c, mask, fname)                                                       \
    do {                                                                                  \
        if (!IN_PHASE((c), (mask)))                                                       \
            FAIL((c), "%s must not be called in %s", (fname), PHASE_NAMES[FMI2_COMMON_PHASE(c)]); \
    } while (0)
#define CHECK_ARRAYS(c, vr, nvr, value, fname)                                            \
    do {                                                                                  \
        if ((nvr) > 0 && (!(vr) || !(value))) FAIL((c), "%s: NULL argument", (fname));    \
    } while (0)

/* fmi2Get<TYPE> and fmi2Set<TYPE> of an FMU without variables of that type. */
#define NO_VARIABLES(TYPE, CTYPE, CONST)                                                  \
    fmi2Status fmi2Get##TYPE(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, \
                             CTYPE value[]) {                                             \
        Instance *c = (Instance *)comp;                                                   \
        (void)vr, (void)value;                                                            \
        CHECK_INSTANCE(c);                                                                \
        if (nvr > 0) FAIL(c, "fmi2Get" #TYPE ": this FMU has no " #TYPE " variables");    \
        return fmi2OK;                                                                    \
    }                                                                                     \
    fmi2Status fmi2Set##TYPE(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, \
                             CONST CTYPE value[]) {                                       \
        Instance *c = (Instance *)comp;                                                   \
        (void)vr, (void)value;                                                            \
        CHECK_INSTANCE(c);                                                                \
        if (nvr > 0) FAIL(c, "fmi2Set" #TYPE ": this FMU has no " #TYPE " variables");    \
        return fmi2OK;                                                                    \
    }

/* ---------------------------------------------------------------------------------------
 * Version, debug logging
 * ------------------------------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    c->logging_on = loggingOn ? 1 : 0;
    if (nCategories == 0) {
        c->log_categories = LOG_ALL;
        return fmi2OK;
    }
    if (!categories) FAIL(c, "fmi2SetDebugLogging: categories is NULL");
    unsigned mask = 0;
    for (size_t i = 0; i < nCategories; i++) {
        const char *cat = categories[i] ? categories[i] : "";
        if (strcmp(cat, "logEvents") == 0) mask |= LOG_EVENTS;
        else if (strcmp(cat, "logStatusWarning") == 0) mask |= LOG_WARNING;
        else if (strcmp(cat, "logStatusError") == 0) mask |= LOG_ERROR;
        else if (strcmp(cat, "logAll") == 0) mask |= LOG_ALL;
        else FAIL(c, "fmi2SetDebugLogging: unknown log category '%s'", cat);
    }
    c->log_categories = mask;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * Initialization and steps
 * ------------------------------------------------------------------------------------- */

/* The checks of fmi2SetupExperiment: instance, phase Instantiated, a finite startTime and,
 * when check_stop, a stopTime (if defined) not before it. */
static fmi2Status setup_checks(Instance *c, fmi2Real startTime, int check_stop,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_INST, "fmi2SetupExperiment");
    if (!isfinite(startTime)) FAIL(c, "fmi2SetupExperiment: startTime %g is not finite", startTime);
    if (check_stop && stopTimeDefined && !(stopTime >= startTime))
        FAIL(c, "fmi2SetupExperiment: stopTime %g is before startTime %g", stopTime, startTime);
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_INST, "fmi2EnterInitializationMode");
    FMI2_COMMON_PHASE(c) = PH_INIT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, FMI2_COMMON_TERMINATE_PHASES, "fmi2Terminate");
    FMI2_COMMON_PHASE(c) = PH_TERM;
    return fmi2OK;
}

/* The argument checks of fmi2DoStep (the instance is not NULL): when check_h, a finite
 * step size h >= 0; then a communication point t within 1e-9 (1 + |now|) of the FMU's
 * time now. */
static fmi2Status step_checks(Instance *c, double t, double h, int check_h, double now) {
    if (check_h && (!isfinite(h) || h < 0.0))
        FAIL(c, "fmi2DoStep: communicationStepSize %g must be finite and >= 0", h);
    if (!isfinite(t) || fabs(t - now) > 1e-9 * (1.0 + fabs(now)))
        FAIL(c, "fmi2DoStep: currentCommunicationPoint %.17g differs from the FMU's time %.17g",
             t, now);
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * Input and output derivatives, asynchronous steps, status
 * ------------------------------------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr, (void)order, (void)value;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (nvr == 0) return fmi2OK;
    FAIL(c, "fmi2SetRealInputDerivatives is not supported (canInterpolateInputs=false"
            FMI2_COMMON_INTERPOLATE_NOTE ")");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)order, (void)value;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (nvr == 0) return fmi2OK;
    FAIL(c, "fmi2GetRealOutputDerivatives is not supported (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    FAIL(c, "fmi2CancelStep: fmi2DoStep never returns fmi2Pending in this FMU");
}

/* A status function that answers the kind KIND with VALUE and fails for every other kind
 * (KIND -1: for every kind) with the message MSG. */
#define STATUS_FUNCTION(NAME, CTYPE, KIND, VALUE, MSG)                                    \
    fmi2Status NAME(fmi2Component comp, const fmi2StatusKind s, CTYPE *value) {           \
        Instance *c = (Instance *)comp;                                                   \
        CHECK_INSTANCE(c);                                                                \
        if ((int)s == (KIND) && value) {                                                  \
            *value = (VALUE);                                                             \
            return fmi2OK;                                                                \
        }                                                                                 \
        FAIL(c, MSG);                                                                     \
    }

STATUS_FUNCTION(fmi2GetStatus, fmi2Status, -1, fmi2OK,
                "fmi2GetStatus: no asynchronous step is pending (fmi2DoStep is synchronous)")
STATUS_FUNCTION(fmi2GetRealStatus, fmi2Real, fmi2LastSuccessfulTime, FMI2_COMMON_LAST_TIME(c),
                "fmi2GetRealStatus: only fmi2LastSuccessfulTime is available")
STATUS_FUNCTION(fmi2GetIntegerStatus, fmi2Integer, -1, 0,
                "fmi2GetIntegerStatus: no integer status is defined")
/* the FMU never asks to terminate the simulation */
STATUS_FUNCTION(fmi2GetBooleanStatus, fmi2Boolean, fmi2Terminated, fmi2False,
                "fmi2GetBooleanStatus: only fmi2Terminated is available")
STATUS_FUNCTION(fmi2GetStringStatus, fmi2String, -1, NULL,
                "fmi2GetStringStatus: no string status is defined")

/* ---------------------------------------------------------------------------------------
 * FMU state: freeing, serializing (an FMU state is its own serialization)
 * ------------------------------------------------------------------------------------- */

#ifdef FMI2_COMMON_FLAT_STATE
typedef FMI2_COMMON_FLAT_STATE FlatState;
#define FMI2_COMMON_STATE_SIZE(state) sizeof(FlatState)
#define FMI2_COMMON_STATE_BYTES(state) ((const void *)(state))
#define FMI2_COMMON_STATE_FREE(c, p) ((c)->cb.freeMemory(p))
#endif

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (FMUstate && *FMUstate) FMI2_COMMON_STATE_FREE(c, *FMUstate);
    if (FMUstate) *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate || !size) FAIL(c, "fmi2SerializedFMUstateSize: NULL argument");
    *size = FMI2_COMMON_STATE_SIZE(FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate || !serializedState) FAIL(c, "fmi2SerializeFMUstate: NULL argument");
    const size_t need = FMI2_COMMON_STATE_SIZE(FMUstate);
    if (size < need)
        FAIL(c, "fmi2SerializeFMUstate: buffer of %zu bytes is too small (need %zu)", size, need);
    memcpy(serializedState, FMI2_COMMON_STATE_BYTES(FMUstate), need);
    return fmi2OK;
}

#ifdef FMI2_COMMON_FLAT_STATE
/* ---------------------------------------------------------------------------------------
 * An instance in one allocation whose state c->s is one flat struct (its own
 * serialization, in native byte order)
 * ------------------------------------------------------------------------------------- */


/* Whether the importer gave the memory callbacks (logged when not). */
static int callbacks_ok(const fmi2CallbackFunctions *functions, fmi2String instanceName) {
    if (functions->allocateMemory && functions->freeMemory) return 1;
    emit(functions, instanceName, fmi2Error, "logStatusError",
         "fmi2Instantiate: allocateMemory and freeMemory callbacks are required");
    return 0;
}

/* Whether fmuGUID is this binary's GUID (logged when not). */
static int guid_ok(const fmi2CallbackFunctions *functions, fmi2String instanceName,
                   fmi2String fmuGUID) {
    char msg[600];
    if (fmuGUID && strcmp(fmuGUID, FMI2_COMMON_GUID) == 0) return 1;
    snprintf(msg, sizeof msg, "fmi2Instantiate: fmuGUID %s does not match this binary's "
             "GUID %s (modelDescription.xml and binary come from different builds)",
             fmuGUID ? fmuGUID : "(NULL)", FMI2_COMMON_GUID);
    emit(functions, instanceName, fmi2Error, "logStatusError", msg);
    return 0;
}

/* A zeroed instance with the callbacks, name, logging flags and the state's header set,
 * its values from reset_values; NULL (logged) when out of memory. */
static Instance *instance_new(const fmi2CallbackFunctions *functions, fmi2String instanceName,
                              fmi2Boolean loggingOn) {
    Instance *c = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (!c) {
        emit(functions, instanceName, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return NULL;
    }
    memset(c, 0, sizeof *c);
    c->cb = *functions;
    snprintf(c->name, sizeof c->name, "%s", instanceName ? instanceName : FMI2_COMMON_MODEL_NAME);
    c->logging_on = loggingOn ? 1 : 0;
    c->log_categories = LOG_ALL;
    memcpy(c->s.magic, FMI2_COMMON_STATE_MAGIC, 8);
    c->s.endian = 0x01020304u;
    snprintf(c->s.guid, sizeof c->s.guid, "%s", FMI2_COMMON_GUID);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (c) c->cb.freeMemory(c);
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    reset_values(c);
    logf_(c, fmi2OK, "fmi2Reset: start values restored");
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate) FAIL(c, "fmi2GetFMUstate: FMUstate is NULL");
    FlatState *b = (FlatState *)*FMUstate;
    if (!b) b = (FlatState *)c->cb.allocateMemory(1, sizeof(FlatState));
    if (!b) FAIL(c, "fmi2GetFMUstate: out of memory");
    *b = c->s;
    *FMUstate = b;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate) FAIL(c, "fmi2SetFMUstate: FMUstate is NULL");
    if (state_check(c, (const FlatState *)FMUstate, sizeof(FlatState), "fmi2SetFMUstate") != fmi2OK)
        return fmi2Error;
    c->s = *(const FlatState *)FMUstate;
    FMI2_COMMON_AFTER_SET_STATE(c);
    return fmi2OK;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!serializedState || !FMUstate) FAIL(c, "fmi2DeSerializeFMUstate: NULL argument");
    FlatState tmp;
    if (size != sizeof(FlatState))
        FAIL(c, "fmi2DeSerializeFMUstate: %zu bytes, expected %zu", size, sizeof(FlatState));
    memcpy(&tmp, serializedState, sizeof tmp);
    if (state_check(c, &tmp, size, "fmi2DeSerializeFMUstate") != fmi2OK) return fmi2Error;
    FlatState *b = (FlatState *)*FMUstate;
    if (!b) b = (FlatState *)c->cb.allocateMemory(1, sizeof(FlatState));
    if (!b) FAIL(c, "fmi2DeSerializeFMUstate: out of memory");
    *b = tmp;
    *FMUstate = b;
    return fmi2OK;
}
#endif /* FMI2_COMMON_FLAT_STATE */

#endif /* FTC_FMI2_COMMON_H */
