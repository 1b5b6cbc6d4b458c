/* Fast G-code move scanner: the C twin of gcode.parse_lines for the passes that only need moves.
 *
 * A Scanner keeps the machine state (positions, G90/G91, M82/M83, the feature role) across the
 * chunks of one file and turns each chunk's complete lines into fixed-size move records, one per
 * G0/G1 and one per chord of a G2/G3 (Marlin's segments, gcode.arc_segments), with exactly the numbers gcode/__init__.py
 * computes: the same line splitting (\n, \r\n and a lone \r, as Python's universal newlines), the
 * same words (letters split words, so "1e5" is two words), decimal values converted by strtod
 * (correctly rounded, as float()), the same arc arithmetic (math.hypot is Python's own, so it is
 * called here too).
 *
 * What it does not handle it refuses instead of guessing: a command line with a byte >= 0x80, a
 * value gcode/__init__.py would reject, an arc gcode/__init__.py would reject. feed() then raises
 * ScanUnsupported(line) and the caller reads the file with gcode/__init__.py, which gives the same moves
 * or the error message with file and line. Comment lines with bytes >= 0x80 are classified by
 * the Python function given to the Scanner (gcode.split_code + feature_of_comment), so their
 * roles are exact too.
 *
 * feed() parses without the GIL, so that another thread runs Python meanwhile (movescan reads and
 * scans the next part of a file while the passes work on this one); hold() takes the GIL back for
 * the few lines that need Python (a new role name, a non-ASCII line, an arc's math.hypot, an
 * error). One Scanner is for one thread at a time: a feed() while another thread's runs raises
 * RuntimeError, and its attributes are only meaningful between feeds.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

/* One move. Python reads these as a numpy structured array (gcode_fast.RECORD). */
typedef struct {
    double x0, y0, z0, x1, y1, z1;
    double e;        /* filament of this move (end E - start E) */
    double e_start;  /* E at its start */
    double f;        /* mm/min */
    int64_t offset;  /* byte offset of its line in the file (feed()'s base + in its buffer) */
    int32_t line_no; /* 1-based */
    int16_t role;    /* index into Scanner.roles, -1: none yet */
    uint8_t flags;   /* 1: outer wall, 2: chord of an arc, 4: G90 (else G91), 8: M82 (else M83) */
    uint8_t pad;
} Record;

#define MAX_ROLES 1024

typedef struct {
    PyObject_HEAD
    double x, y, z, e, f;
    int abs_xyz, abs_e;
    int role;          /* -1: none */
    int outer;
    long line_no;      /* lines done so far */
    int pending_cr;    /* the last chunk ended in '\r': a '\n' starting the next one belongs to it */
    PyObject *roles;   /* list of str */
    PyObject *outer_roles;  /* frozenset of str */
    PyObject *s3d_roles;    /* frozenset of str */
    PyObject *classify;     /* callable(str) -> (has_code: bool, role: str | None) */
    PyObject *hypot;        /* math.hypot */
    /* the roles' and Simplify3D tags' names as UTF-8, so that looking one up needs no GIL */
    char *role_name[MAX_ROLES];
    Py_ssize_t role_len[MAX_ROLES];
    unsigned char role_outer[MAX_ROLES];
    int n_roles;
    char **s3d_name;
    Py_ssize_t *s3d_len;
    Py_ssize_t n_s3d;
    PyThreadState *ts; /* feed() runs without the GIL: its thread state, for hold() */
    int needed;        /* hold() was called (feed() keeps the GIL a while after) */
    int busy;          /* in feed() */
    long long arcs;    /* G2/G3 lines read so far */
    int events;        /* gcode/estimate.py's mode: see event_line() */
    int lean;          /* annotate's reach check in marked mode (1), build's passes (2): see emit() */
    long long moves;   /* records made so far, kept or not (lean 2: each kept one's number) */
    int follow;        /* lean: a move since the last outer-wall one may be owed a record */
    int have_top;      /* lean: the highest z1 of this feed's moves that extrude in XY, not on */
    double top;        /* an arc (movescan.classes' top_not_arc, of every move, emitted or not) */
    int quiet;         /* the line is an event: its moves change the state, no records */
    long flagged;      /* lines that may be gcode.check_not_processed's or an M92 (see flag()) */
    long long n_lf, n_cr, n_crlf;   /* line-end bytes consumed: '\n', '\r', "\r\n" pairs */
    /* output */
    Record *out;
    int64_t *nums;     /* lean 2: the move number of each record of out */
    Py_ssize_t n, cap, ncap;
    const char *base;
    long long base_offset;
} Scanner;

static PyObject *ScanUnsupported;

static int is_ws(unsigned char c) {
    /* str.strip()'s ASCII whitespace */
    return c == ' ' || (c >= '\t' && c <= '\r') || (c >= 0x1c && c <= 0x1f);
}

/* Takes the GIL back (if feed() let it go) before any call into Python. */
static void hold(Scanner *s) {
    s->needed = 1;
    if (s->ts) {
        PyThreadState *ts = s->ts;
        s->ts = NULL;
        PyEval_RestoreThread(ts);
    }
}

/* Room for one more record (and its number, lean 2); the rare part of push(), out of its way. */
#if defined(__GNUC__) || defined(__clang__)
#define COLD __attribute__((noinline, cold))
#else
#define COLD
#endif

static COLD int grow(Scanner *s) {
    Py_ssize_t cap = s->cap ? s->cap * 2 : 4096;
    Record *p = PyMem_RawRealloc(s->out, (size_t)cap * sizeof(Record));   /* (no GIL needed) */
    if (!p) { hold(s); PyErr_NoMemory(); return -1; }
    s->out = p;
    s->cap = cap;
    if (s->lean == 2) {
        int64_t *q = PyMem_RawRealloc(s->nums, (size_t)cap * sizeof(int64_t));  /* (no GIL) */
        if (!q) { hold(s); PyErr_NoMemory(); return -1; }
        s->nums = q;
        s->ncap = cap;
    }
    return 0;
}

/* The next record's place in the output (NULL: no memory, the error set). */
static inline Record *slot(Scanner *s) {
    if (s->n == s->cap && grow(s) < 0) return NULL;
    if (s->lean == 2) s->nums[s->n] = s->moves;
    return &s->out[s->n++];
}

static int push(Scanner *s, Record *r) {
    Record *o = slot(s);
    if (!o) return -1;
    *o = *r;
    return 0;
}

static int unsupported(Scanner *s) {
    hold(s);
    PyObject *v = PyLong_FromLong(s->line_no);
    if (v) { PyErr_SetObject(ScanUnsupported, v); Py_DECREF(v); }
    return -1;
}

/* Index of a role name (UTF-8), added to the list when new; sets s->outer. */
static int set_role(Scanner *s, const char *name, Py_ssize_t len) {
    /* name is valid UTF-8 (ASCII, or from a str): the list's names are its own bytes */
    int n = s->n_roles;
    for (int i = 0; i < n; i++) {
        if (s->role_len[i] == len && memcmp(s->role_name[i], name, (size_t)len) == 0) {
            s->role = i;
            s->outer = s->role_outer[i];
            return 0;
        }
    }
    if (n >= MAX_ROLES) return unsupported(s);
    hold(s);
    char *copy = PyMem_RawMalloc((size_t)len + 1);
    if (!copy) { PyErr_NoMemory(); return -1; }
    memcpy(copy, name, (size_t)len);
    PyObject *str = PyUnicode_DecodeUTF8(name, len, "replace");
    if (!str) { PyMem_RawFree(copy); return -1; }
    int r = PyList_Append(s->roles, str);
    int o = PySet_Contains(s->outer_roles, str);
    Py_DECREF(str);
    if (r < 0 || o < 0) { PyMem_RawFree(copy); return -1; }
    s->role_name[n] = copy;
    s->role_len[n] = len;
    s->role_outer[n] = (unsigned char)(o == 1);
    s->n_roles = n + 1;
    s->role = n;
    s->outer = o;
    return 0;
}

static void free_roles(Scanner *s) {
    for (int i = 0; i < s->n_roles; i++) PyMem_RawFree(s->role_name[i]);
    s->n_roles = 0;
    for (Py_ssize_t i = 0; i < s->n_s3d; i++) PyMem_RawFree(s->s3d_name[i]);
    PyMem_RawFree(s->s3d_name);
    PyMem_RawFree(s->s3d_len);
    s->s3d_name = NULL;
    s->s3d_len = NULL;
    s->n_s3d = 0;
}

/* A whole-line comment, ASCII (gcode.feature_of_comment). */
static int comment_role(Scanner *s, const char *c, const char *end) {
    while (c < end && is_ws((unsigned char)*c)) c++;
    Py_ssize_t len = end - c;
    const char *v = NULL;
    if (len >= 5 && memcmp(c, "TYPE:", 5) == 0) v = c + 5;
    else if (len >= 8 && memcmp(c, "FEATURE:", 8) == 0) v = c + 8;
    if (v == NULL) {
        /* Simplify3D's bare tags are lower-case words: other slicers' comments (";LAYER_CHANGE",
         * ";Z:0.3", ";WIDTH:0.45" ...) need no lookup */
        if (len == 0 || len > 64 || c[0] < 'a' || c[0] > 'z') return 0;
        for (Py_ssize_t i = 0; i < s->n_s3d; i++)     /* (the line is ASCII: bytes compare as str) */
            if (s->s3d_len[i] == len && memcmp(s->s3d_name[i], c, (size_t)len) == 0)
                return set_role(s, c, len);
        return 0;
    }
    while (v < end && is_ws((unsigned char)*v)) v++;
    char buf[256];
    Py_ssize_t l = end - v;
    if (l >= (Py_ssize_t)sizeof buf) return unsupported(s);
    for (Py_ssize_t i = 0; i < l; i++) {
        char ch = v[i];
        buf[i] = (ch >= 'A' && ch <= 'Z') ? (char)(ch + 32) : ch;
    }
    return set_role(s, buf, l);
}

/* A line with bytes >= 0x80: a comment is classified by the Python side, a command refused. */
static int foreign_line(Scanner *s, const char *p, const char *end) {
    hold(s);
    PyObject *text = PyUnicode_DecodeUTF8(p, end - p, "replace");
    if (!text) return -1;
    PyObject *r = PyObject_CallOneArg(s->classify, text);
    Py_DECREF(text);
    if (!r) return -1;
    if (!PyTuple_Check(r) || PyTuple_GET_SIZE(r) != 2) {
        Py_DECREF(r);
        PyErr_SetString(PyExc_TypeError, "classify must return (has_code, role)");
        return -1;
    }
    int has_code = PyObject_IsTrue(PyTuple_GET_ITEM(r, 0));
    PyObject *role = PyTuple_GET_ITEM(r, 1);
    int rc = 0;
    if (has_code) rc = unsupported(s);
    else if (role != Py_None) {
        Py_ssize_t l;
        const char *t = PyUnicode_AsUTF8AndSize(role, &l);
        rc = t ? set_role(s, t, l) : -1;
    }
    Py_DECREF(r);
    return rc;
}

typedef struct {
    unsigned have;     /* bit per letter A..Z */
    double v[26];
} Words;

#define HAS(w, L) ((w)->have & (1u << ((L) - 'A')))
#define GET(w, L) ((w)->v[(L) - 'A'])

/* gcode.parse_words: letters start words, a word runs to the next letter or blank; a first N is
 * skipped; a value must match gcode._NUM (else refused: gcode/__init__.py names the bad word). */
static int parse_words(Scanner *s, const char *p, const char *end, Words *w) {
    w->have = 0;
    while (p < end) {
        char ch = *p;
        if (ch >= 'a' && ch <= 'z') ch = (char)(ch - 32);
        if (ch < 'A' || ch > 'Z') { p++; continue; }
        const char *v = ++p;
        if (ch == 'N' && w->have == 0) {      /* a line number: skipped, not read */
            while (p < end && !is_ws((unsigned char)*p) &&
                   !((*p >= 'A' && *p <= 'Z') || (*p >= 'a' && *p <= 'z'))) p++;
            continue;
        }
        /* [-+]?(\d+\.?\d*|\.\d+), read as it is matched: the digits as an integer */
        const char *q = v;
        if (q < end && (*q == '-' || *q == '+')) q++;
        const char *d0 = q;
        uint64_t m = 0;
        while (q < end && *q >= '0' && *q <= '9') m = m * 10 + (uint64_t)(*q++ - '0');
        int lead = (int)(q - d0);
        int frac = 0;
        if (q < end && *q == '.') {
            q++;
            const char *f0 = q;
            while (q < end && *q >= '0' && *q <= '9') m = m * 10 + (uint64_t)(*q++ - '0');
            frac = (int)(q - f0);
        }
        /* the word runs to the next letter or blank: anything else in it is refused */
        p = q;
        while (p < end && !is_ws((unsigned char)*p) &&
               !((*p >= 'A' && *p <= 'Z') || (*p >= 'a' && *p <= 'z'))) p++;
        if (q != p || (lead == 0 && frac == 0)) return unsupported(s);
        if (lead + frac <= 15) {
            /* Up to 15 digits: the digits as an integer (< 2^53, exact) over a power of ten
             * (<= 1e15, exact): one correctly rounded division, strtod's result (Clinger). */
            static const double p10[16] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8,
                                           1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15};
            double val = (double)m / p10[frac];
            w->v[ch - 'A'] = (*v == '-') ? -val : val;
            w->have |= 1u << (ch - 'A');
            continue;
        }
        char buf[64];
        if (p - v >= (Py_ssize_t)sizeof buf) return unsupported(s);
        memcpy(buf, v, (size_t)(p - v));
        buf[p - v] = 0;
        w->v[ch - 'A'] = strtod(buf, NULL);
        w->have |= 1u << (ch - 'A');
    }
    return 0;
}

static void target(Scanner *s, Words *w, double *x, double *y, double *z, double *e) {
    if (s->abs_xyz) {
        *x = HAS(w, 'X') ? GET(w, 'X') : s->x;
        *y = HAS(w, 'Y') ? GET(w, 'Y') : s->y;
        *z = HAS(w, 'Z') ? GET(w, 'Z') : s->z;
    } else {
        *x = s->x + (HAS(w, 'X') ? GET(w, 'X') : 0.0);
        *y = s->y + (HAS(w, 'Y') ? GET(w, 'Y') : 0.0);
        *z = s->z + (HAS(w, 'Z') ? GET(w, 'Z') : 0.0);
    }
    *e = s->abs_e ? (HAS(w, 'E') ? GET(w, 'E') : s->e) : s->e + (HAS(w, 'E') ? GET(w, 'E') : 0.0);
}

static int emit(Scanner *s, const char *line, double x, double y, double z, double e, int arc) {
    Record r;
    r.x0 = s->x; r.y0 = s->y; r.z0 = s->z;
    r.x1 = x; r.y1 = y; r.z1 = z;
    r.e = e - s->e;
    r.e_start = s->e;
    r.f = s->f;
    r.offset = (int64_t)(s->base_offset + (line - s->base));
    r.line_no = (int32_t)s->line_no;
    r.role = (int16_t)s->role;
    r.flags = (uint8_t)((s->outer ? 1 : 0) | (arc ? 2 : 0) | (s->abs_xyz ? 4 : 0) | (s->abs_e ? 8 : 0));
    r.pad = 0;
    int keep = !s->quiet;
    if (keep && s->lean) {
        /* Only the records annotate's lazy reach check can plan (fallback._plan_lazily): every
         * outer-wall move, every extruding arc chord (RefPlanner.bypass), and the first move
         * after an outer-wall one that moves anything and is no arc chord (the one planned when
         * something is owed; a move outside the wall leaves nothing owed). The top z of the
         * moves left out is kept here. lean 2 (build's passes, movescan.Scan): every arc chord
         * too (a planner that plans chords may owe one to a travel arc), each numbered. */
        int moved = r.x0 != r.x1 || r.y0 != r.y1;
        if (moved && r.e > 0 && !arc && (!s->have_top || r.z1 > s->top || isnan(r.z1)))
            s->top = r.z1, s->have_top = 1;      /* numpy's max: a NaN wins */
        int null = !moved && r.z0 == r.z1 && r.e == 0;
        if (s->outer) s->follow = 1;
        else if (arc) keep = r.e > 0 || s->lean == 2;
        else if (s->follow && !null) s->follow = 0;
        else keep = 0;
    }
    if (keep && push(s, &r) < 0) return -1;
    if (!s->quiet) s->moves++;
    s->x = x; s->y = y; s->z = z; s->e = e;
    return 0;
}

/* Events mode (gcode/estimate.py): a line the estimator reads itself gets a record of its own, flags
 * 16, at its offset and line, holding the state before it (no move: x1.. = x0.., e = 0). Plain
 * moves keep their records: G0/G1/G00/G01 whose words, split at blanks, are each one letter of
 * X Y Z E F and a number as gcode._NUM takes it (so float() reads the same), F not 0, no '*' or
 * '(', and whose comment, if any, is not one the estimator reads (TYPE:, LAYER...). Every other
 * line with a command, and such comments, are events. */
static int is_event(Scanner *s, const char *p, const char *end) {
    const char *semi = memchr(p, ';', (size_t)(end - p));
    if (semi) {
        const char *c = semi + 1;
        while (c < end && is_ws((unsigned char)*c)) c++;
        if ((end - c >= 5 && memcmp(c, "TYPE:", 5) == 0) || (end - c >= 5 && memcmp(c, "LAYER", 5) == 0))
            return 1;
        end = semi;
    }
    while (p < end && is_ws((unsigned char)*p)) p++;
    while (end > p && is_ws((unsigned char)end[-1])) end--;
    if (p == end) return 0;                          /* blank or a comment the estimator skips */
    for (const char *q = p; q < end; q++)
        if (*q == '*' || *q == '(') return 1;
    const char *h = p;
    while (p < end && !is_ws((unsigned char)*p)) p++;
    if (*h == 'N' || *h == 'n') {                    /* a line number: the next word is the command */
        while (p < end && is_ws((unsigned char)*p)) p++;
        if (p == end) return 1;
        h = p;
        while (p < end && !is_ws((unsigned char)*p)) p++;
    }
    Py_ssize_t hl = p - h;
    if (!((*h == 'G' || *h == 'g') && ((hl == 2 && (h[1] == '0' || h[1] == '1')) ||
                                       (hl == 3 && h[1] == '0' && (h[2] == '0' || h[2] == '1')))))
        return 1;
    while (p < end) {
        while (p < end && is_ws((unsigned char)*p)) p++;
        if (p == end) break;
        char L = *p;
        if (L >= 'a' && L <= 'z') L = (char)(L - 32);
        if (L != 'X' && L != 'Y' && L != 'Z' && L != 'E' && L != 'F') return 1;
        const char *q = ++p;
        if (q < end && (*q == '-' || *q == '+')) q++;
        int digits = 0, nonzero = 0, dot = 0;
        for (; q < end && !is_ws((unsigned char)*q); q++) {
            if (*q >= '0' && *q <= '9') { digits++; nonzero |= *q != '0'; }
            else if (*q == '.' && !dot) dot = 1;
            else return 1;
        }
        if (!digits || (L == 'F' && !nonzero)) return 1;
        p = q;
    }
    return 0;
}

static int py_hypot(Scanner *s, double a, double b, double *out) {
    hold(s);
    PyObject *r = PyObject_CallFunction(s->hypot, "dd", a, b);
    if (!r) return -1;
    *out = PyFloat_AsDouble(r);
    Py_DECREF(r);
    return 0;
}

/* gcode.arc_segments, operation for operation: how many segments Marlin 2.1 cuts an arc into. */
static double arc_segments(double radius, double sweep) {
    double a = fabs(sweep), flat = radius * a;
    double min_seg = ceil(72 * (a / (2 * M_PI)));
    if (min_seg < 1) min_seg = 1;
    double nominal = floor(flat / 1.0);
    if (nominal < min_seg) nominal = min_seg;
    double nominal_mm = flat / nominal;
    if (nominal_mm > 1.0) return ceil(flat / 1.0);
    if (nominal_mm < 0.1) {
        double n = floor(flat / 0.1);
        return n < 1 ? 1 : n;
    }
    return nominal;
}

/* gcode._arc (with gcode.arc_geometry and arc_point), operation for operation. */
static int arc(Scanner *s, const char *line, Words *w, int cw) {
    double x, y, z, e;
    target(s, w, &x, &y, &z, &e);
    if (HAS(w, 'F')) s->f = GET(w, 'F');
    double x0 = s->x, y0 = s->y, cx, cy;
    if (HAS(w, 'R')) {
        double r = GET(w, 'R'), dx = x - x0, dy = y - y0, d;
        if (py_hypot(s, dx, dy, &d) < 0) return -1;
        if (d == 0 || fabs(r) < d / 2 - 1e-6) return unsupported(s);
        double hh = r * r - d * d / 4;
        double h = sqrt(hh > 0.0 ? hh : 0.0);
        double sg = (cw ? -1 : 1) * (r > 0 ? 1 : -1);
        cx = x0 + dx / 2 - sg * h * dy / d;
        cy = y0 + dy / 2 + sg * h * dx / d;
    } else if (HAS(w, 'I') || HAS(w, 'J')) {
        cx = x0 + (HAS(w, 'I') ? GET(w, 'I') : 0.0);
        cy = y0 + (HAS(w, 'J') ? GET(w, 'J') : 0.0);
    } else {
        return unsupported(s);
    }
    double r0;
    if (py_hypot(s, x0 - cx, y0 - cy, &r0) < 0) return -1;
    double a0 = atan2(y0 - cy, x0 - cx);
    double a1 = atan2(y - cy, x - cx);
    double sweep = a1 - a0;
    if (cw) {
        if (sweep >= -1e-9) sweep -= 2 * M_PI;
    } else {
        if (sweep <= 1e-9) sweep += 2 * M_PI;
    }
    /* (gcode.ARC_SEGMENTS_MAX * MIN_ARC_SEGMENT_MM: longer, inf or nan is gcode's error) */
    if (!(fabs(r0 * sweep) <= 10000000 * 0.1)) return unsupported(s);
    long n = (long)arc_segments(r0, sweep);
    double zs = s->z, es = s->e;
    for (long i = 1; i <= n; i++) {
        double t = (double)i / (double)n, px, py;
        if (i == n) {
            px = x; py = y;
        } else {
            double a = a0 + sweep * t;
            px = cx + r0 * cos(a);
            py = cy + r0 * sin(a);
        }
        if (emit(s, line, px, py, zs + (z - zs) * t, es + (e - es) * t, 1) < 0) return -1;
    }
    s->x = x; s->y = y; s->z = z; s->e = e;
    if (!s->quiet) s->arcs++;
    return 0;
}

/* ---- the fast path: most lines of a sliced file are "G1 X.. Y.. E.." ----
 * fast_line() reads the plainest shape of a G0/G1 line in one pass, without branching on every
 * byte: "G0" or "G1", then words " <X|Y|Z|E|F><number>" (blanks ' ' only, the number
 * [-+]?[0-9]*(\.[0-9]*)? with a digit, up to 8 on each side of the dot and 15 in all, so that the
 * digits as an integer are exact in a double) up to the line end or a ';' comment (ASCII). Any
 * other line, or any doubt, goes to do_line (the general code), so the records are the same
 * either way: for these lines do_line_state cuts off just the comment, flags nothing (the line
 * starts with 'G'), parse_words finds the same words and takes the same short-number path, and
 * in events mode is_event says "no event" (an F of 0 and a TYPE:/LAYER comment are left to
 * do_line). host/tests/gcode/test_scan_fast.py compares the two on odd lines in every mode;
 * tools/bench_scan.py times feed(). */
#if defined(__SSE2__) && (defined(__GNUC__) || defined(__clang__))
#define FAST_MOVES 1

/* The value of the ASCII digits in w's top bytes (as loaded from memory on a little-endian CPU,
 * the last digit the last byte), its other bytes 0: pairs, quads and the eight added up in three
 * multiplications (no byte carries into the next). */
static inline uint64_t top_digits(uint64_t w) {
    w &= 0x0F0F0F0F0F0F0F0FULL;
    w = (w * 10 + (w >> 8)) & 0x00FF00FF00FF00FFULL;
    w = (w * 100 + (w >> 16)) & 0x0000FFFF0000FFFFULL;
    return (w * 10000 + (w >> 32)) & 0xFFFFFFFFULL;
}

/* The value of the n (1..8) ASCII digits at w's first bytes. */
static inline uint64_t eight_digits(uint64_t w, int n) {
    return top_digits(w << (8 * (8 - n)));
}

/* A byte's class for fast_line: X Y Z E F 0 to 4, a blank (' ') FAST_BLANK, a line end ('\n',
 * '\r') FAST_END, a comment's start (';') FAST_COMMENT, any other -1 */
enum { FAST_BLANK = 5, FAST_END = 6, FAST_COMMENT = 7 };
static signed char fast_class[256];

static void fast_init(void) {
    memset(fast_class, -1, sizeof fast_class);
    fast_class['X'] = 0;
    fast_class['Y'] = 1;
    fast_class['Z'] = 2;
    fast_class['E'] = 3;
    fast_class['F'] = 4;
    fast_class[' '] = FAST_BLANK;
    fast_class['\n'] = fast_class['\r'] = FAST_END;
    fast_class[';'] = FAST_COMMENT;
}

/* emit() of a G0/G1 move (no arc, not quiet), its conditions as bit operations rather than
 * branches: whether a move travels or extrudes, whether a lean run keeps it, follow no
 * pattern a branch predictor could learn, and each branch taken wrongly costs more than the
 * few operations. The same records and state as emit(). */
static inline int emit_move(Scanner *s, const char *line, double x, double y, double z, double e) {
    double de = e - s->e;
    int keep = 1;
    if (s->lean) {
        int moved = (s->x != x) | (s->y != y);
        if ((moved & (de > 0)) && (!s->have_top || z > s->top || isnan(z)))
            s->top = z, s->have_top = 1;      /* numpy's max: a NaN wins */
        int null = !moved & (s->z == z) & (de == 0);
        keep = s->outer | (s->follow & !null);
        s->follow = s->outer | (s->follow & null);
    }
    if (keep) {
        Record *r = slot(s);
        if (!r) return -1;
        r->x0 = s->x; r->y0 = s->y; r->z0 = s->z;
        r->x1 = x; r->y1 = y; r->z1 = z;
        r->e = de;
        r->e_start = s->e;
        r->f = s->f;
        r->offset = (int64_t)(s->base_offset + (line - s->base));
        r->line_no = (int32_t)s->line_no;
        r->role = (int16_t)s->role;
        r->flags = (uint8_t)((s->outer ? 1 : 0) | (s->abs_xyz ? 4 : 0) | (s->abs_e ? 8 : 0));
        r->pad = 0;
    }
    s->moves++;
    /* x and y in one store: the compiler reads them as a pair (the next line's v[], a record's
     * x0 y0), and a read of two earlier stores waits for them to reach the cache, which costs
     * more than a whole move (a store-forwarding stall); one store of both is forwarded */
    _mm_storeu_pd(&s->x, _mm_set_pd(y, x));
    s->z = z; s->e = e;
    return 0;
}

static inline const char *line_end(const char *q, const char *end, unsigned char *high);

/* The line at p, lim the data's end, start its start: 1 if it was read here (and emitted; *le:
 * its line end, '\n' or '\r'), 0 if it is the general code's, -1 on an error. The line end is
 * found as the words are read (the line is not searched for it first). */
static int fast_line(Scanner *s, const char *start, const char *p, const char *lim,
                     const char **le) {
    static const uint64_t p10u[9] = {1, 10, 100, 1000, 10000, 100000, 1000000, 10000000, 100000000};
    static const double p10[16] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8,
                                   1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15};
    static const double sign[2] = {1.0, -1.0};     /* (times -1.0: the same as negating) */
    /* the top n bytes of 8 */
    static const uint64_t top[9] = {0, 0xFFULL << 56, 0xFFFFULL << 48, 0xFFFFFFULL << 40,
                                    0xFFFFFFFFULL << 32, 0xFFFFFFFFFFULL << 24,
                                    0xFFFFFFFFFFFFULL << 16, 0xFFFFFFFFFFFFFFULL << 8, ~0ULL};
    /* a line of up to 64 bytes (a word may run to the 81st): the reads below stay within 96
     * bytes from p, and 8 before it */
    if (lim - p < 96 || p - start < 8 || p[0] != 'G' || (p[1] != '0' && p[1] != '1') ||
        p[2] != ' ')
        return 0;
    const __m128i below = _mm_set1_epi8('0' - 1), above = _mm_set1_epi8('9' + 1),
                  dotc = _mm_set1_epi8('.'), minus = _mm_set1_epi8('-'), plus = _mm_set1_epi8('+'),
                  past = _mm_set1_epi8(' ' + 1);
    /* X Y Z E F as target() takes them: a word's value, else the position (absolute) or 0.0
     * (relative, added to it as target() does), and the feed rate for F */
    double v[5];
    v[0] = s->abs_xyz ? s->x : 0.0;
    v[1] = s->abs_xyz ? s->y : 0.0;
    v[2] = s->abs_xyz ? s->z : 0.0;
    v[3] = s->abs_e ? s->e : 0.0;
    v[4] = s->f;
    const char *q = p + 3;
    int k;
    for (;;) {
        while ((k = fast_class[(unsigned char)*q]) == FAST_BLANK)
            if (++q - p > 64) return 0;
        if (k >= FAST_END) {
            /* a comment after the words (Slic3r's "G1 X.. E.. ; perimeter"): no part of the
             * move (do_line_state cuts it off), but the line must be ASCII as feed() requires
             * of a command line; the estimator reads some comments itself (is_event's) */
            if (k == FAST_COMMENT) {
                unsigned char high = 0;
                const char *c = q + 1;
                q = line_end(q, lim, &high);
                if (high >= 0x80 || q == lim) return 0;
                if (s->events) {
                    while (c < q && is_ws((unsigned char)*c)) c++;
                    if (q - c >= 5 && (memcmp(c, "TYPE:", 5) == 0 || memcmp(c, "LAYER", 5) == 0))
                        return 0;
                }
            }
            break;
        }
        if (k < 0 || q - p > 64) return 0;
        /* [-+]?[0-9]*(\.[0-9]*)?, then a blank or the line end. The word's end is where the
         * next one is looked for: the first of the sixteen bytes after the letter that is
         * <= ' ' or >= 0x80 (one signed compare), so that the steps from word to word are few;
         * that the bytes before it are digits, dots and signs, the number's shape and value are
         * worked out beside */
        __m128i b16 = _mm_loadu_si128((const __m128i *)(q + 1));
        int len = __builtin_ctz((unsigned)_mm_movemask_epi8(_mm_cmplt_epi8(b16, past)) | 0x10000u);
        const char *z = q + 1 + len;           /* the number's end */
        __m128i dg = _mm_and_si128(_mm_cmpgt_epi8(b16, below), _mm_cmplt_epi8(b16, above));
        __m128i dt = _mm_cmpeq_epi8(b16, dotc);
        __m128i sg = _mm_or_si128(_mm_cmpeq_epi8(b16, minus), _mm_cmpeq_epi8(b16, plus));
        unsigned body = (unsigned)_mm_movemask_epi8(_mm_or_si128(_mm_or_si128(dg, dt), sg));
        int s0 = q[1] == '-' || q[1] == '+';
        /* the bytes of the number that are no digit, but for a sign first: a dot or none */
        unsigned odd = ~(unsigned)_mm_movemask_epi8(dg) & ((1u << len) - 1) & ~(unsigned)s0;
        unsigned dots = (unsigned)_mm_movemask_epi8(dt);
        int dot = odd != 0;
        int at = __builtin_ctz(odd | (1u << len));     /* the dot, or the end */
        int lead = at - s0, frac = len - at - dot, n = lead + frac;
        if (fast_class[(unsigned char)*z] < FAST_BLANK || n == 0 || (odd & (odd - 1)) ||
            (odd & ~dots) || (~body & ((1u << len) - 1)))
            return 0;
        uint64_t m;
        if (n + dot <= 8) {
            /* the eight bytes up to the number's end: its digits at the top but for the dot,
             * which the digits before it are moved over */
            uint64_t w, shifted;
            memcpy(&w, z - 8, 8);
            shifted = dot ? w << 8 : w;
            m = top_digits((w & top[frac]) | (shifted & (top[n] ^ top[frac])));
        } else {                               /* up to 8 digits on each side, 15 in all */
            if (lead > 8 || frac > 8 || n > 15) return 0;
            const char *d = q + 1 + s0;
            uint64_t a, b;
            memcpy(&a, d, 8);
            memcpy(&b, d + lead + 1, 8);
            m = (lead ? eight_digits(a, lead) * p10u[frac] : 0) + (frac ? eight_digits(b, frac) : 0);
        }
        if (s->events && k == 4 && m == 0) return 0;         /* F0: an event */
        /* as parse_words: the digits as an integer (exact) over a power of ten */
        v[k] = (double)(int64_t)m / p10[frac] * sign[q[1] == '-'];
        q = z;
    }
    double x, y, z, e;
    if (s->abs_xyz) {
        x = v[0]; y = v[1]; z = v[2];
    } else {
        x = s->x + v[0]; y = s->y + v[1]; z = s->z + v[2];
    }
    e = s->abs_e ? v[3] : s->e + v[3];
    s->f = v[4];
    s->line_no++;
    *le = q;
    return emit_move(s, p, x, y, z, e) < 0 ? -1 : 1;
}
#endif

/* One line without its line end (gcode.split_code + parse_lines). */
static int do_line_state(Scanner *s, const char *p, const char *end, int ascii);

/* One line without its line end; ascii: it has no byte >= 0x80 (feed() saw as it split). */
static int do_line(Scanner *s, const char *p, const char *end, int ascii) {
    if (!s->events) return do_line_state(s, p, end, ascii);
    if (ascii && !is_event(s, p, end)) return do_line_state(s, p, end, 1);
    Record r;
    memset(&r, 0, sizeof r);
    r.x0 = r.x1 = s->x; r.y0 = r.y1 = s->y; r.z0 = r.z1 = s->z;
    r.e_start = s->e;
    r.f = s->f;
    r.offset = (int64_t)(s->base_offset + (p - s->base));
    r.line_no = (int32_t)s->line_no;
    r.role = -1;
    r.flags = (uint8_t)(16 | (s->abs_xyz ? 4 : 0) | (s->abs_e ? 8 : 0));
    if (push(s, &r) < 0) return -1;
    if (!ascii) return 0;                  /* the state is the estimator's to follow */
    s->quiet = 1;                          /* the line's own state changes, without records */
    int rc = do_line_state(s, p, end, 1);
    s->quiet = 0;
    if (rc < 0 && PyErr_ExceptionMatches(ScanUnsupported)) {
        PyErr_Clear();                     /* the estimator reads (or refuses) it */
        rc = 0;
    }
    return rc;
}

/* Counts the lines the regexes of gcode.check_not_processed and fallback.scan_m92 may match, so
 * that Python runs them only on parts of a file that hold one: comments starting "; bulgekit",
 * commands M[0...]72x / M[0...]92 (after any line number), and lines with bytes >= 0x80. A
 * superset: the regexes decide. */
enum { FLAG_OURS = 1, FLAG_M92 = 2 };

/* What a line (p: its first character that is not blank) may be: FLAG_OURS (a "; bulgekit"
 * comment or an M0...72x), FLAG_M92 (an M0...92), or 0. */
static int line_flag(const char *p, const char *end) {
    if (*p == ';') return end - p >= 10 && memcmp(p, "; bulgekit", 10) == 0 ? FLAG_OURS : 0;
    if (*p == 'N' || *p == 'n') {
        while (p < end && !is_ws((unsigned char)*p)) p++;
        while (p < end && is_ws((unsigned char)*p)) p++;
    }
    if (p < end && (*p == 'M' || *p == 'm')) {
        p++;
        while (p < end && *p == '0') p++;
        if (end - p >= 2 && p[1] == '2') {
            if (p[0] == '7') return FLAG_OURS;
            if (p[0] == '9') return FLAG_M92;
        }
    }
    return 0;
}

static void flag(Scanner *s, const char *p, const char *end) {
    if (line_flag(p, end)) s->flagged++;
}

static int do_line_state(Scanner *s, const char *p, const char *end, int ascii) {
    const char *line = p;
    if (!ascii) { s->flagged++; return foreign_line(s, p, end); }
    while (p < end && is_ws((unsigned char)*p)) p++;
    while (end > p && is_ws((unsigned char)end[-1])) end--;
    if (p == end) return 0;
    flag(s, p, end);
    if (*p == ';') return comment_role(s, p + 1, end);
    for (const char *q = p; q < end; q++)
        if (*q == ';' || *q == '*' || *q == '(') { end = q; break; }
    while (end > p && is_ws((unsigned char)end[-1])) end--;
    if (p < end && (*p == 'N' || *p == 'n')) {       /* a line number: drop the first word */
        while (p < end && !is_ws((unsigned char)*p)) p++;
        while (p < end && is_ws((unsigned char)*p)) p++;
    }
    if (p == end) return 0;
    const char *h = p;
    while (p < end && !is_ws((unsigned char)*p)) p++;
    const char *rest = p;
    while (rest < end && is_ws((unsigned char)*rest)) rest++;
    char letter = *h;
    if (letter == 'g') letter = 'G';
    if (letter == 'm') letter = 'M';
    if ((letter != 'G' && letter != 'M') || p - h < 2) return 0;
    long num = 0;
    for (const char *q = h + 1; q < p; q++) {
        if (*q < '0' || *q > '9') return 0;         /* "G1.5", "G1X5": not a command gcode/__init__.py knows */
        if (num < 100000) num = num * 10 + (*q - '0');
    }
    Words w;
    if (letter == 'G') {
        if (num == 0 || num == 1) {
            if (parse_words(s, rest, end, &w) < 0) return -1;
            double x, y, z, e;
            target(s, &w, &x, &y, &z, &e);
            if (HAS(&w, 'F')) s->f = GET(&w, 'F');
            return emit(s, line, x, y, z, e, 0);
        }
        if (num == 2 || num == 3) {
            if (parse_words(s, rest, end, &w) < 0) return -1;
            return arc(s, line, &w, num == 2);
        }
        if (num == 92) {
            if (parse_words(s, rest, end, &w) < 0) return -1;
            if (HAS(&w, 'X')) s->x = GET(&w, 'X');
            if (HAS(&w, 'Y')) s->y = GET(&w, 'Y');
            if (HAS(&w, 'Z')) s->z = GET(&w, 'Z');
            if (HAS(&w, 'E')) s->e = GET(&w, 'E');
            return 0;
        }
        if (num == 90) { s->abs_xyz = s->abs_e = 1; return 0; }
        if (num == 91) { s->abs_xyz = s->abs_e = 0; return 0; }
        return 0;
    }
    if (num == 82) s->abs_e = 1;
    else if (num == 83) s->abs_e = 0;
    return 0;
}

/* The first '\n' or '\r' at or after q (end: none); or's into *high the bytes before it. */
static inline const char *line_end(const char *q, const char *end, unsigned char *high) {
#if defined(__SSE2__) && (defined(__GNUC__) || defined(__clang__))
    /* sixteen bytes at a time (every x86-64 has SSE2): a mask of the line ends, and the bytes'
     * top bits, which are set for bytes >= 0x80 */
    const __m128i lf = _mm_set1_epi8('\n'), cr = _mm_set1_epi8('\r');
    while (end - q >= 16) {
        __m128i v = _mm_loadu_si128((const __m128i *)q);
        unsigned stop = (unsigned)_mm_movemask_epi8(_mm_or_si128(_mm_cmpeq_epi8(v, lf),
                                                                 _mm_cmpeq_epi8(v, cr)));
        unsigned top = (unsigned)_mm_movemask_epi8(v);
        if (stop) {
            unsigned at = (unsigned)__builtin_ctz(stop);
            if (top & ((1u << at) - 1)) *high = 0x80;
            return q + at;
        }
        if (top) *high = 0x80;
        q += 16;
    }
#else
    /* eight bytes at a time while none is '\n', '\r' or >= 0x80 (the zero test has no false
     * negatives), then byte by byte */
    const uint64_t ones = 0x0101010101010101ULL, highs = 0x8080808080808080ULL;
    while (end - q >= 8) {
        uint64_t w, lf, cr;
        memcpy(&w, q, 8);
        lf = w ^ (ones * '\n');
        cr = w ^ (ones * '\r');
        if ((((lf - ones) & ~lf) | ((cr - ones) & ~cr) | w) & highs) break;
        q += 8;
    }
#endif
    unsigned char h = 0;
    while (q < end && *q != '\n' && *q != '\r') h |= (unsigned char)*q++;
    *high |= h;
    return q;
}

/* feed(data, final, base) -> (records: bytes, used: int). Lines that end in data are scanned;
 * without final, the bytes after the last line end are left for the next call (used says where).
 * base: the file offset of data[0], for the records' offsets. */
static PyObject *Scanner_feed(Scanner *s, PyObject *args) {
    Py_buffer buf;
    int final = 0;
    long long base = 0;
    if (!PyArg_ParseTuple(args, "y*|pL", &buf, &final, &base)) return NULL;
    if (s->busy) {
        PyBuffer_Release(&buf);
        PyErr_SetString(PyExc_RuntimeError, "Scanner.feed: the scanner is in use by another thread");
        return NULL;
    }
    s->busy = 1;
    s->base_offset = base;
    const char *p = buf.buf, *end = p + buf.len;
    s->n = 0;
    s->base = p;
    s->have_top = 0;
    if (p < end) {                         /* (an empty feed keeps the pending '\r') */
        if (s->pending_cr && *p == '\n') { p++; s->n_lf++; s->n_crlf++; }
        s->pending_cr = 0;
    }
    const char *used = p;
    /* the lines without the GIL; after a line that took it back (hold()), the next lines keep
     * it a while: taking it again may wait for the thread running Python */
    int since = 0;
    s->needed = 0;
    s->ts = PyEval_SaveThread();
    while (p < end) {
        if (s->needed) {
            s->needed = 0;
            since = 0;
        } else if (!s->ts && ++since >= 1024) {
            s->ts = PyEval_SaveThread();
        }
        const char *q;
        int rc = 0;
#ifdef FAST_MOVES
        rc = fast_line(s, buf.buf, p, end, &q);
#endif
        if (rc == 0) {
            unsigned char high = 0;            /* the line's bytes or'ed: >= 0x80 if any is */
            q = line_end(p, end, &high);
            if (q == end && !final) break;
            s->line_no++;
            rc = do_line(s, p, q, high < 0x80);
        }
        if (rc < 0) {
            hold(s);                           /* (held already: the error was set with it) */
            s->busy = 0;
            PyBuffer_Release(&buf);
            return NULL;
        }
        if (q < end) {
            if (*q == '\r') {
                s->n_cr++;
                if (q + 1 < end) { if (q[1] == '\n') { q++; s->n_lf++; s->n_crlf++; } }
                else if (!final) s->pending_cr = 1;
            } else {
                s->n_lf++;
            }
            q++;
        }
        p = used = q;
    }
    hold(s);
    s->busy = 0;
    if (final) used = end;
    PyObject *out = PyBytes_FromStringAndSize((const char *)s->out, s->n * (Py_ssize_t)sizeof(Record));
    Py_ssize_t n_used = used - (const char *)buf.buf;
    PyBuffer_Release(&buf);
    if (!out) return NULL;
    return Py_BuildValue("(Nn)", out, n_used);
}

static int Scanner_init(Scanner *s, PyObject *args, PyObject *kw) {
    static char *kwlist[] = {"outer_roles", "s3d_roles", "classify", "events", "lean", NULL};
    PyObject *outer, *s3d, *classify;
    int events = 0, lean = 0;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OOO|pi", kwlist, &outer, &s3d, &classify,
                                     &events, &lean))
        return -1;
    if (s->busy) {
        PyErr_SetString(PyExc_RuntimeError, "Scanner: in use by another thread");
        return -1;
    }
    free_roles(s);
    s->ts = NULL;
    s->events = events;
    if (lean < 0 || lean > 2) { PyErr_SetString(PyExc_ValueError, "lean: 0, 1 or 2"); return -1; }
    s->lean = events ? 0 : lean;
    if (s->lean == 2 && s->ncap < s->cap) {    /* (grow() keeps the two as long from now on) */
        int64_t *q = PyMem_RawRealloc(s->nums, (size_t)s->cap * sizeof(int64_t));
        if (!q) { PyErr_NoMemory(); return -1; }
        s->nums = q;
        s->ncap = s->cap;
    }
    s->moves = 0;
    s->follow = 0;
    s->have_top = 0;
    s->quiet = 0;
    s->flagged = 0;
    s->n_lf = s->n_cr = s->n_crlf = 0;
    s->x = s->y = s->z = s->e = 0.0;
    s->f = 1500.0;
    s->abs_xyz = s->abs_e = 1;
    s->role = -1;
    s->outer = 0;
    s->line_no = 0;
    s->pending_cr = 0;
    s->arcs = 0;
    Py_XSETREF(s->roles, PyList_New(0));
    Py_XSETREF(s->outer_roles, PyFrozenSet_New(outer));
    Py_XSETREF(s->s3d_roles, PyFrozenSet_New(s3d));
    Py_INCREF(classify);
    Py_XSETREF(s->classify, classify);
    PyObject *math = PyImport_ImportModule("math");
    if (!math) return -1;
    Py_XSETREF(s->hypot, PyObject_GetAttrString(math, "hypot"));
    Py_DECREF(math);
    if (!s->roles || !s->outer_roles || !s->s3d_roles || !s->hypot) return -1;
    /* the Simplify3D tags as UTF-8 (comment_role compares bytes, without the GIL) */
    Py_ssize_t n3 = PySet_GET_SIZE(s->s3d_roles), i = 0;
    PyObject *key, *it = PyObject_GetIter(s->s3d_roles);
    if (!it) return -1;
    s->s3d_name = PyMem_RawCalloc((size_t)(n3 ? n3 : 1), sizeof(char *));
    s->s3d_len = PyMem_RawCalloc((size_t)(n3 ? n3 : 1), sizeof(Py_ssize_t));
    if (!s->s3d_name || !s->s3d_len) { Py_DECREF(it); PyErr_NoMemory(); return -1; }
    while (i < n3 && (key = PyIter_Next(it)) != NULL) {
        Py_ssize_t l;
        /* (a name that is no str never equals a line's) */
        const char *t = PyUnicode_Check(key) ? PyUnicode_AsUTF8AndSize(key, &l) : NULL;
        char *copy = t ? PyMem_RawMalloc((size_t)l + 1) : NULL;
        Py_DECREF(key);
        if (t && !copy) PyErr_NoMemory();
        if (PyErr_Occurred()) { Py_DECREF(it); return -1; }
        if (!copy) continue;
        memcpy(copy, t, (size_t)l);
        s->s3d_name[i] = copy;
        s->s3d_len[i++] = l;
        s->n_s3d = i;
    }
    Py_DECREF(it);
    return PyErr_Occurred() ? -1 : 0;
}

static void Scanner_dealloc(Scanner *s) {
    Py_XDECREF(s->roles);
    Py_XDECREF(s->outer_roles);
    Py_XDECREF(s->s3d_roles);
    Py_XDECREF(s->classify);
    Py_XDECREF(s->hypot);
    free_roles(s);
    PyMem_RawFree(s->out);
    PyMem_RawFree(s->nums);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

static PyObject *Scanner_roles(Scanner *s, void *c) {
    (void)c;
    return Py_NewRef(s->roles);
}

static PyObject *Scanner_lines(Scanner *s, void *c) {
    (void)c;
    return PyLong_FromLong(s->line_no);
}

static PyObject *Scanner_arcs(Scanner *s, void *c) {
    (void)c;
    return PyLong_FromLongLong(s->arcs);
}

static PyObject *Scanner_flagged(Scanner *s, void *c) {
    (void)c;
    return PyLong_FromLong(s->flagged);
}

static PyObject *Scanner_line_ends(Scanner *s, void *c) {
    (void)c;
    return Py_BuildValue("(LLL)", s->n_lf, s->n_cr, s->n_crlf);
}

static PyObject *Scanner_top(Scanner *s, void *c) {
    (void)c;
    return s->have_top ? PyFloat_FromDouble(s->top) : Py_NewRef(Py_None);
}

static PyObject *Scanner_numbers(Scanner *s, void *c) {
    (void)c;
    if (s->lean != 2) Py_RETURN_NONE;
    return PyBytes_FromStringAndSize((const char *)s->nums, s->n * (Py_ssize_t)sizeof(int64_t));
}

static PyObject *Scanner_e(Scanner *s, void *c) {
    (void)c;
    return PyFloat_FromDouble(s->e);
}

static PyMethodDef Scanner_methods[] = {
    {"feed", (PyCFunction)Scanner_feed, METH_VARARGS,
     "feed(data, final=False, base=0) -> (records, used): move records of data's complete lines"},
    {NULL, NULL, 0, NULL}};

static PyGetSetDef Scanner_getset[] = {
    {"roles", (getter)Scanner_roles, NULL, "role names by index (lower case)", NULL},
    {"lines", (getter)Scanner_lines, NULL, "lines scanned so far", NULL},
    {"e", (getter)Scanner_e, NULL, "E position after the lines scanned so far", NULL},
    {"top", (getter)Scanner_top, NULL,
     "lean: the last feed's highest z1 of the moves extruding in XY off arcs (None: none)", NULL},
    {"numbers", (getter)Scanner_numbers, NULL,
     "lean 2: the move numbers (int64) of the last feed's records, counting every move (else None)",
     NULL},
    {"flagged", (getter)Scanner_flagged, NULL, "lines so far that may be bulgekit's or an M92", NULL},
    {"arcs", (getter)Scanner_arcs, NULL, "G2/G3 lines read so far (not counting events)", NULL},
    {"line_ends", (getter)Scanner_line_ends, NULL,
     "(\\n, \\r, \\r\\n) bytes and pairs so far: bytes.count's of the data consumed", NULL},
    {NULL, NULL, NULL, NULL, NULL}};

static PyTypeObject ScannerType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "bulgekit.gcode._scan.Scanner",
    .tp_basicsize = sizeof(Scanner),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "G-code move scanner (see the module comment)",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Scanner_init,
    .tp_dealloc = (destructor)Scanner_dealloc,
    .tp_methods = Scanner_methods,
    .tp_getset = Scanner_getset,
};

/* ---- annotate's line marks (bulge/annotate.py: _feature_comments, _z_events) ----
 * The same lines annotate's regular expressions find, in one pass in C. Lines end at '\n' only
 * (as the regexes' [^\n]); blanks are ' ' and '\t' (their [ \t]). annotate.py keeps the regexes
 * as the fallback, and host/tests/bulge/test_annotate.py checks both give the same on every
 * test file and on odd and random lines. */

/* _MOVE_HEAD, [ \t]*G0?[01][ \t], at p: where the words start, or -1. */
static Py_ssize_t move_head(const char *d, Py_ssize_t p, Py_ssize_t n) {
    while (p < n && (d[p] == ' ' || d[p] == '\t')) p++;
    if (p >= n || d[p] != 'G') return -1;
    p++;
    if (p + 2 < n && d[p] == '0' && (d[p + 1] == '0' || d[p + 1] == '1') &&
        (d[p + 2] == ' ' || d[p + 2] == '\t'))
        return p + 3;
    if (p + 1 < n && (d[p] == '0' || d[p] == '1') && (d[p + 1] == ' ' || d[p + 1] == '\t'))
        return p + 2;
    return -1;
}

static const char *const FEATURE_WORDS[] = {
    "TYPE:", "FEATURE:", "outer perimeter", "inner perimeter", "infill", "solid layer", "support",
    "dense support", "skirt", "raft", "bridge", "gap fill", "prime pillar", "ooze shield", NULL};

static int is_word(char c) {
    return (c >= '0' && c <= '9') || (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_';
}

typedef struct { Py_ssize_t start, end; double z; } ZLine;

/* The line starting at ls (ending at le) extrudes in XY as _EXTRUDE_RX sees it: a G0/G1 head,
 * then an X or Y and an E before any ';'. */
static int line_extrudes(const char *d, Py_ssize_t ls, Py_ssize_t le, Py_ssize_t n) {
    Py_ssize_t h = move_head(d, ls, n);
    if (h < 0) return 0;
    int xy = 0, e = 0;
    for (Py_ssize_t p = h; p < le && d[p] != ';'; p++) {
        char c = d[p];
        if (c == 'X' || c == 'Y') xy = 1;
        else if (c == 'E') e = 1;
        if (xy && e) return 1;
    }
    return 0;
}

/* Whether p (before end) is a byte the marks pass looks closer at: a ';' (semi), a 'Z' or the 'G'
 * of a "G9" (zg). */
static inline int is_mark(const char *p, const char *end, int semi, int zg) {
    return (semi && *p == ';') || (zg && (*p == 'Z' || (*p == 'G' && end - p >= 2 && p[1] == '9')));
}

/* The first mark (is_mark) at or after p (before end), or NULL: what the marks pass looks closer
 * at, found in one pass over the data (memchr to each ';', to each 'Z' and a third pass for the
 * "G9"s read the 100 MB three times). */
static const char *find_mark(const char *p, const char *end, int semi, int zg) {
#if defined(__SSE2__) && (defined(__GNUC__) || defined(__clang__))
    /* thirty-two places at a time: a mask of the ';'s, the 'Z's and the 'G's whose next byte is a
     * '9' (the same bytes loaded again one on); a mark not asked for compares with one that is */
    const __m128i sv = _mm_set1_epi8(semi ? ';' : 'Z'), zv = _mm_set1_epi8(zg ? 'Z' : ';'),
                  gv = _mm_set1_epi8(zg ? 'G' : ';'), nv = _mm_set1_epi8(zg ? '9' : ';');
    while (end - p >= 33) {
        __m128i a0 = _mm_loadu_si128((const __m128i *)p);
        __m128i b0 = _mm_loadu_si128((const __m128i *)(p + 1));
        __m128i a1 = _mm_loadu_si128((const __m128i *)(p + 16));
        __m128i b1 = _mm_loadu_si128((const __m128i *)(p + 17));
        __m128i m0 = _mm_or_si128(_mm_or_si128(_mm_cmpeq_epi8(a0, sv), _mm_cmpeq_epi8(a0, zv)),
                                  _mm_and_si128(_mm_cmpeq_epi8(a0, gv), _mm_cmpeq_epi8(b0, nv)));
        __m128i m1 = _mm_or_si128(_mm_or_si128(_mm_cmpeq_epi8(a1, sv), _mm_cmpeq_epi8(a1, zv)),
                                  _mm_and_si128(_mm_cmpeq_epi8(a1, gv), _mm_cmpeq_epi8(b1, nv)));
        unsigned lo = (unsigned)_mm_movemask_epi8(m0), hi = (unsigned)_mm_movemask_epi8(m1);
        if (lo | hi) return p + __builtin_ctz(lo | (hi << 16));
        p += 32;
    }
#else
    /* eight bytes at a time, looking closer only at a word holding a ';', a 'Z' or a 'G' (a byte
     * of them is 0 after the xor; the zero test has no false negatives) */
    const uint64_t ones = 0x0101010101010101ULL, highs = 0x8080808080808080ULL;
    while (end - p >= 9) {
        uint64_t w;
        memcpy(&w, p, 8);
        uint64_t x = w ^ (ones * ';'), y = w ^ (ones * 'Z'), g = w ^ (ones * 'G');
        if ((((x - ones) & ~x) | ((y - ones) & ~y) | ((g - ones) & ~g)) & highs)
            for (int k = 0; k < 8; k++)
                if (is_mark(p + k, end, semi, zg)) return p + k;
        p += 8;
    }
#endif
    for (; p < end; p++)
        if (is_mark(p, end, semi, zg)) return p;
    return NULL;
}

/* Where the line holding position p starts. */
static Py_ssize_t start_of_line(const char *d, Py_ssize_t p) {
    while (p > 0 && d[p - 1] != '\n') p--;
    return p;
}

/* The marks pass over d[0, n): with features (a list), feature_lines' (end, comment) of every
 * feature comment line appended to it; with zl, the Z words z_events reads (ZLine: the line's
 * start, the word's end, z after it) in *zl (PyMem), *nz of them. The marks are looked at in file
 * order, a ';' only as its line's first, and a line left at its ';' (what follows is a comment):
 * so a feature line (';' its first byte but blanks) is never skipped for a Z or a G9 before it,
 * and a G90/G91 (at a line's start) counts for the Z lines after it. 0, or -1 with an exception. */
static int marks_pass(const char *d, Py_ssize_t n, PyObject *features, ZLine **zlp,
                      Py_ssize_t *nzp) {
    const int semi = features != NULL, zg = zlp != NULL;
    ZLine *zl = NULL;
    Py_ssize_t nz = 0, cz = 0;
    int absolute = 1;
    double z = 0.0;
    char small[64];
    Py_ssize_t pos = 0;
    /* the line of the last 'Z' looked at: [cur_ls, cur_lim) may hold Z words, cur_le its end */
    Py_ssize_t cur_ls = -1, cur_le = -1, cur_lim = -1;
    while (pos < n) {
        const char *hit = find_mark(d + pos, d + n, semi, zg);
        if (!hit) break;
        Py_ssize_t zp = hit - d;
        if (*hit == ';') {
            /* feature_lines: the line's first ';' is its first byte but blanks, then blanks and a
             * feature word */
            Py_ssize_t b = zp;
            const char *nl = memchr(hit, '\n', (size_t)(n - zp));
            Py_ssize_t le = nl ? nl - d : n;
            while (b > 0 && (d[b - 1] == ' ' || d[b - 1] == '\t')) b--;
            if (b == 0 || d[b - 1] == '\n') {
                Py_ssize_t q = zp + 1;
                while (q < le && (d[q] == ' ' || d[q] == '\t')) q++;
                for (int k = 0; FEATURE_WORDS[k]; k++) {
                    size_t l = strlen(FEATURE_WORDS[k]);
                    if (q < le && d[q] == FEATURE_WORDS[k][0] && (size_t)(le - q) >= l &&
                        memcmp(d + q, FEATURE_WORDS[k], l) == 0) {
                        PyObject *t = Py_BuildValue("(ny#)", le, d + zp + 1, le - zp - 1);
                        int bad = !t || PyList_Append(features, t) < 0;
                        Py_XDECREF(t);
                        if (bad) goto fail;
                        break;
                    }
                }
            }
            pos = le + 1;                      /* (a later ';' on the line is not its first) */
            continue;
        }
        if (*hit == 'G') {
            /* G90/G91 at a line's start, in file order: it counts for the Z lines after it (a Z
             * on its own line is not a move's) */
            Py_ssize_t b = zp;
            while (b > 0 && (d[b - 1] == ' ' || d[b - 1] == '\t')) b--;
            if ((b == 0 || d[b - 1] == '\n') && zp + 2 < n &&
                (d[zp + 2] == '0' || d[zp + 2] == '1') && (zp + 3 >= n || !is_word(d[zp + 3])))
                absolute = d[zp + 2] == '0';
            pos = zp + 1;
            continue;
        }
        if (zp > cur_le) {                     /* a new line */
            cur_ls = start_of_line(d, zp);
            const char *nl = memchr(hit, '\n', (size_t)(n - zp));
            cur_le = nl ? nl - d : n;
            Py_ssize_t h = move_head(d, cur_ls, n);
            cur_lim = -1;
            if (h >= 0) {
                const char *semi_at = memchr(d + h, ';', (size_t)(cur_le - h));
                cur_lim = semi_at ? semi_at - d : cur_le;
            }
        }
        if (zp >= cur_lim) { pos = cur_le + 1; continue; }    /* not a move, or after its ';' */
        Py_ssize_t q = zp + 1;
        while (q < n && (d[q] == ' ' || d[q] == '\t')) q++;
        Py_ssize_t ns = q;
        if (q < n && (d[q] == '-' || d[q] == '+')) q++;
        Py_ssize_t d1 = q;
        while (q < n && d[q] >= '0' && d[q] <= '9') q++;
        if (q + 1 < n && d[q] == '.' && d[q + 1] >= '0' && d[q + 1] <= '9') {
            q++;
            while (q < n && d[q] >= '0' && d[q] <= '9') q++;
        } else if (q == d1) {
            pos = zp + 1;                      /* no number: not a Z word */
            continue;
        }
        char *num = small;
        if (q - ns >= (Py_ssize_t)sizeof small) {
            num = PyMem_Malloc((size_t)(q - ns + 1));
            if (!num) { PyErr_NoMemory(); goto fail; }
        }
        memcpy(num, d + ns, (size_t)(q - ns));
        num[q - ns] = 0;
        double v = PyOS_string_to_double(num, NULL, NULL);   /* float()'s own */
        if (num != small) PyMem_Free(num);
        if (v == -1.0 && PyErr_Occurred()) goto fail;
        z = absolute ? v : z + v;
        if (nz == cz) {
            cz = cz ? 2 * cz : 1024;
            ZLine *t = PyMem_Realloc(zl, (size_t)cz * sizeof *t);
            if (!t) { PyErr_NoMemory(); goto fail; }
            zl = t;
        }
        zl[nz].start = cur_ls;
        zl[nz].end = q;
        zl[nz].z = z;
        nz++;
        pos = q;                               /* the number holds no Z */
    }
    if (zlp) { *zlp = zl; *nzp = nz; }
    return 0;
fail:
    PyMem_Free(zl);
    return -1;
}

/* z_events' list from the marks pass's Z words (see z_events). */
static PyObject *layer_events(const char *d, Py_ssize_t n, const ZLine *zl, Py_ssize_t nz) {
    PyObject *out = PyList_New(0);
    PyObject *last = NULL;                     /* the last layer change's z in 0.01 mm */
    Py_ssize_t self_at = -1, le = -1;          /* the Z line looked at last, its end */
    int self_ext = 0;
    for (Py_ssize_t k = 0; out && k < nz; k++) {
        Py_ssize_t start = zl[k].start;
        Py_ssize_t stop = k + 1 < nz ? zl[k + 1].start : n;
        /* the Z line itself (a line the data starts with is not: the regex wants a '\n' first);
         * once per line, however many Z words it holds */
        if (self_at != start) {
            const char *nl = memchr(d + start, '\n', (size_t)(n - start));
            le = nl ? nl - d : n;
            self_at = start;
            self_ext = start > 0 && line_extrudes(d, start, le, n);
        }
        int layer = self_ext;
        /* or a line starting after it, before stop */
        for (Py_ssize_t ls = le + 1; !layer && ls < stop && ls <= n; ) {
            const char *e = memchr(d + ls, '\n', (size_t)(n - ls));
            Py_ssize_t ee = e ? e - d : n;
            layer = line_extrudes(d, ls, ee, n);
            if (!e) break;
            ls = ee + 1;
        }
        if (!layer) continue;
        double x = zl[k].z * 100;
        PyObject *zc;
        if (fabs(x) < 4e15) {
            zc = PyLong_FromLongLong((long long)rint(x));   /* round(): half to even */
        } else {                               /* huge, inf or nan: Python's round() says */
            PyObject *f = PyFloat_FromDouble(x);
            zc = f ? PyObject_CallMethod(f, "__round__", NULL) : NULL;
            Py_XDECREF(f);
        }
        int same = zc && last ? PyObject_RichCompareBool(zc, last, Py_EQ) : 0;
        if (!zc || same < 0) { Py_XDECREF(zc); Py_CLEAR(out); break; }
        if (same) { Py_DECREF(zc); continue; }
        Py_XSETREF(last, zc);
        PyObject *t = Py_BuildValue("(nO)", start, zc);
        if (!t || PyList_Append(out, t) < 0) Py_CLEAR(out);
        Py_XDECREF(t);
    }
    Py_XDECREF(last);
    return out;
}

/* z_events' list of the data in buf, from the marks pass (with features: feature_lines' too, into
 * that list); NULL with an exception. */
static PyObject *marked_events(const Py_buffer *buf, PyObject *features) {
    ZLine *zl = NULL;
    Py_ssize_t nz = 0;
    PyObject *out = NULL;
    if (marks_pass(buf->buf, buf->len, features, &zl, &nz) == 0)
        out = layer_events(buf->buf, buf->len, zl, nz);
    PyMem_Free(zl);
    return out;
}

/* feature_lines(data) -> [(end, comment)]: every line whose first byte other than ' ' and '\t'
 * is ';' followed by blanks and a feature word (_FEATURE_RX); end: its '\n' (or the data's end),
 * comment: the bytes after the ';' up to end, for gcode.feature_of_comment. Looks only at the
 * lines holding a ';' (marks_pass): the moves between are not walked. */
static PyObject *feature_lines(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer buf;
    if (!PyArg_ParseTuple(args, "y*", &buf)) return NULL;
    PyObject *out = PyList_New(0);
    if (out && marks_pass(buf.buf, buf.len, out, NULL, NULL) < 0) Py_CLEAR(out);
    PyBuffer_Release(&buf);
    return out;
}

/* z_events(data) -> [(offset, z in 0.01 mm)]: annotate._z_events. Each Z word (_Z_RX:
 * Z[ \t]*[-+]?[0-9]*\.?[0-9]+) before any ';' of a G0/G1 line sets z (added to it under G91;
 * G90/G91 at a line's start switch); such a line is a layer change when it, or a line after it
 * and before the next one, extrudes in XY, and its z in 0.01 mm (round(), half to even)
 * differs from the last layer change's. Only the lines around a 'Z' or "G9" are looked at
 * (marks_pass), and after a Z line the lines up to its first extruding one: a file's
 * millions of moves between are not walked. */
static PyObject *z_events(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer buf;
    if (!PyArg_ParseTuple(args, "y*", &buf)) return NULL;
    PyObject *out = marked_events(&buf, NULL);
    PyBuffer_Release(&buf);
    return out;
}

/* line_marks(data) -> (feature_lines(data), z_events(data)), from one pass over the data. */
static PyObject *line_marks(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer buf;
    if (!PyArg_ParseTuple(args, "y*", &buf)) return NULL;
    PyObject *features = PyList_New(0), *events = NULL, *out = NULL;
    if (features && (events = marked_events(&buf, features)) != NULL)
        out = PyTuple_Pack(2, features, events);
    Py_XDECREF(features);
    Py_XDECREF(events);
    PyBuffer_Release(&buf);
    return out;
}

/* move_classes(records) -> (classes, top, top_not_arc): one byte per move record of what the
 * passes ask of every move (movescan.classes, which says the bits and does the same in numpy
 * without this module), read in one pass over the records rather than one per field; top: the
 * highest z1 of the moves that extrude in XY (None: none), top_not_arc: of those not on an arc. */
static PyObject *move_classes(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer buf;
    if (!PyArg_ParseTuple(args, "y*", &buf)) return NULL;
    Py_ssize_t n = buf.len / (Py_ssize_t)sizeof(Record);
    PyObject *out = PyBytes_FromStringAndSize(NULL, n);
    if (!out) { PyBuffer_Release(&buf); return NULL; }
    unsigned char *c = (unsigned char *)PyBytes_AS_STRING(out);
    const Record *r = buf.buf;              /* (numpy's records: aligned as this struct) */
    double top = 0, top_line = 0;
    int have = 0, have_line = 0;
    Py_BEGIN_ALLOW_THREADS                  /* (the records are not Python's to change meanwhile) */
    for (Py_ssize_t i = 0; i < n; i++, r++) {
        Record m;
        memcpy(&m, r, sizeof m);
        int moved = m.x0 != m.x1 || m.y0 != m.y1;
        int ext = moved && m.e > 0;
        unsigned char k = (unsigned char)(m.flags & 3);
        if (moved) k |= 4;
        if (ext) {
            k |= 8;
            /* numpy's max: a NaN wins */
            if (!have || m.z1 > top || isnan(m.z1)) top = m.z1, have = 1;
            if (!(m.flags & 2) && (!have_line || m.z1 > top_line || isnan(m.z1)))
                top_line = m.z1, have_line = 1;
        }
        if (!moved && m.z0 == m.z1 && m.e == 0) k |= 16;
        if ((float)m.e > 0 && ((float)m.x0 != (float)m.x1 || (float)m.y0 != (float)m.y1)) k |= 32;
        c[i] = k;
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&buf);
    PyObject *t = have ? PyFloat_FromDouble(top) : Py_NewRef(Py_None);
    PyObject *tl = have_line ? PyFloat_FromDouble(top_line) : Py_NewRef(Py_None);
    if (!t || !tl) { Py_DECREF(out); Py_XDECREF(t); Py_XDECREF(tl); return NULL; }
    return Py_BuildValue("(NNN)", out, t, tl);
}

/* A z as the firmware reads it, in 0.01 mm (movescan._z_cmm, element by element the same
 * operations): rounded to float32, times 100 in float32, half away from zero. Only for finite z. */
static int64_t z_cmm(double z) {
    float f = (float)z * 100.0f;
    double v = (double)f;
    return (int64_t)(v >= 0 ? floor(v + 0.5) : -floor(0.5 - v));
}

/* wall_rows(records, classes, numbers, row, inside, breaks, last, after, done, rows_done):
 * one chunk of wall.walls_from_records' pass over the moves, as its numpy steps compute it (they
 * say what each part is): the rows (moves whose class has all of row's bits), the breaks between
 * them (a move that is no row and moves in XY or lies outside `inside`'s bits; lean chunks also
 * a gap in the move numbers), whether each row joins the row before (its start within 1e-4 mm of
 * that one's end, no break between), the rows that may begin a chain, and the runs of one z with
 * their z in 0.01 mm and how many of their rows are flat. numbers: the records' move numbers
 * (lean chunks) or None; breaks, last ((x1, y1) of the last row, or None), after (the last
 * record's number): carried from the chunk before; done, rows_done: moves and rows before it.
 * -> (breaks, after, any_outer, parts) with parts None when the chunk has no row, else
 * (ends, nums, link, first_rows, firsts, zst, zr, pz) as bytes (complex128 x1+iy1, int64, bool,
 * int64, complex128 x0+iy0, int64, int64, int64); None when a row's z is not finite (numpy's
 * cast of those is the platform's: the numpy steps do such a chunk). */
static PyObject *wall_rows(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer rb, cb, nb = {0};
    PyObject *numbers, *last;
    int row, inside;
    long long breaks, after, done, rows_done;
    if (!PyArg_ParseTuple(args, "y*y*OiiLOLLL", &rb, &cb, &numbers, &row, &inside, &breaks, &last,
                          &after, &done, &rows_done))
        return NULL;
    PyObject *res = NULL, *out[8] = {0};
    void *scratch = NULL;
    Py_ssize_t n = rb.len / (Py_ssize_t)sizeof(Record);
    int have_last = last != Py_None;
    double lx = 0, ly = 0;
    if (numbers != Py_None && PyObject_GetBuffer(numbers, &nb, PyBUF_SIMPLE) < 0) goto fail;
    if (cb.len != n || (numbers != Py_None && nb.len != n * 8)) {
        PyErr_SetString(PyExc_ValueError, "wall_rows: records, classes and numbers differ in length");
        goto fail;
    }
    if (have_last && !PyArg_ParseTuple(last, "dd", &lx, &ly)) goto fail;
    const Record *r = rb.buf;
    const unsigned char *c = cb.buf;
    const int64_t *num = numbers != Py_None ? nb.buf : NULL;
    /* the rows' parts at their size; the chains' and runs' (far fewer) in scratch space, copied
     * out at theirs (bytes cut to size would leave holes in the heap as large as the chunk) */
    Py_ssize_t n_rows = 0;
    for (Py_ssize_t i = 0; i < n; i++) n_rows += (c[i] & row) == row;
    Py_ssize_t sizes[3] = {16 * n_rows, 8 * n_rows, n_rows};
    for (int k = 0; k < 3; k++)
        if (!(out[k] = PyBytes_FromStringAndSize(NULL, sizes[k]))) goto fail;
    scratch = PyMem_Malloc((size_t)(n_rows ? n_rows : 1) * 48);
    if (!scratch) { PyErr_NoMemory(); goto fail; }
    double *ends = (double *)PyBytes_AS_STRING(out[0]), *firsts = (double *)scratch;
    int64_t *nums = (int64_t *)PyBytes_AS_STRING(out[1]);
    int64_t *first_rows = (int64_t *)(firsts + 2 * n_rows), *zst = first_rows + n_rows;
    int64_t *zr = zst + n_rows, *pz = zr + n_rows;
    char *link = PyBytes_AS_STRING(out[2]);
    Py_ssize_t rows = 0, nf = 0, nz = 0;
    int any_outer = 0, finite = 1;
    long long pending = breaks;             /* breaks since the last row */
    double px = lx, py = ly, pzv = 0;       /* the last row's x1 y1; the z of the run in hand */
    int joined_last = have_last;            /* (the first row's link looks at `last`) */
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++) {
        unsigned char k = c[i];
        any_outer |= k & 1;
        int ok = (k & row) == row;
        int brk = !ok && (k & (4 | inside)) != inside;
        if (num) {
            brk |= num[i] - after > 1;
            after = num[i];
        }
        pending += brk;                     /* (a row's own gap counts before it) */
        if (!ok) continue;
        Record m;
        memcpy(&m, r + i, sizeof m);
        if (!isfinite(m.z1)) { finite = 0; break; }
        /* joins the row before: its start at that one's end (NaN: no) and no break between */
        int j = rows ? 1 : joined_last;
        j = j && fabs(m.x0 - px) <= 1e-4 && fabs(m.y0 - py) <= 1e-4 && !pending;
        link[rows] = (char)j;
        int new_run = !rows || m.z1 != pzv;
        if (new_run) {
            zst[nz] = rows + rows_done;
            zr[nz] = z_cmm(m.z1);
            pz[nz] = 0;
            pzv = m.z1;
            nz++;
        }
        pz[nz - 1] += fabs(m.z1 - m.z0) < 1e-6;
        if (!j || new_run) {
            first_rows[nf] = rows + rows_done;
            firsts[2 * nf] = m.x0, firsts[2 * nf + 1] = m.y0;
            nf++;
        }
        ends[2 * rows] = m.x1, ends[2 * rows + 1] = m.y1;
        nums[rows] = num ? num[i] : i + done;
        px = m.x1, py = m.y1;
        pending = 0;
        rows++;
    }
    Py_END_ALLOW_THREADS
    if (!finite) {
        res = Py_NewRef(Py_None);
        goto fail;
    }
    if (!rows) {
        res = Py_BuildValue("(LLOO)", pending, after, any_outer ? Py_True : Py_False, Py_None);
        goto fail;
    }
    out[3] = PyBytes_FromStringAndSize((const char *)first_rows, 8 * nf);
    out[4] = PyBytes_FromStringAndSize((const char *)firsts, 16 * nf);
    out[5] = PyBytes_FromStringAndSize((const char *)zst, 8 * nz);
    out[6] = PyBytes_FromStringAndSize((const char *)zr, 8 * nz);
    out[7] = PyBytes_FromStringAndSize((const char *)pz, 8 * nz);
    for (int k = 3; k < 8; k++)
        if (!out[k]) goto fail;
    res = Py_BuildValue("(LLO(NNNNNNNN))", pending, after, any_outer ? Py_True : Py_False,
                        out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7]);
    for (int k = 0; k < 8; k++) out[k] = NULL;    /* (the tuple holds them now, or they are gone) */
fail:
    for (int k = 0; k < 8; k++) Py_XDECREF(out[k]);
    PyMem_Free(scratch);
    PyBuffer_Release(&rb);
    PyBuffer_Release(&cb);
    if (nb.obj) PyBuffer_Release(&nb);
    return res;
}

/* flag_lines(data) -> (ours, m92): the lines of data (split as feed() splits them) that
 * gcode.check_not_processed's regex (a comment starting "; bulgekit", an M0...72x) and
 * scan_m92's (an M0...92) may match, by flag()'s look at each line start: supersets, so that
 * with a count of 0 the regex need not run over the file (gcode._flag_counts). */
static PyObject *flag_lines(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer buf;
    if (!PyArg_ParseTuple(args, "y*", &buf)) return NULL;
    const char *p = buf.buf, *end = p + buf.len;
    long ours = 0, m92 = 0;
    Py_BEGIN_ALLOW_THREADS
    while (p < end) {
        const char *q = p;
        while (q < end && *q != '\n' && *q != '\r') q++;
        const char *a = p, *b = q;
        while (a < b && is_ws((unsigned char)*a)) a++;
        if (a < b) {
            int f = line_flag(a, b);
            ours += f == FLAG_OURS;
            m92 += f == FLAG_M92;
        }
        p = q < end ? q + 1 : q;
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&buf);
    return Py_BuildValue("(ll)", ours, m92);
}

static PyMethodDef module_methods[] = {
    {"feature_lines", feature_lines, METH_VARARGS,
     "feature_lines(data) -> [(end, comment)]: annotate's feature comment lines"},
    {"z_events", z_events, METH_VARARGS,
     "z_events(data) -> [(offset, z_cmm)]: annotate's layer changes"},
    {"line_marks", line_marks, METH_VARARGS,
     "line_marks(data) -> (feature_lines(data), z_events(data)), in one pass"},
    {"flag_lines", flag_lines, METH_VARARGS,
     "flag_lines(data) -> (ours, m92): lines check_not_processed's / scan_m92's regexes may match"},
    {"move_classes", move_classes, METH_VARARGS,
     "move_classes(records) -> (classes, top, top_not_arc): see movescan.classes"},
    {"wall_rows", wall_rows, METH_VARARGS,
     "wall_rows(records, classes, numbers, row, inside, breaks, last, after, done, rows_done): "
     "one chunk of wall.walls_from_records' pass"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef scan_module = {
    PyModuleDef_HEAD_INIT, "_scan", "G-code move scanner (C)", -1, module_methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__scan(void) {
#ifdef FAST_MOVES
    fast_init();
#endif
    if (PyType_Ready(&ScannerType) < 0) return NULL;
    PyObject *m = PyModule_Create(&scan_module);
    if (!m) return NULL;
    ScanUnsupported = PyErr_NewException("bulgekit.gcode._scan.ScanUnsupported", NULL, NULL);
    PyModule_AddObject(m, "ScanUnsupported", ScanUnsupported);
    Py_INCREF(&ScannerType);
    PyModule_AddObject(m, "Scanner", (PyObject *)&ScannerType);
    PyModule_AddIntConstant(m, "RECORD_SIZE", (long)sizeof(Record));
    /* what gcode.SCAN_VERSION expects: a module built from an older _scan.c is not used */
    PyModule_AddIntConstant(m, "VERSION", 11);
    return m;
}
