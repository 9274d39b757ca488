/* mtk: the mtcomp kinematic kernel in C (see mtk.h and docs/model.md, docs/fmu.md).
 *
 * Written by hand because it must run inside an FMU without Python: it is a line-by-line port
 * of mtcomp.kinematics (forward, compensate, retarget) and of the error-table CSV reader of
 * mtcomp.errors, and the test suite checks it against them on random poses.
 */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mtk.h"

#define ORIENTATION_SCALE 100.0  /* mm per rad, as mtcomp.kinematics.ORIENTATION_SCALE */
#define FD_STEP 1e-6             /* forward-difference step of the chord Jacobian, mm or deg */
#define LAMBDA 1e-12             /* pull toward the programmed commands at singularities */
#define CONVERGED 1e-7           /* largest residual accepted after the iteration, mm */
#define DEG (3.14159265358979323846 / 180.0)

static void seterr(char *err, const char *msg)
{
    if (err) snprintf(err, MTK_ERRLEN, "%s", msg);
}

/* ---------------------------------------------------------------- small 3-vector algebra */

static void mat_vec(const double A[9], const double x[3], double y[3])
{
    double t0 = A[0] * x[0] + A[1] * x[1] + A[2] * x[2];
    double t1 = A[3] * x[0] + A[4] * x[1] + A[5] * x[2];
    double t2 = A[6] * x[0] + A[7] * x[1] + A[8] * x[2];
    y[0] = t0; y[1] = t1; y[2] = t2;
}

static void mat_mul(const double A[9], const double B[9], double C[9])
{
    double T[9];
    int i, j;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++)
            T[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
    memcpy(C, T, sizeof T);
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
static void axis_rotation(const double u[3], double ang, double R[9])
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

void mtk_free(mtk_model *m)
{
    int i;
    if (!m) return;
    for (i = 0; i < MTK_MAX_AXES; i++) {
        if (m->table[i]) {
            free(m->table[i]->pos);
            free(m->table[i]->val);
            free(m->table[i]);
        }
    }
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
    if (m->table[idx]) {
        free(m->table[idx]->pos); free(m->table[idx]->val); free(m->table[idx]);
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

/* Component errors at q: d (mm), e (rad).  strict: MTK_E_RANGE outside the table (1e-12
 * tolerance); otherwise the end values are held (intermediate iterates of the compensation). */
static int table_eval(const mtk_table *t, double q, double d[3], double e[3], int strict)
{
    int lo = 0, hi = t->n - 1, k;
    double f;
    if (isnan(q)) {
        if (strict) return MTK_E_RANGE;
        for (k = 0; k < 3; k++) d[k] = e[k] = NAN;
        return MTK_OK;
    }
    if (strict && !(q >= t->pos[0] - 1e-12 && q <= t->pos[t->n - 1] + 1e-12)) return MTK_E_RANGE;
    if (q <= t->pos[0]) {
        for (k = 0; k < 3; k++) { d[k] = t->val[k]; e[k] = t->val[3 + k]; }
        return MTK_OK;
    }
    if (q >= t->pos[t->n - 1]) {
        const double *v = t->val + 6 * (t->n - 1);
        for (k = 0; k < 3; k++) { d[k] = v[k]; e[k] = v[3 + k]; }
        return MTK_OK;
    }
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (t->pos[mid] <= q) lo = mid; else hi = mid;
    }
    f = q - t->pos[lo];
    for (k = 0; k < 6; k++) {
        double v0 = t->val[6 * lo + k], v1 = t->val[6 * hi + k];
        double x = (v1 - v0) / (t->pos[hi] - t->pos[lo]) * f + v0;
        if (k < 3) d[k] = x; else e[k - 3] = x;
    }
    return MTK_OK;
}

/* ---------------------------------------------------------------- forward model */

static int forward(const mtk_model *m, const mtk_errors *e, const double *q, double p[3], double Rout[9],
                   char *err, int strict)
{
    double R[9], t[3] = {0, 0, 0}, tp[3];
    int i, k;
    eye(R);
    for (i = 0; i < m->n_axes; i++) {
        const double *u = m->dir[i], *loc = m->loc[i];
        const double *d0 = e ? e->loc[i] : NULL, *e0 = e ? e->loc[i] + 3 : NULL;
        double Rg[9], tg[3], ueff[3];
        if (m->rotary[i]) {
            double zero = 0.0, tilt[3] = {0, 0, 0}, c[3], Rc[3];
            if (e0) {
                zero = e0[0] * u[0] + e0[1] * u[1] + e0[2] * u[2];
                for (k = 0; k < 3; k++) tilt[k] = e0[k] - zero * u[k];
            }
            if (tilt[0] != 0.0 || tilt[1] != 0.0 || tilt[2] != 0.0) {
                double Rt[9];
                rotvec(tilt, Rt);
                mat_vec(Rt, u, ueff);
            } else {
                memcpy(ueff, u, sizeof ueff);
            }
            for (k = 0; k < 3; k++) c[k] = loc[k] + (d0 ? d0[k] : 0.0);
            axis_rotation(ueff, q[i] * DEG + zero, Rg);
            mat_vec(Rg, c, Rc);
            for (k = 0; k < 3; k++) tg[k] = c[k] - Rc[k];
        } else {
            /* Only the tilt (squareness) of a linear axis acts, as in the core. */
            if (e0 && (e0[0] != 0.0 || e0[1] != 0.0 || e0[2] != 0.0)) {
                double Rt[9];
                rotvec(e0, Rt);
                mat_vec(Rt, u, ueff);
            } else {
                memcpy(ueff, u, sizeof ueff);
            }
            eye(Rg);
            for (k = 0; k < 3; k++) tg[k] = q[i] * ueff[k];
        }
        if (e && e->use_tables && m->table[i]) {
            double d[3], ang[3], Re[9], Rl[3], te[3], Rte[3];
            if (table_eval(m->table[i], q[i], d, ang, strict) != MTK_OK) {
                char msg[MTK_ERRLEN];
                snprintf(msg, sizeof msg, "axis %c position %.6f is outside its error table range [%g, %g]",
                         m->axis_name[i], q[i], m->table[i]->pos[0], m->table[i]->pos[m->table[i]->n - 1]);
                seterr(err, msg);
                return MTK_E_RANGE;
            }
            rotvec(ang, Re);
            mat_vec(Re, loc, Rl);
            for (k = 0; k < 3; k++) te[k] = loc[k] + d[k] - Rl[k];
            /* The error motion belongs to the moving body of a linear axis and to the
             * non-rotating body of a rotary axis: it stands before the nominal motion for a
             * workpiece-side linear or a tool-side rotary axis (docs/model.md). */
            if (m->tool_side[i] == m->rotary[i]) {     /* (Re, te) . (Rg, tg) */
                mat_vec(Re, tg, Rte);
                for (k = 0; k < 3; k++) tg[k] = Rte[k] + te[k];
                mat_mul(Re, Rg, Rg);
            } else {                                     /* (Rg, tg) . (Re, te) */
                mat_vec(Rg, te, Rte);
                for (k = 0; k < 3; k++) tg[k] += Rte[k];
                mat_mul(Rg, Re, Rg);
            }
        }
        {
            double Rtg[3];
            mat_vec(R, tg, Rtg);
            for (k = 0; k < 3; k++) t[k] += Rtg[k];
            mat_mul(R, Rg, R);
        }
    }
    for (k = 0; k < 3; k++) tp[k] = m->tool_point[k] + (e ? e->tool[k] : 0.0);
    mat_vec(R, tp, p);
    for (k = 0; k < 3; k++) p[k] += t[k];
    if (e && (e->wp_t[0] != 0.0 || e->wp_t[1] != 0.0 || e->wp_t[2] != 0.0 ||
              e->wp_a[0] != 0.0 || e->wp_a[1] != 0.0 || e->wp_a[2] != 0.0)) {
        double Rw[9], RwT[9], dp[3];
        int r, c;
        rotation_xyz(e->wp_a, Rw);
        for (r = 0; r < 3; r++)
            for (c = 0; c < 3; c++) RwT[3 * r + c] = Rw[3 * c + r];
        for (k = 0; k < 3; k++) dp[k] = p[k] - e->wp_t[k];
        mat_vec(RwT, dp, p);
        mat_mul(RwT, R, R);
    }
    if (Rout) memcpy(Rout, R, sizeof R);
    return MTK_OK;
}

int mtk_forward(const mtk_model *m, const mtk_errors *e, const double *q, double p[3], double R[9], char *err)
{
    return forward(m, e, q, p, R, err, 1);
}

/* ---------------------------------------------------------------- compensation */

static int n_rotary(const mtk_model *m)
{
    int i, n = 0;
    for (i = 0; i < m->n_axes; i++) n += m->rotary[i];
    return n;
}

typedef struct {
    int mode;                 /* 0 position, 2 + tool direction, 3 + full orientation */
    double p[3], R[9], v[3];
} target_t;

static int residual(const mtk_model *m, const mtk_errors *e, const double *q, const target_t *tg,
                    double *r, char *err, int strict)
{
    double p[3], R[9];
    int k, rc = forward(m, e, q, p, R, err, strict);
    if (rc) return rc;
    for (k = 0; k < 3; k++) r[k] = p[k] - tg->p[k];
    if (tg->mode == 2) {
        /* All three components of v - v_target: the two perpendicular ones alone would also
         * vanish for a tool pointing the wrong way. */
        double v[3];
        mat_vec(R, m->tool_axis, v);
        for (k = 0; k < 3; k++) r[3 + k] = ORIENTATION_SCALE * (v[k] - tg->v[k]);
    } else if (tg->mode == 3) {
        double M[9];
        int i, j;
        for (i = 0; i < 3; i++)          /* M = Rt^T R */
            for (j = 0; j < 3; j++)
                M[3 * i + j] = tg->R[i] * R[j] + tg->R[3 + i] * R[3 + j] + tg->R[6 + i] * R[6 + j];
        r[3] = ORIENTATION_SCALE * 0.5 * (M[7] - M[5]);
        r[4] = ORIENTATION_SCALE * 0.5 * (M[2] - M[6]);
        r[5] = ORIENTATION_SCALE * 0.5 * (M[3] - M[1]);
    }
    return MTK_OK;
}


/* Solve A X = B for X (n x n, n x k), partial pivoting; 0 if singular. A and B are destroyed. */
static int solve(int n, double *A, double *B, int k)
{
    int i, j, c, r;
    for (c = 0; c < n; c++) {
        int piv = c;
        for (r = c + 1; r < n; r++)
            if (fabs(A[r * n + c]) > fabs(A[piv * n + c])) piv = r;
        if (A[piv * n + c] == 0.0) return 0;
        if (piv != c) {
            for (j = 0; j < n; j++) { double tmp = A[c * n + j]; A[c * n + j] = A[piv * n + j]; A[piv * n + j] = tmp; }
            for (j = 0; j < k; j++) { double tmp = B[c * k + j]; B[c * k + j] = B[piv * k + j]; B[piv * k + j] = tmp; }
        }
        for (r = c + 1; r < n; r++) {
            double f = A[r * n + c] / A[c * n + c];
            if (f == 0.0) continue;
            for (j = c; j < n; j++) A[r * n + j] -= f * A[c * n + j];
            for (j = 0; j < k; j++) B[r * k + j] -= f * B[c * k + j];
        }
    }
    for (i = n - 1; i >= 0; i--) {
        for (j = 0; j < k; j++) {
            double s = B[i * k + j];
            for (c = i + 1; c < n; c++) s -= A[i * n + c] * B[c * k + j];
            B[i * k + j] = s / A[i * n + i];
        }
    }
    return 1;
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

/* Chord Jacobian at q by forward differences on the rigid model; K = A^-1 J^T, Ainv = A^-1
 * with A = J^T J + lambda I.  Returns 0 if A is singular. */
static int linearise(const mtk_model *m, const mtk_errors *rigid, const double *q, const target_t *tg,
                     int rows, double *K, double *Ainv, char *err, int *rc)
{
    int n = m->n_axes, i, j, k;
    double J[6 * MTK_MAX_AXES], r0[6], dq[MTK_MAX_AXES], A[MTK_MAX_AXES * MTK_MAX_AXES] = {0};
    double Acopy[MTK_MAX_AXES * MTK_MAX_AXES];
    *rc = residual(m, rigid, q, tg, r0, err, 0);
    if (*rc) return 0;
    for (k = 0; k < n; k++) {
        double rk[6];
        memcpy(dq, q, n * sizeof(double));
        dq[k] += FD_STEP;
        *rc = residual(m, rigid, dq, tg, rk, err, 0);
        if (*rc) return 0;
        for (j = 0; j < rows; j++) J[j * n + k] = (rk[j] - r0[j]) / FD_STEP;
    }
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            double s = 0.0;
            for (k = 0; k < rows; k++) s += J[k * n + i] * J[k * n + j];
            A[i * n + j] = s + (i == j ? LAMBDA : 0.0);
        }
    for (i = 0; i < n; i++)
        for (k = 0; k < rows; k++) K[i * rows + k] = J[k * n + i];
    memcpy(Acopy, A, sizeof A);
    if (!solve(n, Acopy, K, rows)) return 0;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) Ainv[i * n + j] = (i == j);
    memcpy(Acopy, A, sizeof A);
    return solve(n, Acopy, Ainv, n);
}

/* The Gauss-Newton iteration of mtcomp.kinematics._solve for one point, started at `seed` and
 * pulled (weight LAMBDA) toward it.  Leaves the iterate in q and its largest residual component
 * (mm, tables held at their ends, NaN propagated) in *resmax; adds the iterations to *iters.
 * A singular Jacobian ends the attempt with *singular set and *resmax infinite. */
static int iterate(const mtk_model *m, const mtk_errors *e, const mtk_errors *rigid, const target_t *tg,
                   int rows, const double *seed, double *q, double tol, int max_iter, int *iters,
                   double *resmax, int *singular, char *err)
{
    int n = m->n_axes, i, k, it = 0, rc = MTK_OK, done = 0;
    double K[MTK_MAX_AXES * 6], Ainv[MTK_MAX_AXES * MTK_MAX_AXES], r[6], nr;
    *singular = 0;
    *resmax = INFINITY;
    memcpy(q, seed, n * sizeof(double));
    while (!done && it < max_iter) {
        int inner, slow = 0;
        if (!linearise(m, rigid, q, tg, rows, K, Ainv, err, &rc)) {
            *iters += it;
            if (rc) return rc;
            *singular = 1;
            return MTK_OK;
        }
        rc = residual(m, e, q, tg, r, err, 0);
        if (rc) return rc;
        nr = norm(r, rows);
        for (inner = 0; inner < 8; inner++) {
            double step[MTK_MAX_AXES], qn[MTK_MAX_AXES], rn[6], nn = nr, big = 0.0, scale, stepped = 0.0;
            int bt;
            it++;
            for (i = 0; i < n; i++) {
                double s = 0.0, pull = 0.0;
                for (k = 0; k < rows; k++) s += K[i * rows + k] * r[k];
                for (k = 0; k < n; k++) pull += Ainv[i * n + k] * (q[k] - seed[k]);
                step[i] = s + LAMBDA * pull;
                if (m->rotary[i] && fabs(step[i]) > big) big = fabs(step[i]);
            }
            /* Damping: rotary steps at most 20 deg (the whole step scaled), halved while the
             * residual does not fall. */
            scale = fmin(1.0, 20.0 / fmax(big, 1e-300));
            memcpy(qn, q, n * sizeof(double));
            memcpy(rn, r, sizeof rn);
            for (bt = 0; bt < 30; bt++) {
                double qt[MTK_MAX_AXES], rt[6], nt;
                for (i = 0; i < n; i++) qt[i] = q[i] - scale * step[i];
                rc = residual(m, e, qt, tg, rt, err, 0);
                if (rc) return rc;
                nt = norm(rt, rows);
                if (nt < nr || nt <= 1e-12) {
                    memcpy(qn, qt, n * sizeof(double));
                    memcpy(rn, rt, sizeof rn);
                    nn = nt;
                    break;
                }
                scale *= 0.5;
            }
            for (i = 0; i < n; i++)
                if (fabs(qn[i] - q[i]) > stepped) stepped = fabs(qn[i] - q[i]);
            slow |= (nn > 0.1 * nr) && (nn > 1e-12);
            done |= (stepped < tol) || (nn <= 1e-12);
            memcpy(q, qn, n * sizeof(double));
            memcpy(r, rn, sizeof r);
            nr = nn;
            if (done || slow) break;
        }
    }
    *iters += it;
    rc = residual(m, e, q, tg, r, err, 0);
    if (rc) return rc;
    *resmax = 0.0;
    for (k = 0; k < rows; k++)
        if (isnan(r[k]) || fabs(r[k]) > *resmax) *resmax = isnan(r[k]) ? NAN : fabs(r[k]);
    return MTK_OK;
}

/* Rotary offsets (deg) of the restart seeds, as mtcomp.kinematics._SEED_OFFSETS. */
static const double SEED_OFFSETS[3] = {90.0, -90.0, 180.0};

int mtk_retarget(const mtk_model *m, const mtk_errors *e, const double *q_prog, double *q,
                 double tol, int max_iter, int *iters, double *residual_out, char *err)
{
    int n = m->n_axes, rows, i, k, it = 0, rc = MTK_OK, singular = 0;
    double r[6], resmax = 0.0, res0;
    mtk_errors rigid;
    target_t tg;
    if (iters) *iters = 0;
    if (residual_out) *residual_out = 0.0;
    for (i = 0; i < n; i++) {
        if (!isfinite(q_prog[i])) {
            char msg[MTK_ERRLEN];
            snprintf(msg, sizeof msg, "axis %c command is not a finite number", m->axis_name[i]);
            seterr(err, msg);
            return MTK_E_ARG;
        }
    }
    if (!e || errors_zero(m, e)) {
        memcpy(q, q_prog, n * sizeof(double));
        goto limits;
    }
    /* Target: the ideal machine's pose at the programmed commands. */
    tg.mode = n_rotary(m) == 0 ? 0 : (n_rotary(m) >= 3 ? 3 : 2);
    rc = mtk_forward(m, NULL, q_prog, tg.p, tg.R, err);
    if (rc) return rc;
    rows = tg.mode == 0 ? 3 : 6;
    mat_vec(tg.R, m->tool_axis, tg.v);
    /* The chord Jacobian is taken on the rigid model (setting errors only). */
    mtk_errors_zero(&rigid);
    memcpy(rigid.tool, e->tool, sizeof rigid.tool);
    memcpy(rigid.wp_t, e->wp_t, sizeof rigid.wp_t);
    memcpy(rigid.wp_a, e->wp_a, sizeof rigid.wp_a);
    rigid.use_tables = 0;
    /* Same iteration as mtcomp.kinematics.compensate, for one point: from the programmed
     * commands first. */
    rc = iterate(m, e, &rigid, &tg, rows, q_prog, q, tol, max_iter, &it, &res0, &singular, err);
    if (rc) return rc;
    if (!(res0 < CONVERGED)) {
        /* Where that fails (a tilted workpiece at a singularity: B = 0 on a B-C table needs C
         * turned by 90 deg), restart from the programmed commands with rotary axes offset by
         * SEED_OFFSETS: each rotary axis alone, then each pair, in the core's order; keep the
         * converged solution with the smallest sum of |rotary change| (ties: the first). */
        enum { MAX_SEEDS = 3 * MTK_MAX_AXES + 9 * MTK_MAX_AXES * (MTK_MAX_AXES - 1) / 2 };
        int rot[MTK_MAX_AXES], nrot = 0, ns = 0, s, a, b, oa, ob, sa[MAX_SEEDS], sb[MAX_SEEDS], sing;
        double va[MAX_SEEDS], vb[MAX_SEEDS], best = INFINITY, seed[MTK_MAX_AXES], qt[MTK_MAX_AXES], et;
        for (i = 0; i < n; i++)
            if (m->rotary[i]) rot[nrot++] = i;
        for (a = 0; a < nrot; a++)
            for (oa = 0; oa < 3; oa++, ns++) {
                sa[ns] = rot[a]; va[ns] = SEED_OFFSETS[oa];
                sb[ns] = -1; vb[ns] = 0.0;
            }
        for (a = 0; a < nrot; a++)
            for (b = a + 1; b < nrot; b++)
                for (oa = 0; oa < 3; oa++)
                    for (ob = 0; ob < 3; ob++, ns++) {
                        sa[ns] = rot[a]; va[ns] = SEED_OFFSETS[oa];
                        sb[ns] = rot[b]; vb[ns] = SEED_OFFSETS[ob];
                    }
        for (s = 0; s < ns; s++) {
            double change = 0.0;
            memcpy(seed, q_prog, n * sizeof(double));
            seed[sa[s]] += va[s];
            if (sb[s] >= 0) seed[sb[s]] += vb[s];
            rc = iterate(m, e, &rigid, &tg, rows, seed, qt, tol, max_iter, &it, &et, &sing, err);
            if (rc) return rc;
            for (a = 0; a < nrot; a++) change += fabs(qt[rot[a]] - q_prog[rot[a]]);
            /* within 1e-6 deg of rotary change a tie: the first seed wins (same branch along a path) */
            if (et < CONVERGED && change < best - 1e-6) {
                memcpy(q, qt, n * sizeof(double));
                best = change;
            }
        }
        if (best == INFINITY) {
            /* No seed converged: report the attempt from the programmed commands, as the core. */
            char msg[MTK_ERRLEN];
            if (iters) *iters = it;
            if (residual_out) *residual_out = res0;
            if (singular)
                snprintf(msg, sizeof msg, "compensation did not converge: singular Jacobian (kinematic "
                         "singularity)");
            else
                snprintf(msg, sizeof msg, "compensation did not converge (residual %.3g); the target may "
                         "be unreachable or at a kinematic singularity", res0);
            seterr(err, msg);
            return MTK_E_CONVERGE;
        }
    }
    /* Strict evaluation: a converged command outside an error table's range is an error. */
    rc = residual(m, e, q, &tg, r, err, 1);
    if (rc) return rc;
    for (k = 0; k < rows; k++)
        if (isnan(r[k]) || fabs(r[k]) > resmax) resmax = isnan(r[k]) ? NAN : fabs(r[k]);
    if (iters) *iters = it;
    if (residual_out) *residual_out = resmax;
    if (!(resmax < CONVERGED)) {
        char msg[MTK_ERRLEN];
        snprintf(msg, sizeof msg, "compensation did not converge (residual %.3g); the target may be "
                 "unreachable or at a kinematic singularity", resmax);
        seterr(err, msg);
        return MTK_E_CONVERGE;
    }
limits:
    for (i = 0; i < n; i++) {
        if (q[i] < m->lo[i] - m->slack[i] || q[i] > m->hi[i] + m->slack[i]) {
            char msg[MTK_ERRLEN];
            snprintf(msg, sizeof msg, "axis %c would have to move to %.6f, outside its travel [%g, %g]",
                     m->axis_name[i], q[i], m->lo[i], m->hi[i]);
            seterr(err, msg);
            return MTK_E_LIMIT;
        }
    }
    return MTK_OK;
}
