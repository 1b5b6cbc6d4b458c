/* The estimator's planner passes (gcode/estimate.py, _plan_segment_np), compiled: for blocks that run
 * without a stop between them, the entry speeds by the backward pass (a look-ahead window of W
 * blocks, or the whole run) and the forward pass, then each block's trapezoid. Operation for
 * operation what the numpy code computes, so the numbers are the same to the bit
 * (host/tests/gcode/test_plan_c.py); built with -ffp-contract=off so that no multiply-add is fused.
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

static PyMethodDef methods[] = {
    {"segment", segment, METH_VARARGS, "Plan blocks lo..hi-1 as one segment; write k0..k1-1 (see the file's comment)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_plan", NULL, -1, methods};

PyMODINIT_FUNC PyInit__plan(void) { return PyModule_Create(&module); }
