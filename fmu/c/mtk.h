/* mtk: the mtcomp kinematic kernel in C, the one implementation of the exact model's hot loop.
 *
 * The FMUs compile it, and the library (mtcomp.kinematics through mtcomp._kernel, ctypes) calls
 * its batch entries as a plain shared library; mtcomp._solver is the numpy reference it mirrors
 * (docs/model.md): a serial chain of linear and rotary axes from the workpiece to the tool, each
 * contributing
 *     G_i(q) = L_i N_i(q) L_i^-1 . T(loc_i) D_i(q) T(-loc_i),
 * tool setting offset at the end of the chain and the workpiece setting pose at its start.
 * Compensation: closed form for rigid errors without rotation, else Gauss-Newton with the
 * analytic Jacobian (of the full model with tables or location errors, else of the rigid one;
 * the rigid one with an axis held), the pole axis held within the pole tolerance, a warm start from the
 * previous pose along a path, restarts from rotary seeds where the iteration fails.
 * Units: mm and deg for commands and setting errors, rad for geometric error angles.
 * For the FMUs the machine comes from a resource file written at build time (docs/fmu.md); the
 * library builds it in memory (mtk_model_new).
 */
#ifndef MTCOMP_MTK_H
#define MTCOMP_MTK_H

#include <stddef.h>

#define MTK_MAX_AXES 9
#define MTK_ERRLEN 512

typedef struct {
    int n;                  /* number of rows */
    double *pos;            /* (n) axis position, mm or deg, strictly increasing */
    double *val;            /* (n*6) components EX?, EY?, EZ? (mm), EA?, EB?, EC? (rad) */
    double *coef;           /* ((n-1)*12) per interval: the six values at its start, then their
                             * slopes per mm or deg (set by the loaders: no division per lookup) */
    double p0, inv_h;       /* first position and (n-1)/span: the interval of an evenly spaced
                             * table by one multiplication (checked against pos) */
} mtk_table;

typedef struct {
    char name[64];
    int n_axes;
    char axis_name[MTK_MAX_AXES];
    int rotary[MTK_MAX_AXES];
    int tool_side[MTK_MAX_AXES];
    double dir[MTK_MAX_AXES][3];
    double loc[MTK_MAX_AXES][3];
    double lo[MTK_MAX_AXES], hi[MTK_MAX_AXES];
    double slack[MTK_MAX_AXES];       /* half a resolution step: travel check tolerance */
    double tool_point[3];
    double tool_axis[3];
    mtk_table *table[MTK_MAX_AXES];   /* NULL: no component errors for that axis */
    void *cache;                      /* mtk_retarget's prepared error set and last correction
                                       * (one caller per model at a time; freed by mtk_free) */
} mtk_model;

/* Setting and location errors: the parameters of an FMU, may change between calls. */
typedef struct {
    double tool[3];                   /* tool setting offset, mm, last tool-side frame */
    double wp_t[3];                   /* workpiece translation, mm */
    double wp_a[3];                   /* workpiece angles a, b, c, deg: R = Rz(c) Ry(b) Rx(a) */
    double loc[MTK_MAX_AXES][6];      /* E{X,Y,Z}0{axis} mm, E{A,B,C}0{axis} rad */
    int use_tables;                   /* 0: ignore the tables (rigid model) */
} mtk_errors;

/* Return codes */
enum { MTK_OK = 0, MTK_E_IO = 1, MTK_E_FORMAT = 2, MTK_E_RANGE = 3, MTK_E_LIMIT = 4,
       MTK_E_CONVERGE = 5, MTK_E_ARG = 6 };

int mtk_load_machine(const char *path, mtk_model **out, char *err);
int mtk_load_table(mtk_model *m, const char *axis_name, const char *path, char *err);
void mtk_free(mtk_model *m);
void mtk_errors_zero(mtk_errors *e);
int mtk_axis_index(const mtk_model *m, char axis_name);

/* Tool edge p (mm) and tool frame R (row-major 3x3, columns = tool frame axes) in the real
 * workpiece frame for commands q (mm, deg); e == NULL: ideal machine. */
int mtk_forward(const mtk_model *m, const mtk_errors *e, const double *q, double p[3], double R[9], char *err);

/* Commands q (n_axes) that put the real tool edge at the ideal pose of q_prog under the errors e
 * (mtcomp.kinematics.retarget with check=True).  Successive calls are taken as a path: each
 * starts from the previous call's correction (warm start) while the errors stay the same; the
 * constants of the error set are prepared once.  max_iter bounds each attempt (the one from
 * q_prog and every restart); iters receives the iterations of all attempts together, residual
 * the largest residual component (mm; orientation scaled by 100 mm/rad; with a pole axis held:
 * position only).  Both may be NULL. */
int mtk_retarget(const mtk_model *m, const mtk_errors *e, const double *q_prog, double *q,
                 double tol, int max_iter, int *iters, double *residual, char *err);

/* Pole tolerance (deg) of mtk_retarget: within it of a pole (C at B = 0 on a B-C table, A and C
 * at B = 90 on an A-B-C head) the pole axis is held and the tool direction met in least squares
 * (mtcomp.kinematics.POLE_TOLERANCE). */
#define MTK_POLE_TOL 0.2

/* ---------------------------------------------------------------- batches (library entry)
 * The machine built in memory (no resource files) and whole arrays of poses per call, row-major:
 * q (n, n_axes), p (n, 3), R (n, 9). */
typedef struct {
    double tol;          /* step tolerance, mm or deg */
    int max_iter;        /* iterations per attempt */
    double pole_tol;     /* deg; 0: no pole handling */
    int continuation;    /* start each pose from the previous pose's correction */
    long run_in;         /* the first run_in poses only take up the path (continuation): solved, not
                          * written; q, res, status and info hold the poses after them */
} mtk_options;

mtk_model *mtk_model_new(int n_axes, const char *axis_names, const int *rotary, const int *tool_side,
                         const double *dir, const double *loc, const double *lo, const double *hi,
                         const double *slack, const double *tool_point, const double *tool_axis);
int mtk_model_set_table(mtk_model *m, int axis, int n, const double *pos, const double *val);
/* Returns the index of the first pose outside a table's range (strict; axis in *bad_axis), or -1.
 * R may be NULL: positions only. */
long mtk_forward_batch(const mtk_model *m, const mtk_errors *e, long n, const double *q, double *p, double *R,
                       int strict, int *bad_axis);
/* Per pose: status MTK_OK, MTK_E_CONVERGE or MTK_E_RANGE; info the held pole axis (-1: none) or the
 * axis outside its table; res the largest residual (mm; held: position only).  Returns the number
 * of failed poses. */
long mtk_retarget_batch(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, double *q,
                        const mtk_options *o, double *res, int *status, int *info);
long mtk_compensate_batch(const mtk_model *m, const mtk_errors *e, long n, const double *p_t, const double *R_t,
                          const double *q0, double *q, const mtk_options *o, double *res, int *status, int *info);

/* The same three batches split into chunks of about MTK_CHUNK poses solved on `threads` threads
 * (<= 0: $MTCOMP_THREADS, else the CPUs this process may use; never more than the chunks).  The
 * chunks do not depend on the number of threads: with continuation each chunk after the first
 * takes up the path from the MTK_RUN_IN poses before it (solved, not written), so one thread and
 * many give bit-identical results.  In mtk_threads.c, compiled into the library only (not the
 * FMUs); without MTK_THREADS at compile time the chunks run in the calling thread.  o->run_in is ignored. */
#define MTK_CHUNK 4096
#define MTK_RUN_IN 16
long mtk_forward_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *q, double *p, double *R,
                          int strict, int *bad_axis, int threads);
long mtk_retarget_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, double *q,
                           const mtk_options *o, double *res, int *status, int *info, int threads);
long mtk_compensate_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *p_t,
                             const double *R_t, const double *q0, double *q, const mtk_options *o, double *res,
                             int *status, int *info, int threads);
/* Threads a batch of n poses runs on (threads as above). */
int mtk_threads(long n, int threads);

/* Verification of compensated commands: per pose the distance (mm) of the real tool edge from the
 * ideal one at q_prog (before) and at q_emit (after); strict as mtk_forward_batch (returns the first
 * pose with a command outside a table, the axis in *bad_axis, else -1). */
long mtk_check_batch(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, const double *q_emit,
                     double *before, double *after, int strict, int *bad_axis);
long mtk_check_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, const double *q_emit,
                        double *before, double *after, int strict, int *bad_axis, int threads);

/* Portable strtok_r: next token of s (or of *save when s is NULL) delimited by any of delim. */
char *mtk_tok(char *s, const char *delim, char **save);

#endif
