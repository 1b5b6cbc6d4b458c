#include "bulge_planner.h"

#include <math.h>
#include <string.h>

#include "float_bits.h"
#include "gcode_args.h"

#include "reply_text.h"
#include "float_strict.h"  // last: no fused multiply-add below

namespace bk {

// A loop over the axes stays a loop: GCC -Os unrolls two or three float
// iterations (each float operation a library call with its register moves),
// which is larger. The empty asm hides the counter's value from it.
static inline uint8_t next_axis(uint8_t k) {
  __asm__("" : "+r"(k));
  return (uint8_t)(k + 1);
}
#define BK_AXIS_LOOP(k, n) for (uint8_t k = 0; k < (n); k = next_axis(k))

// The hot path runs once per G1 on an 8-bit CPU where every float compare or
// multiply is a library call (~50-150 cycles), so cheap tests work on the
// IEEE-754 bits (float_bits.h) and the per-point work is integer.

// ---- setup --------------------------------------------------------------------

// Not inlined: the constructor and a settings reset (M502) share one copy.
__attribute__((noinline)) void BulgePlanner::reset() {
  // Everything not set below starts at zero: no layer, no miss, no cache, no
  // move in progress, nothing owed, no stats.
  memset((void *)this, 0, sizeof(*this));
  dwell_ms_ = BK_DEFAULT_DWELL_MS;
  extra_e_ = BK_DEFAULT_EXTRA_E_MM;
  tol_mm_ = BK_DEFAULT_TOLERANCE_MM;
  q_um_ = 50;
  lh_cmm_ = 30;
  derive();
}

#if BK_PLAN_STATS
void BulgePlanner::clear_stats() { memset(&stats_, 0, sizeof(stats_)); }
#define BK_STAT(x) x
#else
#define BK_STAT(x)
#endif

// Values that depend on the quantum and the tolerance, computed once here
// rather than per move.
void BulgePlanner::derive() {
  inv_q_ = 1000.0f / (float)q_um_;
  // Move ends are truncated to whole quanta (error < 1 q per axis, < sqrt(2) q
  // in distance), so the integer prefilter widens the tolerance by 2 q: it may
  // pass a few extra candidates to the exact test but never rejects a hit.
  // Truncated + 1 covers the tolerance itself (no ceilf in the firmware).
  tol_q_ = (int16_t)((int16_t)(tol_mm_ * inv_q_) + 3);
  cache_ok_ = false;
}

void BulgePlanner::map_changed() {
  has_layer_ = has_miss_ = has_defer_ = false;
  memset(defer_, 0, sizeof(defer_));
  layer_.count = 0;
  if (store_ && store_->loaded()) {
    const MapInfo &in = store_->info();
    if (in.quantum_um != q_um_ || in.layer_height_cmm != lh_cmm_) {
      q_um_ = in.quantum_um;
      lh_cmm_ = in.layer_height_cmm;
      derive();
    }
  }
}

// Sort by x, then y, so a move's x range is found by binary search. Insertion
// sort: stable, no recursion, and run once per layer.
static void sort_points(MapLayer &l) {
  for (uint8_t i = 1; i < l.count; i++) {
    MapPoint p = l.pts[i];
    uint8_t j = i;
    while (j && (l.pts[j - 1].x > p.x || (l.pts[j - 1].x == p.x && l.pts[j - 1].y > p.y))) {
      l.pts[j] = l.pts[j - 1];
      j--;
    }
    l.pts[j] = p;
  }
}

void BulgePlanner::load_layer(const MapLayer &layer, uint8_t quantum_um, uint8_t layer_height_cmm) {
  layer_.z_cmm = layer.z_cmm;
  layer_.count = layer.count > BK_LAYER_POINTS_MAX ? BK_LAYER_POINTS_MAX : layer.count;
  memcpy(layer_.pts, layer.pts, sizeof(MapPoint) * layer_.count);
  sort_points(layer_);
  memset(fired_, 0, sizeof(fired_));
  memset(defer_, 0, sizeof(defer_));
  has_defer_ = false;
  if (quantum_um != q_um_ || layer_height_cmm != lh_cmm_) {
    q_um_ = quantum_um ? quantum_um : 1;
    lh_cmm_ = layer_height_cmm;
    derive();
  }
  has_layer_ = true;
  has_miss_ = false;
  set_window(-1, INT32_MAX);  // a layer given directly: no neighbours known
  seen_last_z_ = store_ ? store_->last_z() : 0;
  BK_STAT(stats_.layers_loaded++);
}

// ---- layer window --------------------------------------------------------------

// The z range (cmm) where the loaded layer is the one find_layer would choose:
// within half a layer height (|dz|*2 <= h), and nearer than the records next
// to it, the lower one on a tie (2 z > layer + below, 2 z <= layer + above).
// Clamped to 0..65535: a z outside asks find_layer, which answers the same.
void BulgePlanner::set_window(int32_t below, int32_t above) {
  const uint16_t z = layer_.z_cmm, h = lh_cmm_ >> 1;
  uint16_t lo = z > h ? (uint16_t)(z - h) : 0, hi = z < 0xFFFF - h ? (uint16_t)(z + h) : 0xFFFF;
  // floor((a + b) / 2) of two uint16 without overflow: (a & b) + ((a ^ b) >> 1)
  if (below >= 0) {
    const uint16_t b = (uint16_t)below, mid = (uint16_t)((z & b) + ((z ^ b) >> 1) + 1);
    if (mid > lo) lo = mid;
  }
  if (above <= 0xFFFF) {
    const uint16_t a = (uint16_t)above, mid = (uint16_t)((z & a) + ((z ^ a) >> 1));
    if (mid < hi) hi = mid;
  }
  win_lo_ = lo;
  win_hi_ = hi;
}

// z (mm) in 0.01 mm, rounded half away from zero: |v| + 0.5 truncated, the
// sign put back.
__attribute__((noinline)) static int32_t to_cmm(float z) {
  uint32_t u = fbits(z * 100.0f);
  const bool neg = u & 0x80000000UL;
  u &= 0x7FFFFFFFUL;
  float a;
  memcpy(&a, &u, sizeof a);
  const int32_t c = (int32_t)(a + 0.5f);
  return neg ? -c : c;
}

// True when the loaded layer is the one for z_cmm without asking the store:
// its own z (see eligible()), or inside its window while nothing was appended.
__attribute__((noinline)) bool BulgePlanner::keeps(int32_t z_cmm) const {
  if (!has_layer_) return false;
  if (z_cmm == (int32_t)layer_.z_cmm) return true;
  const bool appended = store_ && store_->last_z() != seen_last_z_;
  return !appended && z_cmm >= win_lo_ && z_cmm <= win_hi_;
}

// True when a layer within half a layer height of z (mm) is loaded, asking the
// store when z has left the current one's window. Continuously rising z
// (spiral vase) walks from layer to layer the same way.
bool BulgePlanner::window(float z) {
  int32_t z_cmm = cache_z_cmm_;
  if (fbits(z) != fbits(cache_z_)) {  // kept for the next move
    z_cmm = to_cmm(z);
    cache_z_ = z;
    cache_z_cmm_ = z_cmm;
  }
  if (keeps(z_cmm)) return true;
  if (!store_ || (has_miss_ && z_cmm == miss_z_ && store_->last_z() == seen_last_z_)) return false;
  if (!store_->loaded() || store_->empty()) return false;
  seen_last_z_ = store_->last_z();
  const uint16_t old_z = layer_.z_cmm;
  const bool had = has_layer_;
  if (!store_->find_layer(z_cmm, layer_)) {
    has_miss_ = true;  // find_layer leaves layer_ alone on a miss
    miss_z_ = z_cmm;
    return false;
  }
  has_miss_ = false;
  has_layer_ = true;
  sort_points(layer_);
  int32_t below, above;
  store_->neighbors(layer_.z_cmm, below, above);
  set_window(below, above);
  // Only a different layer starts with no point fired: the same one read again
  // (after an append) keeps its marks, so no point dwells twice.
  if (had && layer_.z_cmm == old_z) return true;
  BK_STAT(stats_.layers_loaded++);
  memset(fired_, 0, sizeof(fired_));
  // Printing moved up: the layers below are done, give their bytes back (room
  // for appended records). Never on the way down, so nothing still needed goes.
  if (!had || layer_.z_cmm > old_z) store_->release_below(layer_.z_cmm);
  return true;
}

// ---- matching -------------------------------------------------------------------

// mm -> quanta, truncated (derive() widens the tolerance for that). Beyond
// +-2^14 quanta the result saturates and far is set: the caller then skips the
// integer tests, whose products would no longer fit 32 bits. The range check
// is an integer compare of the float's bits, not a float compare. Inlined: a
// call per conversion would cost a wall move about 130 cycles for 36 bytes.
static inline int16_t to_q(float mm, float inv_q, bool &far) {
  const float v = mm * inv_q;
  const uint32_t u = fbits(v);
  if ((u & 0x7FFFFFFFUL) >= 0x46800000UL) {  // 2^14
    far = true;
    return (u & 0x80000000UL) ? (int16_t)-16384 : (int16_t)16384;
  }
  return (int16_t)(int32_t)v;
}

// The mode allows the move and it extrudes with XY motion (the layer aside).
bool BulgePlanner::qualifies(const Move &m) const {
  if (mode_ == BULGE_OFF || (mode_ == BULGE_MARKED && !marker_)) return false;
  return fpos(m.e) && (fbits(m.x0) != fbits(m.x1) || fbits(m.y0) != fbits(m.y1));
}

bool BulgePlanner::eligible(const Move &m) {
  if (!qualifies(m)) return false;
  // The common case inline: a whole layer printed at the layer's own z (no
  // other layer can be nearer, appended or not). window() handles the rest.
  if (fbits(m.z1) == fbits(cache_z_) && has_layer_ && cache_z_cmm_ == (int32_t)layer_.z_cmm) return layer_.count != 0;
  return window(m.z1) && layer_.count;
}

// The move's XY extent fd[0], fd[1] (mm) and its length squared, returned.
static float extent(const Move &mv, float *fd) {
  float s = 0.0f;
  BK_AXIS_LOOP(k, 2) {
    fd[k] = mv.p[3 + k] - mv.p[k];
    s += fd[k] * fd[k];
  }
  return s;
}

// Exact test in mm against the host's own segment: true and t (the parameter
// of the point's foot, raised to 0, above 1 when the foot lies beyond B) when
// point i lies within the tolerance of the segment. fd
// holds the move's XY extent and fd[2] its length squared, set by the first
// call of a collect() (fd[2] < 0 until then).
bool BulgePlanner::exact(const Move &mv, uint8_t i, float *fd, float &t) {
  if (fbits(fd[2]) & 0x80000000UL) fd[2] = extent(mv, fd);
  if (!fbits(fd[2])) return false;  // no real motion (a sum of squares is never -0)
  const float q_mm = (float)q_um_ * 0.001f;
  float u[2], dot = 0.0f;
  BK_AXIS_LOOP(k, 2) {
    u[k] = (float)(k ? layer_.pts[i].y : layer_.pts[i].x) * q_mm - mv.p[k];
    dot += u[k] * fd[k];
  }
  t = dot / fd[2];
  if (t < 0.0f) t = 0.0f;
  // t above 1 is kept (the caller defers such a point), the distance is to B
  const float tc = t > 1.0f ? 1.0f : t;
  float e2 = 0.0f;
  BK_AXIS_LOOP(k, 2) {
    const float d = u[k] - tc * fd[k];
    e2 += d * d;
  }
  return e2 <= tol_mm_ * tol_mm_;
}

// Finds the unfired point within the tolerance of segment mv nearest to its
// start (hit_, hit_i_, hit_t_); more_ tells that others were found beyond it.
// Run again after that point has fired, it finds the next one.
void BulgePlanner::collect(const Move &mv) {
  hit_ = more_ = false;
  int16_t ax, ay;
  bool far = false;
  if (cache_ok_ && fbits(mv.x0) == fbits(cache_x_) && fbits(mv.y0) == fbits(cache_y_)) {
    ax = cache_qx_;
    ay = cache_qy_;
    far = cache_far_;
  } else {
    ax = to_q(mv.x0, inv_q_, far);
    ay = to_q(mv.y0, inv_q_, far);
  }
  bool far_end = false;
  const int16_t bx = to_q(mv.x1, inv_q_, far_end), by = to_q(mv.y1, inv_q_, far_end);
  far |= far_end;
  cache_x_ = mv.x1;
  cache_y_ = mv.y1;
  cache_qx_ = bx;
  cache_qy_ = by;
  cache_far_ = far_end;
  cache_ok_ = true;

  // Bounding box of the capsule around the segment, in quanta (int16: ends
  // are within +-2^14 and tol_q_ below 2^13). A far move takes every point
  // to the exact test.
  int16_t x_lo = -32768, x_hi = 32767, y_lo = -32768, y_hi = 32767;
  if (!far) {
    x_lo = (int16_t)((ax < bx ? ax : bx) - tol_q_);
    x_hi = (int16_t)((ax < bx ? bx : ax) + tol_q_);
    y_lo = (int16_t)((ay < by ? ay : by) - tol_q_);
    y_hi = (int16_t)((ay < by ? by : ay) + tol_q_);
  }
  const MapPoint *pts = layer_.pts;
  const uint8_t n = layer_.count;

  // The first point with x >= x_lo by binary search.
  uint8_t lo = 0, hi = n;
  while (lo < hi) {
    uint8_t mid = (uint8_t)((lo + hi) >> 1);
    if (pts[mid].x < x_lo)
      lo = (uint8_t)(mid + 1);
    else
      hi = mid;
  }
  if (lo == n || pts[lo].x > x_hi) return;  // most moves: nothing in the x range

  // Below 2^14 quanta of box per side every product of the line test fits
  // int32; longer moves (over 800 mm at 50 um) go to the exact test directly.
  const bool narrow = !far && (int32_t)x_hi - x_lo < 16384 && (int32_t)y_hi - y_lo < 16384;
  const int16_t dx = (int16_t)(bx - ax), dy = (int16_t)(by - ay);
  int32_t lim = -1;  // computed when a point first passes the box

  // Walk the x range. Once a hit is kept, a point whose integer distance along
  // the move is clearly beyond it skips the float test.
  int32_t dot_cut = 0;
  float fd[3] = {0.0f, 0.0f, -1.0f};  // extent and length squared, from exact()
  for (uint8_t i = lo; i < n && pts[i].x <= x_hi; i++) {
    const int16_t py = pts[i].y;
    if (py < y_lo || py > y_hi || (fired_[i >> 3] & (uint8_t)(1 << (i & 7)))) continue;
    int32_t dot = 0;
    if (narrow) {
      if (lim < 0) {
        // |cross| / |d| is the distance to the line; |d| is bounded above by
        // max + min/2 (no sqrt), so the test is loose, never tight.
        uint16_t adx = (uint16_t)(dx < 0 ? -dx : dx), ady = (uint16_t)(dy < 0 ? -dy : dy);
        uint16_t lub = adx > ady ? (uint16_t)(adx + ady / 2) : (uint16_t)(ady + adx / 2);
        lim = (int32_t)tol_q_ * (int32_t)lub;
      }
      const int16_t ux = (int16_t)(pts[i].x - ax), uy = (int16_t)(py - ay);
      int32_t cross = (int32_t)ux * dy - (int32_t)uy * dx;
      if (cross < 0) cross = -cross;
      if (cross > lim) continue;
      dot = (int32_t)ux * dx + (int32_t)uy * dy;
      // "Clearly" beyond = by more than the rounding slack of the ends
      // (tol_q_ quanta times |d|): it waits for the next collect().
      if (hit_ && dot > dot_cut) {
        more_ = true;
        continue;
      }
    }
    float t;
    if (!exact(mv, i, fd, t)) continue;
    if (t > 1.0f) {
      // Its foot lies beyond B, on the next edge if the wall turns there: the
      // next move decides (flush()), so a corner point stops at its foot, not
      // at the vertex up to T away.
      defer_[i >> 3] |= (uint8_t)(1 << (i & 7));
      has_defer_ = true;
      continue;
    }
    if (hit_) {
      more_ = true;
      if (t >= hit_t_) continue;  // equal t: the first in sorted order goes first
    }
    hit_ = true;
    hit_t_ = t;
    hit_i_ = i;
    dot_cut = dot + lim;
  }
}

// ---- output ----------------------------------------------------------------------

// A LINE action to (x, y, z) extruding e.
static Action &put_line(ActionList &out, float x, float y, float z, float e) {
  Action &a = out.a[out.count++];
  a.kind = Action::LINE;
  a.x = x;
  a.y = y;
  a.z = z;
  a.e = e;
  return a;
}

// The line a gets the extra owed from the stop before it. The caller checks
// that something is owed (the common case has nothing: no call).
void BulgePlanner::pay_owed(ActionList &out, Action &a) {
  a.e += owed_;
  out.e_added += owed_;
  BK_STAT(stats_.extra_applied += owed_);
  owed_ = 0.0f;
}

// A LINE to the point at t of the move (its own end at t = 1) extruding e,
// plus what is owed from the stop before it.
void BulgePlanner::line_to(ActionList &out, float t, float e) {
  const Move &m = *m_;
  float p[3];
  const bool inside = t < 1.0f;
  for (uint8_t k = 0; k < 3; k++) {
    p[k] = m.p[3 + k];  // the end: the host's own numbers, not a recomputation
    // z only when it changes along the move (spiral vase)
    if (inside && (k < 2 || fbits(m.z0) != fbits(m.z1))) p[k] = m.p[k] + t * (m.p[3 + k] - m.p[k]);
  }
  Action &a = put_line(out, p[0], p[1], p[2], e);
  stop_ms_ = 0;  // the head moves on: the next stop starts afresh
  if (fbits(owed_)) pay_owed(out, a);
}

// Point i stops where the head is now: marked fired, a DWELL, its extra owed
// to the next piece.
void BulgePlanner::stop(ActionList &out, uint8_t i) {
  fired_[i >> 3] |= (uint8_t)(1 << (i & 7));
  BK_STAT(stats_.points_fired++);
  // P * w / 255, rounded (w = 255 gives P itself)
  uint16_t ms = (uint16_t)(((uint32_t)dwell_ms_ * layer_.pts[i].w + 127) / 255);
  // Points closer than the minimum piece share one stop (also across moves,
  // at a shared vertex): one DWELL, their dwell and extra added up, but one
  // stop never exceeds the hard limits M720 enforces for a single point.
  if (ms > BK_MAX_DWELL_MS - stop_ms_) ms = (uint16_t)(BK_MAX_DWELL_MS - stop_ms_);
  stop_ms_ = (uint16_t)(stop_ms_ + ms);
  if (out.count && out.a[out.count - 1].kind == Action::DWELL) {
    out.a[out.count - 1].ms = (uint16_t)(out.a[out.count - 1].ms + ms);
  } else {
    Action &a = out.a[out.count++];
    a.kind = Action::DWELL;
    a.ms = ms;  // x, y, z are not used
  }
  float extra = extra_e_;
  const float room = BK_MAX_EXTRA_E_MM - owed_;
  if (extra > room) {
    extra = room > 0.0f ? room : 0.0f;
    BK_STAT(stats_.extra_dropped += extra_e_ - extra);
  }
  owed_ += extra;
}

// Turns the hits into actions, one point at a time (collect() again after
// each); true when the move continues in plan_more(). Points that share a stop
// (closer than the minimum piece) go into one DWELL, so a list ends only
// before a cut: the point that needs one stays in hit_ for the next list.
bool BulgePlanner::emit(ActionList &out) {
  float fd[2];
  const float len = sqrtf(extent(*m_, fd));  // the same numbers exact() used
  while (hit_) {
    float t = hit_t_;
    if ((t - t_done_) * len >= BK_MIN_PIECE_MM) {
      // A line to the stop, the stop and a line after it must fit.
      if (out.count + 3 > BK_PLAN_ACTIONS_MAX) return true;
      if ((1.0f - t) * len < BK_MIN_PIECE_MM) t = 1.0f;  // stop at the move end
      line_to(out, t, m_->e * (t - t_done_));
      t_done_ = t;
    }
    // Otherwise the point is too close to where the head already is (the move
    // start, or the stop before; or, by less than a quantum of ordering slack,
    // just behind it): it stops there instead of queueing a sub-step piece.
    stop(out, hit_i_);
    hit_ = false;
    if (more_) collect(*m_);
  }
  // The rest of the move (an untouched move: the host's E as it is); a stop
  // at its last vertex leaves the extra owed to the next move's first piece.
  if (t_done_ < 1.0f) line_to(out, 1.0f, fbits(t_done_) ? m_->e * (1.0f - t_done_) : m_->e);
  return false;
}

// A move that moves nothing: Marlin hands "G1 F1200" to us too.
static bool still(const Move &m) { return m.x0 == m.x1 && m.y0 == m.y1 && m.z0 == m.z1 && m.e == 0.0f; }

// Points the previous move deferred (feet beyond its end B, which is where the
// head is now). This move takes over those within the tolerance of it when it
// continues the wall from B (it starts at B, qualifies, and its z keeps the
// layer): collect() finds them on it. Such a point is within T of B, so of the
// move too; the exact test here only guards against rounding, which would
// otherwise lose it. The others stop at B now, before this move, as they did
// before the rule: at the vertex. If something moved the head meanwhile (an
// arc, homing: the move does not start at B) they stay unfired for a later
// move of the layer. A move that moves nothing waits.
void BulgePlanner::flush(const Move &m, ActionList &out) {
  if (still(m)) return;
  has_defer_ = false;
  const bool at_b = fbits(m.x0) == fbits(cache_x_) && fbits(m.y0) == fbits(cache_y_);
  // (a move into another layer's window would replace the layer: not "on")
  const bool on = at_b && qualifies(m) && keeps(to_cmm(m.z1));
  float fd[3] = {0.0f, 0.0f, -1.0f};
  for (uint8_t i = 0; i < layer_.count; i++) {
    const uint8_t bit = (uint8_t)(1 << (i & 7));
    if (!(defer_[i >> 3] & bit)) continue;
    defer_[i >> 3] &= (uint8_t)~bit;
    float t;
    if (at_b && !(on && exact(m, i, fd, t))) stop(out, i);
  }
}

// A move the planner leaves alone, as one LINE. A move that moves nothing
// (Marlin hands "G1 F1200" to us too) keeps the extra owed from a stop at a
// wall's end for the next piece; any real travel, retraction or non-wall move
// ends the wall, and the extra is not extruded (counted as dropped).
void BulgePlanner::pass(const Move &m, ActionList &out) {
  if (!still(m)) {
    if (fbits(owed_)) {
      BK_STAT(stats_.extra_dropped += owed_);
      owed_ = 0.0f;
    }
    stop_ms_ = 0;
  }
  put_line(out, m.x1, m.y1, m.z1, m.e);
}

bool BulgePlanner::plan(const Move &m, ActionList &out) {
  out.count = 0;
  out.e_added = 0.0f;
  hit_ = false;  // a move left unfinished is given up
  m_ = &m;
  // Before eligible(): a new layer would replace the deferred points' layer.
  if (has_defer_) flush(m, out);
  if (!eligible(m)) {
    pass(m, out);
    return false;
  }
  t_done_ = 0.0f;
  collect(m);
  if (hit_) {
    BK_STAT(stats_.moves_split++);
    return emit(out);
  }
  // Nothing on this move (the common case): the move unchanged, plus any
  // extra owed from a stop at its start, without float work.
  Action &a = put_line(out, m.x1, m.y1, m.z1, m.e);
  stop_ms_ = 0;
  if (fbits(owed_)) pay_owed(out, a);
  return false;
}

bool BulgePlanner::plan_more(ActionList &out) {
  out.count = 0;
  out.e_added = 0.0f;
  return hit_ && emit(out);
}

// ---- M720 / M722 --------------------------------------------------------------------

// M720's settings in the order of its report: S P E T. S and P are whole
// numbers. T's floor allows for the parser's rounding of "0.01".
static const Limit M720_LIMITS[4] BK_FLASH = {
    {'S', false, 0.0f, 2.0f},
    {'P', false, 0.0f, (float)BK_MAX_DWELL_MS},
    {'E', false, 0.0f, BK_MAX_EXTRA_E_MM},
    {'T', false, 0.01f - 1e-6f, BK_MAX_TOLERANCE_MM},
};

static const char M720_CODE[] BK_FLASH = "M720";

void BulgePlanner::report(ReplyText &r, bool echo) const {
  if (echo) r.p(BK_F("echo:"));
  r.p(BK_F("  M720"));
  const float v[4] = {(float)mode_, (float)dwell_ms_, extra_e_, tol_mm_};
  for (uint8_t i = 0; i < 4; i++) {
    r.c(' ');
    r.c((char)BK_RD8(&M720_LIMITS[i].letter));
    r.fixed(v[i], i < 2 ? 0 : 3);
  }
}

// Value v for word i (S P E T) within its limits, and S and P whole numbers;
// otherwise one Error: line.
static bool check(uint8_t i, float v, ReplyText &r) {
  Limit lim;
  BK_RDBLOCK(&lim, &M720_LIMITS[i], sizeof(lim));
  if (!check_limit(lim, v, M720_CODE, r)) return false;
  if (i < 2 && v != (float)(int16_t)v) {
    r.p(BK_F("Error:M720 "));
    r.c(lim.letter);
    r.fixed(v, 3);
    r.p(BK_F(" not a whole number"));
    return false;
  }
  return true;
}

// All of S P E T in force at once (after every check passed).
void BulgePlanner::apply(const float *v) {
  mode_ = (uint8_t)v[0];
  dwell_ms_ = (uint16_t)v[1];
  extra_e_ = v[2];
  tol_mm_ = v[3];
  derive();
}

bool BulgePlanner::restore(float dwell_ms, float extra_e, float tolerance, ReplyText &r) {
  const float v[4] = {(float)mode_, dwell_ms, extra_e, tolerance};
  for (uint8_t i = 1; i < 4; i++)
    if (!check(i, v[i], r)) return false;
  apply(v);
  return true;
}

bool BulgePlanner::m720(const GcodeArgs &a, ReplyText &r) {
  if (a.none()) {
    report(r, true);
    return true;
  }
  if (!check_words(a, BK_F("SPET"), M720_CODE, r)) return false;  // the letters of M720_LIMITS
  // Check everything first, then apply: all or nothing.
  float v[4] = {(float)mode_, (float)dwell_ms_, extra_e_, tol_mm_};
  for (uint8_t i = 0; i < 4; i++) {
    const int8_t k = read_number(a, (char)BK_RD8(&M720_LIMITS[i].letter), M720_CODE, v[i], r);
    if (k < 0 || (k && !check(i, v[i], r))) return false;
  }
  apply(v);
  return true;
}

bool BulgePlanner::m722(const GcodeArgs &a, ReplyText &r) {
  if (!check_words(a, BK_F("S"), BK_F("M722"), r)) return false;
  uint32_t s;  // get_ulong, as M721 uses: one reader less in the firmware
  if (a.get_ulong('S', s) != ARG_OK || s > 1) {
    r.p(BK_F("Error:M722 needs S0 or S1"));
    return false;
  }
  marker_ = s == 1;
  return true;
}

}  // namespace bk
