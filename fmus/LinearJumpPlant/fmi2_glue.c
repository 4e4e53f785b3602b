/*
 * LinearJumpPlant: FMI 2.0 glue (Co-Simulation). Translates the FMI 2.0 C API into calls
 * of the model code in model.c; all numerics live there.
 *
 * Every fmi2 function of the standard is exported; Model Exchange, directional
 * derivatives, input interpolation, output derivatives and asynchronous steps are not
 * supported, and the corresponding functions log a message and return fmi2Error.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

typedef enum { PH_INST = 0, PH_INIT = 1, PH_STEP = 2, PH_TERM = 3, PH_ERROR = 4 } Phase;

static const char *PHASE_NAMES[] = {"Instantiated", "Initialization Mode", "Step Mode",
                                    "Terminated", "Error"};

typedef struct {
    fmi2CallbackFunctions cb;
    LJP_Allocator al;
    char *name;          /* the instance name */
    char *resource_file; /* <resources>/system.txt */
    char *system_file;   /* value of the String parameter systemFile ("" when unset) */
    int logging_on;
    unsigned log_categories;
    Phase phase;
    double start_time;
    LJP_System res_sys;  /* read from the resources at instantiation */
    LJP_System file_sys; /* read from systemFile at exitInitializationMode */
    int have_file_sys;
    LJP_Model model;
} Instance;

/* The glue shared with the other FMUs (../common/fmi2_common.h): logging, FAIL and the
 * CHECK_* macros, version, debug logging, the status functions, freeing and serializing
 * FMU states. */
#define FMI2_COMMON_MODEL_NAME "LinearJumpPlant"
#define FMI2_COMMON_PHASE(c) ((c)->phase)
#define FMI2_COMMON_LAST_TIME(c) ((c)->model.time)
#define FMI2_COMMON_INTERPOLATE_NOTE "; inputs are held constant over a step"
/* An FMU state: its serialization (below) behind its size. */
typedef struct {
    size_t size;
    unsigned char data[];
} StateBlob;
#define FMI2_COMMON_STATE_SIZE(state) (((const StateBlob *)(state))->size)
#define FMI2_COMMON_STATE_BYTES(state) (((const StateBlob *)(state))->data)
#define FMI2_COMMON_STATE_FREE(c, p) ((c)->al.release(p))
#include "fmi2_common.h"

/* ---------------------------------------------------------------------------------------
 * Memory
 * ------------------------------------------------------------------------------------- */

static void *std_calloc(size_t nobj, size_t size) { return calloc(nobj, size); }
static void std_free(void *p) { free(p); }

static char *dup_string(const LJP_Allocator *al, const char *s) {
    if (!s) s = "";
    size_t len = strlen(s);
    char *d = (char *)al->alloc(len + 1, 1);
    if (d) memcpy(d, s, len + 1);
    return d;
}

/* ---------------------------------------------------------------------------------------
 * Paths
 * ------------------------------------------------------------------------------------- */

static int hexval(char ch) {
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

/* A file URI ("file:///a/b", "file://localhost/a/b", "file:/a/b") or a plain path, to a
 * newly allocated path with `suffix` appended. NULL for other URI schemes. */
static char *location_to_path(const LJP_Allocator *al, const char *loc, const char *suffix) {
    const char *p = loc;
    int is_uri = 0;
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        is_uri = 1;
        if (*p != '/') { /* authority, e.g. localhost */
            const char *slash = strchr(p, '/');
            if (!slash) return NULL;
            p = slash;
        }
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
        is_uri = 1;
    } else if (strstr(p, "://")) {
        return NULL;
    }
    size_t len = strlen(p), slen = strlen(suffix);
    char *out = (char *)al->alloc(len + slen + 2, 1);
    if (!out) return NULL;
    size_t k = 0;
    for (size_t i = 0; i < len; i++) {
        if (is_uri && p[i] == '%' && i + 2 < len && hexval(p[i + 1]) >= 0 &&
            hexval(p[i + 2]) >= 0) {
            out[k++] = (char)(hexval(p[i + 1]) * 16 + hexval(p[i + 2]));
            i += 2;
        } else {
            out[k++] = p[i];
        }
    }
    if (slen && k > 0 && out[k - 1] != '/' && suffix[0] != '/') out[k++] = '/';
    memcpy(out + k, suffix, slen + 1);
    return out;
}

/* ---------------------------------------------------------------------------------------
 * Creation and destruction of instances
 * ------------------------------------------------------------------------------------- */

static void free_instance(Instance *c) {
    if (!c) return;
    LJP_Allocator al = c->al;
    ljp_model_free(&c->model);
    ljp_system_free(&al, &c->res_sys);
    if (c->have_file_sys) ljp_system_free(&al, &c->file_sys);
    if (c->name) al.release(c->name);
    if (c->resource_file) al.release(c->resource_file);
    if (c->system_file) al.release(c->system_file);
    al.release(c);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)visible;
    char msg[1024];
    if (!functions) return NULL;
    LJP_Allocator al = {functions->allocateMemory ? functions->allocateMemory : std_calloc,
                        functions->freeMemory ? functions->freeMemory : std_free};
    if (fmuType != fmi2CoSimulation) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "LinearJumpPlant supports Co-Simulation only (fmuType must be fmi2CoSimulation)");
        return NULL;
    }
    if (!fmuResourceLocation || !*fmuResourceLocation) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "fmuResourceLocation is missing: the system matrices are read from "
             "<resources>/system.txt");
        return NULL;
    }
    Instance *c = (Instance *)al.alloc(1, sizeof(Instance));
    if (!c) {
        emit(functions, instanceName, fmi2Error, "logStatusError", "out of memory");
        return NULL;
    }
    c->cb = *functions;
    c->al = al;
    c->logging_on = loggingOn ? 1 : 0;
    c->log_categories = LOG_ALL;
    c->phase = PH_INST;
    c->name = dup_string(&al, instanceName ? instanceName : "LinearJumpPlant");
    c->system_file = dup_string(&al, "");
    c->resource_file = location_to_path(&al, fmuResourceLocation, "system.txt");
    if (!c->name || !c->system_file) {
        emit(functions, instanceName, fmi2Error, "logStatusError", "out of memory");
        free_instance(c);
        return NULL;
    }
    if (!c->resource_file) {
        snprintf(msg, sizeof msg,
                 "fmuResourceLocation '%s' is not a file URI or path", fmuResourceLocation);
        emit(functions, instanceName, fmi2Error, "logStatusError", msg);
        free_instance(c);
        return NULL;
    }
    if (ljp_system_read(&c->al, c->resource_file, &c->res_sys, msg, sizeof msg)) {
        emit(functions, instanceName, fmi2Error, "logStatusError", msg);
        free_instance(c);
        return NULL;
    }
    if (c->res_sys.guid[0] && fmuGUID && strcmp(c->res_sys.guid, fmuGUID) != 0) {
        snprintf(msg, sizeof msg,
                 "%s: guid %s does not match the FMU's GUID %s (resources and "
                 "modelDescription.xml come from different builds)",
                 c->resource_file, c->res_sys.guid, fmuGUID);
        emit(functions, instanceName, fmi2Error, "logStatusError", msg);
        free_instance(c);
        return NULL;
    }
    if (ljp_model_init(&c->model, &c->al, &c->res_sys)) {
        emit(functions, instanceName, fmi2Error, "logStatusError", "out of memory");
        free_instance(c);
        return NULL;
    }
    char dims[256];
    ljp_system_dims_str(&c->res_sys, dims, sizeof dims);
    logf_(c, fmi2OK, "instantiated from %s (%s)", c->resource_file, dims);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) { free_instance((Instance *)comp); }

/* ---------------------------------------------------------------------------------------
 * Initialization, termination, reset
 * ------------------------------------------------------------------------------------- */

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    (void)toleranceDefined, (void)tolerance;
    Instance *c = (Instance *)comp;
    if (setup_checks(c, startTime, 0, stopTimeDefined, stopTime) != fmi2OK) return fmi2Error;
    c->start_time = startTime;
    c->model.time = startTime;
    return fmi2OK;
}

static fmi2Status load_system_file(Instance *c) {
    char msg[1024];
    char *path = location_to_path(&c->al, c->system_file, "");
    if (!path) FAIL(c, "systemFile '%s' is not a file path or file URI", c->system_file);
    LJP_System sys;
    int rc = ljp_system_read(&c->al, path, &sys, msg, sizeof msg);
    if (rc) {
        c->al.release(path);
        FAIL(c, "systemFile: %s", msg);
    }
    if (!ljp_system_same_dims(&sys, &c->res_sys)) {
        char a[256], b[256];
        ljp_system_dims_str(&sys, a, sizeof a);
        ljp_system_dims_str(&c->res_sys, b, sizeof b);
        ljp_system_free(&c->al, &sys);
        logf_(c, fmi2Error,
              "systemFile %s: dimensions (%s) differ from those of this FMU's "
              "modelDescription.xml (%s); build an FMU for that system instead",
              path, a, b);
        c->al.release(path);
        return fmi2Error;
    }
    if (c->have_file_sys) ljp_system_free(&c->al, &c->file_sys);
    c->file_sys = sys;
    c->have_file_sys = 1;
    ljp_model_set_system(&c->model, &c->file_sys);
    logf_(c, fmi2OK, "system matrices read from systemFile %s", path);
    c->al.release(path);
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_INIT, "fmi2ExitInitializationMode");
    if (c->system_file[0]) {
        if (load_system_file(c) != fmi2OK) return fmi2Error;
    } else if (c->have_file_sys) {
        ljp_model_set_system(&c->model, &c->res_sys);
        ljp_system_free(&c->al, &c->file_sys);
        c->have_file_sys = 0;
    }
    LJP_Model *m = &c->model;
    memcpy(m->x, m->x0, (size_t)m->sys->n * sizeof(double));
    m->time = c->start_time;
    c->phase = PH_STEP;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (c->have_file_sys) {
        ljp_model_set_system(&c->model, &c->res_sys);
        ljp_system_free(&c->al, &c->file_sys);
        c->have_file_sys = 0;
    }
    ljp_model_reset(&c->model);
    c->system_file[0] = '\0';
    c->start_time = 0.0;
    c->phase = PH_INST;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * Getting and setting variable values
 * ------------------------------------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2GetReal");
    LJP_Model *m = &c->model;
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        switch (ljp_var_kind(&m->lay, vr[i], &k)) {
        case LJP_VAR_X0: value[i] = m->x0[k]; break;
        case LJP_VAR_U: value[i] = m->u[k]; break;
        case LJP_VAR_W: value[i] = m->w[k]; break;
        case LJP_VAR_DELTA1: value[i] = m->delta1[k]; break;
        case LJP_VAR_DELTA2: value[i] = m->delta2[k]; break;
        case LJP_VAR_X: value[i] = m->x[k]; break;
        case LJP_VAR_Y: value[i] = ljp_model_y(m, k); break;
        case LJP_VAR_YM: value[i] = ljp_model_ym(m, k); break;
        default: FAIL(c, "fmi2GetReal: %u is not the value reference of a Real variable", vr[i]);
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2GetInteger");
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        if (ljp_var_kind(&c->model.lay, vr[i], &k) != LJP_VAR_MODE)
            FAIL(c, "fmi2GetInteger: %u is not the value reference of an Integer variable", vr[i]);
        value[i] = c->model.mode;
    }
    return fmi2OK;
}

NO_VARIABLES(Boolean, fmi2Boolean, const)

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2GetString");
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        if (ljp_var_kind(&c->model.lay, vr[i], &k) != LJP_VAR_SYSTEM_FILE)
            FAIL(c, "fmi2GetString: %u is not the value reference of a String variable", vr[i]);
        value[i] = c->system_file;
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2SetReal");
    LJP_Model *m = &c->model;
    const int can_set_params = IN_PHASE(c, M_INST | M_INIT);
    const int can_set_inputs = IN_PHASE(c, M_INST | M_INIT | M_STEP);
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        LJP_VarKind kind = ljp_var_kind(&m->lay, vr[i], &k);
        if (kind == LJP_VAR_INVALID || kind == LJP_VAR_MODE || kind == LJP_VAR_SYSTEM_FILE)
            FAIL(c, "fmi2SetReal: %u is not the value reference of a Real variable", vr[i]);
        if (kind == LJP_VAR_X || kind == LJP_VAR_Y || kind == LJP_VAR_YM)
            FAIL(c, "fmi2SetReal: value reference %u is an output (%s[%u]) and cannot be set",
                 vr[i], kind == LJP_VAR_X ? "x" : (kind == LJP_VAR_Y ? "y" : "ym"), k + 1);
        if (!isfinite(value[i]))
            FAIL(c, "fmi2SetReal: value reference %u: non-finite value %g", vr[i], value[i]);
        if (kind == LJP_VAR_X0) {
            if (!can_set_params)
                FAIL(c, "fmi2SetReal: x0[%u] is a fixed parameter and cannot be set in %s", k + 1,
                     PHASE_NAMES[c->phase]);
            m->x0[k] = value[i];
            m->x[k] = value[i]; /* x = x0 until the first step */
            continue;
        }
        if (!can_set_inputs)
            FAIL(c, "fmi2SetReal: inputs cannot be set in %s", PHASE_NAMES[c->phase]);
        switch (kind) {
        case LJP_VAR_U: m->u[k] = value[i]; break;
        case LJP_VAR_W: m->w[k] = value[i]; break;
        case LJP_VAR_DELTA1: m->delta1[k] = value[i]; break;
        case LJP_VAR_DELTA2: m->delta2[k] = value[i]; break;
        default: break;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2SetInteger");
    if (nvr > 0) CHECK_PHASE(c, M_INST | M_INIT | M_STEP, "fmi2SetInteger");
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        if (ljp_var_kind(&c->model.lay, vr[i], &k) != LJP_VAR_MODE)
            FAIL(c, "fmi2SetInteger: %u is not the value reference of an Integer variable", vr[i]);
        if (value[i] < 1 || value[i] > c->model.sys->m)
            FAIL(c, "fmi2SetInteger: mode = %d is out of range 1..%d", (int)value[i],
                 c->model.sys->m);
        c->model.mode = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS(c, vr, nvr, value, "fmi2SetString");
    for (size_t i = 0; i < nvr; i++) {
        unsigned k;
        if (ljp_var_kind(&c->model.lay, vr[i], &k) != LJP_VAR_SYSTEM_FILE)
            FAIL(c, "fmi2SetString: %u is not the value reference of a String variable", vr[i]);
        if (!IN_PHASE(c, M_INST | M_INIT))
            FAIL(c, "fmi2SetString: systemFile is a fixed parameter and cannot be set in %s",
                 PHASE_NAMES[c->phase]);
        char *s = dup_string(&c->al, value[i]);
        if (!s) FAIL(c, "fmi2SetString: out of memory");
        c->al.release(c->system_file);
        c->system_file = s;
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------
 * FMU state: an FMU state is its own serialization (a self-describing byte blob).
 *
 *   "LJPSTATE" | u32 0x01020304 | u32 version | u64 system fingerprint | i32 dims[9] |
 *   i32 phase | i32 mode | f64 time | f64 start time | f64 x0[n] x[n] u[nu] w[nw]
 *   Delta1[q1 p1] Delta2[q2 p2] | u32 length of systemFile | systemFile bytes
 *
 * Native byte order (the endianness marker is checked); a state can be restored only
 * into an instance that uses the same system matrices (same fingerprint).
 * ------------------------------------------------------------------------------------- */

static const char STATE_MAGIC[8] = {'L', 'J', 'P', 'S', 'T', 'A', 'T', 'E'};
#define STATE_HEADER (8 + 4 + 4 + 8 + 9 * 4 + 4 + 4 + 8 + 8)

static size_t state_size(const Instance *c) {
    const LJP_System *s = c->model.sys;
    size_t nd = (size_t)2 * s->n + s->nu + s->nw + (size_t)s->q1 * s->p1 + (size_t)s->q2 * s->p2;
    return STATE_HEADER + nd * sizeof(double) + 4 + strlen(c->system_file);
}

static void put(unsigned char **p, const void *src, size_t len) {
    memcpy(*p, src, len);
    *p += len;
}

static void get(const unsigned char **p, void *dst, size_t len) {
    memcpy(dst, *p, len);
    *p += len;
}

static void dims_of(const LJP_System *s, int32_t d[9]) {
    const int v[9] = {s->n, s->nu, s->ny, s->nw, s->m, s->q1, s->p1, s->q2, s->p2};
    for (int i = 0; i < 9; i++) d[i] = (int32_t)v[i];
}

static void state_write(const Instance *c, unsigned char *buf) {
    const LJP_Model *m = &c->model;
    const LJP_System *s = m->sys;
    unsigned char *p = buf;
    const uint32_t endian = 0x01020304u, version = LJP_STATE_VERSION;
    int32_t d[9];
    dims_of(s, d);
    const int32_t phase = (int32_t)c->phase, mode = (int32_t)m->mode;
    put(&p, STATE_MAGIC, 8);
    put(&p, &endian, 4);
    put(&p, &version, 4);
    put(&p, &s->fingerprint, 8);
    put(&p, d, sizeof d);
    put(&p, &phase, 4);
    put(&p, &mode, 4);
    put(&p, &m->time, 8);
    put(&p, &c->start_time, 8);
    put(&p, m->x0, (size_t)s->n * 8);
    put(&p, m->x, (size_t)s->n * 8);
    put(&p, m->u, (size_t)s->nu * 8);
    put(&p, m->w, (size_t)s->nw * 8);
    put(&p, m->delta1, (size_t)s->q1 * s->p1 * 8);
    put(&p, m->delta2, (size_t)s->q2 * s->p2 * 8);
    const uint32_t len = (uint32_t)strlen(c->system_file);
    put(&p, &len, 4);
    put(&p, c->system_file, len);
}

/* Check a blob against this instance; check_fingerprint: also require the same matrices. */
static fmi2Status state_check(Instance *c, const unsigned char *buf, size_t size,
                              int check_fingerprint, const char *fname) {
    const LJP_System *s = c->model.sys;
    if (size < STATE_HEADER + 4) FAIL(c, "%s: serialized state too short (%zu bytes)", fname, size);
    const unsigned char *p = buf;
    char magic[8];
    uint32_t endian, version;
    uint64_t fp;
    int32_t d[9], mine[9], phase, mode;
    get(&p, magic, 8);
    get(&p, &endian, 4);
    get(&p, &version, 4);
    get(&p, &fp, 8);
    get(&p, d, sizeof d);
    get(&p, &phase, 4);
    get(&p, &mode, 4);
    if (memcmp(magic, STATE_MAGIC, 8) != 0)
        FAIL(c, "%s: not a LinearJumpPlant FMU state", fname);
    if (endian != 0x01020304u)
        FAIL(c, "%s: FMU state was serialized on a machine of other byte order", fname);
    if (version != LJP_STATE_VERSION)
        FAIL(c, "%s: FMU state format version %u, this binary reads version %d", fname,
             (unsigned)version, LJP_STATE_VERSION);
    dims_of(s, mine);
    if (memcmp(d, mine, sizeof d) != 0)
        FAIL(c, "%s: FMU state has other dimensions (n=%d nu=%d ny=%d nw=%d m=%d) than this "
                "instance (n=%d nu=%d ny=%d nw=%d m=%d)",
             fname, d[0], d[1], d[2], d[3], d[4], s->n, s->nu, s->ny, s->nw, s->m);
    if (check_fingerprint && fp != s->fingerprint)
        FAIL(c, "%s: FMU state belongs to other system matrices than this instance uses "
                "(different systemFile?)", fname);
    if (phase < PH_INST || phase > PH_ERROR)
        FAIL(c, "%s: FMU state has an invalid phase %d", fname, (int)phase);
    if (mode < 1 || mode > s->m) FAIL(c, "%s: FMU state has an invalid mode %d", fname, (int)mode);
    size_t nd = (size_t)2 * s->n + s->nu + s->nw + (size_t)s->q1 * s->p1 + (size_t)s->q2 * s->p2;
    size_t off = STATE_HEADER + nd * 8;
    if (size < off + 4) FAIL(c, "%s: serialized state truncated (%zu bytes)", fname, size);
    uint32_t len;
    memcpy(&len, buf + off, 4);
    if (size != off + 4 + (size_t)len)
        FAIL(c, "%s: serialized state has %zu bytes, expected %zu", fname, size,
             off + 4 + (size_t)len);
    return fmi2OK;
}

static fmi2Status state_apply(Instance *c, const unsigned char *buf) {
    LJP_Model *m = &c->model;
    const LJP_System *s = m->sys;
    const unsigned char *p = buf + 8 + 4 + 4 + 8 + 9 * 4;
    int32_t phase, mode;
    uint32_t len;
    get(&p, &phase, 4);
    get(&p, &mode, 4);
    get(&p, &m->time, 8);
    get(&p, &c->start_time, 8);
    get(&p, m->x0, (size_t)s->n * 8);
    get(&p, m->x, (size_t)s->n * 8);
    get(&p, m->u, (size_t)s->nu * 8);
    get(&p, m->w, (size_t)s->nw * 8);
    get(&p, m->delta1, (size_t)s->q1 * s->p1 * 8);
    get(&p, m->delta2, (size_t)s->q2 * s->p2 * 8);
    get(&p, &len, 4);
    char *sf = (char *)c->al.alloc((size_t)len + 1, 1);
    if (!sf) FAIL(c, "fmi2SetFMUstate: out of memory");
    memcpy(sf, p, len);
    sf[len] = '\0';
    c->al.release(c->system_file);
    c->system_file = sf;
    c->phase = (Phase)phase;
    m->mode = mode;
    return fmi2OK;
}

static StateBlob *blob_alloc(Instance *c, size_t size) {
    StateBlob *b = (StateBlob *)c->al.alloc(1, sizeof(StateBlob) + size);
    if (b) b->size = size;
    return b;
}

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!FMUstate) FAIL(c, "fmi2GetFMUstate: FMUstate is NULL");
    size_t size = state_size(c);
    StateBlob *b = (StateBlob *)*FMUstate;
    if (b && b->size != size) {
        c->al.release(b);
        b = NULL;
        *FMUstate = NULL;
    }
    if (!b) b = blob_alloc(c, size);
    if (!b) FAIL(c, "fmi2GetFMUstate: out of memory");
    state_write(c, b->data);
    *FMUstate = b;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    StateBlob *b = (StateBlob *)FMUstate;
    if (!b) FAIL(c, "fmi2SetFMUstate: FMUstate is NULL");
    if (state_check(c, b->data, b->size, 1, "fmi2SetFMUstate") != fmi2OK) return fmi2Error;
    return state_apply(c, b->data);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    if (!serializedState || !FMUstate) FAIL(c, "fmi2DeSerializeFMUstate: NULL argument");
    const unsigned char *data = (const unsigned char *)serializedState;
    if (state_check(c, data, size, 0, "fmi2DeSerializeFMUstate") != fmi2OK) return fmi2Error;
    StateBlob *b = (StateBlob *)*FMUstate;
    if (b && b->size != size) {
        c->al.release(b);
        b = NULL;
        *FMUstate = NULL;
    }
    if (!b) b = blob_alloc(c, size);
    if (!b) FAIL(c, "fmi2DeSerializeFMUstate: out of memory");
    memcpy(b->data, data, size);
    *FMUstate = b;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown,
        (void)dvUnknown;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    FAIL(c, "fmi2GetDirectionalDerivative is not supported (providesDirectionalDerivative=false)");
}

/* ---------------------------------------------------------------------------------------
 * Model Exchange: not supported
 * ------------------------------------------------------------------------------------- */

#define NO_ME(c, fname)                                                                   \
    do {                                                                                  \
        CHECK_INSTANCE(c);                                                                \
        FAIL((c), "%s: Model Exchange is not supported by LinearJumpPlant", (fname));      \
    } while (0)

fmi2Status fmi2EnterEventMode(fmi2Component comp) { NO_ME((Instance *)comp, "fmi2EnterEventMode"); }

fmi2Status fmi2NewDiscreteStates(fmi2Component comp, fmi2EventInfo *eventInfo) {
    (void)eventInfo;
    NO_ME((Instance *)comp, "fmi2NewDiscreteStates");
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component comp) {
    NO_ME((Instance *)comp, "fmi2EnterContinuousTimeMode");
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component comp,
                                       fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    NO_ME((Instance *)comp, "fmi2CompletedIntegratorStep");
}

fmi2Status fmi2SetTime(fmi2Component comp, fmi2Real time) {
    (void)time;
    NO_ME((Instance *)comp, "fmi2SetTime");
}

fmi2Status fmi2SetContinuousStates(fmi2Component comp, const fmi2Real x[], size_t nx) {
    (void)x, (void)nx;
    NO_ME((Instance *)comp, "fmi2SetContinuousStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component comp, fmi2Real derivatives[], size_t nx) {
    (void)derivatives, (void)nx;
    NO_ME((Instance *)comp, "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component comp, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators, (void)ni;
    NO_ME((Instance *)comp, "fmi2GetEventIndicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component comp, fmi2Real x[], size_t nx) {
    (void)x, (void)nx;
    NO_ME((Instance *)comp, "fmi2GetContinuousStates");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component comp, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal, (void)nx;
    NO_ME((Instance *)comp, "fmi2GetNominalsOfContinuousStates");
}

/* ---------------------------------------------------------------------------------------
 * Co-Simulation
 * ------------------------------------------------------------------------------------- */

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    Instance *c = (Instance *)comp;
    CHECK_INSTANCE(c);
    CHECK_PHASE(c, M_STEP, "fmi2DoStep");
    LJP_Model *m = &c->model;
    const double t = currentCommunicationPoint, h = communicationStepSize;
    if (step_checks(c, t, h, 1, m->time) != fmi2OK) return fmi2Error;
    if (h == 0.0) return fmi2OK;
    const unsigned long before = m->n_expm;
    char err[512];
    if (ljp_model_step(m, h, err, sizeof err)) FAIL(c, "fmi2DoStep at t = %.17g: %s", t, err);
    m->time = t + h;
    if (m->n_expm != before)
        logf_(c, fmi2OK, "computed the exact discretisation of mode %d for step size %.17g "
                         "(discretisations so far: %lu)",
              m->mode, h, m->n_expm);
    return fmi2OK;
}
