/* mtk_threads: the kernel's batches (mtk.h) cut into chunks and solved on threads.  Compiled into
 * the kernel library only (mtcomp._kernel), never into an FMU; without MTK_THREADS at compile time
 * the chunks run in the calling thread.
 *
 * Written by hand: the chunks must not depend on the number of threads (so that one thread and
 * several give the same bits), and the threads must start in C, not in Python.  Each chunk after
 * the first takes up the path from the MTK_RUN_IN poses before it (solved, not written), as the
 * sequential call would have it; mtk_compensate_batch without a target is mtk_retarget_batch.
 */
#ifdef MTK_THREADS
#define _GNU_SOURCE   /* sched_getaffinity (Linux; elsewhere the online CPUs) */
#include <pthread.h>
#ifdef __linux__
#include <sched.h>
#endif
#include <unistd.h>
#endif
#include <stdlib.h>
#include <string.h>

#include "mtk.h"


typedef struct {
    const mtk_model *m;
    const mtk_errors *e;
    long n, nchunks;
    int fwd, strict;           /* fwd: 1 forward, 2 check (q0 the programmed, q the emitted commands;
                                * p before, res after) */
    const double *q0, *p_t, *R_t;
    double *p, *R, *q, *res;
    const mtk_options *o;
    int *status, *info;
    long next;                 /* next chunk to take (atomic) */
} mt_job;

typedef struct {
    mt_job *job;
    long failed, bad;          /* solve: failed poses; forward: first bad pose (-1: none) */
    int bad_axis;
} mt_worker;

static long chunk_edge(const mt_job *j, long k)
{
    return (long)((long long)k * j->n / j->nchunks);
}

static long take_chunk(mt_job *j)
{
#if defined(MTK_THREADS) && defined(__GNUC__)
    return __atomic_fetch_add(&j->next, 1, __ATOMIC_RELAXED);
#else
    return j->next++;
#endif
}

static void *mt_work(void *arg)
{
    mt_worker *w = (mt_worker *)arg;
    mt_job *j = w->job;
    int nax = j->m->n_axes;
    long k;
    while ((k = take_chunk(j)) < j->nchunks) {
        long a = chunk_edge(j, k), b = chunk_edge(j, k + 1);
        if (b <= a) continue;
        if (j->fwd == 2) {
            int ax = -1;
            long bad = mtk_check_batch(j->m, j->e, b - a, j->q0 + a * nax, j->q + a * nax, j->p + a, j->res + a,
                                       j->strict, &ax);
            if (bad >= 0 && (w->bad < 0 || a + bad < w->bad)) { w->bad = a + bad; w->bad_axis = ax; }
        } else if (j->fwd) {
            int ax = -1;
            long bad = mtk_forward_batch(j->m, j->e, b - a, j->q0 + a * nax, j->p + 3 * a, j->R ? j->R + 9 * a : NULL,
                                         j->strict, &ax);
            if (bad >= 0 && (w->bad < 0 || a + bad < w->bad)) { w->bad = a + bad; w->bad_axis = ax; }
        } else {
            /* the run-in poses before the chunk take up the path (as the sequential call had it) */
            long a0 = j->o->continuation ? (a > MTK_RUN_IN ? a - MTK_RUN_IN : 0) : a;
            mtk_options o = *j->o;
            o.run_in = a - a0;
            w->failed += mtk_compensate_batch(j->m, j->e, b - a0, j->p_t ? j->p_t + 3 * a0 : NULL,
                                              j->R_t ? j->R_t + 9 * a0 : NULL, j->q0 + a0 * nax, j->q + a * nax, &o,
                                              j->res + a, j->status + a, j->info + a);
        }
    }
    return NULL;
}

int mtk_threads(long n, int threads)
{
    long nchunks = (n + MTK_CHUNK - 1) / MTK_CHUNK;
#ifdef MTK_THREADS
    if (threads <= 0) {
        const char *env = getenv("MTCOMP_THREADS");
        threads = env ? atoi(env) : 0;
        if (threads <= 0) {
#ifdef __linux__
            cpu_set_t set;
            threads = sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set)
                                                                 : (int)sysconf(_SC_NPROCESSORS_ONLN);
#elif defined(_WIN32)
            const char *np = getenv("NUMBER_OF_PROCESSORS");
            threads = np ? atoi(np) : 1;
#else
            threads = (int)sysconf(_SC_NPROCESSORS_ONLN);
#endif
        }
    }
    if (threads > 64) threads = 64;
#else
    threads = 1;
#endif
    if (threads > nchunks) threads = (int)nchunks;
    return threads < 1 ? 1 : threads;
}

static long run_job(mt_job *j, int threads, int *bad_axis)
{
    mt_worker w[64];
    long out = 0, bad = -1;
    int t, nt;
    j->nchunks = (j->n + MTK_CHUNK - 1) / MTK_CHUNK;
    if (j->nchunks < 1) j->nchunks = 1;
    j->next = 0;
    nt = mtk_threads(j->n, threads);
    for (t = 0; t < nt; t++) { w[t].job = j; w[t].failed = 0; w[t].bad = -1; w[t].bad_axis = -1; }
#ifdef MTK_THREADS
    {
        pthread_t th[64];
        int started[64] = {0};
        for (t = 1; t < nt; t++) started[t] = pthread_create(&th[t], NULL, mt_work, &w[t]) == 0;
        mt_work(&w[0]);   /* the calling thread works too; chunks a failed thread would take stay with it */
        for (t = 1; t < nt; t++)
            if (started[t]) pthread_join(th[t], NULL);
    }
#else
    mt_work(&w[0]);
#endif
    for (t = 0; t < nt; t++) {
        out += w[t].failed;
        if (w[t].bad >= 0 && (bad < 0 || w[t].bad < bad)) {
            bad = w[t].bad;
            if (bad_axis) *bad_axis = w[t].bad_axis;
        }
    }
    return j->fwd ? bad : out;
}

long mtk_forward_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *q, double *p, double *R,
                          int strict, int *bad_axis, int threads)
{
    mt_job j;
    memset(&j, 0, sizeof j);
    j.m = m; j.e = e; j.n = n; j.fwd = 1; j.strict = strict; j.q0 = q; j.p = p; j.R = R;
    return run_job(&j, threads, bad_axis);
}

long mtk_check_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, const double *q_emit,
                        double *before, double *after, int strict, int *bad_axis, int threads)
{
    mt_job j;
    memset(&j, 0, sizeof j);
    j.m = m; j.e = e; j.n = n; j.fwd = 2; j.strict = strict; j.q0 = q_prog; j.q = (double *)q_emit;
    j.p = before; j.res = after;
    return run_job(&j, threads, bad_axis);
}

long mtk_retarget_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *q_prog, double *q,
                           const mtk_options *o, double *res, int *status, int *info, int threads)
{
    return mtk_compensate_batch_mt(m, e, n, NULL, NULL, q_prog, q, o, res, status, info, threads);
}

long mtk_compensate_batch_mt(const mtk_model *m, const mtk_errors *e, long n, const double *p_t,
                             const double *R_t, const double *q0, double *q, const mtk_options *o, double *res,
                             int *status, int *info, int threads)
{
    mt_job j;
    memset(&j, 0, sizeof j);
    j.m = m; j.e = e; j.n = n; j.p_t = p_t; j.R_t = R_t; j.q0 = q0; j.q = q; j.o = o;
    j.res = res; j.status = status; j.info = info;
    return run_job(&j, threads, NULL);
}
