/*
 * LinearJumpPlant: model code. See model.h for the interface and ../README.md for the
 * system file format and the accuracy of the discretisation.
 */
#include "model.h"

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ======================================================================================
 * System files
 * ==================================================================================== */

typedef struct {
    const char *path;
    const char *p; /* current position */
    int line;
    char *err;
    size_t errlen;
    char tok[128]; /* the last token, NUL-terminated (truncated if longer) */
    int tok_line;
} Lexer;

static int lex_fail(Lexer *lx, const char *fmt, ...) {
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    snprintf(lx->err, lx->errlen, "%s:%d: %s", lx->path, lx->tok_line, msg);
    return -1;
}

/* Next whitespace-separated token, skipping '#' comments. 0: got one, 1: end of file,
 * -1: token too long. */
static int lex_next(Lexer *lx) {
    for (;;) {
        while (*lx->p == ' ' || *lx->p == '\t' || *lx->p == '\r' || *lx->p == '\n' ||
               *lx->p == '\f' || *lx->p == '\v') {
            if (*lx->p == '\n') lx->line++;
            lx->p++;
        }
        if (*lx->p == '#') {
            while (*lx->p && *lx->p != '\n') lx->p++;
            continue;
        }
        break;
    }
    lx->tok_line = lx->line;
    if (!*lx->p) {
        lx->tok[0] = '\0';
        return 1;
    }
    size_t k = 0;
    while (*lx->p && !strchr(" \t\r\n\f\v#", *lx->p)) {
        if (k + 1 >= sizeof lx->tok) {
            lx->tok[k] = '\0';
            lex_fail(lx, "token too long: '%.40s...'", lx->tok);
            return -1;
        }
        lx->tok[k++] = *lx->p++;
    }
    lx->tok[k] = '\0';
    return 0;
}

static int lex_word(Lexer *lx, const char *word, const char *context) {
    int r = lex_next(lx);
    if (r < 0) return -1;
    if (r > 0) return lex_fail(lx, "unexpected end of file, expected '%s'%s", word, context);
    if (strcmp(lx->tok, word) != 0)
        return lex_fail(lx, "expected '%s'%s, got '%s'", word, context, lx->tok);
    return 0;
}

static int lex_int(Lexer *lx, const char *what, long lo, long hi, int *out) {
    int r = lex_next(lx);
    if (r < 0) return -1;
    if (r > 0) return lex_fail(lx, "unexpected end of file, expected %s", what);
    char *end;
    errno = 0;
    long v = strtol(lx->tok, &end, 10);
    if (errno || end == lx->tok || *end)
        return lex_fail(lx, "%s: expected an integer, got '%s'", what, lx->tok);
    if (v < lo || v > hi)
        return lex_fail(lx, "%s = %ld is out of range [%ld, %ld]", what, v, lo, hi);
    *out = (int)v;
    return 0;
}

static int lex_real(Lexer *lx, const char *what, double *out) {
    int r = lex_next(lx);
    if (r < 0) return -1;
    if (r > 0) return lex_fail(lx, "unexpected end of file in %s", what);
    char *end;
    double v = strtod(lx->tok, &end);
    if (end == lx->tok || *end)
        return lex_fail(lx, "%s: expected a number, got '%s'", what, lx->tok);
    if (!isfinite(v)) return lex_fail(lx, "%s: non-finite number '%s'", what, lx->tok);
    *out = v;
    return 0;
}

/* "NAME rows cols v11 v12 ..." for mode k (1-based). */
static int lex_matrix(Lexer *lx, const char *name, int k, int rows, int cols, double *dst) {
    char ctx[64], what[96];
    snprintf(ctx, sizeof ctx, " (mode %d)", k);
    if (lex_word(lx, name, ctx)) return -1;
    int r, c;
    snprintf(what, sizeof what, "mode %d: %s rows", k, name);
    if (lex_int(lx, what, 0, LJP_MAX_DIM, &r)) return -1;
    snprintf(what, sizeof what, "mode %d: %s columns", k, name);
    if (lex_int(lx, what, 0, LJP_MAX_DIM, &c)) return -1;
    if (r != rows || c != cols)
        return lex_fail(lx, "mode %d: %s is %d x %d, expected %d x %d", k, name, r, c, rows,
                        cols);
    for (int i = 0; i < rows; i++)
        for (int j = 0; j < cols; j++) {
            snprintf(what, sizeof what, "mode %d: %s[%d,%d]", k, name, i + 1, j + 1);
            if (lex_real(lx, what, &dst[(size_t)i * cols + j])) return -1;
        }
    return 0;
}

static uint64_t fnv1a(uint64_t h, const void *data, size_t len) {
    const unsigned char *b = (const unsigned char *)data;
    for (size_t i = 0; i < len; i++) {
        h ^= b[i];
        h *= 1099511628211ULL;
    }
    return h;
}

static char *read_text_file(const LJP_Allocator *al, const char *path, char *err,
                            size_t errlen) {
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, errlen, "%s: cannot open system file: %s", path, strerror(errno));
        return NULL;
    }
    char *buf = NULL;
    size_t cap = 0, len = 0;
    for (;;) {
        if (len + 4096 + 1 > cap) {
            size_t ncap = cap ? 2 * cap : 65536;
            char *nb = (char *)al->alloc(ncap, 1);
            if (!nb) {
                snprintf(err, errlen, "%s: out of memory reading the system file", path);
                if (buf) al->release(buf);
                fclose(f);
                return NULL;
            }
            if (buf) {
                memcpy(nb, buf, len);
                al->release(buf);
            }
            buf = nb;
            cap = ncap;
        }
        size_t got = fread(buf + len, 1, cap - len - 1, f);
        len += got;
        if (got == 0) break;
    }
    int bad = ferror(f);
    fclose(f);
    if (bad) {
        snprintf(err, errlen, "%s: read error", path);
        al->release(buf);
        return NULL;
    }
    buf[len] = '\0';
    if (strlen(buf) != len) {
        snprintf(err, errlen, "%s: not a text file (contains a NUL byte)", path);
        al->release(buf);
        return NULL;
    }
    return buf;
}

void ljp_system_free(const LJP_Allocator *al, LJP_System *sys) {
    double **mats[] = {&sys->A, &sys->B, &sys->C, &sys->D, &sys->A1, &sys->A2, &sys->B1, &sys->B2,
                       &sys->Cy};
    for (size_t i = 0; i < sizeof mats / sizeof mats[0]; i++) {
        if (*mats[i]) al->release(*mats[i]);
        *mats[i] = NULL;
    }
    memset(sys, 0, sizeof *sys);
}

static double *alloc_block(const LJP_Allocator *al, int m, int rows, int cols) {
    size_t count = (size_t)m * (size_t)rows * (size_t)cols;
    return (double *)al->alloc(count ? count : 1, sizeof(double));
}

int ljp_system_read(const LJP_Allocator *al, const char *path, LJP_System *sys, char *err,
                    size_t errlen) {
    memset(sys, 0, sizeof *sys);
    char *text = read_text_file(al, path, err, errlen);
    if (!text) return -1;
    Lexer lx = {path, text, 1, err, errlen, {0}, 1};
    int rc = -1;

    int r = lex_next(&lx);
    if (r < 0) goto done;
    if (r > 0 || strcmp(lx.tok, "LinearJumpPlant") != 0) {
        lex_fail(&lx, "not a LinearJumpPlant system file (expected the first word "
                      "'LinearJumpPlant', got '%s')", lx.tok);
        goto done;
    }
    int version;
    if (lex_int(&lx, "format version", 0, 1000000, &version)) goto done;
    if (version != LJP_FORMAT_VERSION) {
        lex_fail(&lx, "format version %d is not supported (this binary reads version %d)",
                 version, LJP_FORMAT_VERSION);
        goto done;
    }
    /* optional "guid <token>" */
    const char *save_p = lx.p;
    int save_line = lx.line;
    r = lex_next(&lx);
    if (r < 0) goto done;
    if (r == 0 && strcmp(lx.tok, "guid") == 0) {
        r = lex_next(&lx);
        if (r != 0) {
            if (r > 0) lex_fail(&lx, "unexpected end of file, expected the guid");
            goto done;
        }
        if (strlen(lx.tok) >= LJP_GUID_MAX) {
            lex_fail(&lx, "guid longer than %d characters", LJP_GUID_MAX - 1);
            goto done;
        }
        strcpy(sys->guid, lx.tok);
    } else {
        lx.p = save_p;
        lx.line = save_line;
    }

    static const char *dim_names[10] = {"n", "nu", "ny", "nw", "m", "q1", "p1", "q2", "p2", "nym"};
    int *dims[10] = {&sys->n, &sys->nu, &sys->ny, &sys->nw, &sys->m,
                     &sys->q1, &sys->p1, &sys->q2, &sys->p2, &sys->nym};
    for (int i = 0; i < 10; i++) {
        if (lex_word(&lx, dim_names[i],
                     " (dimensions come in the order n nu ny nw m q1 p1 q2 p2 nym)"))
            goto done;
        long lo = (i == 0 || i == 4) ? 1 : 0;
        if (lex_int(&lx, dim_names[i], lo, LJP_MAX_DIM, dims[i])) goto done;
    }
    if ((sys->q1 == 0) != (sys->p1 == 0)) {
        lex_fail(&lx, "q1 = %d and p1 = %d: both or neither must be 0", sys->q1, sys->p1);
        goto done;
    }
    if ((sys->q2 == 0) != (sys->p2 == 0)) {
        lex_fail(&lx, "q2 = %d and p2 = %d: both or neither must be 0", sys->q2, sys->p2);
        goto done;
    }
    {
        double N = (double)sys->n + sys->nu + sys->nw;
        double nvars = 2.0 * sys->n + sys->nu + sys->nw + sys->ny +
                       (double)sys->nym + (double)sys->q1 * sys->p1 +
                       (double)sys->q2 * sys->p2 + 2.0;
        if (N * N * 9.0 * sizeof(double) > 4e9) {
            lex_fail(&lx, "system too large: n + nu + nw = %.0f", N);
            goto done;
        }
        if (nvars > 1e8) {
            lex_fail(&lx, "system too large: %.0f variables", nvars);
            goto done;
        }
    }

    const int n = sys->n, nu = sys->nu, ny = sys->ny, nw = sys->nw, m = sys->m;
    sys->A = alloc_block(al, m, n, n);
    sys->B = alloc_block(al, m, n, nu);
    sys->C = alloc_block(al, m, ny, n);
    sys->D = alloc_block(al, m, n, nw);
    sys->A1 = alloc_block(al, m, n, sys->q1);
    sys->A2 = alloc_block(al, m, sys->p1, n);
    sys->B1 = alloc_block(al, m, n, sys->q2);
    sys->B2 = alloc_block(al, m, sys->p2, nu);
    sys->Cy = alloc_block(al, m, sys->nym, n);
    if (!sys->A || !sys->B || !sys->C || !sys->D || !sys->A1 || !sys->A2 || !sys->B1 ||
        !sys->B2 || !sys->Cy) {
        snprintf(err, errlen, "%s: out of memory for the system matrices", path);
        goto done;
    }
    for (int k = 0; k < m; k++) {
        char what[32];
        int kk;
        snprintf(what, sizeof what, "mode number");
        if (lex_word(&lx, "mode", "")) goto done;
        if (lex_int(&lx, what, 1, m, &kk)) goto done;
        if (kk != k + 1) {
            lex_fail(&lx, "modes must be listed in order: expected 'mode %d', got 'mode %d'",
                     k + 1, kk);
            goto done;
        }
        if (lex_matrix(&lx, "A", k + 1, n, n, sys->A + (size_t)k * n * n)) goto done;
        if (lex_matrix(&lx, "B", k + 1, n, nu, sys->B + (size_t)k * n * nu)) goto done;
        if (lex_matrix(&lx, "C", k + 1, ny, n, sys->C + (size_t)k * ny * n)) goto done;
        if (lex_matrix(&lx, "D", k + 1, n, nw, sys->D + (size_t)k * n * nw)) goto done;
        if (lex_matrix(&lx, "Cy", k + 1, sys->nym, n, sys->Cy + (size_t)k * sys->nym * n))
            goto done;
        if (sys->q1) {
            if (lex_matrix(&lx, "A1", k + 1, n, sys->q1, sys->A1 + (size_t)k * n * sys->q1))
                goto done;
            if (lex_matrix(&lx, "A2", k + 1, sys->p1, n, sys->A2 + (size_t)k * sys->p1 * n))
                goto done;
        }
        if (sys->q2) {
            if (lex_matrix(&lx, "B1", k + 1, n, sys->q2, sys->B1 + (size_t)k * n * sys->q2))
                goto done;
            if (lex_matrix(&lx, "B2", k + 1, sys->p2, nu, sys->B2 + (size_t)k * sys->p2 * nu))
                goto done;
        }
    }
    if (lex_word(&lx, "end", " after the last mode")) goto done;
    r = lex_next(&lx);
    if (r < 0) goto done;
    if (r == 0) {
        lex_fail(&lx, "unexpected text after 'end': '%s'", lx.tok);
        goto done;
    }

    /* fingerprint */
    {
        uint64_t h = 1469598103934665603ULL;
        int32_t d[10];
        for (int i = 0; i < 10; i++) d[i] = (int32_t)*dims[i];
        h = fnv1a(h, d, sizeof d);
        struct {
            const double *p;
            size_t count;
        } blocks[9] = {
            {sys->A, (size_t)m * n * n},         {sys->B, (size_t)m * n * nu},
            {sys->C, (size_t)m * ny * n},        {sys->D, (size_t)m * n * nw},
            {sys->A1, (size_t)m * n * sys->q1},  {sys->A2, (size_t)m * sys->p1 * n},
            {sys->B1, (size_t)m * n * sys->q2},  {sys->B2, (size_t)m * sys->p2 * nu},
            {sys->Cy, (size_t)m * sys->nym * n},
        };
        for (int i = 0; i < 9; i++) h = fnv1a(h, blocks[i].p, blocks[i].count * sizeof(double));
        sys->fingerprint = h;
    }
    rc = 0;

done:
    al->release(text);
    if (rc) ljp_system_free(al, sys);
    return rc;
}

int ljp_system_same_dims(const LJP_System *a, const LJP_System *b) {
    return a->n == b->n && a->nu == b->nu && a->ny == b->ny && a->nw == b->nw &&
           a->m == b->m && a->q1 == b->q1 && a->p1 == b->p1 && a->q2 == b->q2 &&
           a->p2 == b->p2 && a->nym == b->nym;
}

void ljp_system_dims_str(const LJP_System *s, char *buf, size_t len) {
    snprintf(buf, len, "n=%d nu=%d ny=%d nw=%d m=%d q1=%d p1=%d q2=%d p2=%d nym=%d", s->n,
             s->nu, s->ny, s->nw, s->m, s->q1, s->p1, s->q2, s->p2, s->nym);
}

/* ======================================================================================
 * Variables
 * ==================================================================================== */

void ljp_layout(const LJP_System *s, LJP_Layout *lay) {
    lay->x0 = 1;
    lay->u = lay->x0 + (unsigned)s->n;
    lay->w = lay->u + (unsigned)s->nu;
    lay->delta1 = lay->w + (unsigned)s->nw;
    lay->delta2 = lay->delta1 + (unsigned)(s->q1 * s->p1);
    lay->x = lay->delta2 + (unsigned)(s->q2 * s->p2);
    lay->y = lay->x + (unsigned)s->n;
    lay->ym = lay->y + (unsigned)s->ny;
    lay->nreal = lay->ym + (unsigned)s->nym - 1;
    lay->mode = lay->ym + (unsigned)s->nym;
    lay->system_file = lay->mode + 1;
}

LJP_VarKind ljp_var_kind(const LJP_Layout *lay, unsigned vr, unsigned *index) {
    const unsigned starts[8] = {lay->x0,     lay->u, lay->w, lay->delta1,
                                lay->delta2, lay->x, lay->y, lay->ym};
    const unsigned ends[8] = {lay->u, lay->w, lay->delta1, lay->delta2,
                              lay->x, lay->y, lay->ym,     lay->mode};
    const LJP_VarKind kinds[8] = {LJP_VAR_X0,     LJP_VAR_U, LJP_VAR_W, LJP_VAR_DELTA1,
                                  LJP_VAR_DELTA2, LJP_VAR_X, LJP_VAR_Y, LJP_VAR_YM};
    *index = 0;
    for (int i = 0; i < 8; i++)
        if (vr >= starts[i] && vr < ends[i]) {
            *index = vr - starts[i];
            return kinds[i];
        }
    if (vr == lay->mode) return LJP_VAR_MODE;
    if (vr == lay->system_file) return LJP_VAR_SYSTEM_FILE;
    return LJP_VAR_INVALID;
}

/* ======================================================================================
 * Dense linear algebra (row-major, N x N)
 * ==================================================================================== */

static void mat_mul(int N, const double *a, const double *b, double *c) {
    size_t NN = (size_t)N * N;
    memset(c, 0, NN * sizeof(double));
    for (int i = 0; i < N; i++) {
        double *ci = c + (size_t)i * N;
        const double *ai = a + (size_t)i * N;
        for (int k = 0; k < N; k++) {
            const double aik = ai[k];
            if (aik == 0.0) continue;
            const double *bk = b + (size_t)k * N;
            for (int j = 0; j < N; j++) ci[j] += aik * bk[j];
        }
    }
}

static double norm1(int N, const double *a) {
    double best = 0.0;
    for (int j = 0; j < N; j++) {
        double s = 0.0;
        for (int i = 0; i < N; i++) s += fabs(a[(size_t)i * N + j]);
        if (s > best || isnan(s)) best = s;
    }
    return best;
}

/* LU factorisation with partial pivoting, in place: P a = L U. */
static int lu_factor(int N, double *a, int *piv) {
    for (int k = 0; k < N; k++) {
        int p = k;
        double big = fabs(a[(size_t)k * N + k]);
        for (int i = k + 1; i < N; i++) {
            double v = fabs(a[(size_t)i * N + k]);
            if (v > big) {
                big = v;
                p = i;
            }
        }
        piv[k] = p;
        if (!(big > 0.0) || !isfinite(big)) return -1;
        if (p != k) {
            double *rk = a + (size_t)k * N, *rp = a + (size_t)p * N;
            for (int j = 0; j < N; j++) {
                double t = rk[j];
                rk[j] = rp[j];
                rp[j] = t;
            }
        }
        const double *rk = a + (size_t)k * N;
        const double inv = 1.0 / rk[k];
        for (int i = k + 1; i < N; i++) {
            double *ri = a + (size_t)i * N;
            const double l = ri[k] * inv;
            ri[k] = l;
            if (l == 0.0) continue;
            for (int j = k + 1; j < N; j++) ri[j] -= l * rk[j];
        }
    }
    return 0;
}

/* Solve (L U) X = P B for N right-hand sides; b (N x N) is overwritten by X. */
static void lu_solve(int N, const double *lu, const int *piv, double *b) {
    for (int k = 0; k < N; k++)
        if (piv[k] != k) {
            double *rk = b + (size_t)k * N, *rp = b + (size_t)piv[k] * N;
            for (int j = 0; j < N; j++) {
                double t = rk[j];
                rk[j] = rp[j];
                rp[j] = t;
            }
        }
    for (int i = 1; i < N; i++) {
        double *bi = b + (size_t)i * N;
        for (int k = 0; k < i; k++) {
            const double l = lu[(size_t)i * N + k];
            if (l == 0.0) continue;
            const double *bk = b + (size_t)k * N;
            for (int j = 0; j < N; j++) bi[j] -= l * bk[j];
        }
    }
    for (int i = N - 1; i >= 0; i--) {
        double *bi = b + (size_t)i * N;
        for (int k = i + 1; k < N; k++) {
            const double u = lu[(size_t)i * N + k];
            if (u == 0.0) continue;
            const double *bk = b + (size_t)k * N;
            for (int j = 0; j < N; j++) bi[j] -= u * bk[j];
        }
        const double inv = 1.0 / lu[(size_t)i * N + i];
        for (int j = 0; j < N; j++) bi[j] *= inv;
    }
}

/* c = sum_k coef[k] * mats[k] (+ diag * I) */
static void lincomb(int N, double *c, int count, const double *coef, const double *const *mats,
                    double diag) {
    size_t NN = (size_t)N * N;
    for (size_t e = 0; e < NN; e++) {
        double s = 0.0;
        for (int k = 0; k < count; k++) s += coef[k] * mats[k][e];
        c[e] = s;
    }
    for (int i = 0; i < N; i++) c[(size_t)i * N + i] += diag;
}

/* ======================================================================================
 * Matrix exponential: Higham, "The scaling and squaring method for the matrix exponential
 * revisited", SIAM J. Matrix Anal. Appl. 26(4), 2005, Algorithm 2.3.
 * ==================================================================================== */

static const double THETA[5] = {1.495585217958292e-2, 2.539398330063230e-1,
                                9.504178996162932e-1, 2.097847961257068e0,
                                5.371920351148152e0};
static const int DEGREE[5] = {3, 5, 7, 9, 13};
static const double PADE[5][14] = {
    {120.0, 60.0, 12.0, 1.0},
    {30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0},
    {17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0},
    {17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0, 2162160.0,
     110880.0, 3960.0, 90.0, 1.0},
    {64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
     129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
     40840800.0, 960960.0, 16380.0, 182.0, 1.0},
};

int ljp_expm(int N, double *a, double *work, int *piv) {
    const size_t NN = (size_t)N * N;
    double *P2 = work, *P4 = work + NN, *P6 = work + 2 * NN, *P8 = work + 3 * NN;
    double *T = work + 4 * NN, *U = work + 5 * NN, *V = work + 6 * NN, *S = work + 7 * NN;
    const double nrm = norm1(N, a);
    if (!isfinite(nrm)) return -1;

    int idx = 4, s = 0;
    for (int i = 0; i < 4; i++)
        if (nrm <= THETA[i]) {
            idx = i;
            break;
        }
    if (idx == 4 && nrm > THETA[4]) {
        int e;
        double f = frexp(nrm / THETA[4], &e); /* nrm / theta = f 2^e, f in [0.5, 1) */
        s = (f == 0.5) ? e - 1 : e;           /* ceil(log2(nrm / theta13)) */
        if (s < 0) s = 0;
        while (ldexp(nrm, -s) > THETA[4]) s++;
        const double scale = ldexp(1.0, -s);
        for (size_t e2 = 0; e2 < NN; e2++) a[e2] *= scale;
    }
    const double *b = PADE[idx];
    const int deg = DEGREE[idx];

    mat_mul(N, a, a, P2);
    if (deg == 13) {
        mat_mul(N, P2, P2, P4);
        mat_mul(N, P4, P2, P6);
        {
            const double c[3] = {b[13], b[11], b[9]};
            const double *m3[3] = {P6, P4, P2};
            lincomb(N, T, 3, c, m3, 0.0);
        }
        mat_mul(N, P6, T, S);
        {
            const double c[4] = {1.0, b[7], b[5], b[3]};
            const double *m4[4] = {S, P6, P4, P2};
            lincomb(N, T, 4, c, m4, b[1]);
        }
        mat_mul(N, a, T, U);
        {
            const double c[3] = {b[12], b[10], b[8]};
            const double *m3[3] = {P6, P4, P2};
            lincomb(N, T, 3, c, m3, 0.0);
        }
        mat_mul(N, P6, T, S);
        {
            const double c[4] = {1.0, b[6], b[4], b[2]};
            const double *m4[4] = {S, P6, P4, P2};
            lincomb(N, V, 4, c, m4, b[0]);
        }
    } else {
        const double *pw[4] = {P2, P4, P6, P8};
        const int npow = deg / 2; /* even powers 2, 4, .., deg - 1 */
        if (npow >= 2) mat_mul(N, P2, P2, P4);
        if (npow >= 3) mat_mul(N, P4, P2, P6);
        if (npow >= 4) mat_mul(N, P4, P4, P8);
        double codd[4], ceven[4];
        for (int k = 0; k < npow; k++) {
            codd[k] = b[2 * k + 3];
            ceven[k] = b[2 * k + 2];
        }
        lincomb(N, T, npow, codd, pw, b[1]);
        mat_mul(N, a, T, U);
        lincomb(N, V, npow, ceven, pw, b[0]);
    }
    /* r = (V - U)^{-1} (V + U) */
    for (size_t e = 0; e < NN; e++) {
        T[e] = V[e] - U[e];
        a[e] = V[e] + U[e];
    }
    if (lu_factor(N, T, piv)) return -1;
    lu_solve(N, T, piv, a);
    for (int k = 0; k < s; k++) {
        mat_mul(N, a, a, S);
        memcpy(a, S, NN * sizeof(double));
    }
    for (size_t e = 0; e < NN; e++)
        if (!isfinite(a[e])) return -1;
    return 0;
}

/* ======================================================================================
 * Model instances
 * ==================================================================================== */

static size_t model_N(const LJP_System *s) { return (size_t)s->n + s->nu + s->nw; }

int ljp_model_init(LJP_Model *mdl, const LJP_Allocator *al, const LJP_System *sys) {
    memset(mdl, 0, sizeof *mdl);
    mdl->al = al;
    mdl->sys = sys;
    ljp_layout(sys, &mdl->lay);
    const size_t n = sys->n, nu = sys->nu, nw = sys->nw, N = model_N(sys);
    const size_t nd1 = (size_t)sys->q1 * sys->p1, nd2 = (size_t)sys->q2 * sys->p2;
    size_t ntmp = n;
    if ((size_t)sys->q1 * n > ntmp) ntmp = (size_t)sys->q1 * n;
    if ((size_t)sys->q2 * nu > ntmp) ntmp = (size_t)sys->q2 * nu;
#define ALLOC(ptr, count, type)                                                           \
    do {                                                                                  \
        size_t c_ = (count);                                                              \
        (ptr) = (type *)al->alloc(c_ ? c_ : 1, sizeof(type));                             \
        if (!(ptr)) goto oom;                                                             \
    } while (0)
    ALLOC(mdl->x0, n, double);
    ALLOC(mdl->x, n, double);
    ALLOC(mdl->u, nu, double);
    ALLOC(mdl->w, nw, double);
    ALLOC(mdl->delta1, nd1, double);
    ALLOC(mdl->delta2, nd2, double);
    ALLOC(mdl->work, 9 * N * N, double);
    ALLOC(mdl->tmp, ntmp, double);
    ALLOC(mdl->piv, N, int);
    ALLOC(mdl->colexp, nu + nw, int);
    const size_t nslots = (size_t)sys->m * LJP_CACHE_SLOTS;
    ALLOC(mdl->disc, nslots, LJP_Disc);
    for (size_t i = 0; i < nslots; i++) {
        LJP_Disc *d = &mdl->disc[i];
        ALLOC(d->delta1, nd1, double);
        ALLOC(d->delta2, nd2, double);
        ALLOC(d->Phi, n * n, double);
        ALLOC(d->Gam, n * (nu + nw), double);
    }
#undef ALLOC
    ljp_model_reset(mdl);
    return 0;
oom:
    ljp_model_free(mdl);
    return -1;
}

void ljp_model_free(LJP_Model *mdl) {
    const LJP_Allocator *al = mdl->al;
    if (!al) return;
    if (mdl->disc) {
        const size_t nslots = (size_t)mdl->sys->m * LJP_CACHE_SLOTS;
        for (size_t i = 0; i < nslots; i++) {
            LJP_Disc *d = &mdl->disc[i];
            if (d->delta1) al->release(d->delta1);
            if (d->delta2) al->release(d->delta2);
            if (d->Phi) al->release(d->Phi);
            if (d->Gam) al->release(d->Gam);
        }
        al->release(mdl->disc);
    }
    void *ptrs[] = {mdl->x0, mdl->x, mdl->u, mdl->w, mdl->delta1, mdl->delta2,
                    mdl->work, mdl->tmp, mdl->piv, mdl->colexp};
    for (size_t i = 0; i < sizeof ptrs / sizeof ptrs[0]; i++)
        if (ptrs[i]) al->release(ptrs[i]);
    memset(mdl, 0, sizeof *mdl);
}

void ljp_model_invalidate_cache(LJP_Model *mdl) {
    const size_t nslots = (size_t)mdl->sys->m * LJP_CACHE_SLOTS;
    for (size_t i = 0; i < nslots; i++) mdl->disc[i].valid = 0;
}

void ljp_model_set_system(LJP_Model *mdl, const LJP_System *sys) {
    mdl->sys = sys;
    ljp_model_invalidate_cache(mdl);
}

void ljp_model_reset(LJP_Model *mdl) {
    const LJP_System *s = mdl->sys;
    memset(mdl->x0, 0, (size_t)s->n * sizeof(double));
    memset(mdl->x, 0, (size_t)s->n * sizeof(double));
    memset(mdl->u, 0, (size_t)s->nu * sizeof(double));
    memset(mdl->w, 0, (size_t)s->nw * sizeof(double));
    memset(mdl->delta1, 0, (size_t)s->q1 * s->p1 * sizeof(double));
    memset(mdl->delta2, 0, (size_t)s->q2 * s->p2 * sizeof(double));
    mdl->mode = 1;
    mdl->time = 0.0;
    ljp_model_invalidate_cache(mdl);
}

double ljp_model_y(const LJP_Model *mdl, unsigned k) {
    const LJP_System *s = mdl->sys;
    const double *C = s->C + (size_t)(mdl->mode - 1) * s->ny * s->n + (size_t)k * s->n;
    double acc = 0.0;
    for (int j = 0; j < s->n; j++) acc += C[j] * mdl->x[j];
    return acc;
}

double ljp_model_ym(const LJP_Model *mdl, unsigned k) {
    const LJP_System *s = mdl->sys;
    const double *Cy = s->Cy + (size_t)(mdl->mode - 1) * s->nym * s->n + (size_t)k * s->n;
    double acc = 0.0;
    for (int j = 0; j < s->n; j++) acc += Cy[j] * mdl->x[j];
    return acc;
}

int ljp_discretise(LJP_Model *mdl, int k, double h, double *Phi, double *Gam, char *err,
                   size_t errlen) {
    const LJP_System *s = mdl->sys;
    const int n = s->n, nu = s->nu, nw = s->nw, ni = nu + nw;
    const int N = n + ni;
    const size_t NN = (size_t)N * N;
    double *M = mdl->work, *work = mdl->work + NN, *tmp = mdl->tmp;
    memset(M, 0, NN * sizeof(double));

    /* A_eff = A + A1 (Delta1 A2) into M[0:n, 0:n] */
    const double *A = s->A + (size_t)k * n * n;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) M[(size_t)i * N + j] = A[(size_t)i * n + j];
    if (s->q1) {
        const int q = s->q1, p = s->p1;
        const double *A1 = s->A1 + (size_t)k * n * q, *A2 = s->A2 + (size_t)k * p * n;
        for (int i = 0; i < q; i++) /* tmp = Delta1 A2 (q x n) */
            for (int j = 0; j < n; j++) {
                double acc = 0.0;
                for (int l = 0; l < p; l++) acc += mdl->delta1[(size_t)i * p + l] * A2[(size_t)l * n + j];
                tmp[(size_t)i * n + j] = acc;
            }
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) {
                double acc = 0.0;
                for (int l = 0; l < q; l++) acc += A1[(size_t)i * q + l] * tmp[(size_t)l * n + j];
                M[(size_t)i * N + j] += acc;
            }
    }
    /* B_eff = B + B1 (Delta2 B2) into M[0:n, n:n+nu] */
    const double *B = s->B + (size_t)k * n * nu;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < nu; j++) M[(size_t)i * N + n + j] = B[(size_t)i * nu + j];
    if (s->q2) {
        const int q = s->q2, p = s->p2;
        const double *B1 = s->B1 + (size_t)k * n * q, *B2 = s->B2 + (size_t)k * p * nu;
        for (int i = 0; i < q; i++) /* tmp = Delta2 B2 (q x nu) */
            for (int j = 0; j < nu; j++) {
                double acc = 0.0;
                for (int l = 0; l < p; l++) acc += mdl->delta2[(size_t)i * p + l] * B2[(size_t)l * nu + j];
                tmp[(size_t)i * nu + j] = acc;
            }
        for (int i = 0; i < n; i++)
            for (int j = 0; j < nu; j++) {
                double acc = 0.0;
                for (int l = 0; l < q; l++) acc += B1[(size_t)i * q + l] * tmp[(size_t)l * nu + j];
                M[(size_t)i * N + n + j] += acc;
            }
    }
    /* D into M[0:n, n+nu:N] */
    const double *D = s->D + (size_t)k * n * nw;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < nw; j++) M[(size_t)i * N + n + nu + j] = D[(size_t)i * nw + j];
    /* times h */
    for (int i = 0; i < n; i++)
        for (int j = 0; j < N; j++) M[(size_t)i * N + j] *= h;

    /* The (1,2) block of expm([[A, G], [0, 0]]) is linear in G, so input columns may be
     * scaled by powers of two (exactly) to keep them from inflating ||M||_1 and with it
     * the number of squarings; the result is scaled back exactly. */
    double nA = 0.0;
    for (int j = 0; j < n; j++) {
        double c = 0.0;
        for (int i = 0; i < n; i++) c += fabs(M[(size_t)i * N + j]);
        if (c > nA) nA = c;
    }
    const double cap = nA > THETA[0] ? nA : THETA[0];
    for (int j = 0; j < ni; j++) {
        double c = 0.0;
        for (int i = 0; i < n; i++) c += fabs(M[(size_t)i * N + n + j]);
        int e = 0;
        if (c > cap) {
            frexp(c / cap, &e);
            while (ldexp(c, -e) > cap) e++;
            for (int i = 0; i < n; i++) M[(size_t)i * N + n + j] = ldexp(M[(size_t)i * N + n + j], -e);
        }
        mdl->colexp[j] = e;
    }

    if (ljp_expm(N, M, work, mdl->piv)) {
        snprintf(err, errlen,
                 "matrix exponential failed for mode %d, step size %.17g (non-finite or "
                 "overflowing entries; is the step size too large for this system?)",
                 k + 1, h);
        return -1;
    }
    for (int i = 0; i < n; i++) {
        for (int j = 0; j < n; j++) Phi[(size_t)i * n + j] = M[(size_t)i * N + j];
        for (int j = 0; j < ni; j++)
            Gam[(size_t)i * ni + j] = ldexp(M[(size_t)i * N + n + j], mdl->colexp[j]);
    }
    for (size_t e = 0; e < (size_t)n * ni; e++)
        if (!isfinite(Gam[e])) {
            snprintf(err, errlen, "discretisation of mode %d overflows for step size %.17g",
                     k + 1, h);
            return -1;
        }
    mdl->n_expm++;
    return 0;
}

static int same_values(const double *a, const double *b, size_t count) {
    for (size_t i = 0; i < count; i++)
        if (a[i] != b[i]) return 0;
    return 1;
}

int ljp_model_step(LJP_Model *mdl, double h, char *err, size_t errlen) {
    const LJP_System *s = mdl->sys;
    const int n = s->n, nu = s->nu, ni = s->nu + s->nw;
    const size_t nd1 = (size_t)s->q1 * s->p1, nd2 = (size_t)s->q2 * s->p2;
    const int k = mdl->mode - 1;
    LJP_Disc *slots = mdl->disc + (size_t)k * LJP_CACHE_SLOTS;
    LJP_Disc *d = NULL;
    mdl->clock++;
    for (int i = 0; i < LJP_CACHE_SLOTS; i++) {
        LJP_Disc *c = &slots[i];
        if (c->valid && c->h == h && same_values(c->delta1, mdl->delta1, nd1) &&
            same_values(c->delta2, mdl->delta2, nd2)) {
            d = c;
            break;
        }
    }
    if (!d) {
        d = &slots[0];
        for (int i = 0; i < LJP_CACHE_SLOTS; i++) {
            LJP_Disc *c = &slots[i];
            if (!c->valid) {
                d = c;
                break;
            }
            if (c->last_use < d->last_use) d = c;
        }
        d->valid = 0;
        if (ljp_discretise(mdl, k, h, d->Phi, d->Gam, err, errlen)) return -1;
        d->h = h;
        if (nd1) memcpy(d->delta1, mdl->delta1, nd1 * sizeof(double));
        if (nd2) memcpy(d->delta2, mdl->delta2, nd2 * sizeof(double));
        d->valid = 1;
    }
    d->last_use = mdl->clock;

    double *xn = mdl->tmp; /* n entries at least */
    for (int i = 0; i < n; i++) {
        const double *Pi = d->Phi + (size_t)i * n, *Gi = d->Gam + (size_t)i * ni;
        double acc = 0.0;
        for (int j = 0; j < n; j++) acc += Pi[j] * mdl->x[j];
        for (int j = 0; j < nu; j++) acc += Gi[j] * mdl->u[j];
        for (int j = 0; j < s->nw; j++) acc += Gi[nu + j] * mdl->w[j];
        xn[i] = acc;
    }
    for (int i = 0; i < n; i++)
        if (!isfinite(xn[i])) {
            snprintf(err, errlen, "state x[%d] became non-finite at mode %d, step size %.17g",
                     i + 1, k + 1, h);
            return -1;
        }
    memcpy(mdl->x, xn, (size_t)n * sizeof(double));
    mdl->time += h;
    return 0;
}
