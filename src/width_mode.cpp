#include "width_mode.h"

#include <math.h>

#include "float_bits.h"
#include "reply_text.h"
#include "float_strict.h"  // last: no fused multiply-add below

namespace bk {

namespace {

const char kCode[] BK_FLASH = "M723";

// Limits of the words Q R D H L U, in the order of the settings they set (Q and R
// both set the target; L's upper end only matters through L <= U).
const Limit kLimits[] BK_FLASH = {
    {'Q', true, 0.0f, BK_WIDTH_MAX_FLOW_MM3S},
    {'R', true, 0.0f, BK_WIDTH_MAX_E_RATE},
    {'D', false, BK_WIDTH_MIN_FILAMENT_DIA, BK_WIDTH_MAX_FILAMENT_DIA},
    {'H', false, 0.0f, BK_WIDTH_MAX_LAYER_MM},
    {'L', false, BK_WIDTH_MIN_SPEED_LIMIT, BK_WIDTH_MAX_SPEED_LIMIT},
    {'U', false, BK_WIDTH_MIN_SPEED_LIMIT, BK_WIDTH_MAX_SPEED_LIMIT},
};
const uint8_t kWords = sizeof kLimits / sizeof kLimits[0];

// "Error:M723 " and the rest of the message: the prefix is stored once.
void error(ReplyText &o, const char *tail) {
  o.p(BK_F("Error:M723 "));
  o.p(tail);
}

// x > 0 on the bits (float_bits.h); noinline here and below: one copy for all
// callers, which LTO would inline.
__attribute__((noinline)) bool positive(float x) { return fpos(x); }

// XY length of a move, one routine for both hooks.
__attribute__((noinline)) float len_xy(float dx, float dy) { return sqrtf(dx * dx + dy * dy); }

// A ratio as a percentage with two decimals.
void percent(ReplyText &o, float ratio) {
  o.fixed(ratio * 100.0f, 2);
  o.c('%');
}

}  // namespace

// Not inlined: the constructor and a settings reset (M502) share one copy.
__attribute__((noinline)) void WidthMode::reset() {
  static const float kPowerOn[SETTINGS] BK_FLASH = {
      0.0f, BK_DEFAULT_FILAMENT_DIA_MM, 0.0f, BK_DEFAULT_WIDTH_MIN_SPEED, BK_DEFAULT_WIDTH_MAX_SPEED};
  on_ = false;
  target_kind_ = TARGET_NONE;
  BK_RDBLOCK(set_, kPowerOn, sizeof set_);
  percent_ = 100;
  stats_ = WidthStats();
  recompute();
}

// The target is 0 without Q or R, so R and "none" share the plain value.
float WidthMode::base_rate() const {
  return target_kind_ == TARGET_FLOW ? set_[TARGET] * inv_area_ : set_[TARGET];
}

// Derived values, so the per-move paths cost one multiply and one divide.
void WidthMode::recompute() {
  const float d = set_[DIA];
  inv_area_ = (4.0f / 3.14159265f) / (d * d);
  rate_ = base_rate() * (float)percent_ * 0.01f;
}

#if !BK_REPLY_SERIAL
bool WidthMode::command(const char *line, char *reply, uint8_t reply_size) {
  ReplyText o(reply, reply_size);
  GcodeArgs a;
  if (!a.parse(line)) {
    error(o, BK_F("not a G-code line"));
    return false;
  }
  return command(a, o);
}
#endif

bool WidthMode::command(const GcodeArgs &a, ReplyText &o) {
  if (a.none()) {
    report(o, true, true);
    return true;
  }
  if (!check_words(a, BK_F("SQRDHLU"), kCode, o)) return false;
  uint32_t s = (uint32_t)-1;  // get_ulong, as M721 and M722 use: one reader less in the firmware
  const ArgStatus st = a.get_ulong('S', s);
  if (st != ARG_ABSENT && (st != ARG_OK || s > 1)) {
    error(o, BK_F("S must be 0 or 1"));
    return false;
  }

  // Work on a copy and commit only when every word passed: all-or-nothing.
  WidthMode n = *this;
  bool q = false;  // this command has a Q
  for (uint8_t i = 0; i < kWords; i++) {
    Limit lim;
    BK_RDBLOCK(&lim, &kLimits[i], sizeof lim);
    float v;
    const int8_t got = read_limited(a, lim, kCode, v, o);
    if (got < 0) return false;
    if (!got) continue;
    uint8_t k = TARGET;
    if (i == 0) {
      q = true;
      n.target_kind_ = TARGET_FLOW;
    } else if (i == 1) {
      if (q) {
        error(o, BK_F("Q or R, not both"));
        return false;
      }
      n.target_kind_ = TARGET_RATE;
    } else {
      k = i - 1;
    }
    n.set_[k] = v;
  }
  return finish(n, (int8_t)s, o);
}

// The checks that involve several settings, then n in force (on: -1 keeps the
// mode, 0 leaves it, 1 enters it).
bool WidthMode::finish(WidthMode &n, int8_t on, ReplyText &o) {
  if (n.set_[MIN_V] > n.set_[MAX_V]) {  // also against the L or U in force
    error(o, BK_F("L"));
    o.fixed(n.set_[MIN_V], 3);
    o.p(BK_F(" > U"));
    o.fixed(n.set_[MAX_V], 3);
    return false;
  }
  n.recompute();
  // Q is checked against the flow limit; with a thin filament it may still ask
  // for an extruder rate beyond R's limit.
  const float r = n.base_rate();
  if (r > BK_WIDTH_MAX_E_RATE) {
    error(o, BK_F("extruder rate "));
    o.fixed(r, 3);
    o.p(BK_F(" > "));
    o.fixed(BK_WIDTH_MAX_E_RATE, 3);
    o.p(BK_F(" (Q, D)"));
    return false;
  }
  if (on == 1 && n.target_kind_ == TARGET_NONE) {
    error(o, BK_F("S1 needs Q or R"));
    return false;
  }
  if (on == 1 && !on_) n.stats_ = WidthStats();  // statistics count from entering the mode
  if (on >= 0) n.on_ = on;
  *this = n;
  return true;
}

bool WidthMode::restore(uint8_t kind, const float *v, ReplyText &o) {
  WidthMode n = *this;
  // No target stored (kind 0) keeps the one in force, as an M723 without Q or
  // R does: the mode may be on, and S1 needs a target.
  const bool target = kind == TARGET_FLOW || kind == TARGET_RATE;
  if (target) n.target_kind_ = kind;
  for (uint8_t i = target ? 0 : 1; i < SETTINGS; i++) {
    // the target's limit is Q's or R's (words 0, 1), the others' their own
    const uint8_t w = i ? (uint8_t)(i + 1) : (uint8_t)(kind - 1);
    Limit lim;
    BK_RDBLOCK(&lim, &kLimits[w], sizeof lim);
    if (!check_limit(lim, v[i], kCode, o)) return false;
    n.set_[i] = v[i];
  }
  return finish(n, -1, o);
}

// The first line is a command that sets what it shows (M500 stores it).
void WidthMode::report(ReplyText &o, bool echo, bool stats) const {
  if (echo) o.p(BK_F("echo:"));
  o.p(BK_F("  M723 S"));
  o.c((char)('0' + on_));
  for (uint8_t i = 0; i < kWords; i++) {
    if (i < 2 && target_kind_ != i + 1) continue;  // Q or R, whichever is the target
    o.c(' ');
    o.c((char)BK_RD8(&kLimits[i].letter));
    o.fixed(set_[i < 2 ? 0 : i - 1], 3);
  }
  if (!stats) return;
  o.p(BK_F("\necho:width rate:"));
  o.fixed(rate_, 3);
  o.p(BK_F(" feed%:"));
  o.u((uint32_t)percent_);
  o.p(BK_F(" moves:"));
  o.u(stats_.moves);
  o.p(BK_F(" low:"));
  o.u(stats_.clamped_low);
  o.p(BK_F(" high:"));
  o.u(stats_.clamped_high);
  o.p(BK_F(" maxdev:"));
  percent(o, stats_.max_dev);
  o.p(BK_F(" meandev:"));
  const uint32_t clamped = stats_.clamped_low + stats_.clamped_high;
  percent(o, stats_.sum_dev / (float)(clamped ? clamped : 1));  // the sum is 0 while none
}

// v = L * r / dE, kept within [L, U]. A clamped move's extruder rate differs from
// r by the factor clamped / wanted; that deviation goes into the statistics.
float WidthMode::retime(float xy_len, float de) {
  stats_.moves++;
  const float v = xy_len * rate_ / de;
  float c;
  uint32_t *count;
  if (v < set_[MIN_V]) {
    c = set_[MIN_V];
    count = &stats_.clamped_low;
  } else if (v > set_[MAX_V]) {
    c = set_[MAX_V];
    count = &stats_.clamped_high;
  } else {
    return v;
  }
  ++*count;
  const float dev = fabsf(c / v - 1.0f);
  if (dev > stats_.max_dev) stats_.max_dev = dev;
  stats_.sum_dev += dev;
  return c;
}

float WidthMode::feed_on(float xy_len, float de, float feed_mm_s) {
  if (!positive(de) || !positive(xy_len)) return feed_mm_s;
  return retime(xy_len, de);
}

float WidthMode::feed_xy_on(float dx, float dy, float de, float feed_mm_s) {
  if (!positive(de)) return feed_mm_s;  // no sqrt for travels and retractions
  const float len = len_xy(dx, dy);
  return positive(len) ? retime(len, de) : feed_mm_s;
}

bool WidthMode::width_e(float w, bool has_e, float xy_len, float &de_out, ReplyText &o) {
  if (!on_ || !positive(set_[HEIGHT])) {
    o.p(BK_F("Error:W needs M723 S1 and H"));
  } else if (has_e) {
    o.p(BK_F("Error:W and E in one move"));
  } else if (!positive(w) || w > BK_WIDTH_MAX_LINE_MM) {
    o.p(BK_F("Error:W"));
    o.fixed(w, 3);
    o.p(BK_F(" not in (0.000.."));
    o.fixed(BK_WIDTH_MAX_LINE_MM, 3);
    o.c(']');
  } else if (!positive(xy_len)) {
    o.p(BK_F("Error:W without XY travel"));
  } else {
    de_out = w * set_[HEIGHT] * xy_len * inv_area_;
    return true;
  }
  return false;
}

bool WidthMode::width_e_xy(float w, bool has_e, float dx, float dy, float &de_out, ReplyText &o) {
  return width_e(w, has_e, len_xy(dx, dy), de_out, o);
}

bool WidthMode::set_feed_percent(int16_t percent) {
  if (percent <= 0) return false;
  percent_ = percent;
  recompute();
  return true;
}

}  // namespace bk
