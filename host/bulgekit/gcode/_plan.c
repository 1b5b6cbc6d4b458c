/* The estimator's per-block passes (gcode/estimate.py), compiled: moves(), Marlin's rule for tiny
 * moves (estimate._drop_tiny); blocks(), each block's limits and junction (_Planner.add); segment(),
 * the planner's passes (_plan_segment_np): for blocks that run without a stop between them, the
 * entry speeds by the backward pass (a look-ahead window of W blocks, or the whole run) and the
 * forward pass, then each block's trapezoid. Operation for operation what the numpy code computes,
 * so the numbers are the same to the bit (host/tests/gcode/test_plan_c.py); built with
 * -ffp-contract=off so that no multiply-add is fused. Optional: without it estimate.py runs its
 * numpy code.
 *
 *   segment(a, L, vn, me2, vmin2, W, lo, hi, k0, k1, t, entry, exit, cruise, ta, tc, td)
 *
 * a, L, vn, me2: the run's acceleration, length, nominal speed and junction speed squared (float64
 * buffers). The blocks lo..hi-1 are planned as one segment (from rest to rest); the results of
 * blocks k0..k1-1 (lo <= k0 <= k1 <= hi) are written at those indices of the output buffers
 * (t: the block's time; the others may be None). W: the look-ahead window (lookahead - 2 blocks,
 * at least 1), or -1 for the whole segment. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdlib.h>
#include <stdint.h>
#include <string.h>

/* numpy's minimum and maximum of two doubles (a NaN in either wins) */
static inline double np_min(double a, double b) { return (a <= b || isnan(a)) ? a : b; }
static inline double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }

typedef struct { Py_buffer b; int set; } Buf;

static int get_buf(PyObject *o, Buf *out, int writable, Py_ssize_t n, const char *name) {
    out->set = 0;
    if (o == Py_None) return 0;
    if (PyObject_GetBuffer(o, &out->b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    out->set = 1;
    if (out->b.itemsize != 8 || !out->b.format || strcmp(out->b.format, "d") != 0 || out->b.len / 8 < n) {
        PyErr_Format(PyExc_ValueError, "_plan.segment: %s must be float64 with at least %zd items", name, n);
        return -1;
    }
    return 0;
}

static PyObject *segment(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *o[11];
    double vmin2;
    Py_ssize_t W, lo, hi, k0, k1;
    if (!PyArg_ParseTuple(args, "OOOOdnnnnnOOOOOOO", &o[0], &o[1], &o[2], &o[3], &vmin2, &W, &lo, &hi,
                          &k0, &k1, &o[4], &o[5], &o[6], &o[7], &o[8], &o[9], &o[10]))
        return NULL;
    static const char *names[11] = {"a", "L", "vn", "me2", "t", "entry", "exit", "cruise", "ta", "tc", "td"};
    Buf bufs[11];
    double *p[11];
    PyObject *ret = NULL;
    double *S = NULL, *back = NULL, *e2 = NULL;
    int i;
    for (i = 0; i < 11; i++) bufs[i].set = 0;
    if (!(0 <= lo && lo <= k0 && k0 <= k1 && k1 <= hi)) {
        PyErr_SetString(PyExc_ValueError, "_plan.segment: need 0 <= lo <= k0 <= k1 <= hi");
        return NULL;
    }
    for (i = 0; i < 11; i++) {
        if (i < 5 && o[i] == Py_None) {
            PyErr_Format(PyExc_TypeError, "_plan.segment: %s is required", names[i]);
            goto done;
        }
        if (get_buf(o[i], &bufs[i], i >= 4, hi, names[i]) < 0) goto done;
        p[i] = bufs[i].set ? (double *)bufs[i].b.buf : NULL;
    }
    {
        const double *a = p[0] + lo, *L = p[1] + lo, *vn = p[2] + lo, *me2 = p[3] + lo;
        Py_ssize_t n = hi - lo, j, q;
        if (n == 0) { ret = Py_None; Py_INCREF(ret); goto done; }
        S = malloc((size_t)(n + 1) * sizeof(double));
        back = malloc((size_t)(n + 1) * sizeof(double));   /* first arr = M + S, then the passes */
        e2 = malloc((size_t)(n + 1) * sizeof(double));
        if (!S || !back || !e2) { PyErr_NoMemory(); goto done; }
        /* M = min(maxentry2, vn^2) with vmin2 first and last; S = cumsum(2 a L); arr = M + S */
        S[0] = 0.0;
        for (j = 0; j < n; j++) {
            double x = 2 * a[j] * L[j];
            S[j + 1] = j == 0 ? x : S[j] + x;
        }
        for (j = 0; j <= n; j++) {
            double M = (j == 0 || j == n) ? vmin2 : np_min(me2[j], vn[j] * vn[j]);
            back[j] = M + S[j];
        }
        /* backward: the least arr over the window (or to the end), less S */
        if (W < 0 || W >= n) {        /* lookahead None, or lookahead - 2 >= n: the whole segment */
            double acc = back[n];
            for (j = n - 1; j >= 0; j--) {
                acc = np_min(acc, back[j]);
                back[j] = acc;
            }
        } else {
            if (W < 1) W = 1;
            for (j = 0; j < n; j++) {
                double mn = back[j];
                Py_ssize_t end = j + W;
                for (q = j + 1; q < end && q <= n; q++) mn = np_min(mn, back[q]);
                if (end > n) end = n;
                back[j] = np_min(mn, vmin2 + S[end]);
            }
        }
        /* forward: S + the running least of (back - S) */
        double run = 0.0;
        for (j = 0; j < n; j++) {
            double b = back[j] - S[j];
            double x = b - S[j];
            run = j == 0 ? x : np_min(run, x);
            double fwd = S[j] + run;
            e2[j] = np_max(np_min(b, fwd), 0.0);
        }
        e2[n] = vmin2;
        for (j = k0 - lo; j < k1 - lo; j++) {
            double entry2 = e2[j], exit2 = j + 1 < n ? e2[j + 1] : vmin2;
            double v0 = sqrt(entry2), v1 = sqrt(exit2);
            double vpeak = sqrt(np_max((2 * a[j] * L[j] + entry2 + exit2) / 2, 0.0));
            double vc = np_min(vn[j], vpeak);
            vc = np_max(vc, np_max(v0, v1));
            double t_a = (vc - v0) / a[j];
            double t_d = (vc - v1) / a[j];
            double d_c = np_max(L[j] - (vc * vc - entry2) / (2 * a[j]) - (vc * vc - exit2) / (2 * a[j]), 0.0);
            double t_c = d_c / vc;
            Py_ssize_t at = lo + j;
            p[4][at] = t_a + t_c + t_d;
            if (p[5]) p[5][at] = v0;
            if (p[6]) p[6][at] = v1;
            if (p[7]) p[7][at] = vc;
            if (p[8]) p[8][at] = t_a;
            if (p[9]) p[9][at] = t_c;
            if (p[10]) p[10][at] = t_d;
        }
    }
    ret = Py_None;
    Py_INCREF(ret);
done:
    free(S);
    free(back);
    free(e2);
    for (i = 0; i < 11; i++)
        if (bufs[i].set) PyBuffer_Release(&bufs[i].b);
    return ret;
}

/* A strided float64 vector or k x 4 matrix (a broadcast row has stride 0) */
typedef struct { Py_buffer b; int set; const char *p; Py_ssize_t s0, s1; } Vec;

static int get_vec(PyObject *o, Vec *v, Py_ssize_t n, int cols, const char *name) {
    v->set = 0;
    if (PyObject_GetBuffer(o, &v->b, PyBUF_RECORDS_RO) < 0) return -1;
    v->set = 1;
    Py_buffer *b = &v->b;
    int ok = b->itemsize == 8 && b->format && strcmp(b->format, "d") == 0;
    if (ok && cols == 0) {
        ok = b->ndim == 1 && b->shape[0] >= n;
        v->s0 = ok ? b->strides[0] : 0;
        v->s1 = 0;
    } else if (ok) {
        ok = (b->ndim == 2 && b->shape[0] >= n && b->shape[1] == cols) || (b->ndim == 1 && b->shape[0] == cols);
        v->s0 = !ok ? 0 : b->ndim == 2 ? b->strides[0] : 0;
        v->s1 = !ok ? 0 : b->ndim == 2 ? b->strides[1] : b->strides[0];
    }
    if (!ok) {
        PyErr_Format(PyExc_ValueError, "_plan.blocks: %s must be float64 of %zd rows%s", name, n,
                     cols ? " by 4 (or one row)" : "");
        return -1;
    }
    v->p = (const char *)b->buf;
    return 0;
}

#define AT(v, i) (*(const double *)((v).p + (i) * (v).s0))
#define AT2(v, i, c) (*(const double *)((v).p + (i) * (v).s0 + (c) * (v).s1))

/* Marlin's JD_USE_LOOKUP_TABLE: estimate._jd_lut_acos_neg, one value */
static const double JD_K[16] = {-1.03145837, -1.30760646, -1.75205851, -2.41705704, -3.37769222, -4.74888992,
                                -6.69649887, -9.45661736, -13.3640480, -18.8928222, -26.7136841, -37.7754593,
                                -53.4201813, -75.5458374, -106.836761, -218.532821};
static const double JD_B[16] = {1.57079637, 1.70887053, 2.04220939, 2.62408352, 3.52467871, 4.85302639,
                                6.77020454, 9.50875854, 13.4009285, 18.9188995, 26.7321243, 37.7885055,
                                53.4293975, 75.5523529, 106.841369, 218.534011};

static double jd_lut_acos_neg(double cos) {
    double neg = cos < 0 ? -1.0 : 1.0;
    double t = neg * cos;
    double xf = floor((1.0 - t) * 32768.0);
    xf = xf < 0 ? 0 : xf > 65535 ? 65535 : xf;
    long x = (long)xf, bits = 0;
    while (x >> bits) bits++;                           /* floor(log2(x)) + 1 for x > 0 */
    long idx = 16 - bits - 1;
    idx = t < 3e-8 ? 0 : idx < 0 ? 0 : idx > 15 ? 15 : idx;
    double theta = t * JD_K[idx] + JD_B[idx];
    return neg > 0 ? 3.141592653589793 - theta : theta;
}

/* blocks(dx, dy, dz, de, v, accel, jd, amax, vmax, prev, small_segments, vmin2, L, vn, acc, me2)
 *
 * estimate._Planner.add's numbers for k blocks, junction deviation (no classic jerk): each block's
 * length L, nominal speed vn and acceleration acc under the per-axis limits (vmax: M203, amax:
 * M201, k x 4 or one row), and me2, the square of the speed it may enter at from its junction with
 * the block before (estimate._junctions). prev: 6 float64, in and out: the previous block's unit
 * vector and nominal speed, and 1 if there is one (else 0: the first block's me2 is 0); the last
 * block's are left there. Inputs may be strided (column views, broadcast rows); outputs are
 * contiguous float64 of k. Returns the number of blocks. */
static PyObject *blocks(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *o[9], *po, *out[4];
    int small;
    double vmin2;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOidOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                          &o[8], &po, &small, &vmin2, &out[0], &out[1], &out[2], &out[3]))
        return NULL;
    static const char *names[9] = {"dx", "dy", "dz", "de", "v", "accel", "jd", "amax", "vmax"};
    Vec in[9];
    Buf ob[4], pb;
    PyObject *ret = NULL;
    Py_ssize_t k, i;
    int c;
    for (i = 0; i < 9; i++) in[i].set = 0;
    for (i = 0; i < 4; i++) ob[i].set = 0;
    pb.set = 0;
    if (get_buf(out[0], &ob[0], 1, 0, "L") < 0 || !ob[0].set) goto done;
    k = ob[0].b.len / 8;
    for (i = 1; i < 4; i++)
        if (get_buf(out[i], &ob[i], 1, k, "an output") < 0 || !ob[i].set) goto done;
    if (get_buf(po, &pb, 1, 6, "prev") < 0) goto done;
    for (i = 0; i < 9; i++)
        if (get_vec(o[i], &in[i], k, i >= 7 ? 4 : 0, names[i]) < 0) goto done;
    {
        double *L = ob[0].b.buf, *vn = ob[1].b.buf, *acc = ob[2].b.buf, *me2 = ob[3].b.buf, *prev = pb.b.buf;
        for (i = 0; i < k; i++) {
            double d[4] = {AT(in[0], i), AT(in[1], i), AT(in[2], i), AT(in[3], i)};
            double xyz = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            double Li = xyz > 0 ? xyz : fabs(d[3]);
            double vlim = 0, alim = 0;
            for (c = 0; c < 4; c++) {
                double r = fabs(d[c]) / Li;
                double vl = r > 0 ? AT2(in[8], i, c) / r : INFINITY;
                double al = r > 0 ? AT2(in[7], i, c) / r : INFINITY;
                vlim = c ? np_min(vlim, vl) : vl;
                alim = c ? np_min(alim, al) : al;
            }
            double v = np_min(AT(in[4], i), vlim);
            double a = xyz > 0 ? np_min(AT(in[5], i), alim) : AT(in[5], i);
            L[i] = Li;
            vn[i] = v;
            acc[i] = a;
            /* the unit vector: XYZE normalised for a move that extrudes, XYZ / length for travel */
            double nd = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + d[3] * d[3]);
            double u[4];
            for (c = 0; c < 4; c++) u[c] = d[3] != 0 ? d[c] / nd : d[c] / Li;
            double e2 = 0.0;
            if (prev[5] != 0) {
                const double *p = prev;
                double cos = -(u[0] * p[0] + u[1] * p[1] + u[2] * p[2] + u[3] * p[3]);
                double j[4];
                for (c = 0; c < 4; c++) j[c] = u[c] - p[c];
                double jn = sqrt(j[0] * j[0] + j[1] * j[1] + j[2] * j[2] + j[3] * j[3]);
                double lim = 0;
                for (c = 0; c < 4; c++) {
                    double jc = jn > 0 ? j[c] / jn : 0.0;
                    double l = fabs(jc) > 0 ? AT2(in[7], i, c) / fabs(jc) : INFINITY;
                    lim = c ? np_min(lim, l) : l;
                }
                double aj = np_min(a, lim);
                double cc = np_max(cos, -0.999999);
                double s2 = sqrt(0.5 * (1 - cc));
                double vj2 = aj * AT(in[6], i) * s2 / (1 - s2);
                if (small && Li < 1 && cc < -0.7071067812) vj2 = np_min(vj2, Li * aj / jd_lut_acos_neg(cc));
                if (cos > 0.999999) vj2 = vmin2;
                double vm = np_min(v, p[4]);
                e2 = np_min(vj2, vm * vm);
            }
            me2[i] = e2;
            for (c = 0; c < 4; c++) prev[c] = u[c];
            prev[4] = v;
            prev[5] = 1.0;
        }
    }
    ret = PyLong_FromSsize_t(k);
done:
    for (i = 0; i < 9; i++)
        if (in[i].set) PyBuffer_Release(&in[i].b);
    for (i = 0; i < 4; i++)
        if (ob[i].set) PyBuffer_Release(&ob[i].b);
    if (pb.set) PyBuffer_Release(&pb.b);
    return ret;
}

static int get_out(PyObject *o, Py_buffer *b, Py_ssize_t n, Py_ssize_t itemsize, const char *name) {
    if (PyObject_GetBuffer(o, b, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE) < 0) return -1;
    if (b->itemsize != itemsize || b->len / itemsize < n) {
        PyBuffer_Release(b);
        PyErr_Format(PyExc_ValueError, "_plan.moves: %s must have %zd items of %zd bytes", name, n, itemsize);
        return -1;
    }
    return 0;
}

/* moves(x0, y0, z0, x1, y1, z1, e, e_to, e_prev, reset, spm, min_steps, pending, D, ne, emitted)
 *
 * estimate._vector_moves' Marlin rule for k moves taken from the scanner's records: a move whose
 * steps (on every axis, E alone counting whole steps from the planner's E position) are fewer
 * than min_steps, or none, is dropped and its distance goes to the next move. Inputs: the moves'
 * coordinates (float64, may be strided), e_to: each move's end E in whole steps, e_prev: the E
 * steps each starts from if the one before is planned (or a G92 set them: reset, bool), spm: steps
 * per mm X Y Z E, pending: 4 float64, the distance carried in (out: carried on past the last move).
 * Out: D (k x 4: dx dy dz de as planned), ne (E-alone whole steps, else 0; of the planned moves),
 * emitted (bool). The
 * same numbers as the numpy code (a move after a dropped one gets the carried distance added, the
 * others are taken as they are). */
static PyObject *moves(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *o[7], *eto_o, *eprev_o, *reset_o, *spm_o, *pend_o, *D_o, *ne_o, *em_o;
    double min_steps;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOdOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &eto_o,
                          &eprev_o, &reset_o, &spm_o, &min_steps, &pend_o, &D_o, &ne_o, &em_o))
        return NULL;
    static const char *names[7] = {"x0", "y0", "z0", "x1", "y1", "z1", "e"};
    Vec in[7];
    Py_buffer eto, eprev, reset, D, ne, em;
    Buf spm, pend;
    int got[6] = {0, 0, 0, 0, 0, 0};
    PyObject *ret = NULL;
    Py_ssize_t k, i;
    int c;
    for (i = 0; i < 7; i++) in[i].set = 0;
    spm.set = pend.set = 0;
    if (get_out(ne_o, &ne, 0, 8, "ne") < 0) return NULL;
    got[4] = 1;
    k = ne.len / 8;
    if (get_out(D_o, &D, 4 * k, 8, "D") < 0) goto done;
    got[3] = 1;
    if (get_out(em_o, &em, k, 1, "emitted") < 0) goto done;
    got[5] = 1;
    if (get_out(eto_o, &eto, k, 8, "e_to") < 0) goto done;
    got[0] = 1;
    if (get_out(eprev_o, &eprev, k, 8, "e_prev") < 0) goto done;
    got[1] = 1;
    if (get_out(reset_o, &reset, k, 1, "reset") < 0) goto done;
    got[2] = 1;
    if (get_buf(spm_o, &spm, 0, 4, "spm") < 0 || get_buf(pend_o, &pend, 1, 4, "pending") < 0) goto done;
    if (!spm.set || !pend.set) {
        PyErr_SetString(PyExc_TypeError, "_plan.moves: spm and pending are required");
        goto done;
    }
    for (i = 0; i < 7; i++)
        if (get_vec(o[i], &in[i], k, 0, names[i]) < 0) goto done;
    {
        const int64_t *e_to = eto.buf, *e_prev = eprev.buf;
        const char *rs = reset.buf;
        const double *sp = spm.b.buf;
        double *pending = pend.b.buf, *Dp = D.buf, *nep = ne.buf;
        char *emitted = em.buf;
        double pend_[4] = {0, 0, 0, 0};
        int in_chain = 0, pending_any = pending[0] != 0 || pending[1] != 0 || pending[2] != 0 || pending[3] != 0;
        int64_t e_at = 0;
        for (i = 0; i < k; i++) {
            double *d = Dp + 4 * i;
            d[0] = AT(in[3], i) - AT(in[0], i);
            d[1] = AT(in[4], i) - AT(in[1], i);
            d[2] = AT(in[5], i) - AT(in[2], i);
            d[3] = AT(in[6], i);
            if (!in_chain) {
                /* the move as it is (the one before it planned) */
                double xyz = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                int64_t de_steps = e_to[i] - e_prev[i];
                double st_e = xyz == 0 ? (double)(de_steps < 0 ? -de_steps : de_steps) : fabs(d[3]) * sp[3];
                double mx = np_max(np_max(fabs(d[0]) * sp[0], fabs(d[1]) * sp[1]), np_max(fabs(d[2]) * sp[2], st_e));
                if (!((i == 0 && pending_any) || mx < min_steps || mx == 0)) {
                    emitted[i] = 1;
                    nep[i] = xyz == 0 ? st_e : 0.0;
                    continue;
                }
                in_chain = 1;                       /* dropped (or a distance carried in): one at a time */
                for (c = 0; c < 4; c++) pend_[c] = i == 0 ? pending[c] : 0.0;
                e_at = e_prev[i];
            }
            if (rs[i]) e_at = e_prev[i];
            double dd[4], steps[4];
            for (c = 0; c < 4; c++) {
                dd[c] = d[c] + pend_[c];
                steps[c] = fabs(dd[c]) * sp[c];
            }
            double xj = sqrt(dd[0] * dd[0] + dd[1] * dd[1] + dd[2] * dd[2]);
            if (xj == 0) {
                int64_t q = e_to[i] - e_at;
                steps[3] = (double)(q < 0 ? -q : q);
            }
            double mx = steps[0];
            for (c = 1; c < 4; c++)
                if (steps[c] > mx) mx = steps[c];
            if (mx < min_steps || mx == 0) {
                emitted[i] = 0;
                nep[i] = 0.0;                       /* not read: a dropped move is no block */
                for (c = 0; c < 4; c++) pend_[c] = dd[c];
                continue;
            }
            for (c = 0; c < 4; c++) d[c] = dd[c];
            nep[i] = xj == 0 ? steps[3] : 0.0;
            emitted[i] = 1;
            e_at = e_to[i];
            in_chain = 0;
        }
        for (c = 0; c < 4; c++) pending[c] = in_chain ? pend_[c] : 0.0;
    }
    ret = Py_None;
    Py_INCREF(ret);
done:
    for (i = 0; i < 7; i++)
        if (in[i].set) PyBuffer_Release(&in[i].b);
    if (got[0]) PyBuffer_Release(&eto);
    if (got[1]) PyBuffer_Release(&eprev);
    if (got[2]) PyBuffer_Release(&reset);
    if (got[3]) PyBuffer_Release(&D);
    if (got[4]) PyBuffer_Release(&ne);
    if (got[5]) PyBuffer_Release(&em);
    if (spm.set) PyBuffer_Release(&spm.b);
    if (pend.set) PyBuffer_Release(&pend.b);
    return ret;
}

static PyMethodDef methods[] = {
    {"moves", moves, METH_VARARGS, "Marlin's rule for tiny moves on the scanner's moves (see the file's comment)."},
    {"segment", segment, METH_VARARGS, "Plan blocks lo..hi-1 as one segment; write k0..k1-1 (see above)."},
    {"blocks", blocks, METH_VARARGS, "Blocks' length, speed, acceleration and junction speed (see above)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_plan", NULL, -1, methods};

PyMODINIT_FUNC PyInit__plan(void) {
    PyObject *m = PyModule_Create(&module);
    /* what estimate.PLAN_VERSION expects: a module built from an older _plan.c is not used */
    if (m && PyModule_AddIntConstant(m, "VERSION", 1) < 0) { Py_DECREF(m); return NULL; }
    return m;
}
