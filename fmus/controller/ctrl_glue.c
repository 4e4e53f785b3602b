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

/* The glue shared with the other FMUs (../common/fmi2_common.h): logging, FAIL and the
 * CHECK_* macros, version, debug logging, status functions, instances, fmi2Reset, FMU state. */
static void reset_values(Instance *c);
static fmi2Status state_check(Instance *c, const CtrlState *b, size_t size, const char *fname);
#define FMI2_COMMON_MODEL_NAME CTRL_MODEL_NAME
#define FMI2_COMMON_PHASE(c) ((c)->s.phase)
#define FMI2_COMMON_LAST_TIME(c) ((c)->s.time)
#define FMI2_COMMON_FLAT_STATE CtrlState
#define FMI2_COMMON_GUID CTRL_GUID
#define FMI2_COMMON_STATE_MAGIC STATE_MAGIC
#define FMI2_COMMON_AFTER_SET_STATE(c) ((void)(c))
#define FMI2_COMMON_TERMINATE_PHASES (~0u) /* in any phase */
#include "fmi2_common.h"

#define M_SETTABLE (M_INST | M_INIT | M_STEP)

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
    if (!functions) return NULL;
    if (!callbacks_ok(functions, instanceName)) return NULL;
    if (fmuType != fmi2CoSimulation) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "fmi2Instantiate: this controller FMU serves Co-Simulation only");
        return NULL;
    }
    if (!guid_ok(functions, instanceName, fmuGUID)) return NULL;
    Instance *c = instance_new(functions, instanceName, loggingOn);
    if (!c) return NULL;
    reset_values(c);
    logf_(c, fmi2OK, "instantiated %s (NV=%d NU=%d NC=%d, %d FDI modes, period %.17g)",
          CTRL_MODEL_NAME, NV, NU, NC, FTC_CTRL_MODES, FTC_CTRL_STEP);
    return c;
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    (void)toleranceDefined, (void)tolerance; /* the update is exact: no tolerance */
    Instance *c = (Instance *)comp;
    if (setup_checks(c, startTime, 1, stopTimeDefined, stopTime) != fmi2OK) return fmi2Error;
    c->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_INIT, "fmi2ExitInitializationMode");
    c->s.phase = PH_STEP;
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
    CHECK_PHASE(c, M_STEP, "fmi2DoStep");
    const double t = currentCommunicationPoint, h = communicationStepSize;
    if (step_checks(c, t, h, 0, c->s.time) != fmi2OK) return fmi2Error;
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
