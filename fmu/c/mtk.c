/* mtk: the mtcomp kinematic kernel in C (see mtk.h and docs/model.md, docs/fmu.md).
 *
 * Written by hand because it must run inside an FMU without Python and as the library's compiled
 * hot loop (no Python headers, loaded through ctypes): the forward model, the compensation and the
 * error-table CSV reader of mtcomp.errors; the tests hold it to the numpy reference
 * (mtcomp.kinematics, mtcomp._solver) to 1e-9 mm on every preset and error kind.
 */
/* The FMUs compile this file with -O2 and errno-setting maths: the hot loop wants -O3 and sqrt
 * inlined (the library build passes both; finite inputs are checked before they get here). */
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC optimize("O3", "no-math-errno")
#endif
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mtk.h"

#define ORIENTATION_SCALE 100.0  /* mm per rad, as mtcomp.kinematics.ORIENTATION_SCALE */
#define LAMBDA 1e-12             /* damping of the least-squares steps (singular Jacobians) */
#define CONVERGED 1e-7           /* largest residual accepted after the iteration, mm */
#define DEG (3.14159265358979323846 / 180.0)

static void seterr(char *err, const char *msg)
{
    if (err) snprintf(err, MTK_ERRLEN, "%s", msg);
}

/* ---------------------------------------------------------------- small 3-vector algebra */

static inline void mat_vec(const double A[9], const double x[3], double y[3])
{
    double t0 = A[0] * x[0] + A[1] * x[1] + A[2] * x[2];
    double t1 = A[3] * x[0] + A[4] * x[1] + A[5] * x[2];
    double t2 = A[6] * x[0] + A[7] * x[1] + A[8] * x[2];
    y[0] = t0; y[1] = t1; y[2] = t2;
}

static inline void mat_mul(const double A[9], const double B[9], double C[9])
{
    double T[9];
    int i, j;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++)
            T[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
    memcpy(C, T, sizeof T);
}

static inline void cross(const double a[3], const double b[3], double c[3])
{
    double c0 = a[1] * b[2] - a[2] * b[1], c1 = a[2] * b[0] - a[0] * b[2], c2 = a[0] * b[1] - a[1] * b[0];
    c[0] = c0; c[1] = c1; c[2] = c2;
}

static inline double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Apply the rotation about unit u by the angle with sine sn and cosine cs to x (Rodrigues);
 * y may be x. */
static inline void turn(const double u[3], double sn, double cs, const double x[3], double y[3])
{
    double ux[3], ud = dot3(u, x) * (1.0 - cs);
    int k;
    cross(u, x, ux);
    for (k = 0; k < 3; k++) y[k] = x[k] * cs + ux[k] * sn + u[k] * ud;
}

static void eye(double A[9])
{
    memset(A, 0, 9 * sizeof(double));
    A[0] = A[4] = A[8] = 1.0;
}

/* Rotation matrix of a rotation vector w (rad), Rodrigues with series near zero. */
static void rotvec(const double w[3], double R[9])
{
    double th = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    double a, b, K[9], KK[9];
    int k;
    if (th < 1e-8) {
        a = 1.0 - th * th / 6.0;
        b = 0.5 - th * th / 24.0;
    } else {
        a = sin(th) / th;
        b = (1.0 - cos(th)) / (th * th);
    }
    K[0] = 0; K[1] = -w[2]; K[2] = w[1];
    K[3] = w[2]; K[4] = 0; K[5] = -w[0];
    K[6] = -w[1]; K[7] = w[0]; K[8] = 0;
    mat_mul(K, K, KK);
    eye(R);
    for (k = 0; k < 9; k++) R[k] += a * K[k] + b * KK[k];
}

/* Rotation about unit vector u by angle (rad). */
static inline void axis_rotation_sc(const double u[3], double s, double c, double R[9])
{
    double C = 1.0 - c;
    double x = u[0], y = u[1], z = u[2];
    R[0] = c + x * x * C;     R[1] = x * y * C - z * s; R[2] = x * z * C + y * s;
    R[3] = y * x * C + z * s; R[4] = c + y * y * C;     R[5] = y * z * C - x * s;
    R[6] = z * x * C - y * s; R[7] = z * y * C + x * s; R[8] = c + z * z * C;
}

static inline void axis_rotation(const double u[3], double ang, double R[9])
{
    double c = cos(ang), s = sin(ang), C = 1.0 - c;
    double x = u[0], y = u[1], z = u[2];
    R[0] = c + x * x * C;     R[1] = x * y * C - z * s; R[2] = x * z * C + y * s;
    R[3] = y * x * C + z * s; R[4] = c + y * y * C;     R[5] = y * z * C - x * s;
    R[6] = z * x * C - y * s; R[7] = z * y * C + x * s; R[8] = c + z * z * C;
}

/* R = Rz(c) Ry(b) Rx(a), angles in deg (mtcomp.errors.rotation_matrix_xyz). */
static void rotation_xyz(const double ang[3], double R[9])
{
    double a = ang[0] * DEG, b = ang[1] * DEG, c = ang[2] * DEG;
    double ca = cos(a), sa = sin(a), cb = cos(b), sb = sin(b), cc = cos(c), sc = sin(c);
    double rx[9] = {1, 0, 0, 0, ca, -sa, 0, sa, ca};
    double ry[9] = {cb, 0, sb, 0, 1, 0, -sb, 0, cb};
    double rz[9] = {cc, -sc, 0, sc, cc, 0, 0, 0, 1};
    mat_mul(ry, rx, R);
    mat_mul(rz, R, R);
}

/* ---------------------------------------------------------------- resources */

char *mtk_tok(char *s, const char *delim, char **save)
{
    char *end;
    if (!s) s = *save;
    if (!s) return NULL;
    s += strspn(s, delim);
    if (!*s) {
        *save = NULL;
        return NULL;
    }
    end = s + strcspn(s, delim);
    if (*end) {
        *end = 0;
        *save = end + 1;
    } else {
        *save = NULL;
    }
    return s;
}

void mtk_errors_zero(mtk_errors *e)
{
    memset(e, 0, sizeof *e);
    e->use_tables = 1;
}

int mtk_axis_index(const mtk_model *m, char axis_name)
{
    int i;
    for (i = 0; i < m->n_axes; i++)
        if (m->axis_name[i] == axis_name) return i;
    return -1;
}

static void table_free(mtk_table *t)
{
    free(t->pos); free(t->val); free(t->coef); free(t);
}

/* The per-interval values and slopes of a loaded table (coef, p0, inv_h); MTK_E_IO without memory. */
static int table_finish(mtk_table *t)
{
    int i, k;
    t->coef = (double *)malloc((size_t)(t->n - 1) * 12 * sizeof(double));
    if (!t->coef) return MTK_E_IO;
    for (i = 0; i < t->n - 1; i++) {
        double inv = 1.0 / (t->pos[i + 1] - t->pos[i]), *c = t->coef + 12 * i;
        for (k = 0; k < 6; k++) {
            c[k] = t->val[6 * i + k];
            c[6 + k] = (t->val[6 * i + 6 + k] - t->val[6 * i + k]) * inv;
        }
    }
    t->p0 = t->pos[0];
    t->inv_h = (t->n - 1) / (t->pos[t->n - 1] - t->pos[0]);
    return MTK_OK;
}

void mtk_free(mtk_model *m)
{
    int i;
    if (!m) return;
    for (i = 0; i < MTK_MAX_AXES; i++) {
        if (m->table[i]) {
            table_free(m->table[i]);
        }
    }
    free(m->cache);
    free(m);
}

static int read_doubles(char **s, double *x, int n)
{
    int k;
    for (k = 0; k < n; k++) {
        char *end;
        x[k] = strtod(*s, &end);
        if (end == *s || !isfinite(x[k])) return 0;
        *s = end;
    }
    return 1;
}

/* Machine description file, one record per line (written by mtcomp.fmu.build):
 *   mtcomp-machine 1
 *   name <name>
 *   tool_point x y z
 *   tool_axis x y z
 *   axis <letter> linear|rotary workpiece|tool dx dy dz lx ly lz lo hi [resolution]
 * Axes in chain order from the workpiece to the tool.  The travel check tolerates half a
 * resolution step, as mtcomp.kinematics.check_limits does (no resolution: none). */
int mtk_load_machine(const char *path, mtk_model **out, char *err)
{
    FILE *f = fopen(path, "r");
    char line[1024], msg[MTK_ERRLEN];
    int lineno = 0, have_header = 0, seen_tool = 0;
    mtk_model *m;
    *out = NULL;
    if (!f) {
        snprintf(msg, sizeof msg, "cannot open machine description '%s'", path);
        seterr(err, msg);
        return MTK_E_IO;
    }
    m = (mtk_model *)calloc(1, sizeof *m);
    if (!m) {
        fclose(f);
        seterr(err, "out of memory");
        return MTK_E_IO;
    }
    m->tool_axis[2] = 1.0;
    while (fgets(line, sizeof line, f)) {
        char key[32], *s = line;
        int used = 0;
        lineno++;
        if (!strchr(line, '\n') && !feof(f)) goto bad;  /* longer than the buffer */
        while (isspace((unsigned char)*s)) s++;
        if (!*s || *s == '#') continue;
        if (sscanf(s, "%31s%n", key, &used) != 1) continue;
        s += used;
        if (!strcmp(key, "mtcomp-machine")) {
            have_header = (atoi(s) == 1);
        } else if (!strcmp(key, "name")) {
            while (isspace((unsigned char)*s)) s++;
            snprintf(m->name, sizeof m->name, "%s", s);
            m->name[strcspn(m->name, "\r\n")] = 0;
        } else if (!strcmp(key, "tool_point")) {
            if (!read_doubles(&s, m->tool_point, 3)) goto bad;
        } else if (!strcmp(key, "tool_axis")) {
            if (!read_doubles(&s, m->tool_axis, 3)) goto bad;
        } else if (!strcmp(key, "axis")) {
            char name[8], kind[16], side[16];
            double v[8];
            int i = m->n_axes;
            if (i >= MTK_MAX_AXES) goto bad;
            if (sscanf(s, "%7s %15s %15s%n", name, kind, side, &used) != 3) goto bad;
            s += used;
            if (strlen(name) != 1 || !read_doubles(&s, v, 8)) goto bad;
            if (strcmp(kind, "linear") && strcmp(kind, "rotary")) goto bad;
            if (strcmp(side, "workpiece") && strcmp(side, "tool")) goto bad;
            m->axis_name[i] = name[0];
            m->rotary[i] = !strcmp(kind, "rotary");
            m->tool_side[i] = !strcmp(side, "tool");
            if (!m->tool_side[i] && seen_tool) goto bad;
            seen_tool |= m->tool_side[i];
            memcpy(m->dir[i], v, 3 * sizeof(double));
            memcpy(m->loc[i], v + 3, 3 * sizeof(double));
            m->lo[i] = v[6];
            m->hi[i] = v[7];
            {
                char *end;
                double res = strtod(s, &end);
                if (end != s) {
                    if (!(res > 0.0 && res <= 1.0)) goto bad;
                    m->slack[i] = 0.5 * res;
                }
            }
            m->n_axes++;
        } else {
            goto bad;
        }
    }
    fclose(f);
    if (!have_header || m->n_axes == 0) {
        snprintf(msg, sizeof msg, "'%s' is not an mtcomp machine description (version 1) with axes", path);
        seterr(err, msg);
        mtk_free(m);
        return MTK_E_FORMAT;
    }
    *out = m;
    return MTK_OK;
bad:
    fclose(f);
    snprintf(msg, sizeof msg, "%s:%d: malformed machine description record", path, lineno);
    seterr(err, msg);
    mtk_free(m);
    return MTK_E_FORMAT;
}

/* Error table CSV of one axis (docs/errors-format.md): '#' comments, a header
 * 'position,E?{axis}...' naming some of the six components, then rows of numbers. */
int mtk_load_table(mtk_model *m, const char *axis_name, const char *path, char *err)
{
    FILE *f;
    char line[4096], msg[MTK_ERRLEN];
    int col[8], ncol = 0, lineno = 0, cap = 0, idx, seen = 0;
    mtk_table *t;
    idx = (axis_name && strlen(axis_name) == 1) ? mtk_axis_index(m, axis_name[0]) : -1;
    if (idx < 0) {
        snprintf(msg, sizeof msg, "error table for unknown axis '%s' (machine axes: %.*s)",
                 axis_name ? axis_name : "", m->n_axes, m->axis_name);
        seterr(err, msg);
        return MTK_E_ARG;
    }
    f = fopen(path, "r");
    if (!f) {
        snprintf(msg, sizeof msg, "error table resource '%s' for axis %c not found", path, m->axis_name[idx]);
        seterr(err, msg);
        return MTK_E_IO;
    }
    t = (mtk_table *)calloc(1, sizeof *t);
    if (!t) { fclose(f); seterr(err, "out of memory"); return MTK_E_IO; }
    while (fgets(line, sizeof line, f)) {
        char *s = line, *tok, *save = NULL;
        lineno++;
        if (!strchr(line, '\n') && !feof(f)) goto bad;  /* longer than the buffer */
        while (isspace((unsigned char)*s)) s++;
        if (!*s || *s == '#') continue;
        if (ncol == 0) {
            /* header */
            for (tok = mtk_tok(s, ",\r\n", &save); tok; tok = mtk_tok(NULL, ",\r\n", &save)) {
                const char *comp = "XYZABC";
                const char *hit;
                size_t len;
                while (isspace((unsigned char)*tok)) tok++;
                len = strlen(tok);
                while (len > 0 && isspace((unsigned char)tok[len - 1])) tok[--len] = 0;
                if (ncol == 0) {
                    if (strcmp(tok, "position")) goto bad;
                    col[ncol++] = -1;
                    continue;
                }
                if (ncol >= 7 || strlen(tok) != 3 || tok[0] != 'E' || tok[2] != m->axis_name[idx]) goto bad;
                hit = strchr(comp, tok[1]);
                if (!hit || !tok[1]) goto bad;
                if (seen & (1 << (hit - comp))) goto bad;   /* a component named twice */
                seen |= 1 << (hit - comp);
                col[ncol++] = (int)(hit - comp);
            }
            if (ncol < 1) goto bad;
            continue;
        }
        if (t->n == cap) {
            /* keep the old blocks on failure so that `bad` frees them */
            double *pos, *val;
            cap = cap ? 2 * cap : 64;
            pos = (double *)realloc(t->pos, cap * sizeof(double));
            if (pos) t->pos = pos;
            val = pos ? (double *)realloc(t->val, 6 * cap * sizeof(double)) : NULL;
            if (val) t->val = val;
            if (!pos || !val) goto bad;
        }
        {
            int k;
            double *row = t->val + 6 * t->n;
            memset(row, 0, 6 * sizeof(double));
            for (k = 0; k < ncol; k++) {
                char *end;
                double x = strtod(s, &end);
                if (end == s || !isfinite(x)) goto bad;
                s = end;
                while (isspace((unsigned char)*s)) s++;
                if (k + 1 < ncol) {
                    if (*s != ',') goto bad;
                    s++;
                }
                if (col[k] < 0) t->pos[t->n] = x;
                else row[col[k]] = x;
            }
            if (*s && *s != '\r' && *s != '\n') goto bad;
            if (t->n > 0 && !(t->pos[t->n] > t->pos[t->n - 1])) goto bad;
            t->n++;
        }
    }
    fclose(f);
    if (t->n < 2) {
        snprintf(msg, sizeof msg, "%s: an error table needs a header and at least two rows", path);
        seterr(err, msg);
        free(t->pos); free(t->val); free(t);
        return MTK_E_FORMAT;
    }
    if (table_finish(t) != MTK_OK) {
        seterr(err, "out of memory");
        table_free(t);
        return MTK_E_IO;
    }
    if (m->table[idx]) {
        table_free(m->table[idx]);
    }
    m->table[idx] = t;
    return MTK_OK;
bad:
    fclose(f);
    snprintf(msg, sizeof msg, "%s:%d: malformed error table (expected 'position,E?%c...' header and "
             "rows of finite numbers with increasing positions)", path, lineno, m->axis_name[idx]);
    seterr(err, msg);
    free(t->pos); free(t->val); free(t);
    return MTK_E_FORMAT;
}

/* Interval [lo, lo + 1] of the table holding q (pos[0] < q < pos[n-1]): *hint if it holds q (the
 * iterates of one pose and the poses of a path stay in the same interval), else on an evenly
 * spaced grid by one multiplication, else by bisection. */
static inline int table_interval(const mtk_table *t, double q, int *hint)
{
    int lo = *hint, hi;
    if (lo >= 0 && lo < t->n - 1 && t->pos[lo] <= q && q < t->pos[lo + 1]) return lo;
    lo = (int)((q - t->p0) * t->inv_h);   /* (pos[0] < q < pos[n-1]: no overflow) */
    if (lo > t->n - 2) lo = t->n - 2;
    if (lo < 0) lo = 0;
    if (t->pos[lo] <= q && q < t->pos[lo + 1]) { *hint = lo; return lo; }
    lo = 0;
    hi = t->n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (t->pos[mid] <= q) lo = mid; else hi = mid;
    }
    *hint = lo;
    return lo;
}

/* Component errors at q: d (mm), e (rad), and their slopes dd, de per mm or deg (may be NULL).
 * strict: MTK_E_RANGE outside the table (1e-12 tolerance); otherwise the end values are held
 * (intermediate iterates of the compensation; slope 0). */
static inline int table_eval_hint(const mtk_table *t, double q, double d[3], double e[3], double *dd, double *de,
                                  int strict, int *hint)
{
    int lo, k;
    double f;
    const double *c;
    if (isnan(q)) {
        if (strict) return MTK_E_RANGE;
        for (k = 0; k < 3; k++) d[k] = e[k] = NAN;
        if (dd) for (k = 0; k < 3; k++) dd[k] = de[k] = 0.0;
        return MTK_OK;
    }
    if (strict && !(q >= t->pos[0] - 1e-12 && q <= t->pos[t->n - 1] + 1e-12)) return MTK_E_RANGE;
    if (q <= t->pos[0] || q >= t->pos[t->n - 1]) {
        const double *v = q <= t->pos[0] ? t->val : t->val + 6 * (t->n - 1);
        for (k = 0; k < 3; k++) { d[k] = v[k]; e[k] = v[3 + k]; }
        if (dd) for (k = 0; k < 3; k++) dd[k] = de[k] = 0.0;
        return MTK_OK;
    }
    lo = table_interval(t, q, hint);
    f = q - t->pos[lo];
    c = t->coef + 12 * lo;
    for (k = 0; k < 3; k++) {
        d[k] = c[6 + k] * f + c[k];
        e[k] = c[9 + k] * f + c[3 + k];
        if (dd) { dd[k] = c[6 + k]; de[k] = c[9 + k]; }
    }
    return MTK_OK;
}

/* ---------------------------------------------------------------- prepared model
 *
 * Everything that does not depend on the commands is computed once per error set: effective
 * axis directions (location tilts), rotary centres and zero errors, the tool point with its
 * setting offset, the transposed workpiece rotation.  A forward evaluation then only builds
 * the axis rotations, looks up the tables and composes 3x3 products (identity skipped). */

typedef struct {
    const mtk_model *m;
    int n, nrot, mode, rows;
    int rot_idx[MTK_MAX_AXES];
    double ueff[MTK_MAX_AXES][3];
    double c[MTK_MAX_AXES][3];        /* rotary centre with its location offset, mm */
    int c0[MTK_MAX_AXES];             /* ... at the origin (the turn moves no point of the axis) */
    double zero[MTK_MAX_AXES];        /* zero-position error of a rotary axis, rad */
    const mtk_table *tab[MTK_MAX_AXES];
    int loc0[MTK_MAX_AXES];           /* the axis' error motion acts about the origin (loc = 0):
                                       * its translation is the table's alone */
    int hint[MTK_MAX_AXES];           /* last table interval per axis (table_interval) */
    double tp[3];                     /* tool point + tool setting offset, mm */
    int wp;                           /* workpiece pose differs from identity */
    double RwT[9], tw[3], Rw[9];
    int closed;                       /* closed form of retarget applies (rigid, no rotation) */
    int geo;                          /* tables or location errors (else the rigid model itself) */
    int lin_first;                    /* the three linear axes precede every rotary axis ... */
    double Ainv[9];                   /* ... so the closed form's matrix is constant: its inverse */
    int closed_rot;                   /* rigid errors with a workpiece rotation, two or three rotary
                                       * axes: closed_rotation applies */
    double c12;                       /* u1 . u2 of the first two rotary axes */
    double b3[3];                     /* a unit vector normal to the third rotary axis (mode 3) */
    int lin_order;                    /* closed_rot: the linear axes all precede (1) or all follow (2)
                                       * the rotary axes, else 0 ... */
    double Dinv[9];                   /* ... and then the inverse of their directions' matrix */
    double u12[3];                    /* closed_rot: u1 x u2, and for a (the tool axis, or the third
                                       * rotary axis) a.a, u2.a and with ap = a - (u2.a) u2 the
                                       * dot products ap.u1, ap.u12, u1.(u2 x ap), u12.(u2 x ap) */
    double aa, u2a, K[4];
    double r2, iden;                  /* a.a - (u2.a)^2, 1 / (1 - (u1.u2)^2) */
    double sc_ref[MTK_MAX_AXES][3];   /* per rotary axis an angle (rad) taken by sin and cos, and
                                       * those (axis_sincos; NAN: none yet) */
    int axal[MTK_MAX_AXES];           /* a rotary axis along +x, +y or +z (0, 1, 2: turn_axal), else -1 */
    double qlo[MTK_MAX_AXES], qhi[MTK_MAX_AXES];   /* in_ranges: travel with its slack, within the
                                                    * table's range (1e-12) where there is one */
    double wmax[MTK_MAX_AXES];        /* bound of |W_i|, the angular velocity of axis i per deg or mm:
                                       * DEG for a rotary axis, plus the steepest slope of its table's
                                       * angles (the second-order bounds of iterate) */
} prep_t;

/* Rotation matrix of a small-or-large rotation vector w (rad): series below 1e-3 rad (the
 * µrad angles of error tables; truncation below 1e-18), sin/cos above. */
static inline void rotvec_fast(const double w[3], double R[9])
{
    double t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2], a, b;
    if (t2 < 1e-8) {   /* (below 1e-4 rad, the usual table angles: truncation below 1e-18) */
        a = 1.0 - t2 * (1.0 / 6.0);
        b = 0.5 - t2 * (1.0 / 24.0);
    } else if (t2 < 1e-6) {
        a = 1.0 - t2 * (1.0 / 6.0) * (1.0 - t2 * (1.0 / 20.0) * (1.0 - t2 * (1.0 / 42.0)));
        b = 0.5 - t2 * (1.0 / 24.0) * (1.0 - t2 * (1.0 / 30.0) * (1.0 - t2 * (1.0 / 56.0)));
    } else {
        double th = sqrt(t2);
        a = sin(th) / th;
        b = (1.0 - cos(th)) / t2;
    }
    R[0] = 1.0 - b * (w[1] * w[1] + w[2] * w[2]);
    R[4] = 1.0 - b * (w[0] * w[0] + w[2] * w[2]);
    R[8] = 1.0 - b * (w[0] * w[0] + w[1] * w[1]);
    R[1] = -a * w[2] + b * w[0] * w[1]; R[3] = a * w[2] + b * w[0] * w[1];
    R[2] = a * w[1] + b * w[0] * w[2];  R[6] = -a * w[1] + b * w[0] * w[2];
    R[5] = -a * w[0] + b * w[1] * w[2]; R[7] = a * w[0] + b * w[1] * w[2];
}

/* Angular velocity (in the frame before the rotation) of R(w) = rotvec(w) as w moves at dw:
 * dR R^T = [J(w) dw]x with J(w) = I + b [w]x + c [w]x^2, b = (1 - cos t) / t^2, c = (t - sin t) / t^3
 * (the left Jacobian of the rotation vector; series below 1e-3 rad, truncation below 1e-24).
 * Not dw alone: that is first order in the angles, and the Jacobian's error e |dw| (µrad angles times
 * their slopes, times the lever to the tool) would enter the steps taken without an evaluation. */
static inline void rotvec_rate(const double w[3], const double dw[3], double out[3])
{
    double t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2], b, c, x[3], y[3];
    int k;
    if (t2 < 1e-6) {
        b = 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0);
        c = 1.0 / 6.0 - t2 / 120.0 * (1.0 - t2 / 42.0);
    } else {
        double th = sqrt(t2);
        b = (1.0 - cos(th)) / t2;
        c = (th - sin(th)) / (t2 * th);
    }
    x[0] = w[1] * dw[2] - w[2] * dw[1];
    x[1] = w[2] * dw[0] - w[0] * dw[2];
    x[2] = w[0] * dw[1] - w[1] * dw[0];
    y[0] = w[1] * x[2] - w[2] * x[1];
    y[1] = w[2] * x[0] - w[0] * x[2];
    y[2] = w[0] * x[1] - w[1] * x[0];
    for (k = 0; k < 3; k++) out[k] = dw[k] + b * x[k] + c * y[k];
}

static int n_rotary(const mtk_model *m)
{
    int i, n = 0;
    for (i = 0; i < m->n_axes; i++) n += m->rotary[i];
    return n;
}

static void u12_cross(const double a[3], const double b[3], double c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

/* geo = 0: the rigid model (setting errors only: the chord Jacobian's model). */
static void prepare(const mtk_model *m, const mtk_errors *e, int geo, prep_t *P)
{
    int i, k, any_geo = 0;
    memset(P, 0, sizeof *P);
    P->m = m;
    P->n = m->n_axes;
    P->nrot = n_rotary(m);
    P->mode = P->nrot == 0 ? 0 : (P->nrot >= 3 ? 3 : 2);
    P->rows = P->mode == 0 ? 3 : 6;
    for (i = 0; i < m->n_axes; i++) {
        const double *u = m->dir[i];
        const double *d0 = (e && geo) ? e->loc[i] : NULL, *e0 = (e && geo) ? e->loc[i] + 3 : NULL;
        if (m->rotary[i]) {
            double zero = 0.0, tilt[3] = {0, 0, 0};
            if (e0) {
                zero = e0[0] * u[0] + e0[1] * u[1] + e0[2] * u[2];
                for (k = 0; k < 3; k++) tilt[k] = e0[k] - zero * u[k];
            }
            if (tilt[0] != 0.0 || tilt[1] != 0.0 || tilt[2] != 0.0) {
                double Rt[9];
                rotvec(tilt, Rt);
                mat_vec(Rt, u, P->ueff[i]);
            } else {
                memcpy(P->ueff[i], u, 3 * sizeof(double));
            }
            for (k = 0; k < 3; k++) P->c[i][k] = m->loc[i][k] + (d0 ? d0[k] : 0.0);
            P->zero[i] = zero;
        } else {
            /* Only the tilt (squareness) of a linear axis acts, as in the core. */
            if (e0 && (e0[0] != 0.0 || e0[1] != 0.0 || e0[2] != 0.0)) {
                double Rt[9];
                rotvec(e0, Rt);
                mat_vec(Rt, u, P->ueff[i]);
            } else {
                memcpy(P->ueff[i], u, 3 * sizeof(double));
            }
        }
        if (e && geo) {
            for (k = 0; k < 6; k++) any_geo |= (e->loc[i][k] != 0.0);
            if (e->use_tables && m->table[i]) {
                P->tab[i] = m->table[i];
                any_geo = 1;
            }
        }
    }
    for (i = 0, k = 0; i < m->n_axes; i++)
        if (m->rotary[i]) P->rot_idx[k++] = i;
    for (i = 0; i < m->n_axes; i++) {
        P->loc0[i] = m->loc[i][0] == 0.0 && m->loc[i][1] == 0.0 && m->loc[i][2] == 0.0;
        P->c0[i] = P->c[i][0] == 0.0 && P->c[i][1] == 0.0 && P->c[i][2] == 0.0;
    }
    for (i = 0; i < MTK_MAX_AXES; i++) P->sc_ref[i][0] = NAN;
    for (i = 0; i < m->n_axes; i++) {
        const double *u = P->ueff[i];
        const mtk_table *t = P->tab[i];
        P->axal[i] = -1;
        for (k = 0; k < 3 && m->rotary[i]; k++)
            if (u[k] == 1.0 && u[(k + 1) % 3] == 0.0 && u[(k + 2) % 3] == 0.0) P->axal[i] = k;
        P->qlo[i] = m->lo[i] - m->slack[i];
        P->qhi[i] = m->hi[i] + m->slack[i];
        if (t) {
            double tl = t->pos[0] - 1e-12, th = t->pos[t->n - 1] + 1e-12;
            if (tl > P->qlo[i]) P->qlo[i] = tl;
            if (th < P->qhi[i]) P->qhi[i] = th;
        }
    }
    for (i = 0; i < m->n_axes; i++) {
        double w = m->rotary[i] ? DEG : 0.0;
        if (P->tab[i]) {
            const mtk_table *t = P->tab[i];
            double smax = 0.0;
            int j;
            for (j = 0; j < t->n - 1; j++) {
                const double *c = t->coef + 12 * j + 9;
                double sl = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
                smax = sl > smax ? sl : smax;
            }
            w += smax;
        }
        P->wmax[i] = w;
    }
    for (k = 0; k < 3; k++) P->tp[k] = m->tool_point[k] + (e ? e->tool[k] : 0.0);
    if (e && (e->wp_t[0] != 0.0 || e->wp_t[1] != 0.0 || e->wp_t[2] != 0.0 ||
              e->wp_a[0] != 0.0 || e->wp_a[1] != 0.0 || e->wp_a[2] != 0.0)) {
        int r, c;
        P->wp = 1;
        rotation_xyz(e->wp_a, P->Rw);
        for (r = 0; r < 3; r++)
            for (c = 0; c < 3; c++) P->RwT[3 * r + c] = P->Rw[3 * c + r];
        memcpy(P->tw, e->wp_t, sizeof P->tw);
    } else {
        eye(P->Rw);
        eye(P->RwT);
    }
    {
        int nlin = 0, rotated = e && (e->wp_a[0] != 0.0 || e->wp_a[1] != 0.0 || e->wp_a[2] != 0.0);
        for (i = 0; i < m->n_axes; i++) nlin += !m->rotary[i];
        P->closed = e && !any_geo && nlin == 3 && !(P->nrot && rotated);
        P->geo = any_geo;
        if (e && !any_geo && nlin == 3 && rotated && (P->nrot == 2 || P->nrot == 3)) {
            const double *u1 = m->dir[P->rot_idx[0]], *u2 = m->dir[P->rot_idx[1]];
            P->c12 = u1[0] * u2[0] + u1[1] * u2[1] + u1[2] * u2[2];
            P->closed_rot = 1 - P->c12 * P->c12 > 1e-6;   /* the first two rotary axes not parallel */
            if (P->nrot == 3) {
                const double *u3 = m->dir[P->rot_idx[2]];
                double ref[3] = {1, 0, 0}, d, nb;
                if (fabs(u3[0]) > 0.9) { ref[0] = 0; ref[1] = 1; }
                d = ref[0] * u3[0] + ref[1] * u3[1] + ref[2] * u3[2];
                for (k = 0; k < 3; k++) P->b3[k] = ref[k] - d * u3[k];
                nb = sqrt(P->b3[0] * P->b3[0] + P->b3[1] * P->b3[1] + P->b3[2] * P->b3[2]);
                for (k = 0; k < 3; k++) P->b3[k] /= nb;
            }
            {
                /* the constants of the subproblems in closed_rot_core */
                const double *a = P->nrot == 3 ? m->dir[P->rot_idx[2]] : m->tool_axis;
                double ap[3], w[3];
                u12_cross(u1, u2, P->u12);
                P->aa = a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
                P->u2a = a[0] * u2[0] + a[1] * u2[1] + a[2] * u2[2];
                for (k = 0; k < 3; k++) ap[k] = a[k] - P->u2a * u2[k];
                u12_cross(u2, ap, w);
                P->K[0] = ap[0] * u1[0] + ap[1] * u1[1] + ap[2] * u1[2];
                P->K[1] = ap[0] * P->u12[0] + ap[1] * P->u12[1] + ap[2] * P->u12[2];
                P->K[2] = w[0] * u1[0] + w[1] * u1[1] + w[2] * u1[2];
                P->K[3] = w[0] * P->u12[0] + w[1] * P->u12[1] + w[2] * P->u12[2];
                P->r2 = P->aa - P->u2a * P->u2a;
                P->iden = 1.0 / (1.0 - P->c12 * P->c12);
                if (!(P->r2 > 1e-9)) P->closed_rot = 0;   /* a along u2: no second angle to find */
            }
            {
                /* order of the linear axes against the rotary ones, and D^-1 for closed_rot_core */
                int first = -1, last = -1, c = 0, r;
                double D[9], det;
                for (i = 0; i < m->n_axes; i++) {
                    if (m->rotary[i]) continue;
                    if (first < 0) first = i;
                    last = i;
                    for (r = 0; r < 3; r++) D[3 * r + c] = m->dir[i][r];
                    c++;
                }
                det = D[0] * (D[4] * D[8] - D[5] * D[7]) - D[1] * (D[3] * D[8] - D[5] * D[6])
                      + D[2] * (D[3] * D[7] - D[4] * D[6]);
                if (det != 0.0 && (last - first == 2)) {
                    P->lin_order = first == 0 ? 1 : (last == m->n_axes - 1 ? 2 : 0);
                    P->Dinv[0] = (D[4] * D[8] - D[5] * D[7]) / det;
                    P->Dinv[1] = (D[2] * D[7] - D[1] * D[8]) / det;
                    P->Dinv[2] = (D[1] * D[5] - D[2] * D[4]) / det;
                    P->Dinv[3] = (D[5] * D[6] - D[3] * D[8]) / det;
                    P->Dinv[4] = (D[0] * D[8] - D[2] * D[6]) / det;
                    P->Dinv[5] = (D[2] * D[3] - D[0] * D[5]) / det;
                    P->Dinv[6] = (D[3] * D[7] - D[4] * D[6]) / det;
                    P->Dinv[7] = (D[1] * D[6] - D[0] * D[7]) / det;
                    P->Dinv[8] = (D[0] * D[4] - D[1] * D[3]) / det;
                }
            }
        }
        if (P->closed) {
            /* linear axes first: columns = their nominal directions, inverted once here */
            int seen_rot = 0, ok = 1, c = 0, r;
            double A[9], det;
            for (i = 0; i < m->n_axes; i++) {
                if (m->rotary[i]) seen_rot = 1;
                else if (seen_rot) ok = 0;
                else { for (r = 0; r < 3; r++) A[3 * r + c] = m->dir[i][r]; c++; }
            }
            det = A[0] * (A[4] * A[8] - A[5] * A[7]) - A[1] * (A[3] * A[8] - A[5] * A[6])
                  + A[2] * (A[3] * A[7] - A[4] * A[6]);
            if (ok && det != 0.0 && P->nrot > 0) {  /* (3-axis: the workpiece rotation term) */
                P->lin_first = 1;
                P->Ainv[0] = (A[4] * A[8] - A[5] * A[7]) / det;
                P->Ainv[1] = (A[2] * A[7] - A[1] * A[8]) / det;
                P->Ainv[2] = (A[1] * A[5] - A[2] * A[4]) / det;
                P->Ainv[3] = (A[5] * A[6] - A[3] * A[8]) / det;
                P->Ainv[4] = (A[0] * A[8] - A[2] * A[6]) / det;
                P->Ainv[5] = (A[2] * A[3] - A[0] * A[5]) / det;
                P->Ainv[6] = (A[3] * A[7] - A[4] * A[6]) / det;
                P->Ainv[7] = (A[1] * A[6] - A[0] * A[7]) / det;
                P->Ainv[8] = (A[0] * A[4] - A[1] * A[3]) / det;
            }
        }
    }
}

/* sin and cos of rotary axis i's angle a (rad) from those of the last angle taken directly for
 * the axis: the iterates of one pose and the poses of a path lie within 1e-2 rad of it, and a =
 * ref + d by the angle sum with the series of sin d and cos d (truncation below 1e-23); else sin
 * and cos, remembered.  (Deterministic: the reference depends only on the poses before in the
 * batch's chunk.) */
static inline void axis_sincos(const prep_t *P, int i, double a, double *s, double *c)
{
    prep_t *Q = (prep_t *)P;   /* (the prepared model's scratch, like the tables' hints) */
    double d = a - Q->sc_ref[i][0];
    if (fabs(d) < 1e-2) {
        double d2 = d * d;
        double sd = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0))));
        double cd = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0) * (1.0 - d2 * (1.0 / 56.0))));
        *s = Q->sc_ref[i][1] * cd + Q->sc_ref[i][2] * sd;
        *c = Q->sc_ref[i][2] * cd - Q->sc_ref[i][1] * sd;
        return;
    }
    *s = sin(a);
    *c = cos(a);
    Q->sc_ref[i][0] = a;
    Q->sc_ref[i][1] = *s;
    Q->sc_ref[i][2] = *c;
}

/* Pose of the tool in the real workpiece frame (mtcomp.kinematics.forward).  A table range
 * violation (strict) returns MTK_E_RANGE with the axis in *bad.  iter: an evaluation of the
 * iteration (the rotary sines and cosines by axis_sincos), else the plain forward model. */
static int fwd(const prep_t *P, const double *q, double p[3], double R[9], int strict, int *bad, int iter)
{
    const mtk_model *m = P->m;
    double t[3] = {0, 0, 0};
    int ident = 1, i, k;
    for (i = 0; i < P->n; i++) {
        double Rg[9], tg[3];
        int grot = 0;
        if (m->rotary[i]) {
            const double *c = P->c[i];
            if (iter) {
                double sn, cs;
                axis_sincos(P, i, q[i] * DEG + P->zero[i], &sn, &cs);
                axis_rotation_sc(P->ueff[i], sn, cs, Rg);
            } else {
                axis_rotation(P->ueff[i], q[i] * DEG + P->zero[i], Rg);
            }
            if (P->c0[i]) tg[0] = tg[1] = tg[2] = 0.0;
            else
                for (k = 0; k < 3; k++)
                    tg[k] = c[k] - (Rg[3 * k] * c[0] + Rg[3 * k + 1] * c[1] + Rg[3 * k + 2] * c[2]);
            grot = 1;
        } else {
            for (k = 0; k < 3; k++) tg[k] = q[i] * P->ueff[i][k];
        }
        if (P->tab[i]) {
            double d[3], ang[3], Re[9], te[3], tmp[3];
            const double *loc = m->loc[i];
            if (table_eval_hint(P->tab[i], q[i], d, ang, NULL, NULL, strict, (int *)&P->hint[i]) != MTK_OK) {
                if (bad) *bad = i;
                return MTK_E_RANGE;
            }
            rotvec_fast(ang, Re);
            if (P->loc0[i]) memcpy(te, d, sizeof te);
            else
                for (k = 0; k < 3; k++)
                    te[k] = loc[k] + d[k] - (Re[3 * k] * loc[0] + Re[3 * k + 1] * loc[1] + Re[3 * k + 2] * loc[2]);
            /* The error motion belongs to the moving body of a linear axis and to the
             * non-rotating body of a rotary axis: it stands before the nominal motion for a
             * workpiece-side linear or a tool-side rotary axis (docs/model.md). */
            if (m->tool_side[i] == m->rotary[i]) {      /* (Re, te) . (Rg, tg) */
                mat_vec(Re, tg, tmp);
                for (k = 0; k < 3; k++) tg[k] = tmp[k] + te[k];
                if (grot) mat_mul(Re, Rg, Rg); else memcpy(Rg, Re, sizeof Rg);
            } else {                                     /* (Rg, tg) . (Re, te) */
                if (grot) {
                    mat_vec(Rg, te, tmp);
                    for (k = 0; k < 3; k++) tg[k] += tmp[k];
                    mat_mul(Rg, Re, Rg);
                } else {
                    for (k = 0; k < 3; k++) tg[k] += te[k];
                    memcpy(Rg, Re, sizeof Rg);
                }
            }
            grot = 1;
        }
        if (ident) {
            for (k = 0; k < 3; k++) t[k] += tg[k];
            if (grot) { memcpy(R, Rg, sizeof Rg); ident = 0; }
        } else {
            double tmp[3];
            mat_vec(R, tg, tmp);
            for (k = 0; k < 3; k++) t[k] += tmp[k];
            if (grot) mat_mul(R, Rg, R);
        }
    }
    if (ident) eye(R);
    mat_vec(R, P->tp, p);
    for (k = 0; k < 3; k++) p[k] += t[k];
    if (P->wp) {
        double dp[3];
        for (k = 0; k < 3; k++) dp[k] = p[k] - P->tw[k];
        mat_vec(P->RwT, dp, p);
        mat_mul(P->RwT, R, R);
    }
    return MTK_OK;
}

/* The position and nd directions (given in dv in the tool's frame, turned in place) of fwd alone
 * (tables held at their ends, no range check), on vectors from the tool end: each axis' motion
 * G = E N (the error motion after the nominal one) or N E applied to the tool point and, without
 * its translation, to the directions; a rotary axis turns them by Rodrigues on the vector.  About
 * half the arithmetic of the matrix products (what the iteration's residual needs: the tool
 * direction on machines with one or two rotary axes, two columns of the tool frame with three). */
#if defined(__GNUC__)
#define MTK_INLINE static inline __attribute__((always_inline))
#else
#define MTK_INLINE static inline
#endif

/* turn() about the coordinate axis al (0, 1, 2: +x, +y, +z) in place: the two components normal
 * to it rotated, the third kept (a nominal axis: the ideal machine's, the rigid model's). */
MTK_INLINE void turn_axal(int al, double sn, double cs, double x[3])
{
    const int a = al == 2 ? 0 : al + 1, b = al == 0 ? 2 : al - 1;   /* (al + 1, al + 2 mod 3) */
    double xa = x[a], xb = x[b];
    x[a] = xa * cs - xb * sn;
    x[b] = xa * sn + xb * cs;
}

/* Axis i's nominal motion at q[i] applied in place, from the tool end, to np points x (mm: turned
 * about the axis' centre, or moved along it) and nd directions dv (turned only): the step of
 * fwd_dirs and of chain_two.  skip0: a point at the origin stays where a rotary axis turns about
 * the origin (the turn left out; fwd_dirs' tool point on a head). */
MTK_INLINE void axis_motion(const prep_t *P, int i, const double *q, double (*x)[3], int np, double (*dv)[3], int nd,
                            int skip0)
{
    int j, k;
    if (P->m->rotary[i]) {
        const double *c = P->c[i], *u = P->ueff[i];
        double sn, cs, y[3];
        axis_sincos(P, i, q[i] * DEG + P->zero[i], &sn, &cs);
        const int al = P->axal[i];
        for (j = 0; j < np; j++) {
            if (skip0 && P->c0[i] && x[j][0] == 0.0 && x[j][1] == 0.0 && x[j][2] == 0.0) continue;
            for (k = 0; k < 3; k++) y[k] = x[j][k] - c[k];
            if (al >= 0) turn_axal(al, sn, cs, y); else turn(u, sn, cs, y, y);
            for (k = 0; k < 3; k++) x[j][k] = c[k] + y[k];
        }
        if (al >= 0) for (j = 0; j < nd; j++) turn_axal(al, sn, cs, dv[j]);
        else for (j = 0; j < nd; j++) turn(u, sn, cs, dv[j], dv[j]);
    } else {
        double t[3];
        for (k = 0; k < 3; k++) t[k] = q[i] * P->ueff[i][k];
        for (j = 0; j < np; j++)
            for (k = 0; k < 3; k++) x[j][k] += t[k];
    }
}

MTK_INLINE void fwd_dirs(const prep_t *P, const double *q, double p[3], double (*dv)[3], int nd)
{
    const mtk_model *m = P->m;
    double x[3];
    int i, j, k;
    memcpy(x, P->tp, sizeof x);
    for (i = P->n - 1; i >= 0; i--) {
        double Re[9], te[3], y[3];
        int has_e = P->tab[i] != NULL, e_after = has_e && m->tool_side[i] == m->rotary[i];
        if (has_e) {
            double dd[3], ang[3];
            const double *loc = m->loc[i];
            table_eval_hint(P->tab[i], q[i], dd, ang, NULL, NULL, 0, (int *)&P->hint[i]);
            rotvec_fast(ang, Re);
            if (P->loc0[i]) memcpy(te, dd, sizeof te);
            else
                for (k = 0; k < 3; k++)
                    te[k] = loc[k] + dd[k] - (Re[3 * k] * loc[0] + Re[3 * k + 1] * loc[1] + Re[3 * k + 2] * loc[2]);
            if (!e_after) {
                mat_vec(Re, x, y);
                for (k = 0; k < 3; k++) x[k] = y[k] + te[k];
                for (j = 0; j < nd; j++) mat_vec(Re, dv[j], dv[j]);
            }
        }
        axis_motion(P, i, q, (double (*)[3])x, 1, dv, nd, 1);
        if (e_after) {
            mat_vec(Re, x, y);
            for (k = 0; k < 3; k++) x[k] = y[k] + te[k];
            for (j = 0; j < nd; j++) mat_vec(Re, dv[j], dv[j]);
        }
    }
    if (P->wp) {
        for (k = 0; k < 3; k++) x[k] -= P->tw[k];
        mat_vec(P->RwT, x, p);
        for (j = 0; j < nd; j++) mat_vec(P->RwT, dv[j], dv[j]);
    } else {
        memcpy(p, x, sizeof x);
    }
}

/* The position and the tool direction v of fwd alone (fwd_dirs). */
static void fwd_pv(const prep_t *P, const double *q, double p[3], double v[3])
{
    double d[1][3];
    memcpy(d[0], P->m->tool_axis, sizeof d[0]);
    fwd_dirs(P, q, p, d, 1);
    memcpy(v, d[0], sizeof d[0]);
}

/* Counters of a test build (-DMTK_STATS, gcc; one thread), printed at exit: forward evaluations of
 * the iteration, Jacobian passes, steps, steps taken under the second-order bound, corrected first
 * steps, poses iterated (docs/benchmarks.md's counts). */
#ifdef MTK_STATS
long mtk_stat[8];
#include <stdio.h>
__attribute__((destructor)) static void mtk_stat_print(void)
{
    fprintf(stderr, "STATS res %ld jac %ld steps %ld acc %ld corr %ld poses %ld\n", mtk_stat[0], mtk_stat[1],
            mtk_stat[2], mtk_stat[3], mtk_stat[4], mtk_stat[5]);
}
#define STAT(i) (mtk_stat[i]++)
#else
#define STAT(i) ((void)0)
#endif

static void range_message(const mtk_model *m, int i, double q, char *err)
{
    char msg[MTK_ERRLEN];
    snprintf(msg, sizeof msg, "axis %c position %.6f is outside its error table range [%g, %g]",
             m->axis_name[i], q, m->table[i]->pos[0], m->table[i]->pos[m->table[i]->n - 1]);
    seterr(err, msg);
}

int mtk_forward(const mtk_model *m, const mtk_errors *e, const double *q, double p[3], double R[9], char *err)
{
    prep_t P;
    int bad = -1, rc;
    double Rl[9];
    prepare(m, e, 1, &P);
    rc = fwd(&P, q, p, R ? R : Rl, 1, &bad, 0);
    if (rc) range_message(m, bad, q[bad], err);
    return rc;
}

/* ---------------------------------------------------------------- compensation */

typedef struct {
    double p[3], R[9], v[3];
} target_t;

/* Residual rows: position (mm), then the orientation (tool direction v - v_target, or the
 * small rotation of R_target^T R) times `wo` (mm per rad). */
static int residual(const prep_t *P, const double *q, const target_t *tg, double *r, double wo, int strict,
                    int *bad)
{
    double p[3], R[9];
    int k, rc;
    STAT(0);
    if (!strict && P->mode != 3) {   /* position and tool direction only */
        double v[3];
        fwd_pv(P, q, p, v);
        for (k = 0; k < 3; k++) r[k] = p[k] - tg->p[k];
        if (P->mode == 2)
            for (k = 0; k < 3; k++) r[3 + k] = wo * (v[k] - tg->v[k]);
        return MTK_OK;
    }
    if (!strict) {   /* mode 3: the first two columns of the tool frame, the third their cross product */
        double X[2][3] = {{1, 0, 0}, {0, 1, 0}}, X2[3], M[3][3];
        const double *T = tg->R;
        int i, j;
        fwd_dirs(P, q, p, X, 2);
        cross(X[0], X[1], X2);
        for (k = 0; k < 3; k++) r[k] = p[k] - tg->p[k];
        for (i = 0; i < 3; i++)   /* M = T^T R: the entries of its skew part (off the diagonal) */
            for (j = 0; j < 3; j++) {
                const double *c = j < 2 ? X[j] : X2;
                if (i != j) M[i][j] = T[i] * c[0] + T[3 + i] * c[1] + T[6 + i] * c[2];
            }
        r[3] = wo * 0.5 * (M[2][1] - M[1][2]);
        r[4] = wo * 0.5 * (M[0][2] - M[2][0]);
        r[5] = wo * 0.5 * (M[1][0] - M[0][1]);
        return MTK_OK;
    }
    rc = fwd(P, q, p, R, strict, bad, 1);
    if (rc) return rc;
    for (k = 0; k < 3; k++) r[k] = p[k] - tg->p[k];
    if (P->mode == 2) {
        /* All three components of v - v_target: the two perpendicular ones alone would also
         * vanish for a tool pointing the wrong way. */
        double v[3];
        mat_vec(R, P->m->tool_axis, v);
        for (k = 0; k < 3; k++) r[3 + k] = wo * (v[k] - tg->v[k]);
    } else if (P->mode == 3) {
        const double *T = tg->R;
        double M21 = T[2] * R[1] + T[5] * R[4] + T[8] * R[7], M12 = T[1] * R[2] + T[4] * R[5] + T[7] * R[8];
        double M02 = T[0] * R[2] + T[3] * R[5] + T[6] * R[8], M20 = T[2] * R[0] + T[5] * R[3] + T[8] * R[6];
        double M10 = T[1] * R[0] + T[4] * R[3] + T[7] * R[6], M01 = T[0] * R[1] + T[3] * R[4] + T[6] * R[7];
        r[3] = wo * 0.5 * (M21 - M12);
        r[4] = wo * 0.5 * (M02 - M20);
        r[5] = wo * 0.5 * (M10 - M01);
    }
    return MTK_OK;
}

static int errors_zero(const mtk_model *m, const mtk_errors *e)
{
    int i, k, geo = 0, rigid = 0;
    for (k = 0; k < 3; k++)
        rigid |= (e->tool[k] != 0.0) | (e->wp_t[k] != 0.0) | (e->wp_a[k] != 0.0);
    for (i = 0; i < m->n_axes; i++) {
        if (e->use_tables && m->table[i]) geo = 1;
        for (k = 0; k < 6; k++) geo |= (e->loc[i][k] != 0.0);
    }
    return !rigid && !geo;
}

static double norm(const double *r, int rows)
{
    double s = 0.0;
    int k;
    for (k = 0; k < rows; k++) s += r[k] * r[k];
    return sqrt(s);
}


/* Jacobian of the full model (location errors and the tables' slopes) and its residual at q
 * (tables held at their ends), in one pass: each axis' motion G_i(q_i) is a rigid motion whose
 * derivative is a twist (w_i, v_i) in the frame before it, dG_i G_i^-1 = ([w_i]x, v_i): a rotary
 * axis turns about the line through its centre c, (u, c x u) per rad; a linear axis moves along
 * u, (0, u); an error motion E = (Re, te) with te = loc + d - Re loc has the twist
 * (we, d' - we x (loc + d)), we = J(e) e' (rotvec_rate; e' alone is exact to first order in the
 * angles only).  Products compose by the adjoint,
 * tw(A B) = tw(A) + (Ra w_b, Ra v_b + ta x Ra w_b).  With (Rpre, tpre) the chain before axis i,
 * the column is dp = W x (p - tpre) + Rpre v_i, dR = [W]x R, W = Rpre w_i.  (Written by hand:
 * the kernel's own model; the numpy reference takes finite differences.) */
/* Residual of the pose (p, R, v) in the workpiece frame against the target: position rows, then
 * (weighted by wo) the tool-vector rows (mode 2) or the orientation rows (mode 3, the skew part of
 * T^T R as a small rotation vector).  Shared by both Jacobian passes. */
static inline void pose_residual(const prep_t *P, const double p[3], const double R[9], const double v[3],
                                 const target_t *tg, double wo, double *r0)
{
    double pr[3], d[3], Rr[9];
    int k;
    for (k = 0; k < 3; k++) d[k] = p[k] - P->tw[k];
    mat_vec(P->RwT, d, pr);
    for (k = 0; k < 3; k++) r0[k] = pr[k] - tg->p[k];
    if (P->mode == 2) {
        double vr[3];
        mat_vec(P->RwT, v, vr);
        for (k = 0; k < 3; k++) r0[3 + k] = wo * (vr[k] - tg->v[k]);
    } else if (P->mode == 3) {
        const double *T = tg->R;
        mat_mul(P->RwT, R, Rr);
        r0[3] = wo * 0.5 * ((T[2] * Rr[1] + T[5] * Rr[4] + T[8] * Rr[7]) - (T[1] * Rr[2] + T[4] * Rr[5] + T[7] * Rr[8]));
        r0[4] = wo * 0.5 * ((T[0] * Rr[2] + T[3] * Rr[5] + T[6] * Rr[8]) - (T[2] * Rr[0] + T[5] * Rr[3] + T[8] * Rr[6]));
        r0[5] = wo * 0.5 * ((T[1] * Rr[0] + T[4] * Rr[3] + T[7] * Rr[6]) - (T[0] * Rr[1] + T[3] * Rr[4] + T[6] * Rr[7]));
    }
}

/* E = T^T Rw^T R (mode 3): the real tool frame R (machine frame) seen from the target's T, for
 * orientation_column. */
static inline void orientation_frame(const prep_t *P, const double R[9], const target_t *tg, double E[9])
{
    double X[9];
    int r, c;
    mat_mul(P->RwT, R, X);
    for (r = 0; r < 3; r++)
        for (c = 0; c < 3; c++)
            E[3 * r + c] = tg->R[r] * X[c] + tg->R[3 + r] * X[3 + c] + tg->R[6 + r] * X[6 + c];
}

/* Column i of the orientation rows of the Jacobian for an axis turning about w (workpiece-side
 * direction in the machine frame): the tool vector's rate w x v (mode 2), or the small rotation
 * of dM = T^T Rw^T [w]x R, half the vee of its antisymmetric part (mode 3).  With u = T^T Rw^T w,
 * dM = [u]x E (E from orientation_frame), and [u]x E - ([u]x E)^T = [(tr E I - E) u]x: the
 * column is wo (tr E u - E u) / 2, no 3x3 product per axis.  Shared by both passes. */
static inline void orientation_column(const prep_t *P, const double w[3], const double E[9],
                                      const double v[3], const target_t *tg, double wo, double *J,
                                      int n, int i)
{
    int k;
    if (P->mode == 2) {
        double c[3], dv[3];
        cross(w, v, c);
        mat_vec(P->RwT, c, dv);
        for (k = 0; k < 3; k++) J[(3 + k) * n + i] = wo * dv[k];
    } else if (P->mode == 3) {
        double wp[3], u[3], Eu[3], tr = E[0] + E[4] + E[8];
        const double *T = tg->R;
        mat_vec(P->RwT, w, wp);
        for (k = 0; k < 3; k++) u[k] = T[k] * wp[0] + T[3 + k] * wp[1] + T[6 + k] * wp[2];
        mat_vec(E, u, Eu);
        for (k = 0; k < 3; k++) J[(3 + k) * n + i] = wo * 0.5 * (tr * u[k] - Eu[k]);
    }
}


static int jacobian_full(const prep_t *P, const double *q, const target_t *tg, double wo, double *J, double *r0,
                         double *Wo, double *Bo)
{
    const mtk_model *m = P->m;
    double W[MTK_MAX_AXES][3], V[MTK_MAX_AXES][3], T[MTK_MAX_AXES][3], R[9], t[3] = {0, 0, 0}, p[3], v[3];
    double WB[MTK_MAX_AXES][3], VB[MTK_MAX_AXES][3];   /* the bracket twists (second_order) */
    double E[9];
    int n = P->n, i, k, anyb = 0;
    eye(R);
    for (i = 0; i < n; i++) {
        double Rg[9], tg3[3], w[3], vv[3];
        int grot = m->rotary[i];      /* Rg differs from the identity (skipped in the products) */
        if (m->rotary[i]) {
            const double *c = P->c[i];
            {
                double sn, cs;
                axis_sincos(P, i, q[i] * DEG + P->zero[i], &sn, &cs);
                axis_rotation_sc(P->ueff[i], sn, cs, Rg);
            }
            for (k = 0; k < 3; k++) {
                tg3[k] = c[k] - (Rg[3 * k] * c[0] + Rg[3 * k + 1] * c[1] + Rg[3 * k + 2] * c[2]);
                w[k] = P->ueff[i][k] * DEG;
            }
            cross(c, w, vv);
        } else {
            eye(Rg);   /* not multiplied by (grot = 0); set for the compilers' flow analysis */
            for (k = 0; k < 3; k++) {
                tg3[k] = q[i] * P->ueff[i][k];
                w[k] = 0.0;
                vv[k] = P->ueff[i][k];
            }
        }
        if (P->tab[i]) {
            double d[3], ang[3], dd[3], de[3], Re[9], te[3], we[3], ve[3], lp[3], a[3], b[3], x[3];
            const double *loc = m->loc[i];
            table_eval_hint(P->tab[i], q[i], d, ang, dd, de, 0, (int *)&P->hint[i]);
            rotvec_fast(ang, Re);
            if (P->loc0[i]) {
                memcpy(te, d, sizeof te);
                memcpy(lp, d, sizeof lp);
            } else {
                for (k = 0; k < 3; k++) {
                    te[k] = loc[k] + d[k] - (Re[3 * k] * loc[0] + Re[3 * k + 1] * loc[1] + Re[3 * k + 2] * loc[2]);
                    lp[k] = loc[k] + d[k];
                }
            }
            rotvec_rate(ang, de, we);
            cross(we, lp, x);
            for (k = 0; k < 3; k++) ve[k] = dd[k] - x[k];
            /* The axis' twist xi_A + Ad_A xi_B (A, B: the nominal and the error motion in their
             * order) turns with A along the axis: d xi / dq = [xi_A, Ad_A xi_B], the bracket
             * (w1 x w2, w1 x v2 - w2 x v1), kept in WB, VB for the diagonal second derivative */
            if (m->tool_side[i] == m->rotary[i]) {      /* E . N */
                if (grot) {
                    mat_vec(Re, w, a);
                    cross(te, a, x);
                } else {                                 /* a linear axis: w = 0 */
                    a[0] = a[1] = a[2] = x[0] = x[1] = x[2] = 0.0;
                }
                mat_vec(Re, vv, b);
                if (Bo) {
                    double v2[3], c1[3], c2[3];
                    for (k = 0; k < 3; k++) v2[k] = b[k] + x[k];
                    cross(we, a, WB[i]);
                    cross(we, v2, c1);
                    cross(a, ve, c2);
                    for (k = 0; k < 3; k++) VB[i][k] = c1[k] - c2[k];
                    anyb = 1;
                }
                for (k = 0; k < 3; k++) { w[k] = we[k] + a[k]; vv[k] = ve[k] + b[k] + x[k]; }
                mat_vec(Re, tg3, b);
                for (k = 0; k < 3; k++) tg3[k] = b[k] + te[k];
                if (grot) mat_mul(Re, Rg, Rg); else memcpy(Rg, Re, sizeof Rg);
            } else if (grot) {                           /* N . E */
                mat_vec(Rg, we, a);
                mat_vec(Rg, ve, b);
                cross(tg3, a, x);
                if (Bo) {
                    double v2[3], c1[3], c2[3];
                    for (k = 0; k < 3; k++) v2[k] = b[k] + x[k];
                    cross(w, a, WB[i]);
                    cross(w, v2, c1);
                    cross(a, vv, c2);
                    for (k = 0; k < 3; k++) VB[i][k] = c1[k] - c2[k];
                    anyb = 1;
                }
                for (k = 0; k < 3; k++) { w[k] += a[k]; vv[k] += b[k] + x[k]; }
                mat_vec(Rg, te, b);
                for (k = 0; k < 3; k++) tg3[k] += b[k];
                mat_mul(Rg, Re, Rg);
            } else {                                     /* N . E, N a translation */
                cross(tg3, we, x);
                if (Bo) {   /* [(0, u), (we, .)] = (0, -we x u) */
                    WB[i][0] = WB[i][1] = WB[i][2] = 0.0;
                    cross(we, vv, VB[i]);
                    for (k = 0; k < 3; k++) VB[i][k] = -VB[i][k];
                    anyb = 1;
                }
                for (k = 0; k < 3; k++) { w[k] += we[k]; vv[k] += ve[k] + x[k]; tg3[k] += te[k]; }
                memcpy(Rg, Re, sizeof Rg);
            }
            grot = 1;
        }
        if (Bo) {
            if (P->tab[i]) {
                double tmp[3];
                mat_vec(R, WB[i], tmp);
                memcpy(WB[i], tmp, sizeof tmp);
                mat_vec(R, VB[i], tmp);
                memcpy(VB[i], tmp, sizeof tmp);
            } else {
                for (k = 0; k < 3; k++) WB[i][k] = VB[i][k] = 0.0;
            }
        }
        mat_vec(R, w, W[i]);
        if (Wo) mat_vec(P->RwT, W[i], Wo + 3 * i);
        mat_vec(R, vv, V[i]);
        memcpy(T[i], t, sizeof t);
        {
            double tmp[3];
            mat_vec(R, tg3, tmp);
            for (k = 0; k < 3; k++) t[k] += tmp[k];
            if (grot) mat_mul(R, Rg, R);
        }
    }
    mat_vec(R, P->tp, p);
    for (k = 0; k < 3; k++) p[k] += t[k];
    mat_vec(R, m->tool_axis, v);
    if (r0) pose_residual(P, p, R, v, tg, wo, r0);
    if (P->mode == 3) orientation_frame(P, R, tg, E);
    for (i = 0; i < n; i++) {
        double dp[3], dpr[3], d[3], *w = W[i];
        for (k = 0; k < 3; k++) d[k] = p[k] - T[i][k];
        cross(w, d, dp);
        for (k = 0; k < 3; k++) dp[k] += V[i][k];
        mat_vec(P->RwT, dp, dpr);
        for (k = 0; k < 3; k++) J[k * n + i] = dpr[k];
        orientation_column(P, w, E, v, tg, wo, J, n, i);
        if (Bo) {
            /* the bracket twist's column: the diagonal term's part beyond W_i x P_i */
            if (anyb && P->tab[i]) {
                for (k = 0; k < 3; k++) d[k] = p[k] - T[i][k];
                cross(WB[i], d, dp);
                for (k = 0; k < 3; k++) dp[k] += VB[i][k];
                mat_vec(P->RwT, dp, dpr);
                for (k = 0; k < 3; k++) Bo[k * n + i] = dpr[k];
                orientation_column(P, WB[i], E, v, tg, wo, Bo, n, i);
            } else {
                for (k = 0; k < P->rows; k++) Bo[k * n + i] = 0.0;
            }
        }
    }
    return MTK_OK;
}

/* Jacobian J (rows x n, row-major, per mm or deg) of the rigid model's residual at q, analytic
 * (mtcomp.kinematics._rigid_jacobian): a linear axis moves the tool along its direction as the
 * axes before it turn it, w = R_pre u; a rotary axis turns the tool about the line through its
 * centre c_w = R_pre c + t_pre along w, dp = w x (p - c_w) and dR = [w]x R (per rad), all in
 * the nominal workpiece frame and then turned into the real one by Rw^T.  The rigid model has
 * no tables and no location errors (prepare with geo = 0). */
static int jacobian(const prep_t *Pr, const double *q, const target_t *tg, double wo, double *J, double *r0,
                    double *Wo, double *Bo)
{
    const mtk_model *m = Pr->m;
    STAT(1);
    double Rpre[MTK_MAX_AXES][9], tpre[MTK_MAX_AXES][3], R[9], t[3] = {0, 0, 0}, p[3], v[3], E[9];
    int n = Pr->n, i, k, ident = 1;
    if (Pr->geo) return jacobian_full(Pr, q, tg, wo, J, r0, Wo, Bo);  /* the full model (see solve_pose) */
    eye(R);
    for (i = 0; i < n; i++) {
        memcpy(Rpre[i], R, sizeof R);
        memcpy(tpre[i], t, sizeof t);
        if (m->rotary[i]) {
            double Rg[9], tg[3], tmp[3];
            const double *c = Pr->c[i];
            axis_rotation(Pr->ueff[i], q[i] * DEG + Pr->zero[i], Rg);
            for (k = 0; k < 3; k++)
                tg[k] = c[k] - (Rg[3 * k] * c[0] + Rg[3 * k + 1] * c[1] + Rg[3 * k + 2] * c[2]);
            if (ident) {
                for (k = 0; k < 3; k++) t[k] += tg[k];
                memcpy(R, Rg, sizeof R);
                ident = 0;
            } else {
                mat_vec(R, tg, tmp);
                for (k = 0; k < 3; k++) t[k] += tmp[k];
                mat_mul(R, Rg, R);
            }
        } else {
            double w[3];
            mat_vec(R, Pr->ueff[i], w);
            for (k = 0; k < 3; k++) t[k] += q[i] * w[k];
        }
    }
    mat_vec(R, Pr->tp, p);
    for (k = 0; k < 3; k++) p[k] += t[k];
    mat_vec(R, m->tool_axis, v);
    if (r0) /* the residual of this (rigid) model at q from the same pass: the caller's model is
             * the rigid one (no tables, no location errors) */
        pose_residual(Pr, p, R, v, tg, wo, r0);
    if (Pr->mode == 3) orientation_frame(Pr, R, tg, E);
    for (i = 0; i < n; i++) {
        double w[3], dp[3], dpr[3];
        mat_vec(Rpre[i], Pr->ueff[i], w);
        if (Bo)
            for (k = 0; k < Pr->rows; k++) Bo[k * n + i] = 0.0;
        if (Wo) {
            double wd[3] = {w[0] * DEG, w[1] * DEG, w[2] * DEG};
            if (m->rotary[i]) mat_vec(Pr->RwT, wd, Wo + 3 * i);
            else Wo[3 * i] = Wo[3 * i + 1] = Wo[3 * i + 2] = 0.0;
        }
        if (!m->rotary[i]) {
            mat_vec(Pr->RwT, w, dpr);
            for (k = 0; k < 3; k++) J[k * n + i] = dpr[k];
            for (k = 3; k < Pr->rows; k++) J[k * n + i] = 0.0;
            continue;
        }
        {
            double cw[3], d[3];
            mat_vec(Rpre[i], Pr->c[i], cw);
            for (k = 0; k < 3; k++) {
                cw[k] += tpre[i][k];
                d[k] = p[k] - cw[k];
                w[k] *= DEG;
            }
            dp[0] = w[1] * d[2] - w[2] * d[1];
            dp[1] = w[2] * d[0] - w[0] * d[2];
            dp[2] = w[0] * d[1] - w[1] * d[0];
            mat_vec(Pr->RwT, dp, dpr);
            for (k = 0; k < 3; k++) J[k * n + i] = dpr[k];
        }
        orientation_column(Pr, w, E, v, tg, wo, J, n, i);
    }
    return MTK_OK;
}

/* A = J^T J + lambda I, LU-factored in place with partial pivoting (the multipliers below the
 * diagonal, the reciprocals of U's diagonal on it, piv the row order); 0 if singular.  Factored once per linearisation, each chord step
 * then solves for one right-hand side (normal_step) rather than forming A^-1 J^T for all rows. */
MTK_INLINE int normal_factor(int n, int rows, const double *J, double *A, int *piv)
{
    int i, j, k, c, r;
    for (i = 0; i < n; i++)
        for (j = i; j < n; j++) {   /* symmetric: the upper triangle, mirrored */
            double s = 0.0;
            for (k = 0; k < rows; k++) s += J[k * n + i] * J[k * n + j];
            A[i * n + j] = s + (i == j ? LAMBDA : 0.0);
            A[j * n + i] = A[i * n + j];
        }
    for (i = 0; i < n; i++) piv[i] = i;
    for (c = 0; c < n; c++) {
        int p = c;
        for (r = c + 1; r < n; r++)
            if (fabs(A[r * n + c]) > fabs(A[p * n + c])) p = r;
        if (A[p * n + c] == 0.0) return 0;
        if (p != c) {
            int t = piv[c];
            piv[c] = piv[p];
            piv[p] = t;
            for (j = 0; j < n; j++) { double tmp = A[c * n + j]; A[c * n + j] = A[p * n + j]; A[p * n + j] = tmp; }
        }
        for (r = c + 1; r < n; r++) {
            double f = A[r * n + c] / A[c * n + c];
            A[r * n + c] = f;
            for (j = c + 1; j < n; j++) A[r * n + j] -= f * A[c * n + j];
        }
    }
    for (c = 0; c < n; c++) A[c * n + c] = 1.0 / A[c * n + c];   /* (the steps multiply) */
    return 1;
}

/* x = A^-1 J^T r from normal_factor's factors. */
MTK_INLINE void normal_step(int n, int rows, const double *J, const double *LU, const int *piv, const double *r,
                            double *x)
{
    double g[MTK_MAX_AXES], y[MTK_MAX_AXES];
    int i, j, k;
    for (i = 0; i < n; i++) {
        double s = 0.0;
        for (k = 0; k < rows; k++) s += J[k * n + i] * r[k];
        g[i] = s;
    }
    for (i = 0; i < n; i++) {
        double s = g[piv[i]];
        for (j = 0; j < i; j++) s -= LU[i * n + j] * y[j];
        y[i] = s;
    }
    for (i = n - 1; i >= 0; i--) {
        double s = y[i];
        for (j = i + 1; j < n; j++) s -= LU[i * n + j] * x[j];
        x[i] = s * LU[i * n + i];
    }
}

/* Factors of A = J^T J + lambda I (normal_factor) of the Jacobian J at q, the columns of frozen
 * axes zeroed.  Returns 0 if A is singular. */
static int linearise(const prep_t *Pr, const double *q, const target_t *tg, double wo, const int *freeze,
                     const double *J0, const double *W0, const double *B0, double *LU, int *piv, double *J,
                     double *W, double *B, int *rc)
{
    int n = Pr->n, rows = Pr->rows, j, k;
    if (J0) {  /* the Jacobian at q already taken (weight ORIENTATION_SCALE) */
        memcpy(J, J0, (size_t)rows * n * sizeof(double));
        if (W0) memcpy(W, W0, (size_t)3 * n * sizeof(double));
        else W[0] = NAN;   /* not taken: no second-order correction */
        if (B0) memcpy(B, B0, (size_t)rows * n * sizeof(double));
        else B[0] = NAN;   /* not taken (second_order leaves the brackets out) */
        if (wo != ORIENTATION_SCALE)   /* (a held axis' weight; else the factor is 1) */
            for (k = 3 * n; k < rows * n; k++) {
                J[k] *= wo / ORIENTATION_SCALE;
                if (B0) B[k] *= wo / ORIENTATION_SCALE;
            }
        *rc = MTK_OK;
    } else {
        *rc = jacobian(Pr, q, tg, wo, J, NULL, W, B);
        if (*rc) return 0;
    }
    if (freeze)
        for (k = 0; k < n; k++)
            if (freeze[k])
                for (j = 0; j < rows; j++) J[j * n + k] = 0.0;
    /* the usual shapes with constant sizes (unrolled by the compiler; the same arithmetic) */
    if (n == 5 && rows == 6) return normal_factor(5, 6, J, LU, piv);
    if (n == 3 && rows == 3) return normal_factor(3, 3, J, LU, piv);
    if (n == 6 && rows == 6) return normal_factor(6, 6, J, LU, piv);
    return normal_factor(n, rows, J, LU, piv);
}

static void chord_step(int n, int rows, const double *J, const double *LU, const int *piv, const double *r, double *x)
{
    if (n == 5 && rows == 6) normal_step(5, 6, J, LU, piv, r, x);
    else if (n == 3 && rows == 3) normal_step(3, 3, J, LU, piv, r, x);
    else if (n == 6 && rows == 6) normal_step(6, 6, J, LU, piv, r, x);
    else normal_step(n, rows, J, LU, piv, r, x);
}

/* Largest steps (deg, mm) over which the model is linear to about 1e-10 mm, below the 5e-10 mm
 * the results are checked to: the rotation about a rotary axis deviates from its tangent by
 * L th^2 / 2 (under 1e-11 mm at 500 mm for 1e-5 deg); a linear step's products with that turn
 * (1e-4 mm x 1.7e-7 rad) and with the tables' changing µrad angles add a few 1e-11 mm (the worst
 * case found by the stress tests' estimate: about 7e-11 mm). */
#define LINEAR_ROTARY 1e-5
#define LINEAR_LINEAR 1e-4

/* The step from q to q - step is within those bounds and crosses no table knot (the tables are
 * linear within an interval). */
static int linear_exact(const prep_t *P, const double *q, const double *step)
{
    int i;
    for (i = 0; i < P->n; i++) {
        const mtk_table *t = P->tab[i];
        double qn = q[i] - step[i];
        if (fabs(step[i]) > (P->m->rotary[i] ? LINEAR_ROTARY : LINEAR_LINEAR)) return 0;
        if (t) {
            int lo = P->hint[i];
            if (!(q[i] > t->pos[0] && q[i] < t->pos[t->n - 1])) return 0;
            if (!(t->pos[lo] <= q[i] && q[i] < t->pos[lo + 1] && t->pos[lo] <= qn && qn < t->pos[lo + 1])) return 0;
        }
    }
    return 1;
}

/* Second-order term of the residual along a step: r(q - s) = r(q) - J s + h + O(s^3) with
 * h = 1/2 sum_ij s_i s_j d2r/dq_i dq_j.  For a serial chain the mixed derivative of a point is
 * the earlier axis' angular velocity crossed with the later axis' velocity of the point,
 * d2p/dq_i dq_j = W_i x P_j (i <= j; the spatial twists of the axes after i turn with it; on the
 * diagonal of an axis with a table also its twist's own rate, the bracket column B_j of
 * jacobian_full: 1/2 s_j^2 B_j), and
 * the same for the tool direction (mode 2: its columns O_j = W_j x v); the orientation rows of
 * mode 3 (the skew part of T^T R) have 1/2 O_i x O_j (O_j = T^T W_j) at a small residual, and no
 * diagonal term.  So h = sum_j s_j A_j x col_j with A_j = sum_{i<j} s_i W_i + s_j W_j / 2 (mode
 * 3: 1/2 sum_{i<j} s_i s_j O_i x O_j).  J: the columns (position rows, then the orientation rows
 * times wo), W (n x 3): the axes' angular velocities in the workpiece frame, per deg or mm.
 * (The tables' own curvature within an interval and the rates of the error motions' twists are
 * of the order of their µrad angles relative to these: the term improves a step, it is not used
 * as a bound.) */
static void second_order(const prep_t *P, const double *J, const double *W, const double *B, const double *s,
                         double wo, double *h)
{
    int n = P->n, i, j, k;
    double A[3] = {0, 0, 0}, S[3] = {0, 0, 0};
    for (k = 0; k < P->rows; k++) h[k] = 0.0;
    for (j = 0; j < n; j++) {
        double a[3], col[3], c[3];
        if (s[j] == 0.0) continue;
        for (k = 0; k < 3; k++) a[k] = A[k] + 0.5 * s[j] * W[3 * j + k];
        for (k = 0; k < 3; k++) col[k] = J[k * n + j];
        cross(a, col, c);
        for (k = 0; k < 3; k++) h[k] += s[j] * c[k];
        if (P->mode == 2) {
            for (k = 0; k < 3; k++) col[k] = J[(3 + k) * n + j];
            cross(a, col, c);
            for (k = 0; k < 3; k++) h[3 + k] += s[j] * c[k];
        } else if (P->mode == 3) {
            /* 1/(2 wo) (sum_{i<j} s_i Jo_i) x s_j Jo_j */
            for (k = 0; k < 3; k++) col[k] = J[(3 + k) * n + j];
            cross(S, col, c);
            for (k = 0; k < 3; k++) h[3 + k] += s[j] * c[k] * (0.5 / wo);
            for (k = 0; k < 3; k++) S[k] += s[j] * col[k];
        }
        for (k = 0; k < 3; k++) A[k] += s[j] * W[3 * j + k];
        if (P->tab[j] && !isnan(B[0]))   /* the tables' bracket column: d xi_j / dq_j applied */
            for (k = 0; k < P->rows; k++) h[k] += 0.5 * s[j] * s[j] * B[k * n + j];
    }
    (void)i;
}

/* Bound of the error of the chord prediction r(q - s) = r(q) - J s, with J taken at qlin and
 * every table axis within one interval over qlin, q and q - s (the model smooth there).  With
 * D_i = |q_i - qlin_i| + |s_i| (the box about qlin holding both segments), w_i = wmax_i and p_i
 * the length of J's position column i at qlin:
 *     |r(q - s) - r(q) + J s| <= sum_ij M_ij (|q_i - qlin_i| + |s_i| / 2) |s_j|,
 *     M_ij = 2 (w_i P_j + w_j P_i + wo w_i w_j),
 * the second derivatives of all rows bounded by second_order's expressions (|W_i x P_j| <=
 * w_i |P_j|, the orientation rows' by wo w_i w_j), the factor 2 for the tables' twists turning
 * with their axis and their curvature (both of the order of their µrad angles relative to
 * these).  P_j bounds the column's length over the box: |dP_j/dq_i| <= w_i P_j + w_j P_i gives,
 * with e = sum_i w_i D_i and Q = sum_i P_i D_i <= (sum_i p_i D_i) / (1 - 2 e),
 * P_j = (p_j + w_j Q) / (1 - e).  So the bound is 2 sum_j |s_j| (P_j A_w + w_j A_p + wo w_j A_w)
 * with A_w = sum_i w_i a_i, A_p = sum_i P_i a_i, a_i = |q_i - qlin_i| + |s_i| / 2.  pn: the
 * lengths p_j; ilin: each table axis' interval at qlin (-1: at or beyond an end).  Returns
 * INFINITY where the conditions do not hold. */
static void column_lengths(const prep_t *P, const double *J, double *pn)
{
    int n = P->n, j;
    for (j = 0; j < n; j++)
        pn[j] = sqrt(J[j] * J[j] + J[n + j] * J[n + j] + J[2 * n + j] * J[2 * n + j]);
}

static double second_order_bound(const prep_t *P, const double *pn, const int *ilin, const double *qlin,
                                 const double *q, const double *s, double wo)
{
    int n = P->n, i;
    double a[MTK_MAX_AXES], D[MTK_MAX_AXES], e = 0.0, T = 0.0, Q, Aw = 0.0, Ap = 0.0, b = 0.0;
    for (i = 0; i < n; i++) {
        const mtk_table *t = P->tab[i];
        double qn = q[i] - s[i], d = fabs(q[i] - qlin[i]);
        if (t) {
            int lo = ilin[i];
            if (lo < 0) return INFINITY;
            if (!(t->pos[lo] <= q[i] && q[i] < t->pos[lo + 1] && t->pos[lo] <= qn && qn < t->pos[lo + 1]))
                return INFINITY;
        }
        a[i] = d + 0.5 * fabs(s[i]);
        D[i] = d + fabs(s[i]);
        e += P->wmax[i] * D[i];
        T += pn[i] * D[i];
    }
    /* (the column bounds hold for e < 1/2; e <= 0.05 keeps 1 - 2 e >= 0.9: along a path about 3 deg
     * of rotary travel from qlin, rather than 0.6 deg at 0.01) */
    if (!(e <= 0.05)) return INFINITY;
    Q = T / (1.0 - 2.0 * e);
    e = 1.0 / (1.0 - e);   /* (reused) */
    for (i = 0; i < n; i++) {
        double Pb = (pn[i] + P->wmax[i] * Q) * e;
        D[i] = Pb;   /* (reused: the column bounds) */
        Aw += P->wmax[i] * a[i];
        Ap += Pb * a[i];
    }
    for (i = 0; i < n; i++)
        b += fabs(s[i]) * (D[i] * Aw + P->wmax[i] * Ap + wo * P->wmax[i] * Aw);
    return 2.0 * b;
}

/* A lower bound of second_order_bound from J's entries alone (no lengths, no table intervals):
 * the columns' largest components for their lengths and the terms with P_j A_w and wo w_j A_w
 * only.  Above LINEAR_BOUND the bound is not taken (tried on the first step of a linearisation,
 * which along a path is mostly beyond it; the later steps are mostly within). */
static double second_order_floor(const prep_t *P, const double *J, const double *qlin, const double *q,
                                 const double *s, double wo)
{
    int n = P->n, j;
    double Aw = 0.0, b = 0.0;
    for (j = 0; j < n; j++) Aw += P->wmax[j] * (fabs(q[j] - qlin[j]) + 0.5 * fabs(s[j]));
    for (j = 0; j < n; j++) {
        /* (compares rather than fmax, a libm call here: a NaN entry fails the bound either way) */
        double pl = fabs(J[j]), p1 = fabs(J[n + j]), p2 = fabs(J[2 * n + j]);
        pl = p1 > pl ? p1 : pl;
        pl = p2 > pl ? p2 : pl;
        b += fabs(s[j]) * (pl + wo * P->wmax[j]);
    }
    return 2.0 * b * Aw;
}

/* Largest bound (mm) of second_order_bound at which a step is taken without an evaluation: half
 * the resolution of the iteration itself, which stops at steps below tol = 1e-10 mm or deg
 * (residuals of about 1e-10 mm). */
#define LINEAR_BOUND 5e-11

/* With a held axis, rotary axes within this (deg) of where the Jacobian was taken do not make it
 * stale (its orientation rows depend on the rotary angles alone): the bias of the least-squares point it
 * leaves is below 1e-10 deg for the orientation residuals the pole tolerance admits (a warm start
 * along a path moves less). */
#define HELD_STALE 1e-7

/* The Gauss-Newton iteration of mtcomp._solver._solve for one point, started at `seed` and
 * damped least-squares steps; frozen axes (freeze[k] != 0, may be NULL) keep the seed's
 * value.  Leaves the iterate in q and its residual rows (tables held at their ends) in r; adds
 * the iterations to *iters.  A singular Jacobian ends the attempt with *singular set.  J0, r0: the
 * rigid Jacobian and the residual at seed if already known (NULL: evaluated here). */
static int iterate(const prep_t *P, const prep_t *Pr, const target_t *tg, double wo, const int *freeze,
                   const double *seed, const double *J0, const double *W0, const double *B0, const double *r0,
                   double *q, double tol,
                   int max_iter, int *iters, double *r, int *singular)
{
    int n = P->n, rows = P->rows, i, k, it = 0, rc = MTK_OK, done = 0;
    double LU[MTK_MAX_AXES * MTK_MAX_AXES], J[6 * MTK_MAX_AXES], W[3 * MTK_MAX_AXES], B[6 * MTK_MAX_AXES], nr,
           qlin[MTK_MAX_AXES];
    double pn[MTK_MAX_AXES];
    int piv[MTK_MAX_AXES], ilin[MTK_MAX_AXES], bounded, have_pn = 0, lin;
    *singular = 0;
    memcpy(q, seed, n * sizeof(double));
    if (r0) {  /* the residual at seed already known (weight ORIENTATION_SCALE) */
        for (k = 0; k < rows; k++) r[k] = k < 3 ? r0[k] : r0[k] * (wo / ORIENTATION_SCALE);
    } else {
        rc = residual(P, q, tg, r, wo, 0, NULL);
        if (rc) return rc;
    }
    nr = norm(r, rows);
    while (!done && it < max_iter) {
        int inner, slow = 0;
        memcpy(qlin, q, n * sizeof(double));
        if (!linearise(Pr, q, tg, wo, freeze, it == 0 ? J0 : NULL, W0, B0, LU, piv, J, W, B, &rc)) {
            *iters += it;
            if (rc) return rc;
            *singular = 1;
            return MTK_OK;
        }
        /* J the Jacobian of the evaluated model itself (not the rigid one's; no axis held): its
         * second-order term corrects the first step, and a chord step whose second-order bound
         * is below LINEAR_BOUND needs no evaluation */
        bounded = (Pr == P || !P->geo) && !freeze;
        have_pn = 0;   /* column lengths and intervals at qlin: taken when first needed */
        for (inner = 0; inner < 8; inner++) {
            double step[MTK_MAX_AXES], qn[MTK_MAX_AXES], rn[6], nn = nr, big = 0.0, scale, stepped = 0.0,
                   smax = 0.0, rstep = 0.0;
            int bt;
            it++;
            STAT(2);
            /* damped least squares: no component along a null direction of J (an axis the
             * orientation leaves free keeps the seed's value), no bias of the solution */
            chord_step(n, rows, J, LU, piv, r, step);
            if (inner == 0 && bounded && nr > 1e-4 && !isnan(W[0])) {
                /* Newton on the quadratic model r - J s + h(s) = 0: s = J+ (r + h(J+ r)), where
                 * the quadratic term is a small part of the residual and the rotary steps below
                 * 0.5 deg (the error left is then of third order, rather than second; far from
                 * the solution or near a pole the plain step).  Where the term is below 1e-7 mm
                 * the plain chord step already ends the iteration with one evaluation. */
                double h[6], rh[6], nh, rmax = 0.0;
                for (i = 0; i < n; i++)
                    if (P->m->rotary[i] && fabs(step[i]) > rmax) rmax = fabs(step[i]);
                second_order(P, J, W, B, step, wo, h);
                nh = norm(h, rows);
                if (nh > 1e-7 && nh < 1e-3 * nr && rmax <= 0.5) {
                    STAT(4);
                    for (k = 0; k < rows; k++) rh[k] = r[k] + h[k];
                    chord_step(n, rows, J, LU, piv, rh, step);
                }
            }
            for (i = 0; i < n; i++) {
                if (freeze && freeze[i]) { step[i] = 0.0; continue; }
                if (P->m->rotary[i] && fabs(step[i]) > big) big = fabs(step[i]);
                if (fabs(step[i]) > smax) smax = fabs(step[i]);
            }
            /* Damping: rotary steps at most 20 deg (the whole step scaled), halved while the
             * residual does not fall.  A step below the tolerance is convergence: no evaluation
             * (at the rounding floor a trial cannot lower the residual). */
            scale = big > 20.0 ? 20.0 / big : 1.0;   /* (big is finite: rotary steps at most 20 deg) */
            memcpy(qn, q, n * sizeof(double));
            memcpy(rn, r, rows * sizeof(double));
            lin = smax >= tol && bounded && inner == 0 && linear_exact(P, q, step);
            if (smax >= tol && bounded && !lin && !have_pn &&
                (inner > 0 || second_order_floor(P, J, qlin, q, step, wo) <= LINEAR_BOUND)) {
                column_lengths(P, J, pn);
                for (i = 0; i < n; i++) {
                    const mtk_table *t = P->tab[i];
                    ilin[i] = t && qlin[i] > t->pos[0] && qlin[i] < t->pos[t->n - 1] ?
                              table_interval(t, qlin[i], (int *)&P->hint[i]) : -1;
                }
                have_pn = 1;
            }
            if (smax >= tol && bounded && (lin || (have_pn && second_order_bound(P, pn, ilin, qlin, q, step, wo)
                                                       <= LINEAR_BOUND))) {
                /* Newton or chord step on the full model's Jacobian so small that the model is
                 * linear over it to about 1e-10 mm: the residual after it is the linear
                 * prediction, no evaluation (a warm start along a path ends here, and a random
                 * pose once its residual is below about 1e-9 mm) */
                STAT(3);
                for (i = 0; i < n; i++) qn[i] = q[i] - step[i];
                for (k = 0; k < rows; k++) {
                    double sk = r[k];
                    for (i = 0; i < n; i++) sk -= J[k * n + i] * step[i];
                    rn[k] = sk;
                }
                memcpy(q, qn, n * sizeof(double));
                memcpy(r, rn, rows * sizeof(double));
                done = 1;
                break;
            }
            for (bt = 0; bt < (smax >= tol ? 30 : 0); bt++) {
                double qt[MTK_MAX_AXES], rt[6], nt;
                for (i = 0; i < n; i++) qt[i] = q[i] - scale * step[i];
                rc = residual(P, qt, tg, rt, wo, 0, NULL);
                if (rc) return rc;
                nt = norm(rt, rows);
                if (nt < nr || nt <= 1e-12) {
                    memcpy(qn, qt, n * sizeof(double));
                    memcpy(rn, rt, rows * sizeof(double));
                    nn = nt;
                    break;
                }
                scale *= 0.5;
            }
            for (i = 0; i < n; i++) {
                if (fabs(qn[i] - q[i]) > stepped) stepped = fabs(qn[i] - q[i]);
                if (P->m->rotary[i] && fabs(qn[i] - qlin[i]) > rstep) rstep = fabs(qn[i] - qlin[i]);
            }
            /* contraction too weak: re-linearise (with a held axis every step: the least-squares
             * residual does not vanish, and only the Jacobian at the iterate leads to the
             * least-squares point rather than to one biased by a stale Jacobian) */
            slow |= (nn > 0.1 * nr) && (nn > 1e-12) && !(freeze && rstep < HELD_STALE);
            done |= (stepped < tol) || (nn <= 1e-12);
            memcpy(q, qn, n * sizeof(double));
            memcpy(r, rn, rows * sizeof(double));
            nr = nn;
            if (done || slow) break;
        }
    }
    *iters += it;
    return MTK_OK;
}

/* Orientation weight (mm per rad) while an axis at a pole is held: the tool direction is then
 * met in least squares, and the small weight keeps the position exact even where the tables'
 * angular errors couple the linear axes into the orientation. */
#define WO_HELD (ORIENTATION_SCALE * 1e-3)

static double maxabs(const double *r, int rows)
{
    double s = 0.0;
    int k, nan = 0;
    for (k = 0; k < rows; k++) {   /* (no branch per row: a NaN anywhere is the result) */
        double a = fabs(r[k]);
        nan |= a != a;
        s = a > s ? a : s;
    }
    return nan ? NAN : s;
}

/* Angle (rad) of the orientation residual rows r (weight wo). */
static double orientation_angle(const prep_t *P, const double *r, double wo)
{
    double x = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) / wo;
    return P->mode == 2 ? 2.0 * asin(fmin(1.0, 0.5 * x)) : asin(fmin(1.0, x));
}

/* The rotary axis at a pole, or -1, from the orientation columns col[a] of the rotary axes (their
 * effect on the orientation per rad: w_a x v for the tool direction v, or w_a with the full
 * orientation): an axis whose column lies within sin(pole_tol) = thr of the span of the others
 * (C at B = 0 on a B-C table turns the tool about itself; A and C at B = 90 on an A-B-C head turn
 * it about the same line).  Of several, the last in the chain (mtcomp._solver._pole_axis_of).
 * *margin (if given): the least distance of a column from the others' span. */
static int pole_axis_cols(const prep_t *Pr, double (*col)[3], double thr, double *margin)
{
    int a, b, j, k, hold = -1;
    double least = INFINITY;
    for (a = 0; a < Pr->nrot; a++) {
        double basis[MTK_MAX_AXES][3], v[3];
        int nb = 0;
        for (b = 0; b < Pr->nrot; b++) {
            double w[3], s;
            if (b == a) continue;
            memcpy(w, col[b], sizeof w);
            for (k = 0; k < nb; k++) {
                double d = w[0] * basis[k][0] + w[1] * basis[k][1] + w[2] * basis[k][2];
                for (j = 0; j < 3; j++) w[j] -= d * basis[k][j];
            }
            s = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
            if (s > 1e-9) {
                for (j = 0; j < 3; j++) basis[nb][j] = w[j] / s;
                nb++;
            }
        }
        memcpy(v, col[a], sizeof v);
        for (k = 0; k < nb; k++) {
            double d = v[0] * basis[k][0] + v[1] * basis[k][1] + v[2] * basis[k][2];
            for (j = 0; j < 3; j++) v[j] -= d * basis[k][j];
        }
        {
            double len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            if (len < thr) hold = Pr->rot_idx[a];
            if (len < least) least = len;
        }
    }
    if (margin) *margin = least;
    return hold;
}

/* pole_axis_cols on the orientation rows of a Jacobian J (weight ORIENTATION_SCALE, per deg). */
static int pole_axis_margin(const prep_t *Pr, const double *J, double thr, double *margin)
{
    int n = Pr->n, a, j;
    double col[MTK_MAX_AXES][3];
    for (a = 0; a < Pr->nrot; a++)
        for (j = 0; j < 3; j++) col[a][j] = J[(3 + j) * n + Pr->rot_idx[a]] / (ORIENTATION_SCALE * DEG);
    return pole_axis_cols(Pr, col, thr, margin);
}

/* Paden-Kahan subproblem 2 of the rigid model for a target's orientation, shared by
 * pole_columns and pole_clear: v = Rw R_t a, x = al u1 + be u2 + ga u1 x u2 (ga >= 0; 0 where the
 * orientation is out of reach).  Returns 0 where the first two rotary axes are parallel (two or
 * three rotary axes only). */
typedef struct {
    const double *u1, *u2, *a;
    double c, u1v, u2a, aa, al, be, ga;
} pole_sp_t;

static int pole_subproblem(const prep_t *P, const target_t *tg, pole_sp_t *s)
{
    const mtk_model *m = P->m;
    double v[3], iden, ga2;
    s->u1 = m->dir[P->rot_idx[0]];
    s->u2 = m->dir[P->rot_idx[1]];
    s->c = dot3(s->u1, s->u2);
    if (!(1.0 - s->c * s->c > 1e-6)) return 0;
    if (P->nrot == 3) {
        double Mt[9];
        s->a = m->dir[P->rot_idx[2]];
        mat_mul(P->Rw, tg->R, Mt);
        mat_vec(Mt, s->a, v);
    } else {
        s->a = m->tool_axis;
        mat_vec(P->Rw, tg->v, v);
    }
    iden = 1.0 / (1.0 - s->c * s->c);
    s->u1v = dot3(s->u1, v);
    s->u2a = dot3(s->u2, s->a);
    s->aa = dot3(s->a, s->a);
    s->al = (s->u1v - s->c * s->u2a) * iden;
    s->be = (s->u2a - s->c * s->u1v) * iden;
    ga2 = (s->aa - s->al * s->al - s->be * s->be - 2.0 * s->al * s->be * s->c) * iden;
    s->ga = ga2 > 0.0 ? sqrt(ga2) : 0.0;
    return 1;
}

/* The orientation columns the pole rule tests (pole_axis_cols): those of the rigid model (the
 * nominal axes, the workpiece setting's rotation Rw) at its exact solution for the target's
 * orientation, so that the decision depends on the target pose alone (not on where an iteration
 * starts, the path before, or the backend), and on the real machine's distance from its pole (a
 * tilted blank moves the pole: the exact solution's sensitivity, about 1 / sin of that distance,
 * is what holding the axis bounds; the held solution's orientation error is within the same
 * distance).  The rigid orientation is R(u1, th1) R(u2, th2) [R(u3, th3)] = Rw R_t, of which the
 * columns' lengths and mutual projections depend on th2 alone (the first turn rotates them all;
 * the third turns w3 about itself), found from the target direction v = Rw R_t a (a the tool
 * axis; with three rotary axes a = u3) as in closed_rot_core: x = R(u2, th2) a = al u1 + be u2 +
 * ga u1 x u2, either sign of ga (the columns of the two solutions have the same lengths and
 * projections).  Columns in the frame before the first turn: u1 x x, u2 x x (two rotary axes),
 * u1, u2, x (three), u1 x a (one).  ga^2 < 0 (an orientation the rigid model cannot reach): the
 * nearest, ga = 0.  Returns 0 (col not set) where the first two rotary axes are parallel. */
static int pole_columns(const prep_t *P, const target_t *tg, double (*col)[3])
{
    pole_sp_t s;
    double w[3], x[3];
    int k;
    if (P->nrot == 1) {
        cross(P->m->dir[P->rot_idx[0]], P->m->tool_axis, col[0]);
        return 1;
    }
    if (!pole_subproblem(P, tg, &s)) return 0;
    cross(s.u1, s.u2, w);
    for (k = 0; k < 3; k++) x[k] = s.al * s.u1[k] + s.be * s.u2[k] + s.ga * w[k];
    if (P->nrot == 3) {
        memcpy(col[0], s.u1, sizeof col[0]);
        memcpy(col[1], s.u2, sizeof col[1]);
        memcpy(col[2], x, sizeof col[2]);
    } else {
        cross(s.u1, x, col[0]);
        cross(s.u2, x, col[1]);
    }
    return 1;
}

/* No rotary axis within lim (a sine) of the others' span on the rigid model's exact solution, from
 * the invariants of pole_columns (u1.v, u2.a, t12 = u12.x = ga (1 - c^2), a.a; see closed_rot_core):
 * with two rotary axes the columns' lengths and the distance of each from the other's line, with
 * three (unit axes) the determinant, a lower bound of each column's distance from the others'
 * span.  1: pole_decision holds no axis at a tolerance below lim. */
static inline int pole_clear_inv(int nrot, double aa, double u1v, double u2a, double t12, double lim)
{
    double lim2 = lim * lim, n1, n2, nx;
    if (nrot == 3) return t12 * t12 >= lim2;
    n1 = aa - u1v * u1v;
    n2 = aa - u2a * u2a;
    nx = t12 * t12 * aa;
    return n1 >= lim2 && n2 >= lim2 && nx >= lim2 * (n1 > n2 ? n1 : n2);
}

/* pole_clear_inv for a target: 1 where the pole rule certainly holds no axis at the tolerance
 * whose sine is thr, 0 where it might (or the first two rotary axes are parallel). */
static int pole_clear(const prep_t *P, const target_t *tg, double thr)
{
    pole_sp_t s;
    thr *= 1.0 + 1e-9;
    if (P->nrot == 1) {
        double w[3];
        cross(P->m->dir[P->rot_idx[0]], P->m->tool_axis, w);
        return dot3(w, w) >= thr * thr;
    }
    if (P->nrot > 3 || !pole_subproblem(P, tg, &s)) return 0;
    return pole_clear_inv(P->nrot, s.aa, s.u1v, s.u2a, s.ga * (1.0 - s.c * s.c), thr);
}

/* The pole axis the compensation holds for a target (mtcomp._solver._pole_axis), or -1: the test
 * of pole_axis_cols on pole_columns; where those do not apply, on the rigid Jacobian at q0 (the
 * programmed commands). */
static int pole_decision(const prep_t *Pr, const target_t *tg, const double *q0, double thr)
{
    double col[MTK_MAX_AXES][3];
    if (Pr->nrot > 3 || !pole_columns(Pr, tg, col)) {
        double J[6 * MTK_MAX_AXES], r[6];
        if (Pr->geo || jacobian(Pr, q0, tg, ORIENTATION_SCALE, J, r, NULL, NULL) != MTK_OK) return -1;
        return pole_axis_margin(Pr, J, thr, NULL);
    }
    return pole_axis_cols(Pr, col, thr, NULL);
}

typedef struct {
    double tol;
    int max_iter;
    double pole_tol;
    double pole_sin;     /* sin(pole_tol), taken once per batch or error set */
} opt_t;

/* Rotary offsets (deg) of the restart seeds, as mtcomp.kinematics._SEED_OFFSETS. */
static const double SEED_OFFSETS[3] = {90.0, -90.0, 180.0};

/* The commands within every axis' travel and error table: a branch taken over from the previous
 * pose is kept only there (else the pose is solved afresh, as without a path). */
static int in_ranges(const prep_t *P, const double *q)
{
    int k;
    for (k = 0; k < P->n; k++)   /* (NaN: out where there is a table, as the table's test) */
        if (!(q[k] >= P->qlo[k] && q[k] <= P->qhi[k]) && (P->tab[k] || !isnan(q[k]))) return 0;
    return 1;
}

/* How a pose was solved (solve_pose's *how) */
enum { HOW_HELD = 0, HOW_WARM = 1, HOW_Q0 = 2, HOW_SEED = 3 };

/* Commands q for one target (mtcomp.kinematics.compensate for one point).  At a pole (of the
 * rigid model at its exact solution for the target's orientation, pole_decision) the pole axis is held
 * at its programmed value and the result kept if the tool direction is then within pole_tol; else the exact solution
 * from start if warm (the previous pose on the branch nearest its program: a warm start costs
 * one iteration less and keeps the path's branch), from q0, from start, then from rotary seeds
 * about q0 (least rotary change).  Returns MTK_OK, MTK_E_CONVERGE (*res0: the attempt from q0)
 * or MTK_E_RANGE (*bad). */
static int solve_pose(const prep_t *P, const prep_t *Pr, const target_t *tg, const double *q0,
                      const double *start, int warm, int far, const opt_t *o, double *q, int *iters, double *res,
                      double *res0, int *singular, int *bad, int *held, int *how, double *Jout)
{
    int n = P->n, rows = P->rows, sing = 0, rc, k, differs = memcmp(start, q0, n * sizeof(double)) != 0;
    int tables = 0;
    double r[6], racc[6], qt[MTK_MAX_AXES], J0[6 * MTK_MAX_AXES], W0[3 * MTK_MAX_AXES], B0[6 * MTK_MAX_AXES], r0s[6];
    double *Bs = B0, *Ws = W0;   /* the axes' angular velocities and the bracket columns (second_order:
                                  * far starts only, NULL otherwise) */
    const double *rs;
    const double *Jq0 = differs ? NULL : J0;
    const prep_t *Pj;
    *held = -1;
    *singular = 0;
    *res0 = INFINITY;
    for (k = 0; k < n; k++) tables |= P->tab[k] != NULL;
    /* With tables or location errors the Jacobian is the full model's (their slopes in it: Newton
     * steps rather than a chord contracting by the tables' slopes); either pass also gives the
     * residual at start.  With an axis held the rigid Jacobian stays (the least-squares point
     * the reference defines, mtcomp._solver). */
    Pj = P->geo ? P : Pr;
    far = far && P->nrot > 0;   /* (linear axes alone: the second-order term is the tables' µrad slopes
                                 * times the step, and the chord step after the first is exact) */
    rc = jacobian(Pj, start, tg, ORIENTATION_SCALE, J0, r0s, far ? W0 : NULL, far ? B0 : NULL);
    if (!far) Bs = Ws = NULL;
    if (rc) return rc;
    rs = r0s;
    if (o->pole_tol > 0.0 && P->mode >= 2) {
        int hold = pole_decision(Pr, tg, q0, o->pole_sin);
        if (hold >= 0) {
            /* The pole axis keeps its programmed value (not the path's: a pole stretch does not
             * depend on what came before it); the others start from `start`, and again from q0
             * if that lands outside a travel or table. */
            int freeze[MTK_MAX_AXES] = {0}, attempt;
            freeze[hold] = 1;
            for (attempt = 0; attempt < (differs ? 2 : 1); attempt++) {
                double hs[MTK_MAX_AXES];
                int same;
                memcpy(hs, attempt ? q0 : start, n * sizeof(double));
                hs[hold] = q0[hold];
                same = !memcmp(hs, start, n * sizeof(double));  /* else J0, rs were taken elsewhere */
                rc = iterate(P, Pr, tg, WO_HELD, freeze, hs, same && Pj == Pr ? J0 : NULL, Ws, Bs, same ? rs : NULL, qt, o->tol,
                             o->max_iter, iters, r, &sing);
                if (rc) return rc;
                if (!sing && maxabs(r, 3) < CONVERGED && orientation_angle(P, r + 3, WO_HELD) <= o->pole_tol * DEG
                    && (attempt || !differs || in_ranges(P, qt))) {
                    *held = hold;
                    *how = HOW_HELD;
                    goto accept;
                }
            }
        }
    }
    if (differs && warm) {
        rc = iterate(P, Pj, tg, ORIENTATION_SCALE, NULL, start, J0, Ws, Bs, rs, qt, o->tol, o->max_iter, iters, r, &sing);
        if (rc) return rc;
        if (!sing && maxabs(r, rows) < CONVERGED && in_ranges(P, qt)) {
            *how = HOW_WARM;
            goto accept;
        }
    }
    rc = iterate(P, Pj, tg, ORIENTATION_SCALE, NULL, q0, Jq0, Ws, Bs, differs ? NULL : rs, qt, o->tol, o->max_iter, iters, r, &sing);
    if (rc) return rc;
    *singular = sing;
    *res0 = sing ? INFINITY : maxabs(r, rows);
    if (*res0 < CONVERGED) {
        *how = HOW_Q0;
        goto accept;
    }
    if (differs && !warm) {
        /* continuation: the previous pose's correction keeps the branch the path is on */
        rc = iterate(P, Pj, tg, ORIENTATION_SCALE, NULL, start, J0, Ws, Bs, rs, qt, o->tol, o->max_iter, iters, r, &sing);
        if (rc) return rc;
        if (!sing && maxabs(r, rows) < CONVERGED && in_ranges(P, qt)) {
            *how = HOW_WARM;
            goto accept;
        }
    }
    {
        /* Where that fails (a tilted workpiece at a singularity: B = 0 on a B-C table needs C
         * turned by 90 deg), restart from q0 with rotary axes offset by SEED_OFFSETS: each rotary
         * axis alone, then each pair, in the core's order; keep the converged solution with the
         * smallest sum of |rotary change| (within 1e-6 deg a tie: the first seed wins). */
        int a, b, oa, ob, s, ns = 0, sa[3 * MTK_MAX_AXES * MTK_MAX_AXES], sb[3 * MTK_MAX_AXES * MTK_MAX_AXES];
        double va[3 * MTK_MAX_AXES * MTK_MAX_AXES], vb[3 * MTK_MAX_AXES * MTK_MAX_AXES];
        double best = INFINITY, seed[MTK_MAX_AXES];
        for (a = 0; a < P->nrot; a++)
            for (oa = 0; oa < 3; oa++, ns++) {
                sa[ns] = P->rot_idx[a]; va[ns] = SEED_OFFSETS[oa];
                sb[ns] = -1; vb[ns] = 0.0;
            }
        for (a = 0; a < P->nrot; a++)
            for (b = a + 1; b < P->nrot; b++)
                for (oa = 0; oa < 3; oa++)
                    for (ob = 0; ob < 3; ob++, ns++) {
                        sa[ns] = P->rot_idx[a]; va[ns] = SEED_OFFSETS[oa];
                        sb[ns] = P->rot_idx[b]; vb[ns] = SEED_OFFSETS[ob];
                    }
        for (s = 0; s < ns; s++) {
            double change = 0.0, et;
            memcpy(seed, q0, n * sizeof(double));
            seed[sa[s]] += va[s];
            if (sb[s] >= 0) seed[sb[s]] += vb[s];
            rc = iterate(P, Pj, tg, ORIENTATION_SCALE, NULL, seed, NULL, NULL, NULL, NULL, qt, o->tol, o->max_iter, iters, r, &sing);
            if (rc) return rc;
            et = sing ? INFINITY : maxabs(r, rows);
            for (k = 0; k < P->nrot; k++) change += fabs(qt[P->rot_idx[k]] - q0[P->rot_idx[k]]);
            if (et < CONVERGED && change < best - 1e-6) {
                memcpy(q, qt, n * sizeof(double));
                memcpy(racc, r, rows * sizeof(double));
                best = change;
            }
        }
        if (best == INFINITY) {
            *res = *res0;
            return MTK_E_CONVERGE;
        }
        *how = HOW_SEED;
        goto strict;
    }
accept:
    memcpy(q, qt, n * sizeof(double));
    memcpy(racc, r, rows * sizeof(double));
    if (Jout) memcpy(Jout, J0, (size_t)rows * n * sizeof(double));   /* (the Jacobian at start) */
strict:
    /* Strict check: a converged command outside an error table's range is an error.  Inside the
     * ranges the iteration's residual (tables held at their ends) is the strict one, so the
     * ranges are checked directly, in chain order as the strict forward model would. */
    if (tables) {
        for (k = 0; k < n; k++) {
            const mtk_table *t = P->tab[k];
            if (t && !(q[k] >= t->pos[0] - 1e-12 && q[k] <= t->pos[t->n - 1] + 1e-12)) {
                *bad = k;
                return MTK_E_RANGE;
            }
        }
    }
    *res = maxabs(racc, *held >= 0 ? 3 : rows);
    if (!(*res < CONVERGED)) {
        *res0 = *res;
        return MTK_E_CONVERGE;
    }
    return MTK_OK;
}

/* A x = rhs for a 3x3 A by Cramer's rule (the closed forms' linear axes); 0 where A is singular. */
static int solve3_cramer(const double A[3][3], const double rhs[3], double x[3])
{
#define DET3(c0, c1, c2) (c0[0] * (c1[1] * c2[2] - c1[2] * c2[1]) - c0[1] * (c1[0] * c2[2] - c1[2] * c2[0]) \
                          + c0[2] * (c1[0] * c2[1] - c1[1] * c2[0]))
    double c0[3] = {A[0][0], A[1][0], A[2][0]}, c1[3] = {A[0][1], A[1][1], A[2][1]},
           c2[3] = {A[0][2], A[1][2], A[2][2]};
    double det = DET3(c0, c1, c2);
    if (det == 0.0) return 0;
    x[0] = DET3(rhs, c1, c2) / det;
    x[1] = DET3(c0, rhs, c2) / det;
    x[2] = DET3(c0, c1, rhs) / det;
    return 1;
#undef DET3
}

/* Closed form of retarget for rigid setting errors when the rotary angles need not change (no
 * geometric errors; no workpiece rotation unless the machine has no rotary axes): with the
 * rotary angles fixed the nominal tool position is affine in the three linear axes,
 * A dq = Rw p_ideal + tw - p_ideal - R_c t (mtcomp.kinematics._retarget_rigid). */
static int closed_form(const prep_t *P, const double *q, double *out)
{
    const mtk_model *m = P->m;
    double R[9], A[3][3], rhs[3], t[3], Rt[3], x[3];
    int i, k, nc = 0, lin[3], ident = 1;
    if (P->lin_first) {
        /* R t by turning the vector t through the rotary axes from the tool end (Rodrigues on a
         * vector); the matrix of the linear axes is constant */
        for (k = 0; k < 3; k++) Rt[k] = P->tp[k] - m->tool_point[k];
        for (i = P->n - 1; i >= 0; i--) {
            if (m->rotary[i]) {
                const double *u = m->dir[i];
                double sn, cs, ux[3], ud;
                sn = sin(q[i] * DEG);
                cs = cos(q[i] * DEG);
                ux[0] = u[1] * Rt[2] - u[2] * Rt[1];
                ux[1] = u[2] * Rt[0] - u[0] * Rt[2];
                ux[2] = u[0] * Rt[1] - u[1] * Rt[0];
                ud = (u[0] * Rt[0] + u[1] * Rt[1] + u[2] * Rt[2]) * (1.0 - cs);
                for (k = 0; k < 3; k++) Rt[k] = Rt[k] * cs + ux[k] * sn + u[k] * ud;
            } else {
                lin[2 - nc++] = i;
            }
        }
        for (k = 0; k < 3; k++) rhs[k] = P->tw[k] - Rt[k];
        mat_vec(P->Ainv, rhs, x);
        memcpy(out, q, P->n * sizeof(double));
        for (k = 0; k < 3; k++) out[lin[k]] += x[k];
        return 1;
    }
    eye(R);
    for (i = 0; i < P->n; i++) {
        if (m->rotary[i]) {
            double Rg[9];
            axis_rotation(m->dir[i], q[i] * DEG, Rg);
            if (ident) memcpy(R, Rg, sizeof R); else mat_mul(R, Rg, R);
            ident = 0;
        } else {
            double c[3];
            mat_vec(R, m->dir[i], c);
            for (k = 0; k < 3; k++) A[k][nc] = c[k];
            lin[nc++] = i;
        }
    }
    for (k = 0; k < 3; k++) t[k] = P->tp[k] - m->tool_point[k];
    mat_vec(R, t, Rt);
    for (k = 0; k < 3; k++) rhs[k] = P->tw[k] - Rt[k];
    if (P->wp && P->nrot == 0) {
        double p[3], Rp[3];
        for (k = 0; k < 3; k++) p[k] = m->tool_point[k];  /* nominal chain without rotation: p = tp + sum q u */
        for (i = 0; i < P->n; i++)
            for (k = 0; k < 3; k++) p[k] += q[i] * m->dir[i][k];
        mat_vec(P->Rw, p, Rp);
        for (k = 0; k < 3; k++) rhs[k] += Rp[k] - p[k];
    }
    if (!solve3_cramer(A, rhs, x)) return 0;
    memcpy(out, q, P->n * sizeof(double));
    for (k = 0; k < 3; k++) out[lin[k]] += x[k];
    return 1;
}


/* Components of the rotation about the unit vector u that takes a to b, both seen in the plane
 * normal to u (Paden-Kahan subproblem 1; a and b need not be normalised): *y = u.(a' x b') and
 * *c = a'.b' with a', b' the projections, so that the angle is atan2(y, c). */
static inline void turn_yc(const double u[3], const double a[3], const double b[3], double *y, double *c)
{
    double ap[3], bp[3], x[3], ua = dot3(u, a), ub = dot3(u, b);
    int k;
    for (k = 0; k < 3; k++) { ap[k] = a[k] - ua * u[k]; bp[k] = b[k] - ub * u[k]; }
    cross(ap, bp, x);
    *y = dot3(u, x);
    *c = dot3(ap, bp);
}

/* Subproblem 1 in full: the angle in deg, and its sine and cosine in *sn, *cs (the rigid chain at
 * the solution is built from them, no sin/cos again). */
static inline double turn_angle(const double u[3], const double a[3], const double b[3], double *sn, double *cs)
{
    double y, c, r;
    turn_yc(u, a, b, &y, &c);
    r = sqrt(y * y + c * c);
    *sn = y / r;
    *cs = c / r;
    return atan2(y, c) / DEG;
}

/* th + 360 k nearest ref (th within 540 deg of ref: atan2's range and the travels). */
static inline double near_turn(double th, double ref)
{
    double d = th - ref;
    while (d > 180.0) d -= 360.0;
    while (d < -180.0) d += 360.0;
    return ref + d;
}


/* The rigid chain on vectors, from the sines and cosines sc of its rotary angles (per rotary
 * axis, in chain order): no rotation matrix is built, each rotary axis turns a vector once. */

/* x turned by the rotary axes before axis `upto` (P->n: all of them, the chain's rotation). */
static inline void rigid_turn(const prep_t *P, const double (*sc)[2], int upto, double x[3])
{
    int r;
    for (r = P->nrot - 1; r >= 0; r--)
        if (P->rot_idx[r] < upto) turn(P->m->dir[P->rot_idx[r]], sc[r][0], sc[r][1], x, x);
}

/* Nominal tool position (no workpiece pose) of the rigid chain with tool point tp, the linear
 * axes at q and the rotary axes at the angles of sc: from the tool end, x <- c + R (x - c) for a
 * rotary axis about its centre c, x <- x + q u for a linear axis. */
static inline void rigid_position(const prep_t *P, const double *q, const double (*sc)[2], const double tp[3],
                                  double p[3])
{
    const mtk_model *m = P->m;
    double x[3] = {tp[0], tp[1], tp[2]};
    int i, k, r = P->nrot - 1;
    for (i = P->n - 1; i >= 0; i--) {
        const double *u = m->dir[i];
        if (m->rotary[i]) {
            const double *c = P->c[i];
            double d[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
            turn(u, sc[r][0], sc[r][1], d, d);
            for (k = 0; k < 3; k++) x[k] = c[k] + d[k];
            r--;
        } else {
            for (k = 0; k < 3; k++) x[k] += q[i] * u[k];
        }
    }
    memcpy(p, x, sizeof x);
}

/* The rotary axes' columns of the orientation rows (rotation rates w_i in the machine frame, for
 * the tool direction v: w_i x v) are this far (sine) from depending on each other at the solution
 * before a pose is taken as regular: five times the pole tolerance (the rule, pole_decision, holds
 * an axis within one; between, the iteration solves the pose exactly). */
#define CLOSED_POLE_MARGIN 5.0

/* Largest change of a rotary axis (deg) the closed form takes: beyond it the iteration from the
 * start might settle on another solution, and it is left to decide. */
#define CLOSED_MAX_TURN 10.0

/* Largest |y / x| (x > 0) small_atan2 takes by its series: tan(10.2 deg), above tan(CLOSED_MAX_TURN)
 * with room for the rounding of the candidates' test. */
#define SMALL_ATAN_MAX 0.18

/* atan2(y, x) (rad) for the turns the closed form takes, a few degrees at most from the
 * reference angle: for x > 0 and |t| <= SMALL_ATAN_MAX, t = y / x, the alternating series of
 * atan(t), else atan2.  Its truncation after t^(2n+1)/(2n+1) is below t^(2n+3)/(2n+3), relative
 * to atan(t) >= 0.98 t: after t^9 for t^2 < 1e-4 (the usual turns, below 0.6 deg) below
 * 1e-20 / 11, after t^21 for t^2 <= 0.0324 below 0.0324^11 / 23 < 2e-18; with the rounding of t
 * and of the last sum, within about 1 ulp of atan2 (y = 0 gives 0 of y's sign, as atan2).  A
 * tenth of atan2's instructions. */
static inline double small_atan2(double y, double x)
{
    double t = y / x;
    if (x > 0.0 && fabs(t) <= SMALL_ATAN_MAX) {   /* (not y = x = inf: t is NaN) */
        double t2 = t * t, s;
        if (t2 < 1e-4)
            s = -1.0 / 3 + t2 * (1.0 / 5 + t2 * (-1.0 / 7 + t2 * (1.0 / 9)));
        else
            s = -1.0 / 3 + t2 * (1.0 / 5 + t2 * (-1.0 / 7 + t2 * (1.0 / 9 + t2 * (-1.0 / 11 + t2 * (1.0 / 13 +
                t2 * (-1.0 / 15 + t2 * (1.0 / 17 + t2 * (-1.0 / 19 + t2 * (1.0 / 21)))))))));
        return t2 == 0.0 ? t : t + t * t2 * s;   /* (t = -0: -0, as atan2) */
    }
    return atan2(y, x);
}

/* small_atan2 for the tests (its accuracy against atan2 over its whole domain). */
double mtk_small_atan2(double y, double x)
{
    return small_atan2(y, x);
}

/* Closed form of retarget/compensate for rigid setting errors with a workpiece rotation on a
 * machine with two or three rotary axes (P->closed_rot): the rigid model's orientation depends
 * on the rotary angles alone, R = R(u1, th1) R(u2, th2) [R(u3, th3)], and its tool position is
 * affine in the three linear axes once those angles are fixed.
 *   Orientation: the real tool frame Rw^T R must equal the target's R_t, so R = Rw R_t (mode 3)
 * or R a = Rw R_t a = v for the tool direction a (mode 2).  Both reduce to R(u1, th1) R(u2, th2) a
 * = v (mode 3: a = u3, v = Rw R_t u3), solved as Paden-Kahan subproblem 2: x = R(u2, th2) a =
 * R(u1, -th1) v lies on both cones u2.x = u2.a, u1.x = u1.v with |x| = 1, so x = al u1 + be u2 +
 * ga u1 x u2 with
 *     al = (u1.v - c u2.a) / (1 - c^2),  be = (u2.a - c u1.v) / (1 - c^2),  c = u1.u2,
 *     ga^2 = (1 - al^2 - be^2 - 2 al be c) / (1 - c^2),
 * two solutions (+-ga); th2 turns a into x about u2, th1 turns x into v about u1 (subproblem 1),
 * and in mode 3 th3 turns b into (R1 R2)^T mb about u3 for a b normal to u3 (mb = Rw R_t b).  Of
 * the two, the one with the least rotary change from `ref` (each angle taken within 180 deg of
 * it); a solution whose th2 is more than CLOSED_MAX_TURN from ref is dropped by the cosine of
 * the difference (from rsc, the sines and cosines of ref's rotary angles) before any atan2.
 *   Position: with the angles fixed, p_nom(q) = p_nom(q_lin) + A dq_lin with the columns of A
 * the linear axes' directions turned by the rotary axes before them; the real position
 * Rw^T (p_nom - tw) equals p_t for dq_lin = A^-1 (Rw p_t + tw - p_nom(q_lin)).  A = D (the linear
 * axes' directions) where they precede the rotary axes, A = R D where they follow them (A^-1 =
 * D^-1 R^T: the right-hand side turned back), else its columns turned one by one.
 *   Pole test on the solution (pole_columns: the rule's columns, x = R(u2, th2) a): |u1 x x|^2 =
 * a.a - (u1.v)^2, |u2 x x|^2 = a.a - (u2.a)^2, |(u1 x x) x (u2 x x)|^2 = (u12.x)^2 a.a and
 * det(u1, u2, x) = u12.x = ga (1 - c^2) (mode 3), the same for both solutions; where they pass,
 * every column is further than CLOSED_POLE_MARGIN sin(pole_tol) from the others' span, so the
 * rule (pole_decision) holds no axis.
 * Returns 0 (the iteration decides) near a pole (CLOSED_POLE_MARGIN times the pole tolerance),
 * for a change of a rotary axis above CLOSED_MAX_TURN, an unreachable orientation, or a result
 * outside a travel; else 1 with the commands in out and the sines and cosines of the rotary
 * angles in osc. */
static int closed_rot_core(const prep_t *P, const double pt[3], const double v[3], const double mb[3],
                           const double *q0, const double *ref, const double (*rsc)[2],
                           double pole_sin, double *out, double (*osc)[2])
{
    const mtk_model *m = P->m;
    const int i1 = P->rot_idx[0], i2 = P->rot_idx[1], i3 = P->nrot == 3 ? P->rot_idx[2] : -1;
    const double *u1 = m->dir[i1], *u2 = m->dir[i2];
    const double c = P->c12, iden = P->iden;
    const double cos_max = cos(CLOSED_MAX_TURN * DEG) - 1e-12;
    double w[3], al, be, ga2, ga, u1v, u2v, vw, th[2][3], best = INFINITY, sc[2][3][2];
    int k, br, pick = -1, ok[2];
    {
        u1v = dot3(u1, v);
        u2v = dot3(u2, v);
        vw = dot3(P->u12, v);
        al = (u1v - c * P->u2a) * iden;
        be = (P->u2a - c * u1v) * iden;
        ga2 = (P->aa - al * al - be * be - 2.0 * al * be * c) * iden;
        if (!(ga2 > 1e-12)) return 0;   /* unreachable, or the two solutions merge */
        ga = sqrt(ga2);
    }
    if (!pole_clear_inv(P->nrot, P->aa, u1v, P->u2a, ga * (1.0 - c * c), CLOSED_POLE_MARGIN * pole_sin)) return 0;
    /* the second rotary angle of both solutions first (subproblem 1 for a into x about u2, its
     * components from the constants of prepare: y = x.(u2 x ap), c = ap.x, and |ap| |x - (u2.x)
     * u2| = a.a - (u2.a)^2 as |x| = |a|): a solution that turns it by more than CLOSED_MAX_TURN is
     * out without the rest */
    {
        /* Both solutions' (y, c) for th2, and turned back by ref2, (Y, X) = the sine and cosine
         * of th2 - ref2 times a.a - (u2.a)^2: X >= cos(CLOSED_MAX_TURN) r2 is the test, and
         * atan2(Y, X) the turn from ref2 (no wrapping).  Decided without a branch on which of the
         * two it is (random poses pick either: a mispredicted branch costs more than the sums). */
        double y2[2], c2[2], Y2[2], X2[2];
        int cand[2], ncand = 0, ci;
        for (br = 0; br < 2; br++) {
            double g = br ? -ga : ga;
            y2[br] = al * P->K[2] + g * P->K[3];
            c2[br] = al * P->K[0] + g * P->K[1];
            Y2[br] = y2[br] * rsc[1][1] - c2[br] * rsc[1][0];
            X2[br] = c2[br] * rsc[1][1] + y2[br] * rsc[1][0];
            ok[br] = X2[br] >= cos_max * P->r2;
        }
        cand[0] = ok[0] ? 0 : 1;
        cand[1] = 1;
        ncand = ok[0] + ok[1];
        for (ci = 0; ci < ncand; ci++) {
            double sum, mx, g, y, cc, ir, Y, X;
            int j;
            br = cand[ci];
            g = br ? -ga : ga;
            ir = 1.0 / sqrt(y2[br] * y2[br] + c2[br] * c2[br]);   /* (unit sine and cosine: near a pole
                                                     * y and c are small and r2 off by their rounding) */
            sc[br][1][0] = y2[br] * ir;
            sc[br][1][1] = c2[br] * ir;
            th[br][1] = ref[i2] + small_atan2(Y2[br], X2[br]) / DEG;
            /* subproblem 1 for x into v about u1: y = u1.(x x v), c = x.v - (u1.x)(u1.v) */
            y = be * vw + g * (c * u1v - u2v);
            cc = al * u1v + be * u2v + g * vw - (al + be * c) * u1v;
            ir = 1.0 / sqrt(y * y + cc * cc);
            sc[br][0][0] = y * ir;
            sc[br][0][1] = cc * ir;
            Y = y * rsc[0][1] - cc * rsc[0][0];
            X = cc * rsc[0][1] + y * rsc[0][0];
            th[br][0] = ref[i1] + small_atan2(Y, X) / DEG;
            if (i3 >= 0) {
                /* R3 = (R1 R2)^T Mt: turn b by R3 and compare with (R1 R2)^T Mt b */
                double t[3];
                turn(u1, -sc[br][0][0], sc[br][0][1], mb, t);
                turn(u2, -sc[br][1][0], sc[br][1][1], t, w);
                th[br][2] = near_turn(turn_angle(m->dir[i3], P->b3, w, &sc[br][2][0], &sc[br][2][1]), ref[i3]);
            }
            for (j = 0, sum = 0.0, mx = 0.0; j < P->nrot; j++) {
                double d = fabs(th[br][j] - ref[P->rot_idx[j]]);
                sum += d;
                mx = d > mx ? d : mx;
            }
            if (mx <= CLOSED_MAX_TURN && sum < best) { best = sum; pick = br; }
        }
    }
    if (pick < 0) return 0;
    memcpy(out, q0, P->n * sizeof(double));
    for (k = 0; k < P->nrot; k++) {
        out[P->rot_idx[k]] = th[pick][k];
        osc[k][0] = sc[pick][k][0];
        osc[k][1] = sc[pick][k][1];
    }
    {
        const double (*s)[2] = (const double (*)[2])sc[pick];
        double pn[3], rhs[3], x[3];
        int i, nc = 0, lin[3];
        for (i = 0; i < P->n; i++)
            if (!m->rotary[i]) lin[nc++] = i;
        mat_vec(P->Rw, pt, rhs);
        for (k = 0; k < 3; k++) rhs[k] += P->tw[k];
        if (P->lin_order == 2) {
            /* the rotary axes first: undo them, x <- c + R^T (x - c) from the workpiece end, and
             * tp + D q_lin is what remains */
            for (k = 0; k < P->nrot; k++) {
                const double *cc = P->c[P->rot_idx[k]];
                double d[3] = {rhs[0] - cc[0], rhs[1] - cc[1], rhs[2] - cc[2]};
                turn(m->dir[P->rot_idx[k]], -s[k][0], s[k][1], d, d);
                for (i = 0; i < 3; i++) rhs[i] = cc[i] + d[i];
            }
            for (i = 0; i < 3; i++) rhs[i] -= P->tp[i];
            mat_vec(P->Dinv, rhs, x);
            for (k = 0; k < 3; k++) out[lin[k]] = x[k];
            return in_ranges(P, out);
        }
        rigid_position(P, out, s, P->tp, pn);
        for (k = 0; k < 3; k++) rhs[k] -= pn[k];
        if (P->lin_order == 1) {
            mat_vec(P->Dinv, rhs, x);
        } else {
            double A[3][3];
            for (k = 0; k < 3; k++) {
                double col[3];
                memcpy(col, m->dir[lin[k]], sizeof col);
                rigid_turn(P, s, lin[k], col);
                A[0][k] = col[0]; A[1][k] = col[1]; A[2][k] = col[2];
            }
            if (!solve3_cramer(A, rhs, x)) return 0;
        }
        for (k = 0; k < 3; k++) out[lin[k]] += x[k];
    }
    return in_ranges(P, out);
}

/* The orientation inputs of closed_rot_core from a target pose (p, R, v in the workpiece frame):
 * v = Rw R_t a and, with three rotary axes, mb = Rw R_t b. */
static void closed_target(const prep_t *P, const target_t *tg, double v[3], double mb[3])
{
    if (P->nrot == 3) {
        double Mt[9];
        mat_mul(P->Rw, tg->R, Mt);
        mat_vec(Mt, P->m->dir[P->rot_idx[2]], v);
        mat_vec(Mt, P->b3, mb);
    } else {
        mat_vec(P->Rw, tg->v, v);
    }
}

/* The same inputs for the ideal pose of q (retarget), composed on vectors from the sines and
 * cosines of q's rotary angles: p_t the nominal position with the nominal tool point. */
static inline void closed_ideal_target(const prep_t *P, const double *q, const double (*sc)[2], double pt[3],
                                       double v[3], double mb[3])
{
    double x[3];
    rigid_position(P, q, sc, P->m->tool_point, pt);
    memcpy(x, P->nrot == 3 ? P->m->dir[P->rot_idx[2]] : P->m->tool_axis, sizeof x);
    rigid_turn(P, sc, P->n, x);
    mat_vec(P->Rw, x, v);
    if (P->nrot == 3) {
        memcpy(x, P->b3, sizeof x);
        rigid_turn(P, sc, P->n, x);
        mat_vec(P->Rw, x, mb);
    }
}

/* closed_rot_core for a target pose, the ref angles given as commands (deg). */
static int closed_rotation(const prep_t *P, const target_t *tg, const double *q0, const double *ref, double pole_sin,
                           double *out)
{
    double v[3], mb[3] = {0, 0, 0}, rsc[3][2], osc[3][2];
    int r;
    closed_target(P, tg, v, mb);
    for (r = 0; r < P->nrot; r++) {
        rsc[r][0] = sin(ref[P->rot_idx[r]] * DEG);
        rsc[r][1] = cos(ref[P->rot_idx[r]] * DEG);
    }
    return closed_rot_core(P, tg->p, v, mb, q0, ref, (const double (*)[2])rsc, pole_sin, out, osc);
}

static int limits(const mtk_model *m, const double *q)
{
    int i;
    for (i = 0; i < m->n_axes; i++)
        if (q[i] < m->lo[i] - m->slack[i] || q[i] > m->hi[i] + m->slack[i]) return i;
    return -1;
}

static void rigid_errors(const mtk_errors *e, mtk_errors *rigid)
{
    mtk_errors_zero(rigid);
    memcpy(rigid->tool, e->tool, sizeof rigid->tool);
    memcpy(rigid->wp_t, e->wp_t, sizeof rigid->wp_t);
    memcpy(rigid->wp_a, e->wp_a, sizeof rigid->wp_a);
    rigid->use_tables = 0;
}

static void make_target(const prep_t *Pi, const double *q, target_t *tg)
{
    if (Pi->mode != 3) {
        /* up to two rotary axes: the residual and the closed forms take the position and the
         * tool direction alone (fwd_pv on vectors); R is not read */
        fwd_pv(Pi, q, tg->p, tg->v);
        eye(tg->R);
        return;
    }
    {
        /* the tool frame's columns R e0, R e1 on vectors (fwd_dirs: the sines and cosines along a
         * path by the angle sum), the third their cross product */
        double X[2][3] = {{1, 0, 0}, {0, 1, 0}}, X2[3];
        int k;
        fwd_dirs(Pi, q, tg->p, X, 2);
        cross(X[0], X[1], X2);
        for (k = 0; k < 3; k++) {
            tg->R[3 * k] = X[0][k];
            tg->R[3 * k + 1] = X[1][k];
            tg->R[3 * k + 2] = X2[k];
        }
    }
    mat_vec(tg->R, Pi->m->tool_axis, tg->v);
}

/* mtk_retarget's state per model: the prepared error set and the path's last correction. */
typedef struct {
    int valid;
    mtk_errors e;
    mtk_table *tables[MTK_MAX_AXES];
    prep_t P, Pr, Pi;
    int have_prev, warm;
    double corr[MTK_MAX_AXES];
    double pole_sin;                  /* sin(MTK_POLE_TOL) */
    int zero;                         /* the error set is zero: q = q_prog */
} retarget_cache;

static int same_errors(const mtk_errors *a, const mtk_errors *b)
{
    return !memcmp(a->tool, b->tool, sizeof a->tool) && !memcmp(a->wp_t, b->wp_t, sizeof a->wp_t) &&
           !memcmp(a->wp_a, b->wp_a, sizeof a->wp_a) && !memcmp(a->loc, b->loc, sizeof a->loc) &&
           a->use_tables == b->use_tables;
}

int mtk_retarget(const mtk_model *m, const mtk_errors *e, const double *q_prog, double *q,
                 double tol, int max_iter, int *iters, double *residual_out, char *err)
{
    int n = m->n_axes, i, k, it = 0, rc, bad = -1, held, singular = 0;
    double res = 0.0, res0 = 0.0;
    char msg[MTK_ERRLEN];
    retarget_cache local, *c = (retarget_cache *)m->cache;
    if (iters) *iters = 0;
    if (residual_out) *residual_out = 0.0;
    for (i = 0; i < n; i++) {
        if (!isfinite(q_prog[i])) {
            snprintf(msg, sizeof msg, "axis %c command is not a finite number", m->axis_name[i]);
            seterr(err, msg);
            return MTK_E_ARG;
        }
    }
    if (!e) {
        memcpy(q, q_prog, n * sizeof(double));
        goto limits;
    }
    if (!c) {
        c = (retarget_cache *)calloc(1, sizeof *c);
        ((mtk_model *)m)->cache = c;       /* the model's own scratch state */
        if (!c) {
            memset(&local, 0, sizeof local);
            c = &local;
        }
    }
    if (!c->valid || !same_errors(&c->e, e) || memcmp(c->tables, m->table, sizeof c->tables)) {
        mtk_errors rigid;
        c->e = *e;
        memcpy(c->tables, m->table, sizeof c->tables);
        prepare(m, e, 1, &c->P);
        rigid_errors(e, &rigid);
        prepare(m, &rigid, 0, &c->Pr);
        prepare(m, NULL, 0, &c->Pi);
        c->have_prev = 0;
        c->pole_sin = sin(MTK_POLE_TOL * DEG);
        c->zero = errors_zero(m, e);
        c->valid = 1;
    }
    if (c->zero) {   /* (checked once per error set, not per call) */
        memcpy(q, q_prog, n * sizeof(double));
        goto limits;
    }
    if (!(c->P.closed && closed_form(&c->P, q_prog, q))) {
        target_t tg;
        opt_t o;
        double start[MTK_MAX_AXES];
        int how = HOW_SEED;
        make_target(&c->Pi, q_prog, &tg);
        o.tol = tol;
        o.max_iter = max_iter;
        o.pole_tol = MTK_POLE_TOL;
        o.pole_sin = c->pole_sin;
        memcpy(start, q_prog, n * sizeof(double));
        if (c->have_prev)
            for (k = 0; k < n; k++) start[k] += c->corr[k];
        if (c->P.closed_rot &&
            closed_rotation(&c->P, &tg, q_prog, c->have_prev && c->warm ? start : q_prog, o.pole_sin, q)) {
            for (k = 0; k < n; k++) c->corr[k] = q[k] - q_prog[k];
            c->have_prev = 1;
            c->warm = 1;
            goto limits;
        }
        rc = solve_pose(&c->P, &c->Pr, &tg, q_prog, start, c->have_prev && c->warm, !(c->have_prev && c->warm), &o, q,
                        &it, &res, &res0,
                        &singular, &bad, &held, &how, NULL);
        if (iters) *iters = it;
        if (residual_out) *residual_out = rc == MTK_E_CONVERGE ? res0 : res;
        c->have_prev = rc == MTK_OK;
        if (rc == MTK_OK) {
            for (k = 0; k < n; k++) c->corr[k] = q[k] - q_prog[k];
            c->warm = how != HOW_SEED;
        }
        if (rc == MTK_E_RANGE) {
            range_message(m, bad, q[bad], err);
            return rc;
        }
        if (rc == MTK_E_CONVERGE) {
            if (singular && res0 == INFINITY)
                snprintf(msg, sizeof msg, "compensation did not converge: singular Jacobian (kinematic "
                         "singularity)");
            else
                snprintf(msg, sizeof msg, "compensation did not converge (residual %.3g); the target may "
                         "be unreachable or at a kinematic singularity", res0);
            seterr(err, msg);
            return rc;
        }
        if (rc) return rc;
    }
limits:
    i = limits(m, q);
    if (i >= 0) {
        snprintf(msg, sizeof msg, "axis %c would have to move to %.6f, outside its travel [%g, %g]",
                 m->axis_name[i], q[i], m->lo[i], m->hi[i]);
        seterr(err, msg);
        return MTK_E_LIMIT;
    }
    return MTK_OK;
}

/* ---------------------------------------------------------------- batches (the library's entry) */

mtk_model *mtk_model_new(int n_axes, const char *axis_names, const int *rotary, const int *tool_side,
                         const double *dir, const double *loc, const double *lo, const double *hi,
                         const double *slack, const double *tool_point, const double *tool_axis)
{
    mtk_model *m;
    int i;
    if (n_axes < 1 || n_axes > MTK_MAX_AXES) return NULL;
    m = (mtk_model *)calloc(1, sizeof *m);
    if (!m) return NULL;
    m->n_axes = n_axes;
    for (i = 0; i < n_axes; i++) {
        m->axis_name[i] = axis_names[i];
        m->rotary[i] = rotary[i];
        m->tool_side[i] = tool_side[i];
        memcpy(m->dir[i], dir + 3 * i, 3 * sizeof(double));
        memcpy(m->loc[i], loc + 3 * i, 3 * sizeof(double));
        m->lo[i] = lo[i];
        m->hi[i] = hi[i];
        m->slack[i] = slack[i];
    }
    memcpy(m->tool_point, tool_point, 3 * sizeof(double));
    memcpy(m->tool_axis, tool_axis, 3 * sizeof(double));
    return m;
}

int mtk_model_set_table(mtk_model *m, int axis, int n, const double *pos, const double *val)
{
    mtk_table *t;
    if (axis < 0 || axis >= m->n_axes || n < 2) return MTK_E_ARG;
    t = (mtk_table *)calloc(1, sizeof *t);
    if (!t) return MTK_E_IO;
    t->pos = (double *)malloc(n * sizeof(double));
    t->val = (double *)malloc(6 * n * sizeof(double));
    if (!t->pos || !t->val) {
        free(t->pos); free(t->val); free(t);
        return MTK_E_IO;
    }
    memcpy(t->pos, pos, n * sizeof(double));
    memcpy(t->val, val, 6 * n * sizeof(double));
    t->n = n;
    if (table_finish(t) != MTK_OK) {
        table_free(t);
        return MTK_E_IO;
    }
    if (m->table[axis]) {
        table_free(m->table[axis]);
    }
    m->table[axis] = t;
    return MTK_OK;
}

long mtk_forward_batch(const mtk_model *m, const mtk_errors *e, long n, const double *q, double *p, double *R,
                       int strict, int *bad_axis)
{
    prep_t P;
    long i;
    int nax = m->n_axes;
    double Rl[9];
    prepare(m, e, 1, &P);
    for (i = 0; i < n; i++) {
        if (fwd(&P, q + i * nax, p + 3 * i, R ? R + 9 * i : Rl, strict, bad_axis, 0) != MTK_OK) return i;
    }
    return -1;
}

/* The commands q within 1 deg and 1 mm of the previous pose's qp on every axis (a path: the
 * previous correction is the better start). */
static int near_previous(const prep_t *P, const double *q, const double *qp)
{
    int k;
    for (k = 0; k < P->n; k++)
        if (!(fabs(q[k] - qp[k]) <= 1.0)) return 0;
    return 1;
}

/* Weights of the previous poses' corrections (c1 the last) in the start of the pose qa along a
 * path: the correction changes smoothly with the program, and extrapolated from the poses before
 * (a parabola through three, a line through two, in the distance along the path) the start is
 * within the third (second) power of the step of the solution inside a table interval, rather
 * than the first: the Newton step from it is then small enough to be taken without an
 * evaluation.  Three poses where the last two segments are about as long as this one and point
 * about the same way, else two where this segment's projection on the last is within twice its
 * length, else the last correction alone (w1 = 1). */
static void path_weights(const double *qa, int nax, int three, double *w1, double *w2, double *w3)
{
    const double *q1 = qa - nax, *q2 = qa - 2 * nax;
    double dd = 0.0, d11 = 0.0, d1 = 0.0, d00 = 0.0, d10 = 0.0;
    int k;
    for (k = 0; k < nax; k++) {
        double a = qa[k] - q1[k], b = q1[k] - q2[k];
        dd += a * a;
        d1 += a * b;
        d11 += b * b;
        if (three) {
            double c = q2[k] - q2[k - nax];
            d00 += c * c;
            d10 += b * c;
        }
    }
    *w1 = 1.0; *w2 = *w3 = 0.0;
    if (!(d11 > 0.0) || !(d1 > 0.0) || d1 > 2.0 * d11) return;
    if (three && d00 > 0.0 && d1 * d1 >= 0.98 * dd * d11 && d10 * d10 >= 0.98 * d11 * d00 && d10 > 0.0 &&
        dd <= 4.0 * d11 && d11 <= 4.0 * dd && d00 <= 4.0 * d11 && d11 <= 4.0 * d00) {
        /* Lagrange through the corrections at distances -h1 - h0, -h1, 0, taken at h */
        double h = sqrt(dd), h1 = sqrt(d11), h0 = sqrt(d00);
        *w1 = (h + h1) * (h + h1 + h0) / (h1 * (h1 + h0));
        *w2 = -h * (h + h1 + h0) / (h1 * h0);
        *w3 = h * (h + h1) / ((h1 + h0) * h0);
        return;
    }
    {
        double x = d1 / d11;
        *w1 = 1.0 + x;
        *w2 = -x;
    }
}

/* The Jacobian J (at q, weight ORIENTATION_SCALE) of a pose solved afresh, prepared for the poses
 * after it along the path: the matrix K (n x rows) of its chord step s = K r = (J^T J + lambda
 * I)^-1 J^T r (the normal equations' factors applied to the unit residuals once, rather than to
 * each pose's residual), column lengths and table intervals at q (second_order_bound's): J is the
 * same for every pose taken on it.  0 where the normal matrix is singular. */
static int path_linearisation(const prep_t *P, const double *q, const double *J, double *K, double *pn, int *ilin)
{
    double LU[MTK_MAX_AXES * MTK_MAX_AXES];
    int n = P->n, rows = P->rows, i, k, ok, piv[MTK_MAX_AXES];
    if (n == 5 && rows == 6) ok = normal_factor(5, 6, J, LU, piv);
    else if (n == 3 && rows == 3) ok = normal_factor(3, 3, J, LU, piv);
    else if (n == 6 && rows == 6) ok = normal_factor(6, 6, J, LU, piv);
    else ok = normal_factor(n, rows, J, LU, piv);
    if (!ok) return 0;
    for (k = 0; k < rows; k++) {
        double e[6] = {0, 0, 0, 0, 0, 0}, x[MTK_MAX_AXES];
        e[k] = 1.0;
        chord_step(n, rows, J, LU, piv, e, x);
        for (i = 0; i < n; i++) K[i * rows + k] = x[i];
    }
    column_lengths(P, J, pn);
    for (i = 0; i < n; i++) {
        const mtk_table *t = P->tab[i];
        ilin[i] = t && q[i] > t->pos[0] && q[i] < t->pos[t->n - 1] ? table_interval(t, q[i], (int *)&P->hint[i]) : -1;
    }
    return 1;
}

/* y = A x for A (n x rows, row-major). */
MTK_INLINE void mat_apply(int n, int rows, const double *A, const double *x, double *y)
{
    int i, k;
    for (i = 0; i < n; i++) {
        double s = 0.0;
        for (k = 0; k < rows; k++) s += A[i * rows + k] * x[k];
        y[i] = s;
    }
}

/* r - J s in r (J: rows x n, row-major), the residual the linear model predicts after the step s. */
MTK_INLINE void linear_prediction(int n, int rows, const double *J, const double *s, double *r)
{
    int i, k;
    for (k = 0; k < rows; k++) {
        double sk = r[k];
        for (i = 0; i < n; i++) sk -= J[k * n + i] * s[i];
        r[k] = sk;
    }
}

/* One pose along a path solved on the Jacobian J of an earlier pose (taken at qlin against the
 * target frame Tlin; no axis held): the residual at start evaluated, the chord step on J's
 * factors, and the step taken where the model's departure from the linear prediction over it is
 * bounded within LINEAR_BOUND (the same test as the chord steps of iterate) and the predicted
 * residual is converged.  Returns 1 with the commands in q and the residual in *res, else 0
 * (solve_pose then solves the pose; nothing is changed).
 *
 * The bound.  With r the residual against this pose's target T and J_T(x) its Jacobian,
 *     r(q - s) - (r(q) - J s) = [r(q - s) - r(q) + J_T(qlin) s] + (J - J_T(qlin)) s.
 * The first term is second_order_bound's (the second derivatives it bounds do not depend on the
 * target: those of the position rows are the chain's, those of the orientation rows of mode 3
 * are, with d2R/dq_i dq_j = [W_i]x [W_j]x R (i <= j), wo f(T^T Rw^T [W_i]x [W_j]x R) with
 * f(A) = vee(A - A^T) / 2, |f(A)| <= |A|_F / sqrt 2 and |[a]x [b]x|_F <= sqrt 2 |a| |b|: at most
 * wo w_i w_j for every T).  The second is zero on machines with up to two rotary axes (the
 * position and tool-direction rows do not depend on the target).  With three (mode 3) the
 * orientation column j of J_T(qlin) is wo f(T^T Rw^T [W_j]x R) at qlin, so J differs from it by
 * wo f((Tlin - T)^T Rw^T [W_j]x R) in the orientation rows only, of length at most
 * wo |Tlin - T|_F |W_j| / sqrt 2 (Rw, R rotations), and |W_j| <= 2 w_j (wmax; the factor 2 for
 * the tables' rotation-vector rates, as in second_order_bound):
 *     |(J - J_T(qlin)) s| <= sqrt 2 wo |Tlin - T|_F sum_j w_j |s_j|,
 * about wo th w |s| for targets th (rad) apart: along a path (th under a degree, |s| about 1e-10
 * mm or deg from the extrapolated start) orders of magnitude below LINEAR_BOUND.
 *
 * Not where the pole rule might hold an axis (pole_clear on the pose's own target): such a pose
 * is solved afresh by solve_pose, which decides. */
static int path_step(const prep_t *P, const target_t *tg, const double *start, const opt_t *o, const double *J,
                     const double *K, const double *pn, const int *ilin, const double *qlin,
                     const double *Tlin, double *q, double *res)
{
    int n = P->n, rows = P->rows, i, k;
    double r[6], s[MTK_MAX_AXES], qn[MTK_MAX_AXES], frame = 0.0;
    if (o->pole_tol > 0.0 && P->mode >= 2 && !pole_clear(P, tg, o->pole_sin)) return 0;
    if (residual(P, start, tg, r, ORIENTATION_SCALE, 0, NULL) != MTK_OK) return 0;
    /* the chord step K r (the usual shapes with constant sizes: unrolled by the compiler) */
    if (n == 6 && rows == 6) mat_apply(6, 6, K, r, s);
    else if (n == 5 && rows == 6) mat_apply(5, 6, K, r, s);
    else if (n == 3 && rows == 3) mat_apply(3, 3, K, r, s);
    else mat_apply(n, rows, K, r, s);
    for (i = 0; i < n; i++)
        if (fabs(s[i]) >= o->tol) break;
    if (i == n) {
        /* a step below the tolerance is convergence, as in iterate: start kept to the bit */
        if (!in_ranges(P, start) || !(maxabs(r, rows) < CONVERGED)) return 0;
        memcpy(q, start, n * sizeof(double));
        *res = maxabs(r, rows);
        return 1;
    }
    if (P->mode == 3) {
        double dT = 0.0, ws = 0.0;
        for (k = 0; k < 9; k++) dT += (tg->R[k] - Tlin[k]) * (tg->R[k] - Tlin[k]);
        for (i = 0; i < n; i++) ws += P->wmax[i] * fabs(s[i]);
        frame = sqrt(2.0 * dT) * ORIENTATION_SCALE * ws;
    }
    if (!(second_order_bound(P, pn, ilin, qlin, start, s, ORIENTATION_SCALE) + frame <= LINEAR_BOUND)) return 0;
    for (i = 0; i < n; i++) qn[i] = start[i] - s[i];
    if (n == 6 && rows == 6) linear_prediction(6, 6, J, s, r);
    else if (n == 5 && rows == 6) linear_prediction(5, 6, J, s, r);
    else if (n == 3 && rows == 3) linear_prediction(3, 3, J, s, r);
    else linear_prediction(n, rows, J, s, r);
    if (!in_ranges(P, qn) || !(maxabs(r, rows) < CONVERGED)) return 0;
    memcpy(q, qn, n * sizeof(double));
    *res = maxabs(r, rows);
    STAT(3);
    return 1;
}

/* Shared loop of the two batch entries: targets either given (p_t, R_t) or the ideal poses of q0. */
static long batch(const mtk_model *m, const mtk_errors *e, long n, const double *p_t, const double *R_t,
                  const double *q0, double *q, const mtk_options *o, double *res, int *status, int *info)
{
    prep_t P, Pr, Pi;
    mtk_errors rigid, zero;
    opt_t so;
    long i, failed = 0;
    int nax = m->n_axes, k, have_prev = 0, warm = 0, chain = 0, held_prev = -1, have_lin = 0, fresh = 0, lin_try, lin_miss = 0,
        lin_wait = 0, lin_ready = 0;
    double corr[MTK_MAX_AXES] = {0}, corr2[MTK_MAX_AXES] = {0}, corr3[MTK_MAX_AXES] = {0};
    /* the path's linearisation (path_linearisation): the Jacobian at the start of the last pose
     * solved afresh, its factors, column lengths and table intervals, where it was taken, and
     * against which target frame (path_step) */
    double Jl[6 * MTK_MAX_AXES], Kl[6 * MTK_MAX_AXES], pnl[MTK_MAX_AXES], qlin[MTK_MAX_AXES];
    double Tl[9] = {0};
    int ilinl[MTK_MAX_AXES];
    if (!e) {
        mtk_errors_zero(&zero);
        e = &zero;
    }
    prepare(m, e, 1, &P);
    rigid_errors(e, &rigid);
    prepare(m, &rigid, 0, &Pr);
    prepare(m, NULL, 0, &Pi);
    so.tol = o->tol;
    so.max_iter = o->max_iter;
    so.pole_tol = o->pole_tol;
    so.pole_sin = sin(o->pole_tol * DEG);
    long skip = o->run_in > 0 ? (o->run_in < n ? o->run_in : n) : 0;
    double q_in[MTK_MAX_AXES], res_in;
    /* closed_rot along a retarget batch: the sines and cosines of the previous correction's
     * rotary angles (csc_ok: they belong to corr), so that those of the start follow by the
     * angle sum from the pose's own */
    double csc[3][2];
    int csc_ok = 0, fast_rot = !p_t && P.closed_rot;
    /* retarget with tables or location errors: the iteration seeded by the rigid closed form */
    int seed_rigid = !p_t && P.geo && (Pr.closed_rot || Pr.closed), seeded, have_geo = 0;
    double qr[MTK_MAX_AXES], dgeo[MTK_MAX_AXES];
    int status_in, info_in;
    for (i = 0; i < n; i++) {
        const double *qa = q0 + i * nax;
        double *qo, start[MTK_MAX_AXES], r0 = 0.0, *resi;
        int *statusi, *infoi;
        target_t tg;
        int it = 0, bad = -1, held = -1, sing = 0, rc, how = HOW_SEED, near;
        STAT(5);
        if (i < skip) {
            if (!o->continuation || (!p_t && P.closed)) continue;   /* nothing to take up */
            qo = q_in; resi = &res_in; statusi = &status_in; infoi = &info_in;
        } else {
            qo = q + (i - skip) * nax; resi = res + (i - skip); statusi = status + (i - skip);
            infoi = info + (i - skip);
        }
        *statusi = MTK_OK;
        *infoi = -1;
        *resi = 0.0;
        if (!p_t && P.closed) {
            if (closed_form(&P, qa, qo)) continue;
        }
        if (fast_rot) {
            /* the ideal target composed on vectors, one sine and cosine per rotary angle */
            double scq[3][2], scs[3][2], osc[3][2], pt[3], v[3], mb[3] = {0, 0, 0};
            int r, cont = o->continuation && have_prev;
            for (r = 0; r < P.nrot; r++) {
                double a = qa[P.rot_idx[r]] * DEG;
                scq[r][0] = sin(a);
                scq[r][1] = cos(a);
            }
            if (cont && !csc_ok) {
                for (r = 0; r < P.nrot; r++) {
                    csc[r][0] = sin(corr[P.rot_idx[r]] * DEG);
                    csc[r][1] = cos(corr[P.rot_idx[r]] * DEG);
                }
                csc_ok = 1;
            }
            for (r = 0; r < P.nrot; r++) {
                if (cont) {
                    scs[r][0] = scq[r][0] * csc[r][1] + scq[r][1] * csc[r][0];
                    scs[r][1] = scq[r][1] * csc[r][1] - scq[r][0] * csc[r][0];
                } else {
                    scs[r][0] = scq[r][0];
                    scs[r][1] = scq[r][1];
                }
                start[P.rot_idx[r]] = qa[P.rot_idx[r]] + (cont ? corr[P.rot_idx[r]] : 0.0);
            }
            closed_ideal_target(&P, qa, (const double (*)[2])scq, pt, v, mb);
            if (closed_rot_core(&P, pt, v, mb, qa, cont && warm ? start : qa,
                                (const double (*)[2])(cont && warm ? scs : scq), so.pole_sin, qo, osc)) {
                for (k = 0; k < nax; k++) corr[k] = qo[k] - qa[k];
                for (r = 0; r < P.nrot; r++) {   /* sin and cos of (th - qa) */
                    csc[r][0] = osc[r][0] * scq[r][1] - osc[r][1] * scq[r][0];
                    csc[r][1] = osc[r][1] * scq[r][1] + osc[r][0] * scq[r][0];
                }
                csc_ok = 1;
                have_prev = 1;
                chain = 1;
                have_lin = 0;
                warm = 1;
                continue;
            }
            make_target(&Pi, qa, &tg);
        } else if (p_t) {
            memcpy(tg.p, p_t + 3 * i, sizeof tg.p);
            memcpy(tg.R, R_t + 9 * i, sizeof tg.R);
            mat_vec(tg.R, m->tool_axis, tg.v);
        } else {
            make_target(&Pi, qa, &tg);
        }
        memcpy(start, qa, nax * sizeof(double));
        near = i > 0 && near_previous(&P, qa, qa - nax);
        if (o->continuation && have_prev) {
            double w1 = 1.0, w2 = 0.0, w3 = 0.0;
            if (chain >= 2 && i > 1 && near)
                path_weights(qa, nax, chain >= 3 && i > 2, &w1, &w2, &w3);
            /* on the differences of the corrections: where they do not change (an axis the
             * errors leave alone, a rotary axis held over a pass) the start is the last one's
             * to the bit */
            for (k = 0; k < nax; k++)
                start[k] += corr[k] - (w2 != 0.0 ? (w2 + w3) * (corr[k] - corr2[k]) : 0.0) -
                            (w3 != 0.0 ? w3 * (corr2[k] - corr3[k]) : 0.0);
        }
        if (P.closed_rot && !fast_rot &&
            closed_rotation(&P, &tg, qa, o->continuation && have_prev && warm ? start : qa, so.pole_sin, qo)) {
            for (k = 0; k < nax; k++) corr[k] = qo[k] - qa[k];
            have_prev = 1;
            chain = 1;
            have_lin = 0;
            warm = 1;
            continue;
        }
        seeded = 0;
        if (seed_rigid && !(o->continuation && have_prev && warm && near) &&
            (Pr.closed_rot ? closed_rotation(&Pr, &tg, qa, qa, so.pole_sin, qr) : closed_form(&Pr, qa, qr))) {
            /* with tables or location errors: start from the rigid model's closed-form solution
             * plus the previous pose's correction beyond it (the tables' part, µm and µrad) */
            for (k = 0; k < nax; k++) start[k] = qr[k] + (o->continuation && have_prev && have_geo ? dgeo[k] : 0.0);
            seeded = 1;
        }
        lin_try = !seeded && have_lin && o->continuation && have_prev && warm && held_prev < 0 && i > 0 &&
                  lin_wait == 0 && near;
        if (lin_wait > 0) lin_wait--;
        if (lin_try && !lin_ready) {   /* (factored when first needed: not for random poses) */
            lin_ready = path_linearisation(&P, qlin, Jl, Kl, pnl, ilinl);
            have_lin = lin_try = lin_ready;
        }
        if (lin_try && path_step(&P, &tg, start, &so, Jl, Kl, pnl, ilinl, qlin, Tl, qo, resi)) {
            /* (the previous poses' Jacobian: no pass, no factorisation, one evaluation) */
            rc = MTK_OK;
            held = -1;
            how = HOW_WARM;
            fresh = 0;
            lin_miss = 0;
        } else {
            if (lin_try) {
                /* a path too coarse or too curved for it (the evaluation is lost): tried again
                 * on the next pose, then after 1, 3, 7, 15 poses while it fails */
                lin_miss = lin_miss < 5 ? lin_miss + 1 : 5;
                lin_wait = (1 << (lin_miss - 1)) - 1;
            }
            rc = solve_pose(&P, &Pr, &tg, qa, start, seeded || (have_prev && warm), seeded || !(have_prev && warm),
                            &so, qo, &it, resi, &r0, &sing, &bad, &held, &how, Jl);
            fresh = 1;
        }
        csc_ok = 0;
        have_geo = 0;
        if (rc == MTK_OK && seeded) {
            for (k = 0; k < nax; k++) dgeo[k] = qo[k] - qr[k];
            have_geo = 1;
        }
        if (rc == MTK_OK) {
            *infoi = held;
            /* the corrections of the poses before kept for the extrapolation while each followed
             * the one before on the same branch without a held axis (one smooth branch) */
            chain = have_prev && warm && how != HOW_SEED && held < 0 && held_prev < 0 && near ?
                    (chain < 3 ? chain + 1 : 3) : 1;
            for (k = 0; k < nax; k++) {
                corr3[k] = corr2[k];
                corr2[k] = corr[k];
                corr[k] = qo[k] - qa[k];
            }
            if (fresh) {   /* the Jacobian at this pose's start (in Jl), for the poses after it */
                have_lin = how != HOW_SEED && held < 0 && o->continuation;
                lin_ready = 0;
                memcpy(qlin, start, nax * sizeof(double));
                if (P.mode == 3) memcpy(Tl, tg.R, sizeof Tl);
            }
            held_prev = held;
            have_prev = 1;
            warm = how != HOW_SEED;
        } else {
            *statusi = rc;
            *infoi = bad;
            if (rc == MTK_E_CONVERGE) *resi = r0;
            have_prev = chain = have_lin = 0;
            failed += i >= skip;
        }
    }
    return failed;
}

long mtk_retarget_batch(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, double *q,
                        const mtk_options *o, double *res, int *status, int *info)
{
    return batch(m, e, n, NULL, NULL, q_prog, q, o, res, status, info);
}

long mtk_compensate_batch(const mtk_model *m, const mtk_errors *e, long n, const double *p_t, const double *R_t,
                          const double *q0, double *q, const mtk_options *o, double *res, int *status, int *info)
{
    return batch(m, e, n, p_t, R_t, q0, q, o, res, status, info);
}

/* Two points x[0], x[1] (mm, in the last tool-side frame) through the rigid chain at q (fwd_dirs'
 * nominal motions without error motions, in place): on a prepared model without tables or location
 * errors the ideal tool point and the real one (with the tool setting offset) share the chain. */
static void chain_two(const prep_t *P, const double *q, double (*x)[3])
{
    int i;
    for (i = P->n - 1; i >= 0; i--) axis_motion(P, i, q, x, 2, NULL, 0, 0);
}

/* The tool edge's distance (mm) from the ideal machine's at q_prog: at q_prog itself and at q_emit,
 * both on the real machine (errors e).  The three positions of a pose on vectors (fwd_pv), the
 * rotary sines and cosines of q_emit by the angle sum from those of q_prog (axis_sincos: the
 * compensation moves a rotary axis by micro-degrees).  strict: a command outside an axis' table
 * returns the pose (the axis in *bad_axis), as mtk_forward_batch does; -1 when all are done. */
long mtk_check_batch(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, const double *q_emit,
                     double *before, double *after, int strict, int *bad_axis)
{
    prep_t P, Pi;
    long i;
    int nax = m->n_axes, k, tabs = 0;
    prepare(m, e, 1, &P);
    prepare(m, NULL, 0, &Pi);
    for (k = 0; k < nax; k++) tabs |= P.tab[k] != NULL;
    for (i = 0; i < n; i++) {
        const double *qp = q_prog + i * nax, *qe = q_emit + i * nax;
        double pt[3], pr[3], pe[3], v[3], db = 0.0, da = 0.0;
        if (strict && tabs) {
            for (k = 0; k < nax; k++) {
                const mtk_table *t = P.tab[k];
                if (t && (!(qp[k] >= t->pos[0] - 1e-12 && qp[k] <= t->pos[t->n - 1] + 1e-12) ||
                          !(qe[k] >= t->pos[0] - 1e-12 && qe[k] <= t->pos[t->n - 1] + 1e-12))) {
                    if (bad_axis) *bad_axis = k;
                    return i;
                }
            }
        }
        if (!P.geo) {
            /* setting errors alone: one chain for the ideal and the real tool point at q_prog */
            double x[2][3];
            memcpy(x[0], m->tool_point, sizeof x[0]);
            memcpy(x[1], P.tp, sizeof x[1]);
            chain_two(&P, qp, x);
            memcpy(pt, x[0], sizeof pt);
            if (P.wp) {
                for (k = 0; k < 3; k++) x[1][k] -= P.tw[k];
                mat_vec(P.RwT, x[1], pr);
            } else {
                memcpy(pr, x[1], sizeof pr);
            }
        } else {
            fwd_pv(&Pi, qp, pt, v);
            /* the real machine's rotary angles differ from the ideal's by its zero errors alone */
            memcpy(P.sc_ref, Pi.sc_ref, sizeof P.sc_ref);
            fwd_pv(&P, qp, pr, v);
        }
        fwd_pv(&P, qe, pe, v);
        for (k = 0; k < 3; k++) {
            double b = pr[k] - pt[k], a = pe[k] - pt[k];
            db += b * b;
            da += a * a;
        }
        before[i] = sqrt(db);
        after[i] = sqrt(da);
    }
    return -1;
}
