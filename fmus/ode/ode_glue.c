/*
 * Generic FMI 2.0 glue for an ODE model  x' = f(t, x, u, p),  y = g(t, x, u, p)  written in
 * plain C (contract and value-reference layout: ode_model.h). One binary serves
 *
 *   - Model Exchange: the importer integrates; states via fmi2SetContinuousStates,
 *     derivatives via fmi2GetDerivatives; no event indicators, no time events;
 *   - Co-Simulation: fmi2DoStep integrates with an embedded Dormand-Prince 5(4) pair
 *     (FSAL, local extrapolation), inputs held constant over the step. Error control:
 *         err = sqrt(mean_i (e_i / (atol + rtol * max(|x_i|, |x_new_i|)))^2) <= 1,
 *     rtol = tolerance of fmi2SetupExperiment when defined (default 1e-8, at least 1e-13),
 *     atol = 1e-2 * rtol; new step h * min(5, max(0.2, 0.9 err^(-1/5))) (no growth right
 *     after a rejection); first step by the Hairer-Norsett-Wanner heuristic; the last
 *     internal step is cut so that the step ends exactly at t + h.
 *
 * Exact directional derivatives come from the model's ode_jac (when
 * ODE_SPEC_HAS_JACOBIAN). The FMU state is a flat copy of OdeState (serializable).
 * Errors never crash: every failing call logs a message and returns fmi2Error.
 */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "ode_model.h"
#include "ode_spec.h"

#define NX ODE_SPEC_NX
#define NU ODE_SPEC_NU
#define NP ODE_SPEC_NP
#define NY ODE_SPEC_NY
#define NXA (NX > 0 ? NX : 1)
#define NUA (NU > 0 ? NU : 1)
#define NPA (NP > 0 ? NP : 1)
#define NYA (NY > 0 ? NY : 1)

#define VR_X 1u
#define VR_DX (VR_X + NX)
#define VR_U (VR_DX + NX)
#define VR_P (VR_U + NU)
#define VR_Y (VR_P + NP)
#define VR_END (VR_Y + NY)

#define DEFAULT_RTOL 1e-8
#define MIN_RTOL 1e-13
#define ATOL_FACTOR 1e-2
#define MAX_SUBSTEPS 1000000UL

typedef enum { PH_INST = 0, PH_INIT, PH_EVENT, PH_CONT, PH_STEP, PH_TERM, PH_ERROR } Phase;
static const char *PHASE_NAMES[] = {"Instantiated", "Initialization Mode", "Event Mode",
                                    "Continuous-Time Mode", "Step Mode", "Terminated", "Error"};
#define M_EVENT (1u << PH_EVENT)
#define M_CONT (1u << PH_CONT)
#define M_ANY 0x7Fu

typedef enum { K_NONE = 0, K_X, K_DX, K_U, K_P, K_Y } Kind;

/* Everything fmi2GetFMUstate saves: a flat struct, its own serialization. */
typedef struct {
    char magic[8];
    uint32_t endian;
    int32_t fmu_type, phase, dims[4];
    char guid[64];
    double time, start_time, last_ok_time, rtol, atol, h_last;
    double x[NXA], u[NUA], p[NPA];
} OdeState;

typedef struct {
    fmi2CallbackFunctions cb;
    char name[128];
    int logging_on;
    unsigned log_categories;
    OdeState s;
    int dx_valid, y_valid; /* caches, cleared when time, x, u or p change */
    double dx[NXA], y[NYA];
    double k[7][NXA], xs[NXA], xn[NXA], xe[NXA]; /* Dormand-Prince work space */
    double dfdx[NXA * NXA], dfdu[NXA * NUA], dgdx[NYA * NXA], dgdu[NYA * NUA];
    unsigned long n_accepted, n_rejected, n_rhs;
} Instance;

static const char STATE_MAGIC[8] = {'O', 'D', 'E', 'S', 'T', 'A', 'T', '1'};

/* ---------------------------------------------------------------------------------------
 * The glue shared with the other FMUs (../common/fmi2_common.h): logging, FAIL and the
 * CHECK_* macros, version, debug logging, status functions, instances, fmi2Reset, FMU state
 * ------------------------------------------------------------------------------------- */

static void reset_values(Instance *c);
static void invalidate(Instance *c);
static fmi2Status state_check(Instance *c, const OdeState *b, size_t size, const char *fname);
#define FMI2_COMMON_MODEL_NAME ODE_SPEC_MODEL_NAME
#define FMI2_COMMON_PHASE(c) ((c)->s.phase)
#define FMI2_COMMON_LAST_TIME(c) ((c)->s.last_ok_time)
#define FMI2_COMMON_FLAT_STATE OdeState
#define FMI2_COMMON_GUID ODE_SPEC_GUID
#define FMI2_COMMON_STATE_MAGIC STATE_MAGIC
#define FMI2_COMMON_AFTER_SET_STATE(c) invalidate(c)
#include "fmi2_common.h"

#define CHECK_TYPE(c, type, fname)                                                        \
    do {                                                                                  \
        if ((c)->s.fmu_type != (type))                                                    \
            FAIL((c), "%s is a %s function; this instance is %s", (fname),                \
                 (type) == fmi2ModelExchange ? "Model Exchange" : "Co-Simulation",        \
                 (type) == fmi2ModelExchange ? "Co-Simulation" : "Model Exchange");       \
    } while (0)

/* ---------------------------------------------------------------------------------------
 * Variables and evaluation
 * ------------------------------------------------------------------------------------- */

static Kind var_kind(fmi2ValueReference vr, unsigned *k) {
    if (vr >= VR_X && vr < VR_DX) return *k = vr - VR_X, K_X;
    if (vr >= VR_DX && vr < VR_U) return *k = vr - VR_DX, K_DX;
    if (vr >= VR_U && vr < VR_P) return *k = vr - VR_U, K_U;
    if (vr >= VR_P && vr < VR_Y) return *k = vr - VR_P, K_P;
    if (vr >= VR_Y && vr < VR_END) return *k = vr - VR_Y, K_Y;
    return *k = 0, K_NONE;
}

/* Name of a variable (for messages), written to buf when it must be composed. */
typedef struct { char s[300]; } NameBuf;
static const char *var_name(Kind kind, unsigned k, NameBuf *buf) {
    switch (kind) {
    case K_X: return ODE_SPEC_X_NAMES[k];
    case K_DX: snprintf(buf->s, sizeof buf->s, "der(%s)", ODE_SPEC_X_NAMES[k]); return buf->s;
    case K_U: return ODE_SPEC_U_NAMES[k];
    case K_P: return ODE_SPEC_P_NAMES[k];
    case K_Y: return ODE_SPEC_Y_NAMES[k];
    default: return "?";
    }
}

static void invalidate(Instance *c) { c->dx_valid = c->y_valid = 0; }

/* dx = f(t, x, u, p); the index of the first non-finite component, or -1. */
static int rhs(Instance *c, double t, const double *x, double *dx) {
    c->n_rhs++;
    ode_rhs(t, x, c->s.u, c->s.p, dx);
    for (int i = 0; i < NX; i++)
        if (!isfinite(dx[i])) return i;
    return -1;
}

static fmi2Status derivatives(Instance *c, const char *fname) {
    if (c->dx_valid) return fmi2OK;
    int bad = rhs(c, c->s.time, c->s.x, c->dx);
    if (bad >= 0)
        FAIL(c, "%s: der(%s) = %g is not finite at t = %.17g", fname, ODE_SPEC_X_NAMES[bad],
             c->dx[bad], c->s.time);
    c->dx_valid = 1;
    return fmi2OK;
}

static fmi2Status outputs(Instance *c, const char *fname) {
    if (c->y_valid) return fmi2OK;
    ode_out(c->s.time, c->s.x, c->s.u, c->s.p, c->y);
    for (int i = 0; i < NY; i++)
        if (!isfinite(c->y[i]))
            FAIL(c, "%s: output %s = %g is not finite at t = %.17g", fname, ODE_SPEC_Y_NAMES[i],
                 c->y[i], c->s.time);
    c->y_valid = 1;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * Version, logging, instances, initialization
 * ------------------------------------------------------------------------------------- */

/* Start values, time 0, default tolerance, phase Instantiated. */
static void reset_values(Instance *c) {
    OdeState *s = &c->s;
    memcpy(s->x, ODE_SPEC_X_START, sizeof s->x);
    memcpy(s->u, ODE_SPEC_U_START, sizeof s->u);
    memcpy(s->p, ODE_SPEC_P_START, sizeof s->p);
    s->time = s->start_time = s->last_ok_time = 0.0;
    s->rtol = DEFAULT_RTOL;
    s->atol = ATOL_FACTOR * DEFAULT_RTOL;
    s->h_last = 0.0;
    s->phase = PH_INST;
    invalidate(c);
}

/* Whether the model file matches the spec compiled into ode_spec.h (0) or not (1, msg). */
static int contract_error(char *msg, size_t size) {
    const int mine[4] = {NX, NU, NP, NY}, model[4] = {ODE_NX, ODE_NU, ODE_NP, ODE_NY};
    const char *what[4] = {"ODE_NX (states)", "ODE_NU (inputs)", "ODE_NP (parameters)",
                           "ODE_NY (outputs)"};
    for (int i = 0; i < 4; i++)
        if (mine[i] != model[i]) {
            snprintf(msg, size, "the model file defines %s = %d but the FMU spec has %d",
                     what[i], model[i], mine[i]);
            return 1;
        }
    if ((ODE_HAS_JACOBIAN != 0) != (ODE_SPEC_HAS_JACOBIAN != 0)) {
        snprintf(msg, size, "the model file defines ODE_HAS_JACOBIAN = %d but the FMU "
                 "spec has has_jacobian = %s", ODE_HAS_JACOBIAN,
                 ODE_SPEC_HAS_JACOBIAN ? "True" : "False");
        return 1;
    }
    return 0;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)visible, (void)fmuResourceLocation;
    char msg[600];
    if (!functions) return NULL;
    if (!callbacks_ok(functions, instanceName)) return NULL;
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) {
        snprintf(msg, sizeof msg, "fmi2Instantiate: fmuType %d is neither fmi2ModelExchange "
                 "nor fmi2CoSimulation", (int)fmuType);
        emit(functions, instanceName, fmi2Error, "logStatusError", msg);
        return NULL;
    }
    if (!guid_ok(functions, instanceName, fmuGUID)) return NULL;
    char bad[400];
    if (contract_error(bad, sizeof bad)) {
        snprintf(msg, sizeof msg, "fmi2Instantiate: %s: %s", ODE_SPEC_MODEL_NAME, bad);
        emit(functions, instanceName, fmi2Error, "logStatusError", msg);
        return NULL;
    }
    Instance *c = instance_new(functions, instanceName, loggingOn);
    if (!c) return NULL;
    c->s.fmu_type = (int32_t)fmuType;
    c->s.dims[0] = NX, c->s.dims[1] = NU, c->s.dims[2] = NP, c->s.dims[3] = NY;
    reset_values(c);
    logf_(c, fmi2OK, "instantiated %s for %s (NX=%d NU=%d NP=%d NY=%d)", ODE_SPEC_MODEL_NAME,
          fmuType == fmi2ModelExchange ? "Model Exchange" : "Co-Simulation", NX, NU, NP, NY);
    return c;
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *c = (Instance *)comp;
    if (setup_checks(c, startTime, 1, stopTimeDefined, stopTime) != fmi2OK) return fmi2Error;
    fmi2Status status = fmi2OK;
    if (toleranceDefined) {
        if (!isfinite(tolerance) || tolerance <= 0.0)
            FAIL(c, "fmi2SetupExperiment: tolerance %g must be finite and > 0", tolerance);
        c->s.rtol = tolerance;
        if (tolerance < MIN_RTOL) {
            logf_(c, fmi2Warning, "fmi2SetupExperiment: tolerance %g raised to %g", tolerance,
                  MIN_RTOL);
            c->s.rtol = MIN_RTOL;
            status = fmi2Warning;
        }
        c->s.atol = ATOL_FACTOR * c->s.rtol;
    }
    c->s.time = c->s.start_time = c->s.last_ok_time = startTime;
    invalidate(c);
    return status;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_INIT, "fmi2ExitInitializationMode");
    if (derivatives(c, "fmi2ExitInitializationMode") != fmi2OK) return fmi2Error;
    c->s.phase = c->s.fmu_type == fmi2ModelExchange ? PH_EVENT : PH_STEP;
    c->s.h_last = 0.0;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * Getting and setting variables
 * ------------------------------------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2GetReal");
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        switch (var_kind(vr[i], &k)) {
        case K_X: value[i] = c->s.x[k]; break;
        case K_U: value[i] = c->s.u[k]; break;
        case K_P: value[i] = c->s.p[k]; break;
        case K_DX:
            if (derivatives(c, "fmi2GetReal") != fmi2OK) return fmi2Error;
            value[i] = c->dx[k];
            break;
        case K_Y:
            if (outputs(c, "fmi2GetReal") != fmi2OK) return fmi2Error;
            value[i] = c->y[k];
            break;
        default: FAIL(c, "fmi2GetReal: %u is not the value reference of a variable", vr[i]);
        }
    }
    return fmi2OK;
}

/* Why variable (kind, k) cannot be set in the current phase, or NULL. */
static const char *not_settable(const Instance *c, Kind kind, unsigned k) {
    const unsigned ph = 1u << c->s.phase;
    switch (kind) {
    case K_X:
        if (ph & (M_INST | M_INIT)) return NULL;
        return c->s.fmu_type == fmi2ModelExchange
                   ? "is a state: set it with fmi2SetContinuousStates after initialization"
                   : "is a state and can be set only before or in Initialization Mode";
    case K_DX: case K_Y: return "is calculated and cannot be set";
    case K_U: return (ph & (M_INST | M_INIT | M_EVENT | M_CONT | M_STEP)) ? NULL : "is an input";
    case K_P:
        if (ph & (M_INST | M_INIT)) return NULL;
        if (!ODE_SPEC_P_TUNABLE[k]) return "is a fixed parameter";
        return (ph & (M_EVENT | M_CONT | M_STEP)) ? NULL : "is a tunable parameter";
    default: return "is not a variable";
    }
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2SetReal");
    NameBuf nb;
    for (size_t i = 0; i < nvr; i++) { /* check all first: all or nothing */
        unsigned k;
        Kind kind = var_kind(vr[i], &k);
        if (kind == K_NONE) FAIL(c, "fmi2SetReal: %u is not the value reference of a variable", vr[i]);
        const char *why = not_settable(c, kind, k);
        if (why)
            FAIL(c, "fmi2SetReal: %s (value reference %u) %s; it cannot be set in %s",
                 var_name(kind, k, &nb), vr[i], why, PHASE_NAMES[c->s.phase]);
        if (!isfinite(value[i]))
            FAIL(c, "fmi2SetReal: %s = %g at t = %.17g: the value is not finite", var_name(kind, k, &nb),
                 value[i], c->s.time);
    }
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        switch (var_kind(vr[i], &k)) {
        case K_X: c->s.x[k] = value[i]; break;
        case K_U: c->s.u[k] = value[i]; break;
        case K_P: c->s.p[k] = value[i]; break;
        default: break;
        }
    }
    if (nvr) invalidate(c);
    return fmi2OK;
}

NO_VARIABLES(Integer, fmi2Integer, const)
NO_VARIABLES(Boolean, fmi2Boolean, const)
NO_VARIABLES(String, fmi2String, const)

/* ---------------------------------------------------------------------------------------
 * FMU state: a copy of OdeState (native byte order; magic, GUID and size checked)
 * ------------------------------------------------------------------------------------- */

static fmi2Status state_check(Instance *c, const OdeState *b, size_t size, const char *fname) {
    if (size != sizeof(OdeState))
        FAIL(c, "%s: FMU state has %zu bytes, expected %zu", fname, size, sizeof(OdeState));
    if (memcmp(b->magic, STATE_MAGIC, 8) != 0) FAIL(c, "%s: not an FMU state of this glue", fname);
    if (b->endian != 0x01020304u) FAIL(c, "%s: FMU state of another byte order", fname);
    if (strncmp(b->guid, ODE_SPEC_GUID, sizeof b->guid) != 0)
        FAIL(c, "%s: FMU state of another FMU (GUID %.63s, this is %s)", fname, b->guid,
             ODE_SPEC_GUID);
    if (b->fmu_type != c->s.fmu_type)
        FAIL(c, "%s: FMU state of a %s instance", fname,
             b->fmu_type == fmi2ModelExchange ? "Model Exchange" : "Co-Simulation");
    if (b->phase < PH_INST || b->phase > PH_ERROR) FAIL(c, "%s: invalid phase %d", fname, (int)b->phase);
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * Directional derivatives: d(der(x), y) / d(x, u) from the exact Jacobians of ode_jac
 * ------------------------------------------------------------------------------------- */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
#if !ODE_SPEC_HAS_JACOBIAN
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown,
        (void)dvUnknown;
    FAIL(c, "fmi2GetDirectionalDerivative: %s provides no exact Jacobian (ODE_HAS_JACOBIAN = 0, "
            "providesDirectionalDerivative=false)", ODE_SPEC_MODEL_NAME);
#else
    const char *fname = "fmi2GetDirectionalDerivative";
    NameBuf nb;
    CHECK_ARRAYS(c, vUnknown_ref, nUnknown, dvUnknown, fname);
    CHECK_ARRAYS(c, vKnown_ref, nKnown, dvKnown, fname);
    for (size_t j = 0; j < nKnown; j++) {
        unsigned k;
        Kind kind = var_kind(vKnown_ref[j], &k);
        if (kind != K_X && kind != K_U)
            FAIL(c, "%s: known %u (%s) is neither a state nor an input", fname, vKnown_ref[j],
                 var_name(kind, k, &nb));
        if (!isfinite(dvKnown[j]))
            FAIL(c, "%s: seed of %s = %g is not finite", fname, var_name(kind, k, &nb), dvKnown[j]);
    }
    for (size_t i = 0; i < nUnknown; i++) {
        unsigned k;
        Kind kind = var_kind(vUnknown_ref[i], &k);
        if (kind != K_DX && kind != K_Y)
            FAIL(c, "%s: unknown %u (%s) is neither a derivative nor an output", fname,
                 vUnknown_ref[i], var_name(kind, k, &nb));
    }
    memset(c->dfdx, 0, sizeof c->dfdx);
    memset(c->dfdu, 0, sizeof c->dfdu);
    memset(c->dgdx, 0, sizeof c->dgdx);
    memset(c->dgdu, 0, sizeof c->dgdu);
    ode_jac(c->s.time, c->s.x, c->s.u, c->s.p, c->dfdx, c->dfdu, c->dgdx, c->dgdu);
    for (size_t i = 0; i < nUnknown; i++) {
        unsigned row;
        const int is_dx = var_kind(vUnknown_ref[i], &row) == K_DX;
        const double *jx = (is_dx ? c->dfdx : c->dgdx) + (size_t)row * NX;
        const double *ju = (is_dx ? c->dfdu : c->dgdu) + (size_t)row * NU;
        double sum = 0.0;
        for (size_t j = 0; j < nKnown; j++) {
            unsigned col;
            const Kind kind = var_kind(vKnown_ref[j], &col);
            sum += (kind == K_X ? jx[col] : ju[col]) * dvKnown[j];
        }
        if (!isfinite(sum))
            FAIL(c, "%s: directional derivative of %s is not finite at t = %.17g", fname,
                 var_name(is_dx ? K_DX : K_Y, row, &nb), c->s.time);
        dvUnknown[i] = sum;
    }
    return fmi2OK;
#endif
}

/* ---------------------------------------------------------------------------------------
 * Model Exchange
 * ------------------------------------------------------------------------------------- */

#define ME_CALL(c, mask, fname)                                                           \
    do {                                                                                  \
        CHECK_INSTANCE(c);                                                                \
        CHECK_TYPE((c), fmi2ModelExchange, (fname));                                      \
        CHECK_PHASE((c), (mask), (fname));                                                \
    } while (0)
#define M_ME_READ (M_INIT | M_EVENT | M_CONT | M_TERM | M_ERR)

fmi2Status fmi2EnterEventMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_EVENT | M_CONT, "fmi2EnterEventMode");
    c->s.phase = PH_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component comp, fmi2EventInfo *eventInfo) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_EVENT, "fmi2NewDiscreteStates");
    if (!eventInfo) FAIL(c, "fmi2NewDiscreteStates: eventInfo is NULL");
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_EVENT, "fmi2EnterContinuousTimeMode");
    c->s.phase = PH_CONT;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component comp,
                                       fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_CONT, "fmi2CompletedIntegratorStep");
    if (!enterEventMode || !terminateSimulation)
        FAIL(c, "fmi2CompletedIntegratorStep: NULL argument");
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    c->s.last_ok_time = c->s.time;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component comp, fmi2Real time) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_EVENT | M_CONT, "fmi2SetTime");
    if (!isfinite(time)) FAIL(c, "fmi2SetTime: time %g is not finite", time);
    c->s.time = time;
    invalidate(c);
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component comp, const fmi2Real x[], size_t nx) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_INIT | M_EVENT | M_CONT, "fmi2SetContinuousStates");
    if (nx != (size_t)NX) FAIL(c, "fmi2SetContinuousStates: nx = %zu, the FMU has %d states", nx, NX);
    if (nx > 0 && !x) FAIL(c, "fmi2SetContinuousStates: x is NULL");
    for (size_t i = 0; i < nx; i++)
        if (!isfinite(x[i]))
            FAIL(c, "fmi2SetContinuousStates: %s = %g at t = %.17g is not finite",
                 ODE_SPEC_X_NAMES[i], x[i], c->s.time);
    if (nx) memcpy(c->s.x, x, nx * sizeof(double));
    invalidate(c);
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component comp, fmi2Real derivatives_[], size_t nx) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_ME_READ, "fmi2GetDerivatives");
    if (nx != (size_t)NX) FAIL(c, "fmi2GetDerivatives: nx = %zu, the FMU has %d states", nx, NX);
    if (nx > 0 && !derivatives_) FAIL(c, "fmi2GetDerivatives: derivatives is NULL");
    if (derivatives(c, "fmi2GetDerivatives") != fmi2OK) return fmi2Error;
    if (nx) memcpy(derivatives_, c->dx, nx * sizeof(double));
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component comp, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_ME_READ, "fmi2GetEventIndicators");
    if (ni != 0) FAIL(c, "fmi2GetEventIndicators: ni = %zu, the FMU has no event indicators", ni);
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component comp, fmi2Real x[], size_t nx) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_ME_READ, "fmi2GetContinuousStates");
    if (nx != (size_t)NX) FAIL(c, "fmi2GetContinuousStates: nx = %zu, the FMU has %d states", nx, NX);
    if (nx > 0 && !x) FAIL(c, "fmi2GetContinuousStates: x is NULL");
    if (nx) memcpy(x, c->s.x, nx * sizeof(double));
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component comp, fmi2Real x_nominal[], size_t nx) {
    Instance *c = (Instance *)comp;
    ME_CALL(c, M_INST | M_ME_READ, "fmi2GetNominalsOfContinuousStates");
    if (nx != (size_t)NX)
        FAIL(c, "fmi2GetNominalsOfContinuousStates: nx = %zu, the FMU has %d states", nx, NX);
    if (nx > 0 && !x_nominal) FAIL(c, "fmi2GetNominalsOfContinuousStates: x_nominal is NULL");
    for (size_t i = 0; i < nx; i++) x_nominal[i] = 1.0;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * Co-Simulation: Dormand-Prince 5(4)
 * ------------------------------------------------------------------------------------- */

static const double C2 = 1.0 / 5, C3 = 3.0 / 10, C4 = 4.0 / 5, C5 = 8.0 / 9;
static const double A21 = 1.0 / 5;
static const double A31 = 3.0 / 40, A32 = 9.0 / 40;
static const double A41 = 44.0 / 45, A42 = -56.0 / 15, A43 = 32.0 / 9;
static const double A51 = 19372.0 / 6561, A52 = -25360.0 / 2187, A53 = 64448.0 / 6561,
                    A54 = -212.0 / 729;
static const double A61 = 9017.0 / 3168, A62 = -355.0 / 33, A63 = 46732.0 / 5247,
                    A64 = 49.0 / 176, A65 = -5103.0 / 18656;
static const double A71 = 35.0 / 384, A73 = 500.0 / 1113, A74 = 125.0 / 192,
                    A75 = -2187.0 / 6784, A76 = 11.0 / 84;
/* error weights: 5th-order minus 4th-order weights */
static const double E1 = 71.0 / 57600, E3 = -71.0 / 16695, E4 = 71.0 / 1920,
                    E5 = -17253.0 / 339200, E6 = 22.0 / 525, E7 = -1.0 / 40;

/* Weighted RMS norm of v with scale atol + rtol * max(|a|, |b|). */
static double wnorm(const Instance *c, const double *v, const double *a, const double *b) {
    double s = 0.0;
    for (int i = 0; i < NX; i++) {
        const double sc = c->s.atol + c->s.rtol * fmax(fabs(a[i]), fabs(b[i]));
        s += (v[i] / sc) * (v[i] / sc);
    }
    return NX > 0 ? sqrt(s / NX) : 0.0;
}

/* One trial step from (t, x) with k[0] = f(t, x): xn (5th order), k[6] = f(t + h, xn),
 * xe = local error estimate. The index of a non-finite stage derivative, or -1. */
static int dp_step(Instance *c, double t, const double *x, double h) {
    double(*k)[NXA] = c->k;
    double *xs = c->xs;
    int i, bad;
#define STAGE(s, tt, expr)                                                                \
    for (i = 0; i < NX; i++) xs[i] = x[i] + h * (expr);                                   \
    if ((bad = rhs(c, (tt), xs, k[s])) >= 0) return bad;
    STAGE(1, t + C2 * h, A21 * k[0][i])
    STAGE(2, t + C3 * h, A31 * k[0][i] + A32 * k[1][i])
    STAGE(3, t + C4 * h, A41 * k[0][i] + A42 * k[1][i] + A43 * k[2][i])
    STAGE(4, t + C5 * h, A51 * k[0][i] + A52 * k[1][i] + A53 * k[2][i] + A54 * k[3][i])
    STAGE(5, t + h, A61 * k[0][i] + A62 * k[1][i] + A63 * k[2][i] + A64 * k[3][i] + A65 * k[4][i])
#undef STAGE
    for (i = 0; i < NX; i++)
        c->xn[i] = x[i] + h * (A71 * k[0][i] + A73 * k[2][i] + A74 * k[3][i] + A75 * k[4][i] +
                               A76 * k[5][i]);
    if ((bad = rhs(c, t + h, c->xn, k[6])) >= 0) return bad;
    for (i = 0; i < NX; i++)
        c->xe[i] = h * (E1 * k[0][i] + E3 * k[2][i] + E4 * k[3][i] + E5 * k[4][i] +
                        E6 * k[5][i] + E7 * k[6][i]);
    return -1;
}

/* First step size (Hairer, Norsett, Wanner, Solving ODEs I, II.4), at most H. */
static double initial_step(Instance *c, double t, const double *x, double H) {
    const double d0 = wnorm(c, x, x, x), d1 = wnorm(c, c->k[0], x, x);
    double h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    h0 = fmin(h0, H);
    for (int i = 0; i < NX; i++) c->xs[i] = x[i] + h0 * c->k[0][i];
    if (rhs(c, t + h0, c->xs, c->k[1]) >= 0) return 1e-3 * h0;
    for (int i = 0; i < NX; i++) c->xe[i] = c->k[1][i] - c->k[0][i];
    const double d2 = wnorm(c, c->xe, x, x) / h0, dm = fmax(d1, d2);
    const double h1 = dm <= 1e-15 ? fmax(1e-6, 1e-3 * h0) : pow(0.01 / dm, 0.2);
    return fmin(fmin(100.0 * h0, h1), H);
}

/* Integrate from c->s.time to t_end; on failure the state stays at the last accepted
 * internal step (c->s.time, c->s.last_ok_time) and *bad names a non-finite derivative. */
static const char *integrate(Instance *c, double t_end, int *bad) {
    double *x = c->s.x, t = c->s.time, h = c->s.h_last;
    unsigned long steps = 0;
    int rejected = 0;
    *bad = rhs(c, t, x, c->k[0]);
    if (*bad >= 0) return "non-finite derivative";
    if (!(h > 0.0)) h = t_end > t ? initial_step(c, t, x, t_end - t) : 0.0;
    while (1) {
        if (++steps > MAX_SUBSTEPS) return "too many internal steps";
        const double remaining = t_end - t, tiny = 16.0 * DBL_EPSILON * fmax(1.0, fabs(t));
        /* the last step may stretch by 1% rather than leave a sliver */
        const int last = h >= 0.99 * remaining;
        const double hs = last ? remaining : h;
        if (last && hs <= tiny) { /* below time resolution: one Euler step */
            for (int i = 0; i < NX; i++) x[i] += hs * c->k[0][i];
            c->s.time = c->s.last_ok_time = t_end;
            return NULL;
        }
        if (hs <= tiny) return "step size underflow";
        const int nf = dp_step(c, t, x, hs);
        const double err = nf >= 0 ? INFINITY : wnorm(c, c->xe, x, c->xn);
        if (!(err <= 1.0)) { /* reject */
            c->n_rejected++;
            *bad = nf;
            h = hs * (nf >= 0 ? 0.25 : fmax(0.2, 0.9 * pow(err, -0.2)));
            rejected = 1;
            continue;
        }
        c->n_accepted++;
        *bad = -1;
        double fac = err == 0.0 ? 5.0 : fmin(5.0, fmax(0.2, 0.9 * pow(err, -0.2)));
        if (rejected) fac = fmin(fac, 1.0);
        rejected = 0;
        memcpy(x, c->xn, sizeof c->xn);
        memcpy(c->k[0], c->k[6], sizeof c->k[0]); /* FSAL */
        t = last ? t_end : t + hs;
        c->s.time = c->s.last_ok_time = t;
        /* a step cut to end at t_end does not shrink the next step unless it had to */
        h = (last && hs < h && fac >= 1.0) ? fmax(h, hs * fac) : hs * fac;
        c->s.h_last = h;
        if (last) return NULL;
    }
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_TYPE(c, fmi2CoSimulation, "fmi2DoStep");
    CHECK_PHASE(c, M_STEP, "fmi2DoStep");
    const double t = currentCommunicationPoint, H = communicationStepSize;
    if (step_checks(c, t, H, 1, c->s.time) != fmi2OK) return fmi2Error;
    c->s.time = t;
    if (H == 0.0) return fmi2OK;
    const unsigned long acc = c->n_accepted, rej = c->n_rejected;
    int bad = -1;
    invalidate(c);
    const char *why = integrate(c, t + H, &bad);
    invalidate(c);
    if (why) {
        c->s.phase = PH_ERROR;
        if (bad >= 0)
            FAIL(c, "fmi2DoStep from t = %.17g with h = %g: %s: der(%s) is not finite at "
                    "t = %.17g", t, H, why, ODE_SPEC_X_NAMES[bad], c->s.time);
        FAIL(c, "fmi2DoStep from t = %.17g with h = %g: %s at t = %.17g (rtol %g, atol %g)", t,
             H, why, c->s.time, c->s.rtol, c->s.atol);
    }
    logf_(c, fmi2OK, "fmi2DoStep to t = %.17g: %lu accepted, %lu rejected internal steps, next "
          "h = %g", c->s.time, c->n_accepted - acc, c->n_rejected - rej, c->s.h_last);
    return fmi2OK;
}
