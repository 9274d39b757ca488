/* The stepping loop of mtcomp.fmu.cosim in C: compiled into the kernel library (mtcomp._kernel),
 * never into an FMU.
 *
 * Written by hand because the loop's cost per step is the point: driven from Python, each FMI
 * call is a ctypes call (about 0.5-0.8 µs), six per co-simulation step; here the master calls the
 * FMUs' own fmi2SetReal / fmi2GetReal / fmi2DoStep through the function pointers it is given,
 * for a whole range of steps per ctypes call, reading and writing the rows of the caller's
 * preallocated arrays.  The order of the calls is mtcomp.fmu.cosim._run's.
 */
#include <stddef.h>

typedef int (*fmi_values)(void *c, const unsigned *vr, size_t nvr, double *v);
typedef int (*fmi_step)(void *c, double t, double h, int no_set_prior);

typedef struct {
    void *comp;                   /* compensator instance, or NULL: the machine gets q itself */
    fmi_values c_set, c_get;
    fmi_step c_step;
    const unsigned *c_in, *c_out; /* n value references each */
    void *mach;                   /* machine instance, or NULL: the compensator alone */
    fmi_values m_set, m_get;
    fmi_step m_step;
    const unsigned *m_in, *m_out; /* n and n_out value references */
    int n, n_out;
    double step;                  /* communication step, s; step k starts at t = k * step */
    double *q;                    /* (K, n) programmed commands */
    double *qc;                   /* (K, n) compensated commands (with comp; else read: q) */
    double *out;                  /* (K, n_out) machine outputs after each step */
} mtk_cosim;

/* What failed: the step index times 8 plus one of these; -1: every step of [k0, k1) done. */
enum { FAIL_COMP = 1, FAIL_MACH_SET = 2, FAIL_COMP_STEP = 3, FAIL_MACH_STEP = 4 };

long mtk_cosim_steps(const mtk_cosim *s, long k0, long k1)
{
    long k;
    const int n = s->n;
    for (k = k0; k < k1; k++) {
        double t = (double)k * s->step, *qk = s->q + k * n, *qck = s->qc + k * n;
        if (s->comp && (s->c_set(s->comp, s->c_in, n, qk) > 1 || s->c_get(s->comp, s->c_out, n, qck) > 1))
            return 8 * k + FAIL_COMP;
        if (s->mach && s->m_set(s->mach, s->m_in, n, s->comp ? qck : qk) > 1)
            return 8 * k + FAIL_MACH_SET;
        if (s->comp && s->c_step(s->comp, t, s->step, 1) > 1)
            return 8 * k + FAIL_COMP_STEP;
        if (s->mach && (s->m_step(s->mach, t, s->step, 1) > 1 ||
                        s->m_get(s->mach, s->m_out, s->n_out, s->out + k * s->n_out) > 1))
            return 8 * k + FAIL_MACH_STEP;
    }
    return -1;
}
