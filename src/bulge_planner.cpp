#include "bulge_planner.h"

#include <math.h>
#include <string.h>

#include "gcode_args.h"

#include "reply_text.h"

namespace bk {

// ---- reply text (messages stay in flash on AVR) -----------------------------

namespace {

// "Error:M720 P" + the word exactly as the host wrote it
void error_word(ReplyText &r, const GcodeArgs &a, const char *code_P, char letter) {
  r.p(BK_F("Error:"));
  r.p(code_P);
  r.c(' ');
  r.c(letter);
  const char *t;
  uint8_t n;
  if (a.raw(letter, t, n)) r.raw(t, n);
}

}  // namespace

// ---- setup --------------------------------------------------------------------

void BulgePlanner::reset() {
  mode_ = BULGE_OFF;
  marker_ = false;
  dwell_ms_ = BK_DEFAULT_DWELL_MS;
  extra_e_ = BK_DEFAULT_EXTRA_E_MM;
  tol_mm_ = BK_DEFAULT_TOLERANCE_MM;
  store_ = nullptr;
  has_layer_ = has_miss_ = cache_ok_ = overflow_ = active_ = false;
  q_um_ = 50;
  lh_cmm_ = 30;
  miss_z_ = 0;
  below_z_ = -1;
  above_z_ = INT32_MAX;
  seen_last_z_ = 0;
  cache_z_ = 0.0f;  // z 0 is 0 cmm: a consistent starting pair
  cache_z_cmm_ = 0;
  cache_x_ = cache_y_ = 0.0f;
  cache_qx_ = cache_qy_ = 0;
  len_ = len2_ = t_done_ = 0.0f;
  layer_.count = 0;
  layer_.z_cmm = 0;
  carry_ = pending_ = 0.0f;
  stop_ms_ = 0;
  nhit_ = 0;
  memset(fired_, 0, sizeof(fired_));
  clear_stats();
  derive();
}

void BulgePlanner::clear_stats() { memset(&stats_, 0, sizeof(stats_)); }

// Values that depend on the quantum and the tolerance, computed once here
// rather than per move.
void BulgePlanner::derive() {
  q_mm_ = (float)q_um_ * 0.001f;
  inv_q_ = 1000.0f / (float)q_um_;
  tol2_ = tol_mm_ * tol_mm_;
  // Move ends are truncated to whole quanta (error < 1 q per axis, < sqrt(2) q
  // in distance), so the integer prefilter widens the tolerance by 2 q: it may
  // pass a few extra candidates to the exact test but never rejects a hit.
  tol_q_ = (int16_t)(ceilf(tol_mm_ * inv_q_) + 2.0f);
  cache_ok_ = false;
}

void BulgePlanner::map_changed() {
  has_layer_ = has_miss_ = false;
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
  if (quantum_um != q_um_ || layer_height_cmm != lh_cmm_) {
    q_um_ = quantum_um ? quantum_um : 1;
    lh_cmm_ = layer_height_cmm;
    derive();
  }
  has_layer_ = true;
  has_miss_ = false;
  below_z_ = -1;  // a layer given directly: no neighbours known
  above_z_ = INT32_MAX;
  seen_last_z_ = store_ ? store_->last_z() : 0;
  stats_.layers_loaded++;
}

// ---- layer window --------------------------------------------------------------

// True when a layer within half a layer height of z_cmm is loaded, asking the
// store when z has left the current one or a neighbouring layer is nearer
// (layers closer than a layer height, e.g. adaptive layer heights): the same
// layer find_layer would choose, the lower one on a tie. Continuously rising z
// (spiral vase) walks from layer to layer the same way.
bool BulgePlanner::window(int32_t z_cmm) {
  if (has_layer_ && z_cmm == (int32_t)layer_.z_cmm) return true;  // see eligible()
  const bool appended = store_ && store_->last_z() != seen_last_z_;
  if (has_layer_ && !appended) {
    const int32_t d = z_cmm - (int32_t)layer_.z_cmm;
    if (d > 0 ? (2 * d <= (int32_t)lh_cmm_ && (above_z_ == INT32_MAX || d <= above_z_ - z_cmm))
              : (-2 * d <= (int32_t)lh_cmm_ && (below_z_ < 0 || -d < z_cmm - below_z_)))
      return true;
  }
  if (!store_ || (has_miss_ && z_cmm == miss_z_ && !appended)) return false;
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
  store_->neighbors(layer_.z_cmm, below_z_, above_z_);
  // Only a different layer starts with no point fired: the same one read again
  // (after an append) keeps its marks, so no point dwells twice.
  if (had && layer_.z_cmm == old_z) return true;
  stats_.layers_loaded++;
  memset(fired_, 0, sizeof(fired_));
  // Printing moved up: the layers below are done, give their bytes back (room
  // for appended records). Never on the way down, so nothing still needed goes.
  if (!had || layer_.z_cmm > old_z) store_->release_below(layer_.z_cmm);
  return true;
}

// ---- matching -------------------------------------------------------------------

// The hot path runs once per G1 on an 8-bit CPU where every float compare or
// multiply is a library call (~50-150 cycles), so cheap tests work on the
// IEEE-754 bits and the per-point work is integer.
static inline uint32_t fbits(float f) {
  uint32_t u;
  memcpy(&u, &f, sizeof u);
  return u;
}
static inline bool fpos(float f) {  // > 0 (not -0, not NaN from the parser)
  uint32_t u = fbits(f);
  return u && !(u & 0x80000000UL);
}

// mm -> quanta, truncated (derive() widens the tolerance for that). Beyond
// +-2^14 quanta the result saturates and far is set: the caller then skips the
// integer tests, whose products would no longer fit 32 bits. The range check
// is an integer compare of the float's bits, not a float compare.
static inline int16_t to_q(float mm, float inv_q, bool &far) {
  const float v = mm * inv_q;
  const uint32_t u = fbits(v);
  if ((u & 0x7FFFFFFFUL) >= 0x46800000UL) {  // 2^14
    far = true;
    return (u & 0x80000000UL) ? (int16_t)-16384 : (int16_t)16384;
  }
  return (int16_t)(int32_t)v;
}

bool BulgePlanner::eligible(const Move &m) {
  if (mode_ == BULGE_OFF || (mode_ == BULGE_MARKED && !marker_)) return false;
  if (!fpos(m.e) || (fbits(m.x0) == fbits(m.x1) && fbits(m.y0) == fbits(m.y1))) return false;
  int32_t zc;
  if (fbits(m.z1) == fbits(cache_z_)) {
    zc = cache_z_cmm_;
  } else {
    float v = m.z1 * 100.0f;
    zc = v >= 0.0f ? (int32_t)(v + 0.5f) : -(int32_t)(0.5f - v);
    cache_z_ = m.z1;
    cache_z_cmm_ = zc;
  }
  // The common case inline: a whole layer printed at the layer's own z (no
  // other layer can be nearer, appended or not). window() handles the rest.
  if (has_layer_ && zc == (int32_t)layer_.z_cmm) return layer_.count != 0;
  return window(zc) && layer_.count;
}

// Exact test in mm against the host's own segment: true and t (0..1, the
// parameter of the nearest point) when point i lies within the tolerance.
bool BulgePlanner::exact(const Move &mv, uint8_t i, float &t) {
  if (len2_ < 0.0f) {  // first candidate of this move
    fdx_ = mv.x1 - mv.x0;
    fdy_ = mv.y1 - mv.y0;
    len2_ = fdx_ * fdx_ + fdy_ * fdy_;
  }
  if (len2_ == 0.0f) return false;  // -0.0 vs 0.0: no real motion
  const float ux = (float)layer_.pts[i].x * q_mm_ - mv.x0, uy = (float)layer_.pts[i].y * q_mm_ - mv.y0;
  t = (ux * fdx_ + uy * fdy_) / len2_;
  if (t < 0.0f) t = 0.0f;
  if (t > 1.0f) t = 1.0f;
  const float ex = ux - t * fdx_, ey = uy - t * fdy_;
  return ex * ex + ey * ey <= tol2_;
}

// Finds the unfired points within the tolerance of segment m_ and keeps the
// BK_PLAN_HITS_MAX nearest to its start in hit_t_/hit_i_ (sorted by t).
// overflow_ tells that more were found than kept.
void BulgePlanner::collect(const Move &mv) {
  nhit_ = 0;
  overflow_ = false;
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
  if (lo == n || pts[lo].x > x_hi) return;

  // Below 2^14 quanta of box per side every product of the line test fits
  // int32; longer moves (over 800 mm at 50 um) go to the exact test directly.
  const bool narrow = !far && (int32_t)x_hi - x_lo < 16384 && (int32_t)y_hi - y_lo < 16384;
  const int16_t dx = (int16_t)(bx - ax), dy = (int16_t)(by - ay);
  int32_t lim = -1;  // computed when a point first passes the box

  // Walk the x range. Once the list is full, a point whose integer distance
  // along the move is beyond the last kept one skips the float test.
  int32_t dot_cut = 0;
  len2_ = -1.0f;
  for (uint8_t i = lo; i < n && pts[i].x <= x_hi; i++) {
    const int16_t py = pts[i].y;
    if (py >= y_lo && py <= y_hi && !(fired_[i >> 3] & (uint8_t)(1 << (i & 7)))) {
      int32_t dot = 0;
      bool pass = true;
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
        pass = cross <= lim;
        if (pass) {
          dot = (int32_t)ux * dx + (int32_t)uy * dy;
          // Full list: a point clearly further along than the last kept one
          // waits for plan_more(). "Clearly" = by more than the rounding
          // slack of the ends (tol_q_ quanta times |d|).
          if (nhit_ == BK_PLAN_HITS_MAX && dot > dot_cut) {
            overflow_ = true;
            pass = false;
          }
        }
      }
      float t;
      if (pass && exact(mv, i, t)) {
        // Insert by t; keep the nearest BK_PLAN_HITS_MAX, the rest come later.
        uint8_t j = nhit_;
        bool keep = true;
        if (j == BK_PLAN_HITS_MAX) {
          overflow_ = true;
          if (t >= hit_t_[j - 1])
            keep = false;
          else
            j--;
        } else {
          nhit_++;
        }
        if (keep) {
          while (j && hit_t_[j - 1] > t) {
            hit_t_[j] = hit_t_[j - 1];
            hit_i_[j] = hit_i_[j - 1];
            hit_d_[j] = hit_d_[j - 1];
            j--;
          }
          hit_t_[j] = t;
          hit_i_[j] = i;
          hit_d_[j] = dot;
          if (nhit_ == BK_PLAN_HITS_MAX) dot_cut = hit_d_[nhit_ - 1] + lim;
        }
      }
    }
  }
}

// ---- output ----------------------------------------------------------------------

void BulgePlanner::line_to(ActionList &out, float t, float e) {
  Action &a = out.a[out.count++];
  a.kind = Action::LINE;
  a.ms = 0;
  if (t >= 1.0f) {
    a.x = m_.x1;  // the host's own numbers, not a recomputation
    a.y = m_.y1;
    a.z = m_.z1;
  } else {
    a.x = m_.x0 + t * (m_.x1 - m_.x0);
    a.y = m_.y0 + t * (m_.y1 - m_.y0);
    a.z = fbits(m_.z0) == fbits(m_.z1) ? m_.z1 : m_.z0 + t * (m_.z1 - m_.z0);
  }
  a.e = e;
  stop_ms_ = 0;  // the head moves again: the next stop starts afresh
  if (fbits(pending_)) {
    a.e += pending_;
    out.e_added += pending_;
    stats_.extra_applied += pending_;
    pending_ = 0.0f;
  }
}

// Turns the collected hits into actions; true when the move continues in
// plan_more().
bool BulgePlanner::emit(ActionList &out) {
  if (nhit_) len_ = sqrtf(len2_);
  for (uint8_t h = 0; h < nhit_; h++) {
    float t = hit_t_[h];
    const uint8_t i = hit_i_[h];
    fired_[i >> 3] |= (uint8_t)(1 << (i & 7));
    stats_.points_fired++;
    if ((t - t_done_) * len_ < BK_MIN_PIECE_MM) {
      // Too close to where the head already is (the move start, or the stop
      // before; or, by less than a quantum of ordering slack, just behind it):
      // stop there instead of queueing a sub-step piece.
    } else {
      if ((1.0f - t) * len_ < BK_MIN_PIECE_MM) t = 1.0f;  // stop at the move end
      line_to(out, t, m_.e * (t - t_done_));
      t_done_ = t;
    }
    const uint8_t w = layer_.pts[i].w;
    uint16_t ms = w == MAP_WEIGHT_FULL ? dwell_ms_ : (uint16_t)(((uint32_t)dwell_ms_ * w + 127) / 255);
    // Points closer than the minimum piece share one stop (also across moves,
    // at a shared vertex). Their dwell and extra add up, but one stop never
    // exceeds the hard limits M720 enforces for a single point.
    if (ms > BK_MAX_DWELL_MS - stop_ms_) ms = (uint16_t)(BK_MAX_DWELL_MS - stop_ms_);
    stop_ms_ = (uint16_t)(stop_ms_ + ms);
    Action *last = out.count ? &out.a[out.count - 1] : nullptr;
    if (last && last->kind == Action::DWELL) {
      last->ms = (uint16_t)(last->ms + ms);
    } else {
      Action &a = out.a[out.count++];
      a.kind = Action::DWELL;
      a.ms = ms;
      a.x = a.y = a.z = a.e = 0.0f;
    }
    float extra = extra_e_;
    const float room = BK_MAX_EXTRA_E_MM - pending_;
    if (extra > room) {
      extra = room > 0.0f ? room : 0.0f;
      stats_.extra_dropped += extra_e_ - extra;
    }
    pending_ += extra;
  }
  if (overflow_) return true;
  if (!fbits(t_done_)) {
    line_to(out, 1.0f, m_.e);  // untouched move: the host's E as it is
  } else if (t_done_ < 1.0f) {
    line_to(out, 1.0f, m_.e * (1.0f - t_done_));
  } else {
    carry_ += pending_;  // the stop was at the last vertex: the next piece gets it
    pending_ = 0.0f;
  }
  active_ = false;
  return false;
}

void BulgePlanner::drop_carry() {
  if (carry_ != 0.0f) {
    stats_.extra_dropped += carry_;
    carry_ = 0.0f;
  }
}

// The host's move unchanged, plus any extra owed from a stop at its start.
static void whole(ActionList &out, const Move &m) {
  Action &a = out.a[out.count++];
  a.kind = Action::LINE;
  a.ms = 0;
  a.x = m.x1;
  a.y = m.y1;
  a.z = m.z1;
  a.e = m.e;
}

bool BulgePlanner::plan(const Move &m, ActionList &out) {
  out.count = 0;
  out.e_added = 0.0f;
  active_ = false;
  if (!eligible(m)) {
    // A move that moves nothing (Marlin hands "G1 F1200" to us too) keeps the
    // extra owed from a stop at a wall's end for the next piece; any real
    // travel, retraction or non-wall move ends it.
    const bool null_move = m.x0 == m.x1 && m.y0 == m.y1 && m.z0 == m.z1 && m.e == 0.0f;
    if (!null_move) {
      drop_carry();
      stop_ms_ = 0;
    }
    whole(out, m);
    return false;
  }
  collect(m);
  if (!nhit_ && !overflow_) {
    // Nothing on this move: the common case, kept free of float work.
    whole(out, m);
    stop_ms_ = 0;
    if (fbits(carry_)) {
      out.a[0].e += carry_;
      out.e_added = carry_;
      stats_.extra_applied += carry_;
      carry_ = 0.0f;
    }
    return false;
  }
  m_ = m;
  t_done_ = 0.0f;
  pending_ = carry_;
  carry_ = 0.0f;
  active_ = true;
  stats_.moves_split++;
  return emit(out);
}

bool BulgePlanner::plan_more(ActionList &out) {
  out.count = 0;
  out.e_added = 0.0f;
  if (!active_) return false;
  collect(m_);
  return emit(out);
}

// ---- M720 / M722 --------------------------------------------------------------------

bool BulgePlanner::m720(const GcodeArgs &a, char *reply, uint8_t size) {
  ReplyText r(reply, size);
  if (a.none()) {
    r.p(BK_F("echo:  M720 S"));
    r.u(mode_);
    r.p(BK_F(" P"));
    r.u(dwell_ms_);
    r.p(BK_F(" E"));
    r.fixed(extra_e_, 3);
    r.p(BK_F(" T"));
    r.fixed(tol_mm_, 3);
    return true;
  }
  const char *code = BK_F("M720");
  if (!check_words(a, "SPET", code, r)) return false;
  // Check everything first, then apply: all or nothing.
  int32_t s = mode_, p = dwell_ms_;
  float e = extra_e_, t = tol_mm_;
  ArgStatus st = a.get_long('S', s);
  if (st != ARG_ABSENT && (st != ARG_OK || s < 0 || s > 2)) {
    error_word(r, a, code, 'S');
    r.p(BK_F(": mode must be 0 (off), 1 (marked) or 2 (geometric)"));
    return false;
  }
  st = a.get_long('P', p);
  if (st != ARG_ABSENT && (st != ARG_OK || p < 0)) {
    error_word(r, a, code, 'P');
    r.p(BK_F(": dwell must be a whole number of ms, 0.."));
    r.u(BK_MAX_DWELL_MS);
    return false;
  }
  if (p > BK_MAX_DWELL_MS) {
    error_word(r, a, code, 'P');
    r.p(BK_F(" exceeds max dwell "));
    r.u(BK_MAX_DWELL_MS);
    r.p(BK_F(" ms"));
    return false;
  }
  st = a.get_float('E', e);
  if (st != ARG_ABSENT && (st != ARG_OK || e < 0.0f)) {
    error_word(r, a, code, 'E');
    r.p(BK_F(": extra must be 0.."));
    r.fixed(BK_MAX_EXTRA_E_MM, 3);
    r.p(BK_F(" mm"));
    return false;
  }
  if (e > BK_MAX_EXTRA_E_MM) {
    error_word(r, a, code, 'E');
    r.p(BK_F(" exceeds max extra "));
    r.fixed(BK_MAX_EXTRA_E_MM, 3);
    r.p(BK_F(" mm"));
    return false;
  }
  st = a.get_float('T', t);
  if (st != ARG_ABSENT && (st != ARG_OK || t < 0.01f - 1e-6f || t > BK_MAX_TOLERANCE_MM)) {
    error_word(r, a, code, 'T');
    r.p(BK_F(": tolerance must be 0.010.."));
    r.fixed(BK_MAX_TOLERANCE_MM, 3);
    r.p(BK_F(" mm"));
    return false;
  }
  mode_ = (uint8_t)s;
  dwell_ms_ = (uint16_t)p;
  extra_e_ = e;
  if (t != tol_mm_) {
    tol_mm_ = t;
    derive();
  }
  return true;
}

bool BulgePlanner::m722(const GcodeArgs &a, char *reply, uint8_t size) {
  ReplyText r(reply, size);
  if (!check_words(a, "S", BK_F("M722"), r)) return false;
  int32_t s = -1;
  ArgStatus st = a.get_long('S', s);
  if (st != ARG_OK || (s != 0 && s != 1)) {
    r.p(BK_F("Error:M722 needs S1 (enter outer wall) or S0 (leave)"));
    return false;
  }
  marker_ = s == 1;
  return true;
}

}  // namespace bk
