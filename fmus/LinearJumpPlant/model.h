/*
 * LinearJumpPlant: model code (no FMI types in here).
 *
 * A linear plant whose true fault mode r in 1..m selects the matrices:
 *
 *     x' = (A_r + A1_r Delta1 A2_r) x + (B_r + B1_r Delta2 B2_r) u + D_r w,
 *     y  = C_r x,      ym = Cy_r x   (measured output; Cy_r = C_r when not given).
 *
 * This file declares
 *   - LJP_System:  the matrices of all modes, read from a plain-text system file
 *                  (format in ../README.md);
 *   - LJP_Layout:  the value references, derived from the dimensions alone;
 *   - LJP_Model:   the variables of one instance and the exact (zero-order-hold)
 *                  discretisation of the dynamics, cached per mode.
 *
 * The FMI glue (fmi2_glue.c) only translates FMI calls into calls of these functions.
 */
#ifndef LJP_MODEL_H
#define LJP_MODEL_H

#include <stddef.h>
#include <stdint.h>

#define LJP_FORMAT_VERSION 2      /* version of the system file format   */
#define LJP_STATE_VERSION 1       /* version of the serialized FMU state */
#define LJP_CACHE_SLOTS 4         /* cached discretisations per mode (LRU) */
#define LJP_MAX_DIM 100000        /* sanity bound on every dimension     */
#define LJP_GUID_MAX 128

/* Memory management: the FMI callbacks (calloc-like allocate, free). */
typedef struct {
    void *(*alloc)(size_t nobj, size_t size);
    void (*release)(void *obj);
} LJP_Allocator;

/* The plant: m modes of equal dimensions. Matrices are row-major; the block of mode k
 * (0-based) of a rows x cols matrix M starts at M + k * rows * cols. */
typedef struct {
    int n, nu, ny, nw, m; /* states, controls, outputs, disturbances, modes   */
    int q1, p1;           /* Delta1 is q1 x p1 (A1: n x q1, A2: p1 x n); 0: none */
    int q2, p2;           /* Delta2 is q2 x p2 (B1: n x q2, B2: p2 x nu); 0: none */
    int nym;              /* measured outputs ym = Cy x (Cy: nym x n)            */
    double *A, *B, *C, *D, *A1, *A2, *B1, *B2, *Cy;
    char guid[LJP_GUID_MAX]; /* empty when the file has no guid line */
    uint64_t fingerprint;    /* FNV-1a hash of the dimensions and all numbers */
} LJP_System;

/* Kinds of variables, and the value-reference layout (all references distinct). */
typedef enum {
    LJP_VAR_INVALID = 0,
    LJP_VAR_X0,     /* Real parameter x0[k]                */
    LJP_VAR_U,      /* Real input u[k]                     */
    LJP_VAR_W,      /* Real input w[k]                     */
    LJP_VAR_DELTA1, /* Real input Delta1[i,j], row-major   */
    LJP_VAR_DELTA2, /* Real input Delta2[i,j], row-major   */
    LJP_VAR_X,      /* Real output x[k]                    */
    LJP_VAR_Y,      /* Real output y[k]                    */
    LJP_VAR_YM,     /* Real output ym[k] (measured)        */
    LJP_VAR_MODE,   /* Integer input mode (1..m)           */
    LJP_VAR_SYSTEM_FILE /* String parameter systemFile     */
} LJP_VarKind;

typedef struct {
    unsigned x0, u, w, delta1, delta2, x, y, ym; /* first value reference of each block */
    unsigned nreal;                 /* Real variables have references 1 .. nreal       */
    unsigned mode, system_file;     /* nreal + 1 (Integer), nreal + 2 (String)         */
} LJP_Layout;

/* One cached discretisation x+ = Phi x + Gam [u; w] of one mode. */
typedef struct {
    int valid;
    double h;
    double *delta1, *delta2; /* the Delta values it was computed for */
    double *Phi;             /* n x n          */
    double *Gam;             /* n x (nu + nw)  */
    unsigned long last_use;
} LJP_Disc;

typedef struct {
    const LJP_System *sys;
    LJP_Layout lay;
    double time;
    int mode; /* 1..m */
    double *x0, *x, *u, *w, *delta1, *delta2;
    LJP_Disc *disc;         /* m * LJP_CACHE_SLOTS entries */
    double *work;           /* 9 * N * N doubles, N = n + nu + nw: M and expm workspace */
    double *tmp;            /* max(q1 * n, q2 * nu, n) doubles */
    int *piv;               /* N ints */
    int *colexp;            /* nu + nw ints: power-of-two scaling of the input columns */
    unsigned long clock;    /* for least-recently-used replacement */
    unsigned long n_expm;   /* number of discretisations computed */
    const LJP_Allocator *al;
} LJP_Model;

/* --- system files --------------------------------------------------------------------- */

/* Read a system file. Returns 0 on success; otherwise writes a message naming the file
 * (and line) into err and returns -1. *sys must be zeroed or freed before. */
int ljp_system_read(const LJP_Allocator *al, const char *path, LJP_System *sys,
                    char *err, size_t errlen);
void ljp_system_free(const LJP_Allocator *al, LJP_System *sys);
/* 1 when both systems have the same ten dimensions. */
int ljp_system_same_dims(const LJP_System *a, const LJP_System *b);
/* Describe the dimensions ("n=2 nu=2 ...") into buf. */
void ljp_system_dims_str(const LJP_System *sys, char *buf, size_t len);

/* --- variables ------------------------------------------------------------------------ */

void ljp_layout(const LJP_System *sys, LJP_Layout *lay);
/* The kind of value reference vr and its 0-based index within its block. */
LJP_VarKind ljp_var_kind(const LJP_Layout *lay, unsigned vr, unsigned *index);

/* --- model instances ------------------------------------------------------------------ */

/* Allocate the variables for sys (kept by pointer). Returns 0, or -1 when out of memory. */
int ljp_model_init(LJP_Model *mdl, const LJP_Allocator *al, const LJP_System *sys);
void ljp_model_free(LJP_Model *mdl);
/* Switch to another system of the same dimensions (drops the cache). */
void ljp_model_set_system(LJP_Model *mdl, const LJP_System *sys);
/* Start values: x0 = x = u = w = Delta = 0, mode = 1, time = 0; drops the cache. */
void ljp_model_reset(LJP_Model *mdl);
void ljp_model_invalidate_cache(LJP_Model *mdl);

/* Output k (0-based) of y = C_mode x. */
double ljp_model_y(const LJP_Model *mdl, unsigned k);
/* Measured output k (0-based) of ym = Cy_mode x. */
double ljp_model_ym(const LJP_Model *mdl, unsigned k);

/* Advance from mdl->time by h with u, w, mode and Delta held constant (exact solution
 * of the linear ODE for piecewise-constant inputs). Returns 0, or -1 with a message. */
int ljp_model_step(LJP_Model *mdl, double h, char *err, size_t errlen);

/* Exact discretisation of mode k (0-based) for step h and the current Delta values:
 * Phi = e^{A h}, Gam = int_0^h e^{A s} ds [B D]. Returns 0, or -1 with a message.
 * Exposed for testing; ljp_model_step uses the cache in front of it. */
int ljp_discretise(LJP_Model *mdl, int k, double h, double *Phi, double *Gam,
                   char *err, size_t errlen);

/* Matrix exponential of the N x N row-major matrix a (overwritten by e^a): Pade
 * approximants of degree 3, 5, 7, 9 or 13 with scaling and squaring (Higham 2005).
 * work: 8 * N * N doubles, piv: N ints. Returns 0, or -1 if a Pade denominator is
 * numerically singular (cannot happen for finite input). */
int ljp_expm(int N, double *a, double *work, int *piv);

#endif /* LJP_MODEL_H */
