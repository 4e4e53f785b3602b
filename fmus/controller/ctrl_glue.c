/*
 * FMI 2.0 Co-Simulation glue of an exported FDI-switched controller (ftc-verify
 * export-controller). The controller itself is the generated, dependency-free C99 file
 * ftc_controller.c (ftc_ctrl_init, ftc_ctrl_output, ftc_ctrl_step); ctrl_spec.h (generated)
 * holds the model name and GUID.
 *
 * Value references (one sequence for every type, so the FMI 3.0 glue can use the same ones):
 *   1 .. NV                    v[i]      Real input (the measured vector), held over a step
 *   NV+1 .. NV+NU              u[i]      Real output, u = Cc[l] xc + Dc[l] v (direct feedthrough)
 *   NV+NU+1 .. NV+NU+NC        xc[i]     Real local (the controller state)
 *   NV+NU+NC+1                 samplePeriod  Real constant (the exported period h)
 *   NV+NU+NC+2                 fdi_mode  Integer input, 1..MODES
 * fmi2DoStep advances xc by the exact sampled update of period h (v, fdi_mode held); a step of
 * another length is refused with fmi2Error and a log message. Errors never crash: every failing
 * call logs a message and returns fmi2Error.
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "ctrl_spec.h"
#include "ftc_controller.c"

#define NV FTC_CTRL_NV
#define NU FTC_CTRL_NU
#define NC FTC_CTRL_NC
#define VR_V 1u
#define VR_U (VR_V + NV)
#define VR_XC (VR_U + NU)
#define VR_PERIOD (VR_XC + NC)
#define VR_MODE (VR_PERIOD + 1u)

typedef enum { PH_INST = 0, PH_INIT, PH_STEP, PH_TERM, PH_ERROR } Phase;
static const char *PHASE_NAMES[] = {"Instantiated", "Initialization Mode", "Step Mode", "Terminated",
                                    "Error"};
enum { LOG_EVENTS = 1, LOG_WARNING = 2, LOG_ERROR = 4, LOG_ALL = 7 };

/* Everything fmi2GetFMUstate saves (a flat struct: its own serialization). */
typedef struct {
    char magic[8];
    uint32_t endian;
    int32_t phase, fdi_mode;
    char guid[64];
    double time;
    double v[NV];
    ftc_ctrl_state ctrl;
} CtrlState;

typedef struct {
    fmi2CallbackFunctions cb;
    char name[128];
    int logging_on;
    unsigned log_categories;
    CtrlState s;
} Instance;

static const char STATE_MAGIC[8] = {'F', 'T', 'C', 'C', 'T', 'R', 'L', '1'};

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
    cb->logger(cb->componentEnvironment, name ? name : CTRL_MODEL_NAME, status, category, esc);
}

static void logf_(Instance *c, fmi2Status status, const char *fmt, ...) {
    const char *category = "logEvents";
    unsigned bit = LOG_EVENTS;
    if (status == fmi2Warning) category = "logStatusWarning", bit = LOG_WARNING;
    if (status > fmi2Warning) category = "logStatusError", bit = LOG_ERROR;
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
        if (!(((mask) >> (c)->s.phase) & 1u))                                             \
            FAIL((c), "%s must not be called in %s", (fname), PHASE_NAMES[(c)->s.phase]);  \
    } while (0)
#define CHECK_ARRAYS(c, vr, nvr, value, fname)                                            \
    do {                                                                                  \
        if ((nvr) > 0 && (!(vr) || !(value))) FAIL((c), "%s: NULL argument", (fname));    \
    } while (0)
#define M_ANY 0x1Fu
#define M_SETTABLE ((1u << PH_INST) | (1u << PH_INIT) | (1u << PH_STEP))

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

/* Start values: v = 0, fdi_mode = 1, xc = 0, time 0, phase Instantiated. */
static void reset_values(Instance *c) {
    memset(c->s.v, 0, sizeof c->s.v);
    ftc_ctrl_init(&c->s.ctrl);
    c->s.fdi_mode = 1;
    c->s.time = 0.0;
    c->s.phase = PH_INST;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)visible, (void)fmuResourceLocation;
    char msg[600];
    if (!functions) return NULL;
    if (!functions->allocateMemory || !functions->freeMemory) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "fmi2Instantiate: allocateMemory and freeMemory callbacks are required");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "fmi2Instantiate: this controller FMU serves Co-Simulation only");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, CTRL_GUID) != 0) {
        snprintf(msg, sizeof msg, "fmi2Instantiate: fmuGUID %s does not match this binary's "
                 "GUID %s (modelDescription.xml and binary come from different builds)",
                 fmuGUID ? fmuGUID : "(NULL)", CTRL_GUID);
        emit(functions, instanceName, fmi2Error, "logStatusError", msg);
        return NULL;
    }
    Instance *c = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (!c) {
        emit(functions, instanceName, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return NULL;
    }
    memset(c, 0, sizeof *c);
    c->cb = *functions;
    snprintf(c->name, sizeof c->name, "%s", instanceName ? instanceName : CTRL_MODEL_NAME);
    c->logging_on = loggingOn ? 1 : 0;
    c->log_categories = LOG_ALL;
    memcpy(c->s.magic, STATE_MAGIC, 8);
    c->s.endian = 0x01020304u;
    snprintf(c->s.guid, sizeof c->s.guid, "%s", CTRL_GUID);
    reset_values(c);
    logf_(c, fmi2OK, "instantiated %s (NV=%d NU=%d NC=%d, %d FDI modes, period %.17g)",
          CTRL_MODEL_NAME, NV, NU, NC, FTC_CTRL_MODES, FTC_CTRL_STEP);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (c) c->cb.freeMemory(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    (void)toleranceDefined, (void)tolerance; /* the update is exact: no tolerance */
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, 1u << PH_INST, "fmi2SetupExperiment");
    if (!isfinite(startTime)) FAIL(c, "fmi2SetupExperiment: startTime %g is not finite", startTime);
    if (stopTimeDefined && !(stopTime >= startTime))
        FAIL(c, "fmi2SetupExperiment: stopTime %g is before startTime %g", stopTime, startTime);
    c->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, 1u << PH_INST, "fmi2EnterInitializationMode");
    c->s.phase = PH_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, 1u << PH_INIT, "fmi2ExitInitializationMode");
    c->s.phase = PH_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    c->s.phase = PH_TERM;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    reset_values(c);
    logf_(c, fmi2OK, "fmi2Reset: start values restored");
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2GetReal");
    double u[NU];
    int have_u = 0;
    for (size_t i = 0; i < nvr; i++) {
        const fmi2ValueReference r = vr[i];
        if (r >= VR_V && r < VR_U) value[i] = c->s.v[r - VR_V];
        else if (r >= VR_XC && r < VR_PERIOD) value[i] = c->s.ctrl.xc[r - VR_XC];
        else if (r == VR_PERIOD) value[i] = FTC_CTRL_STEP;
        else if (r >= VR_U && r < VR_XC) {
            if (!have_u && ftc_ctrl_output(&c->s.ctrl, c->s.fdi_mode, c->s.v, u) != FTC_CTRL_OK)
                FAIL(c, "fmi2GetReal: fdi_mode = %d is not an FDI mode (1..%d)", (int)c->s.fdi_mode,
                     FTC_CTRL_MODES);
            have_u = 1;
            value[i] = u[r - VR_U];
        } else
            FAIL(c, "fmi2GetReal: %u is not the value reference of a Real variable", r);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_SETTABLE, "fmi2SetReal");
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2SetReal");
    for (size_t i = 0; i < nvr; i++) {
        const fmi2ValueReference r = vr[i];
        if (!(r >= VR_V && r < VR_U))
            FAIL(c, "fmi2SetReal: %u is not the value reference of an input v[i] (1..%d)", r, NV);
        if (!isfinite(value[i])) FAIL(c, "fmi2SetReal: v[%u] = %g is not finite", r - VR_V + 1, value[i]);
        c->s.v[r - VR_V] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2GetInteger");
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] != VR_MODE) FAIL(c, "fmi2GetInteger: %u is not the value reference of fdi_mode", vr[i]);
        value[i] = c->s.fdi_mode;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_SETTABLE, "fmi2SetInteger");
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2SetInteger");
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] != VR_MODE) FAIL(c, "fmi2SetInteger: %u is not the value reference of fdi_mode", vr[i]);
        if (value[i] < 1 || value[i] > FTC_CTRL_MODES)
            FAIL(c, "fmi2SetInteger: fdi_mode = %d is not an FDI mode (1..%d)", (int)value[i],
                 FTC_CTRL_MODES);
        c->s.fdi_mode = value[i];
    }
    return fmi2OK;
}

#define NO_VARIABLES(TYPE, CTYPE, CONST)                                                  \
    fmi2Status fmi2Get##TYPE(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, \
                             CTYPE value[]) {                                             \
        (void)vr, (void)value;                                                            \
        Instance *c = (Instance *)comp;                                                   \
        CHECK_INSTANCE(c);                                                                \
        if (nvr == 0) return fmi2OK;                                                      \
        FAIL(c, "fmi2Get" #TYPE ": this FMU has no " #TYPE " variables");                 \
    }                                                                                     \
    fmi2Status fmi2Set##TYPE(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, \
                             CONST CTYPE value[]) {                                       \
        (void)vr, (void)value;                                                            \
        Instance *c = (Instance *)comp;                                                   \
        CHECK_INSTANCE(c);                                                                \
        if (nvr == 0) return fmi2OK;                                                      \
        FAIL(c, "fmi2Set" #TYPE ": this FMU has no " #TYPE " variables");                 \
    }

NO_VARIABLES(Boolean, fmi2Boolean, const)
NO_VARIABLES(String, fmi2String, const)

/* FMU state: a copy of CtrlState (native byte order; magic and GUID checked). */
static fmi2Status state_check(Instance *c, const CtrlState *b, size_t size, const char *fname) {
    if (size != sizeof(CtrlState))
        FAIL(c, "%s: FMU state has %zu bytes, expected %zu", fname, size, sizeof(CtrlState));
    if (memcmp(b->magic, STATE_MAGIC, 8) != 0 || b->endian != 0x01020304u)
        FAIL(c, "%s: not an FMU state of this glue", fname);
    if (strncmp(b->guid, CTRL_GUID, sizeof b->guid) != 0)
        FAIL(c, "%s: FMU state of another FMU (GUID %.63s, this is %s)", fname, b->guid, CTRL_GUID);
    if (b->phase < PH_INST || b->phase > PH_ERROR) FAIL(c, "%s: invalid phase %d", fname, (int)b->phase);
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate) FAIL(c, "fmi2GetFMUstate: FMUstate is NULL");
    CtrlState *b = (CtrlState *)*FMUstate;
    if (!b) b = (CtrlState *)c->cb.allocateMemory(1, sizeof(CtrlState));
    if (!b) FAIL(c, "fmi2GetFMUstate: out of memory");
    *b = c->s;
    *FMUstate = b;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate) FAIL(c, "fmi2SetFMUstate: FMUstate is NULL");
    if (state_check(c, (const CtrlState *)FMUstate, sizeof(CtrlState), "fmi2SetFMUstate") != fmi2OK)
        return fmi2Error;
    c->s = *(const CtrlState *)FMUstate;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (FMUstate && *FMUstate) c->cb.freeMemory(*FMUstate);
    if (FMUstate) *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate || !size) FAIL(c, "fmi2SerializedFMUstateSize: NULL argument");
    *size = sizeof(CtrlState);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate || !serializedState) FAIL(c, "fmi2SerializeFMUstate: NULL argument");
    if (size < sizeof(CtrlState))
        FAIL(c, "fmi2SerializeFMUstate: buffer of %zu bytes is too small (need %zu)", size,
             sizeof(CtrlState));
    memcpy(serializedState, FMUstate, sizeof(CtrlState));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!serializedState || !FMUstate) FAIL(c, "fmi2DeSerializeFMUstate: NULL argument");
    CtrlState tmp;
    if (size != sizeof(CtrlState))
        FAIL(c, "fmi2DeSerializeFMUstate: %zu bytes, expected %zu", size, sizeof(CtrlState));
    memcpy(&tmp, serializedState, sizeof tmp);
    if (state_check(c, &tmp, size, "fmi2DeSerializeFMUstate") != fmi2OK) return fmi2Error;
    CtrlState *b = (CtrlState *)*FMUstate;
    if (!b) b = (CtrlState *)c->cb.allocateMemory(1, sizeof(CtrlState));
    if (!b) FAIL(c, "fmi2DeSerializeFMUstate: out of memory");
    *b = tmp;
    *FMUstate = b;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    FAIL(c, "fmi2GetDirectionalDerivative is not provided (providesDirectionalDerivative=false)");
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, 1u << PH_STEP, "fmi2DoStep");
    const double t = currentCommunicationPoint, h = communicationStepSize;
    if (!isfinite(t) || fabs(t - c->s.time) > 1e-9 * (1.0 + fabs(c->s.time)))
        FAIL(c, "fmi2DoStep: currentCommunicationPoint %.17g differs from the FMU's time %.17g",
             t, c->s.time);
    switch (ftc_ctrl_step(&c->s.ctrl, c->s.fdi_mode, c->s.v, h)) {
    case FTC_CTRL_OK: break;
    case FTC_CTRL_BAD_MODE:
        FAIL(c, "fmi2DoStep at t = %.17g: fdi_mode = %d is not an FDI mode (1..%d)", t,
             (int)c->s.fdi_mode, FTC_CTRL_MODES);
    default:
        FAIL(c, "fmi2DoStep at t = %.17g: communicationStepSize %.17g is not the controller's "
                "sampling period %.17g (the exported update is exact for that period only)",
             t, h, FTC_CTRL_STEP);
    }
    c->s.time = t + h;
    logf_(c, fmi2OK, "fmi2DoStep to t = %.17g in FDI mode %d", c->s.time, (int)c->s.fdi_mode);
    return fmi2OK;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr, (void)order, (void)value;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (nvr == 0) return fmi2OK;
    FAIL(c, "fmi2SetRealInputDerivatives is not supported (canInterpolateInputs=false)");
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

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value) {
    (void)s, (void)value;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    FAIL(c, "fmi2GetStatus: no asynchronous step is pending (fmi2DoStep is synchronous)");
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (s == fmi2LastSuccessfulTime && value) {
        *value = c->s.time;
        return fmi2OK;
    }
    FAIL(c, "fmi2GetRealStatus: only fmi2LastSuccessfulTime is available");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s, (void)value;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    FAIL(c, "fmi2GetIntegerStatus: no integer status is defined");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (s == fmi2Terminated && value) {
        *value = fmi2False;
        return fmi2OK;
    }
    FAIL(c, "fmi2GetBooleanStatus: only fmi2Terminated is available");
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value) {
    (void)s, (void)value;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    FAIL(c, "fmi2GetStringStatus: no string status is defined");
}
