/* The reach check's planning, compiled: the moves fallback.Skipper picks, planned lazily by
 * fallback.RefPlanner.plan (fallback._plan_lazily), for annotate's and build's check that every
 * map point is stopped at. Operation for operation what the Python code computes, in float32
 * where it computes in float32 (as the firmware's BulgePlanner) and in double where it uses
 * Python floats, so the stops and statistics are the same to the bit (host/tests/bulge/
 * test_reach_c.py, and test_movescan.py's lazy runs against planning every move); built with
 * -ffp-contract=off so that no multiply-add is fused. Only what a lazy run keeps is computed:
 * stops (where, how long, which point), statistics, the highest extruding z; no action lists.
 * Optional: without it the Python code does the work (a 100 MB file's picking and few thousand
 * planned moves: ~0.3 s of the reach check's 0.45 s).
 *
 *   st = new(zs, off, px, py, pw, q_um, lh, mode, dwell_ms, extra_e, tolerance, offsets, itemsize,
 *            lz, pz, sx, sy, margin, bypass)
 *       The planner: zs, the map's layer z (0.01 mm), strictly ascending; off, each layer's first
 *       point (len(zs) + 1 entries); px, py, pw, the points in quanta and their weights, each
 *       layer's sorted by (x, y) as RefPlanner._window sorts them (int64 buffers); the map's
 *       quantum and layer height and the M720 settings. offsets: the byte offsets of x0 y0 z0 x1
 *       y1 z1 e (float64), line_no (int32) and flags (uint8) in a record of itemsize bytes
 *       (movescan.RECORD). The Skipper: lz, every layer's z, ascending; pz, sx, sy, the points'
 *       layer z and place in mm, ascending in z and in x within a z; its box margin; bypass: arc
 *       chords are not the planner's (the firmware's view).
 *   owed = run(st, records, classes, owed)
 *       picks and plans one chunk (classes: movescan.classes' bits, one byte per record). owed:
 *       a moving move is owed a planning after the last chunk's (in) or after this one (out). The
 *       GIL is released meanwhile.
 *   (rows, owed) = pick(st, records, classes, owed)
 *       only picks (Skipper.select with followers: rows as int64 bytes) for a planner that is
 *       handed every planned move and plans in Python (the stock rewrite, the statistics).
 *   result(st) -> (stops, stats, top_z, carry, stop_ms)
 *       stops: [(line_no, x, y, z, ms, px, py, layer z)], stats: (moves_split, points_fired,
 *       extra_applied, extra_dropped, layers_loaded, dwell_ms_total), top_z: float or None. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define MIN_PIECE_MM 0.1        /* fallback.MIN_PIECE_MM */
#define MAX_DWELL_MS 2000       /* fallback.MAX_DWELL_MS */
#define MAX_EXTRA_E_MM 1.0      /* fallback.MAX_EXTRA_E_MM */
#define MODE_OFF 0
#define MODE_MARKED 1
#define OUTER 1                 /* movescan.OUTER and its other class bits (movescan.classes) */
#define ARC 2
#define NULL_MOVE 16
#define EXTRUDES_F32 32

typedef struct {
    int64_t line;
    double x, y, z;
    int64_t ms, px, py, zc;
} Stop;

typedef struct {
    double x0, y0, z0, x1, y1, z1, e;
    int64_t line;
    int outer;
} Move;

typedef struct {
    /* the map */
    Py_ssize_t nl, most;        /* layers, the most points of one layer */
    int64_t *zs, *off, *px, *py, *pw;
    uint8_t *fired;             /* per point; a layer loaded anew starts unfired */
    uint8_t *deferred;          /* per point of the loaded layer */
    Py_ssize_t ndeferred;
    int64_t lh, q_um, dwell_ms;
    int mode;
    float q_mm, tol2, extra_e;
    double margin;
    /* what fallback.Skipper picks by: every layer's z, the points' layer z (ascending) and place
     * in mm (ascending x within a z), its margin; the last candidate's z */
    Py_ssize_t nlz, npz;
    int64_t *lz, *pz;
    double *sx, *sy, sk_margin;
    int bypass, has_last_zc;
    int64_t last_zc;
    int has_near_zc;            /* the points near the last candidate's z: pz[near_lo..near_hi) */
    int64_t near_zc;
    Py_ssize_t near_lo, near_hi;
    /* the record layout */
    Py_ssize_t itemsize, o[9];
    /* the layer window */
    Py_ssize_t cur;             /* loaded layer, -1: none */
    int has_miss, has_below, has_above, has_floor;
    int64_t miss_z, below, above, floor;
    float carry;
    int64_t stop_ms;
    uint32_t last_x, last_y;    /* float bits of the last eligible move's end (points are
                                 * deferred only by one: flush never reads them unset) */
    int has_top;
    double top_z;
    /* statistics */
    int64_t moves_split, points_fired, layers_loaded, dwell_total;
    double extra_applied, extra_dropped;
    /* stops */
    Stop *stops;
    Py_ssize_t nstops, cap;
    int failed;                 /* out of memory while planning without the GIL */
} Reach;

static uint32_t bits(double v) {
    float f = (float)v;
    uint32_t u;
    memcpy(&u, &f, 4);
    return u;
}

/* RefPlanner._cmm: z in 0.01 mm as the firmware rounds it */
static int64_t cmm(double z) {
    float v32 = (float)z * 100.0f;
    double v = v32;
    return v >= 0 ? (int64_t)(v + 0.5) : -(int64_t)(0.5 - v);
}

static Py_ssize_t bisect_left(const int64_t *a, Py_ssize_t n, int64_t x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (a[mid] < x) lo = mid + 1; else hi = mid;
    }
    return lo;
}

static Py_ssize_t bisect_right(const int64_t *a, Py_ssize_t n, int64_t x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (x < a[mid]) hi = mid; else lo = mid + 1;
    }
    return lo;
}

/* RefPlanner._keeps */
static int keeps(const Reach *r, int64_t zc) {
    if (r->cur < 0) return 0;
    int64_t d = zc - r->zs[r->cur];
    if (d == 0) return 1;
    if (d > 0 && 2 * d <= r->lh && (!r->has_above || d <= r->above - zc)) return 1;
    if (d < 0 && -2 * d <= r->lh && (!r->has_below || -d < zc - r->below)) return 1;
    return 0;
}

/* RefPlanner._find: the nearest layer within half a layer height, not released; -1: none */
static Py_ssize_t find(const Reach *r, int64_t zc) {
    Py_ssize_t best = -1, i;
    int64_t best_d = 0;
    Py_ssize_t lo = r->has_floor ? bisect_left(r->zs, r->nl, r->floor) : 0;
    for (i = lo; i < r->nl; i++) {
        int64_t d = r->zs[i] - zc;
        if (d > 0 && 2 * d > r->lh) break;
        if (d < 0) d = -d;
        if (2 * d <= r->lh && (best < 0 || d < best_d)) { best = i; best_d = d; }
    }
    return best;
}

/* RefPlanner._window: load the layer for zc; whether one is loaded */
static int window(Reach *r, int64_t zc) {
    if (keeps(r, zc)) return 1;
    if (r->nl == 0) return 0;
    if (r->has_miss && zc == r->miss_z) return 0;
    Py_ssize_t i = find(r, zc);
    if (i < 0) { r->has_miss = 1; r->miss_z = zc; return 0; }
    r->has_miss = 0;
    int64_t z = r->zs[i];
    /* the neighbours, by the floor as it was (RefPlanner._neighbors) */
    Py_ssize_t b = bisect_left(r->zs, r->nl, z);
    Py_ssize_t lo = r->has_floor ? bisect_left(r->zs, r->nl, r->floor) : 0;
    Py_ssize_t j = bisect_right(r->zs, r->nl, z);
    if (j < lo) j = lo;
    r->has_below = b > lo;
    if (r->has_below) r->below = r->zs[b - 1];
    r->has_above = j < r->nl;
    if (r->has_above) r->above = r->zs[j];
    Py_ssize_t old = r->cur;
    r->cur = i;
    if (old == i) return 1;                  /* the same layer again keeps its marks */
    memset(r->fired + r->off[i], 0, (size_t)(r->off[i + 1] - r->off[i]));
    r->layers_loaded++;
    if (old < 0 || z > r->zs[old]) { r->has_floor = 1; r->floor = z; }
    return 1;
}

static Py_ssize_t layer_size(const Reach *r) { return r->cur < 0 ? 0 : r->off[r->cur + 1] - r->off[r->cur]; }

/* RefPlanner._eligible */
static int eligible(Reach *r, const Move *m) {
    if (r->mode == MODE_OFF || (r->mode == MODE_MARKED && !m->outer)) return 0;
    if (!((float)m->e > 0 && ((float)m->x0 != (float)m->x1 || (float)m->y0 != (float)m->y1))) return 0;
    return window(r, cmm(m->z1)) && layer_size(r) > 0;
}

/* RefPlanner._foot for point k (an index into the map) of the loaded layer */
static float foot(const Reach *r, Py_ssize_t k, float x0, float y0, float fdx, float fdy, float len2, int *near) {
    float ux = (float)r->px[k] * r->q_mm - x0;
    float uy = (float)r->py[k] * r->q_mm - y0;
    float t = (ux * fdx + uy * fdy) / len2;
    if (0.0f > t) t = 0.0f;                  /* max(t, 0): a NaN stays */
    float tc = t;
    if (1.0f < tc) tc = 1.0f;
    float ex = ux - tc * fdx, ey = uy - tc * fdy;
    *near = ex * ex + ey * ey <= r->tol2;
    return t;
}

/* the head's place in one plan() call: the end of its last line, else the move's start */
typedef struct { int has; double x, y, z; } Head;

/* RefPlanner._stop: point k of the loaded layer stops where the head is; the extra owed after */
static float stop(Reach *r, const Move *m, Py_ssize_t k, const Head *h, float pending) {
    r->fired[k] = 1;
    r->points_fired++;
    int64_t ms = (r->dwell_ms * r->pw[k] + 127) / 255;
    if (ms > MAX_DWELL_MS - r->stop_ms) ms = MAX_DWELL_MS - r->stop_ms;
    r->stop_ms += ms;
    r->dwell_total += ms;
    if (r->nstops == r->cap) {
        Py_ssize_t cap = r->cap ? 2 * r->cap : 256;
        Stop *s = realloc(r->stops, (size_t)cap * sizeof(Stop));
        if (!s) r->failed = 1;
        else { r->stops = s; r->cap = cap; }
    }
    if (r->nstops < r->cap) {
        Stop *s = &r->stops[r->nstops++];
        s->line = m->line;
        s->x = h->has ? h->x : m->x0;
        s->y = h->has ? h->y : m->y0;
        s->z = h->has ? h->z : m->z0;
        s->ms = ms;
        s->px = r->px[k];
        s->py = r->py[k];
        s->zc = r->zs[r->cur];
    }
    float extra = r->extra_e;
    float room = (float)MAX_EXTRA_E_MM - pending;
    if (extra > room) {
        extra = room > 0 ? room : 0.0f;
        r->extra_dropped += (double)(r->extra_e - extra);
    }
    return pending + extra;
}

/* RefPlanner._flush: the points the last move deferred */
static void flush(Reach *r, const Move *m, Head *h) {
    Py_ssize_t a = r->off[r->cur], n = layer_size(r), i;
    int at_b = bits(m->x0) == r->last_x && bits(m->y0) == r->last_y;
    int on = at_b && keeps(r, cmm(m->z1)) && r->mode != MODE_OFF && (r->mode != MODE_MARKED || m->outer)
             && (float)m->e > 0 && (bits(m->x0) != bits(m->x1) || bits(m->y0) != bits(m->y1));
    float x0 = (float)m->x0, y0 = (float)m->y0;
    float fdx = (float)m->x1 - x0, fdy = (float)m->y1 - y0;
    float len2 = fdx * fdx + fdy * fdy;
    for (i = 0; i < n; i++) {                /* in index order, as sorted(deferred) */
        if (!r->deferred[i]) continue;
        r->deferred[i] = 0;
        if (!at_b) continue;                 /* the head was moved: they stay unfired */
        int near = 0;
        if (on && len2 != 0) foot(r, a + i, x0, y0, fdx, fdy, len2, &near);
        if (on && len2 != 0 && near) continue;   /* this move's own matching takes it */
        r->carry = stop(r, m, a + i, h, r->carry);
    }
    r->ndeferred = 0;
}

typedef struct { float t; Py_ssize_t i; } Hit;

/* the end of a piece: RefPlanner.plan's line_to */
static void line_to(Reach *r, const Move *m, float t, float x0, float y0, float z0, float x1, float y1,
                    float z1, float *pending, Head *h) {
    if (t >= 1) { h->x = m->x1; h->y = m->y1; h->z = m->z1; }
    else {
        h->x = (float)(x0 + t * (x1 - x0));
        h->y = (float)(y0 + t * (y1 - y0));
        h->z = z0 == z1 ? m->z1 : (double)(float)(z0 + t * (z1 - z0));
    }
    h->has = 1;
    r->extra_applied += (double)*pending;
    *pending = 0.0f;
    r->stop_ms = 0;
}

/* RefPlanner.plan for one G0/G1 move; hits: room for the largest layer */
static void plan(Reach *r, const Move *m, Hit *hits) {
    Head h = {0, 0, 0, 0};
    if (m->e > 0 && (m->x0 != m->x1 || m->y0 != m->y1) && (!r->has_top || m->z1 > r->top_z)) {
        r->has_top = 1;
        r->top_z = m->z1;
    }
    int null = m->x0 == m->x1 && m->y0 == m->y1 && m->z0 == m->z1 && m->e == 0;
    if (r->ndeferred && !null) flush(r, m, &h);
    if (!eligible(r, m)) {
        if (!null) {                         /* a move that moves nothing keeps the owed extra */
            r->stop_ms = 0;
            if (r->carry != 0) {
                r->extra_dropped += (double)r->carry;
                r->carry = 0.0f;
            }
        }
        return;
    }
    r->last_x = bits(m->x1);
    r->last_y = bits(m->y1);
    float x0 = (float)m->x0, y0 = (float)m->y0, z0 = (float)m->z0;
    float x1 = (float)m->x1, y1 = (float)m->y1, z1 = (float)m->z1;
    float fdx = x1 - x0, fdy = y1 - y0;
    float len2 = fdx * fdx + fdy * fdy;
    float pending = r->carry;
    r->carry = 0.0f;
    /* all hits, nearest to the start first (ties: the sorted point order) */
    double q = (double)r->q_um;
    double bx0 = (m->x1 < m->x0 ? m->x1 : m->x0) - r->margin, bx1 = (m->x1 > m->x0 ? m->x1 : m->x0) + r->margin;
    double by0 = (m->y1 < m->y0 ? m->y1 : m->y0) - r->margin, by1 = (m->y1 > m->y0 ? m->y1 : m->y0) + r->margin;
    Py_ssize_t a = r->off[r->cur], n = layer_size(r), i, nh = 0;
    for (i = 0; i < n; i++) {
        Py_ssize_t k = a + i;
        if (r->fired[k]) continue;
        double xm = (double)r->px[k] * q / 1000, ym = (double)r->py[k] * q / 1000;
        if (xm < bx0 || xm > bx1 || ym < by0 || ym > by1) continue;
        int near;
        float t = foot(r, k, x0, y0, fdx, fdy, len2, &near);
        if (!near) continue;
        if (t > 1) {                         /* its foot is beyond the end: the next move decides */
            if (!r->deferred[i]) { r->deferred[i] = 1; r->ndeferred++; }
            continue;
        }
        /* insertion by t, after equal ones: a stable sort */
        Py_ssize_t j = nh++;
        while (j > 0 && hits[j - 1].t > t) { hits[j] = hits[j - 1]; j--; }
        hits[j].t = t;
        hits[j].i = k;
    }
    if (nh) r->moves_split++;
    float ln = sqrtf(len2), t_done = 0.0f, min_piece = (float)MIN_PIECE_MM;
    for (i = 0; i < nh; i++) {
        float t = hits[i].t;
        if ((t - t_done) * ln < min_piece) {
            /* stop where the head already is */
        } else {
            if ((1.0f - t) * ln < min_piece) t = 1.0f;
            line_to(r, m, t, x0, y0, z0, x1, y1, z1, &pending, &h);
            t_done = t;
        }
        pending = stop(r, m, hits[i].i, &h, pending);
    }
    if (t_done < 1) line_to(r, m, 1.0f, x0, y0, z0, x1, y1, z1, &pending, &h);
    else r->carry = r->carry + pending;
}

/* fallback._clean: nothing owed to the next move */
static int clean(const Reach *r) { return r->ndeferred == 0 && r->carry == 0 && r->stop_ms == 0; }

static void reach_free(PyObject *cap) {
    Reach *r = PyCapsule_GetPointer(cap, "bulgekit.reach");
    if (!r) return;
    free(r->zs); free(r->off); free(r->px); free(r->py); free(r->pw);
    free(r->fired); free(r->deferred); free(r->stops);
    free(r->lz); free(r->pz); free(r->sx); free(r->sy);
    free(r);
}

/* a copy of an int64 buffer of n items (n < 0: any length, returned in *n) */
static int64_t *copy_i64(PyObject *o, Py_ssize_t *n, const char *name) {
    Py_buffer b;
    if (PyObject_GetBuffer(o, &b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return NULL;
    int ok = b.itemsize == 8 && b.format && (strcmp(b.format, "q") == 0 || strcmp(b.format, "l") == 0)
             && (*n < 0 || b.len / 8 == *n);
    int64_t *out = NULL;
    if (!ok) PyErr_Format(PyExc_ValueError, "_reach.new: %s must be int64%s", name, *n < 0 ? "" : " of the right length");
    else {
        *n = b.len / 8;
        out = malloc((size_t)(*n ? *n : 1) * 8);
        if (!out) PyErr_NoMemory();
        else memcpy(out, b.buf, (size_t)*n * 8);
    }
    PyBuffer_Release(&b);
    return out;
}

/* a copy of a float64 buffer of n items */
static double *copy_f64(PyObject *o, Py_ssize_t n, const char *name) {
    Py_buffer b;
    if (PyObject_GetBuffer(o, &b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return NULL;
    double *out = NULL;
    if (b.itemsize != 8 || !b.format || strcmp(b.format, "d") != 0 || b.len / 8 != n)
        PyErr_Format(PyExc_ValueError, "_reach.new: %s must be float64 of the right length", name);
    else if (!(out = malloc((size_t)(n ? n : 1) * 8))) PyErr_NoMemory();
    else memcpy(out, b.buf, (size_t)n * 8);
    PyBuffer_Release(&b);
    return out;
}

static PyObject *new_reach(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *ozs, *ooff, *opx, *opy, *opw, *ooffs, *olz, *opz, *osx, *osy;
    long long q_um, lh, mode, dwell_ms;
    double extra_e, tol, sk_margin;
    Py_ssize_t itemsize;
    int bypass;
    if (!PyArg_ParseTuple(args, "OOOOOLLLLddOnOOOOdp", &ozs, &ooff, &opx, &opy, &opw, &q_um, &lh, &mode,
                          &dwell_ms, &extra_e, &tol, &ooffs, &itemsize, &olz, &opz, &osx, &osy,
                          &sk_margin, &bypass))
        return NULL;
    Reach *r = calloc(1, sizeof(Reach));
    if (!r) return PyErr_NoMemory();
    PyObject *cap = PyCapsule_New(r, "bulgekit.reach", reach_free);
    if (!cap) { free(r); return NULL; }
    Py_ssize_t nl = -1, noff, np = -1, i;
    if (!(r->zs = copy_i64(ozs, &nl, "zs"))) goto fail;
    r->nl = nl;
    noff = nl + 1;
    if (!(r->off = copy_i64(ooff, &noff, "off"))) goto fail;
    if (!(r->px = copy_i64(opx, &np, "px"))) goto fail;
    if (!(r->py = copy_i64(opy, &np, "py")) || !(r->pw = copy_i64(opw, &np, "pw"))) goto fail;
    for (i = 0; i < nl; i++)
        if ((i && r->zs[i] <= r->zs[i - 1]) || r->off[i] < 0 || r->off[i] > r->off[i + 1]) break;
    if (i < nl || (nl && r->off[0] != 0) || r->off[nl] != np) {
        PyErr_SetString(PyExc_ValueError, "_reach.new: zs must be strictly ascending and off must bound the points");
        goto fail;
    }
    Py_ssize_t most = 0;
    for (i = 0; i < nl; i++) if (r->off[i + 1] - r->off[i] > most) most = r->off[i + 1] - r->off[i];
    r->most = most;
    r->fired = calloc((size_t)(np ? np : 1), 1);
    r->deferred = calloc((size_t)(most ? most : 1), 1);
    if (!r->fired || !r->deferred) { PyErr_NoMemory(); goto fail; }
    if (!PyArg_ParseTuple(ooffs, "nnnnnnnnn", &r->o[0], &r->o[1], &r->o[2], &r->o[3], &r->o[4], &r->o[5],
                          &r->o[6], &r->o[7], &r->o[8]))
        goto fail;
    for (i = 0; i < 9; i++)
        if (r->o[i] < 0 || r->o[i] + (i < 7 ? 8 : i == 7 ? 4 : 1) > itemsize) {
            PyErr_SetString(PyExc_ValueError, "_reach.new: a field offset lies outside the record");
            goto fail;
        }
    Py_ssize_t nlz = -1, npz = -1;
    if (!(r->lz = copy_i64(olz, &nlz, "lz")) || !(r->pz = copy_i64(opz, &npz, "pz"))) goto fail;
    r->nlz = nlz;
    r->npz = npz;
    if (!(r->sx = copy_f64(osx, npz, "sx")) || !(r->sy = copy_f64(osy, npz, "sy"))) goto fail;
    for (i = 1; i < nlz && r->lz[i - 1] <= r->lz[i]; i++) {}
    if (nlz > 1 && i < nlz) goto unsorted;
    for (i = 1; i < npz && (r->pz[i - 1] < r->pz[i] || (r->pz[i - 1] == r->pz[i] && r->sx[i - 1] <= r->sx[i])); i++) {}
    if (npz > 1 && i < npz) goto unsorted;
    r->sk_margin = sk_margin;
    r->bypass = bypass;
    r->itemsize = itemsize;
    r->q_um = q_um; r->lh = lh; r->mode = (int)mode; r->dwell_ms = dwell_ms;
    r->q_mm = (float)q_um * (float)0.001;
    r->tol2 = (float)tol * (float)tol;
    r->margin = tol + (double)(3 * q_um) / 1000;
    r->extra_e = (float)extra_e;
    r->cur = -1;
    return cap;
unsorted:
    PyErr_SetString(PyExc_ValueError, "_reach.new: lz must ascend, and pz with sx within each z");
fail:
    Py_DECREF(cap);
    return NULL;
}

static void read_move(const Reach *r, const char *rec, Move *m) {
    double v[7];
    int k;
    for (k = 0; k < 7; k++) memcpy(&v[k], rec + r->o[k], 8);
    int32_t line;
    memcpy(&line, rec + r->o[7], 4);
    m->x0 = v[0]; m->y0 = v[1]; m->z0 = v[2]; m->x1 = v[3]; m->y1 = v[4]; m->z1 = v[5]; m->e = v[6];
    m->line = line;
    m->outer = (((const uint8_t *)rec)[r->o[8]] & OUTER) != 0;
}

/* the first index of a[lo..hi) not below v (numpy's searchsorted, side left), or above it (right) */
static Py_ssize_t first_at_least(const int64_t *a, Py_ssize_t lo, Py_ssize_t hi, double v) {
    while (lo < hi) { Py_ssize_t mid = (lo + hi) / 2; if ((double)a[mid] < v) lo = mid + 1; else hi = mid; }
    return lo;
}
static Py_ssize_t first_above(const int64_t *a, Py_ssize_t lo, Py_ssize_t hi, double v) {
    while (lo < hi) { Py_ssize_t mid = (lo + hi) / 2; if ((double)a[mid] <= v) lo = mid + 1; else hi = mid; }
    return lo;
}

/* Skipper._near for one candidate: a map point of a layer within half a layer height of zc lies in
 * its box widened by the margin. The points of one z ascend in x: only those from bx0 on are
 * looked at. */
static int near_point(Reach *r, const Move *m, int64_t zc) {
    if (!r->has_near_zc || zc != r->near_zc) {   /* (a file's moves come in runs of one z) */
        double half = (double)r->lh / 2;
        r->near_lo = first_at_least(r->pz, 0, r->npz, (double)zc - half);
        r->near_hi = first_above(r->pz, r->near_lo, r->npz, (double)zc + half);
        r->has_near_zc = 1;
        r->near_zc = zc;
    }
    Py_ssize_t lo = r->near_lo, hi = r->near_hi;
    double bx0 = (m->x1 < m->x0 ? m->x1 : m->x0) - r->sk_margin, bx1 = (m->x1 > m->x0 ? m->x1 : m->x0) + r->sk_margin;
    double by0 = (m->y1 < m->y0 ? m->y1 : m->y0) - r->sk_margin, by1 = (m->y1 > m->y0 ? m->y1 : m->y0) + r->sk_margin;
    while (lo < hi) {
        Py_ssize_t end = first_above(r->pz, lo, hi, (double)r->pz[lo]);      /* this z's points */
        Py_ssize_t a = lo, b = end;
        while (a < b) { Py_ssize_t mid = (a + b) / 2; if (r->sx[mid] < bx0) a = mid + 1; else b = mid; }
        for (; a < end && r->sx[a] <= bx1; a++)
            if (r->sy[a] >= by0 && r->sy[a] <= by1) return 1;
        lo = end;
    }
    return 0;
}

/* Skipper.select(a, followers=False) on one chunk's records and class bits: the rows to plan
 * (candidates that reach a new z with a map layer near, or pass near a map point) and the
 * moving rows the planner sees */
static void select_rows(Reach *r, const char *base, Py_ssize_t n, const uint8_t *cls, int64_t *picked,
                        Py_ssize_t *npicked, int64_t *moving, Py_ssize_t *nmoving) {
    Py_ssize_t i, np_ = 0, nm = 0;
    int want = EXTRUDES_F32 | (r->mode == MODE_MARKED ? OUTER : 0);
    int any = r->mode != MODE_OFF && r->npz > 0;
    double half = (double)r->lh / 2;
    for (i = 0; i < n; i++) {
        int c = cls[i];
        int seen = !r->bypass || !(c & ARC);
        if (!seen) continue;
        if (!(c & NULL_MOVE)) moving[nm++] = i;
        if (!any || (c & want) != want) continue;
        Move m;
        read_move(r, base + i * r->itemsize, &m);
        int64_t zc = cmm(m.z1);
        int pick = 0;
        if (!r->has_last_zc || zc != r->last_zc) {
            /* a new z with no map layer within half a layer height cannot load or switch the
             * window: planned, it would only miss */
            Py_ssize_t lo = first_at_least(r->lz, 0, r->nlz, (double)zc - half);
            pick = first_above(r->lz, lo, r->nlz, (double)zc + half) > lo;
        }
        r->has_last_zc = 1;
        r->last_zc = zc;
        if (pick || near_point(r, &m, zc)) picked[np_++] = i;
    }
    *npicked = np_;
    *nmoving = nm;
}

/* run's and pick's arguments (st, records, classes, owed): the planner, the two buffers (held:
 * the caller releases them) and the records' count; NULL with an exception */
static Reach *chunk_args(PyObject *args, const char *name, Py_buffer *rec, Py_buffer *cls, int *owed,
                         Py_ssize_t *n) {
    PyObject *cap, *orec, *ocls;
    if (!PyArg_ParseTuple(args, "OOOp", &cap, &orec, &ocls, owed)) return NULL;
    Reach *r = PyCapsule_GetPointer(cap, "bulgekit.reach");
    if (!r) return NULL;
    if (PyObject_GetBuffer(orec, rec, PyBUF_C_CONTIGUOUS) < 0) return NULL;
    if (PyObject_GetBuffer(ocls, cls, PyBUF_C_CONTIGUOUS) < 0) { PyBuffer_Release(rec); return NULL; }
    *n = rec->len / r->itemsize;
    if (rec->len % r->itemsize != 0 || cls->len != *n) {
        PyBuffer_Release(rec); PyBuffer_Release(cls);
        PyErr_Format(PyExc_ValueError, "_reach.%s: need whole records and one class byte each", name);
        return NULL;
    }
    return r;
}

static PyObject *run(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer rec, cls;
    int owed;
    Py_ssize_t n;
    Reach *r = chunk_args(args, "run", &rec, &cls, &owed, &n);
    if (!r) return NULL;
    int64_t *todo = malloc((size_t)(n ? n : 1) * 8), *moving = malloc((size_t)(n ? n : 1) * 8);
    Hit *hits = malloc((size_t)(r->most ? r->most : 1) * sizeof(Hit));
    if (!todo || !moving || !hits) {
        free(todo); free(moving); free(hits);
        PyBuffer_Release(&rec); PyBuffer_Release(&cls);
        return PyErr_NoMemory();
    }
    Py_BEGIN_ALLOW_THREADS
    const char *base = rec.buf;
    Py_ssize_t ntodo, nmov;
    select_rows(r, base, n, cls.buf, todo, &ntodo, moving, &nmov);
    /* fallback._plan_lazily: the picked rows in order; after a move that leaves something owed,
     * the next moving row too */
    Py_ssize_t k = 0, last = -1;
    int follow = owed;
    for (;;) {
        Py_ssize_t row;
        if (follow) {
            Py_ssize_t lo = 0, hi = nmov;    /* the first moving row after the last one planned */
            while (lo < hi) {
                Py_ssize_t mid = (lo + hi) / 2;
                if (moving[mid] <= last) lo = mid + 1; else hi = mid;
            }
            if (lo == nmov) break;           /* owed to the next chunk's first moving move */
            row = moving[lo];
            if (k < ntodo && todo[k] == row) k++;
        } else if (k < ntodo) row = todo[k++];
        else break;
        Move m;
        read_move(r, base + row * r->itemsize, &m);
        plan(r, &m, hits);
        last = row;
        follow = !clean(r);
    }
    owed = follow;
    Py_END_ALLOW_THREADS
    free(todo); free(moving); free(hits);
    PyBuffer_Release(&rec); PyBuffer_Release(&cls);
    if (r->failed) return PyErr_NoMemory();
    return PyBool_FromLong(owed);
}

/* fallback.Skipper.select(a) with its followers: the rows a planner that is handed every planned
 * move (the stock rewrite, the statistics) plans in Python; (rows as int64 bytes, owed). */
static PyObject *pick(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer rec, cls;
    int owed;
    Py_ssize_t n, ntodo = 0, nmov = 0, nout = 0, np_ = 0, nf = 0, i, j;
    Reach *r = chunk_args(args, "pick", &rec, &cls, &owed, &n);
    if (!r) return NULL;
    int64_t *todo = malloc((size_t)(n ? n : 1) * 8), *moving = malloc((size_t)(n ? n : 1) * 8),
            *P = malloc((size_t)(n + 1) * 8), *F = malloc((size_t)(n + 1) * 8),
            *out = malloc((size_t)(2 * n + 2) * 8);
    if (!todo || !moving || !P || !F || !out) {
        free(todo); free(moving); free(P); free(F); free(out);
        PyBuffer_Release(&rec); PyBuffer_Release(&cls);
        return PyErr_NoMemory();
    }
    Py_BEGIN_ALLOW_THREADS
    select_rows(r, rec.buf, n, cls.buf, todo, &ntodo, moving, &nmov);
    /* the picked rows, and the chunk's first moving row when one is owed to it */
    int first = owed && nmov > 0;
    for (i = 0; i < ntodo; i++) {
        if (first && moving[0] <= todo[i]) {
            if (moving[0] < todo[i]) P[np_++] = moving[0];
            first = 0;
        }
        P[np_++] = todo[i];
    }
    if (first) P[np_++] = moving[0];
    /* each one's follower: the first moving row after it (in order, as the rows are) */
    for (i = 0, j = 0; i < np_; i++) {
        while (j < nmov && moving[j] <= P[i]) j++;
        if (j < nmov) F[nf++] = moving[j];
    }
    /* both, in order and once each (numpy: pick[...] = True) */
    Py_ssize_t a = 0, b = 0;
    while (a < np_ || b < nf) {
        int64_t v = (b >= nf || (a < np_ && P[a] <= F[b])) ? P[a++] : F[b++];
        if (!nout || v > out[nout - 1]) out[nout++] = v;
    }
    if (np_)                                 /* a picked row with no moving row after it */
        owed = nmov == 0 || P[np_ - 1] >= moving[nmov - 1];
    Py_END_ALLOW_THREADS
    free(P); free(F);
    PyObject *rows = PyBytes_FromStringAndSize((const char *)out, nout * 8);
    free(todo); free(moving); free(out);
    PyBuffer_Release(&rec); PyBuffer_Release(&cls);
    if (!rows) return NULL;
    return Py_BuildValue("(Ni)", rows, owed);
}

static PyObject *result(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *cap;
    if (!PyArg_ParseTuple(args, "O", &cap)) return NULL;
    Reach *r = PyCapsule_GetPointer(cap, "bulgekit.reach");
    if (!r) return NULL;
    PyObject *stops = PyList_New(r->nstops);
    if (!stops) return NULL;
    Py_ssize_t i;
    for (i = 0; i < r->nstops; i++) {
        const Stop *s = &r->stops[i];
        PyObject *t = Py_BuildValue("(LdddLLLL)", (long long)s->line, s->x, s->y, s->z, (long long)s->ms,
                                    (long long)s->px, (long long)s->py, (long long)s->zc);
        if (!t) { Py_DECREF(stops); return NULL; }
        PyList_SET_ITEM(stops, i, t);
    }
    PyObject *top = r->has_top ? PyFloat_FromDouble(r->top_z) : (Py_INCREF(Py_None), Py_None);
    return Py_BuildValue("(N(LLddLL)NdL)", stops, (long long)r->moves_split, (long long)r->points_fired,
                         r->extra_applied, r->extra_dropped, (long long)r->layers_loaded,
                         (long long)r->dwell_total, top, (double)r->carry, (long long)r->stop_ms);
}

static PyMethodDef methods[] = {
    {"new", new_reach, METH_VARARGS, "A reach planner for a map (see the file's comment)."},
    {"run", run, METH_VARARGS, "Pick and plan one chunk's rows lazily; whether a move is owed on."},
    {"pick", pick, METH_VARARGS, "The rows Skipper.select(a) picks, and whether a move is owed on."},
    {"result", result, METH_VARARGS, "(stops, stats, top_z, carry, stop_ms)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_reach", NULL, -1, methods};

PyMODINIT_FUNC PyInit__reach(void) {
    PyObject *m = PyModule_Create(&module);
    /* what fallback.REACH_VERSION expects: a module built from an older _reach.c is not used */
    if (m && PyModule_AddIntConstant(m, "VERSION", 1) < 0) { Py_DECREF(m); return NULL; }
    return m;
}
