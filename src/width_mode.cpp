#include "width_mode.h"

#include <math.h>

#include "reply_text.h"

namespace bk {

namespace {

const float kPi = 3.14159265f;

// Reads letter as a float: 0 absent, 1 present and well-formed, -1 malformed
// (then the Error: line is written).
int8_t get_value(const GcodeArgs &a, char letter, float &v, ReplyText &o) {
  ArgStatus st = a.get_float(letter, v);
  if (st == ARG_ABSENT) return 0;
  if (st == ARG_OK) return 1;
  o.p(BK_F("Error:M723 bad value for "));
  o.c(letter);
  return -1;
}

}  // namespace

void WidthMode::reset() {
  on_ = false;
  target_kind_ = TARGET_NONE;
  target_ = 0;
  dia_ = BK_DEFAULT_FILAMENT_DIA_MM;
  h_ = 0;
  min_v_ = BK_DEFAULT_WIDTH_MIN_SPEED;
  max_v_ = BK_DEFAULT_WIDTH_MAX_SPEED;
  percent_ = 100;
  stats_ = WidthStats();
  recompute();
}

// Derived values, so the per-move paths cost one multiply and one divide.
void WidthMode::recompute() {
  area_ = kPi * 0.25f * dia_ * dia_;
  inv_area_ = 1.0f / area_;
  if (target_kind_ == TARGET_FLOW)
    base_rate_ = target_ * inv_area_;
  else if (target_kind_ == TARGET_RATE)
    base_rate_ = target_;
  else
    base_rate_ = 0;
  rate_ = base_rate_ * (float)percent_ * 0.01f;
}

bool WidthMode::command(const char *line, char *reply, uint8_t reply_size) {
  GcodeArgs a;
  if (!a.parse(line)) {
    ReplyText o(reply, reply_size);
    o.p(BK_F("Error:M723 not a G-code line"));
    return false;
  }
  return command(a, reply, reply_size);
}

bool WidthMode::command(const GcodeArgs &a, char *reply, uint8_t reply_size) {
  ReplyText o(reply, reply_size);
  if (reply_size < REPLY_MIN) {
    o.p(BK_F("Error:M723 reply buffer too small"));
    return false;
  }
  if (a.code_letter() != 'M' || a.code() != 723) {
    o.p(BK_F("Error:M723 handler given another command"));
    return false;
  }
  if (a.none()) {
    report(reply, reply_size);
    return true;
  }
  if (!check_words(a, "SQRDHLU", BK_F("M723"), o)) return false;

  // Work on a copy and commit only when every word passed: all-or-nothing.
  WidthMode n = *this;
  int32_t s = -1;
  ArgStatus st = a.get_long('S', s);
  if (st != ARG_ABSENT && (st != ARG_OK || (s != 0 && s != 1))) {
    o.p(BK_F("Error:M723 S must be 0 (off) or 1 (on)"));
    return false;
  }

  float v;
  int8_t q = get_value(a, 'Q', v, o);
  if (q < 0) return false;
  if (q) {
    if (!(v > 0)) {
      o.p(BK_F("Error:M723 Q must be > 0 mm3/s"));
      return false;
    }
    if (v > BK_WIDTH_MAX_FLOW_MM3S) {
      o.p(BK_F("Error:M723 Q"));
      o.fixed(v, 3);
      o.p(BK_F(" exceeds max flow "));
      o.fixed(BK_WIDTH_MAX_FLOW_MM3S, 1);
      o.p(BK_F(" mm3/s"));
      return false;
    }
    n.target_kind_ = TARGET_FLOW;
    n.target_ = v;
  }
  int8_t r = get_value(a, 'R', v, o);
  if (r < 0) return false;
  if (r) {
    if (q) {
      o.p(BK_F("Error:M723 give Q (flow) or R (rate), not both"));
      return false;
    }
    if (!(v > 0)) {
      o.p(BK_F("Error:M723 R must be > 0 mm/s"));
      return false;
    }
    if (v > BK_WIDTH_MAX_E_RATE) {
      o.p(BK_F("Error:M723 R"));
      o.fixed(v, 3);
      o.p(BK_F(" exceeds max extruder rate "));
      o.fixed(BK_WIDTH_MAX_E_RATE, 1);
      o.p(BK_F(" mm/s"));
      return false;
    }
    n.target_kind_ = TARGET_RATE;
    n.target_ = v;
  }
  int8_t d = get_value(a, 'D', v, o);
  if (d < 0) return false;
  if (d) {
    if (!(v > 0)) {
      o.p(BK_F("Error:M723 D must be > 0 mm"));
      return false;
    }
    if (v < BK_WIDTH_MIN_FILAMENT_DIA || v > BK_WIDTH_MAX_FILAMENT_DIA) {
      o.p(BK_F("Error:M723 D"));
      o.fixed(v, 3);
      o.p(BK_F(" outside "));
      o.fixed(BK_WIDTH_MIN_FILAMENT_DIA, 2);
      o.p(BK_F(".."));
      o.fixed(BK_WIDTH_MAX_FILAMENT_DIA, 2);
      o.p(BK_F(" mm"));
      return false;
    }
    n.dia_ = v;
  }
  int8_t h = get_value(a, 'H', v, o);
  if (h < 0) return false;
  if (h) {
    if (v < 0) {
      o.p(BK_F("Error:M723 H must be >= 0 mm (0: no layer height)"));
      return false;
    }
    if (v > BK_WIDTH_MAX_LAYER_MM) {
      o.p(BK_F("Error:M723 H"));
      o.fixed(v, 3);
      o.p(BK_F(" exceeds max layer height "));
      o.fixed(BK_WIDTH_MAX_LAYER_MM, 2);
      o.p(BK_F(" mm"));
      return false;
    }
    n.h_ = v;
  }
  int8_t l = get_value(a, 'L', v, o);
  if (l < 0) return false;
  if (l) {
    if (!(v >= BK_WIDTH_MIN_SPEED_LIMIT)) {
      o.p(BK_F("Error:M723 L must be at least "));
      o.fixed(BK_WIDTH_MIN_SPEED_LIMIT, 2);
      o.p(BK_F(" mm/s"));
      return false;
    }
    n.min_v_ = v;
  }
  int8_t u = get_value(a, 'U', v, o);
  if (u < 0) return false;
  if (u) {
    if (!(v >= BK_WIDTH_MIN_SPEED_LIMIT)) {
      o.p(BK_F("Error:M723 U must be at least "));
      o.fixed(BK_WIDTH_MIN_SPEED_LIMIT, 2);
      o.p(BK_F(" mm/s"));
      return false;
    }
    if (v > BK_WIDTH_MAX_SPEED_LIMIT) {
      o.p(BK_F("Error:M723 U"));
      o.fixed(v, 2);
      o.p(BK_F(" exceeds max "));
      o.fixed(BK_WIDTH_MAX_SPEED_LIMIT, 1);
      o.p(BK_F(" mm/s"));
      return false;
    }
    n.max_v_ = v;
  }
  if (n.min_v_ > n.max_v_) {
    o.p(BK_F("Error:M723 L"));
    o.fixed(n.min_v_, 2);
    o.p(BK_F(" above U"));
    o.fixed(n.max_v_, 2);
    o.p(BK_F(" mm/s"));
    return false;
  }
  n.recompute();
  // Q is checked against the flow limit; with a thin filament it may still ask
  // for an extruder rate beyond the rate limit.
  if (n.base_rate_ > BK_WIDTH_MAX_E_RATE) {
    o.p(BK_F("Error:M723 extruder rate "));
    o.fixed(n.base_rate_, 3);
    o.p(BK_F(" exceeds max "));
    o.fixed(BK_WIDTH_MAX_E_RATE, 1);
    o.p(BK_F(" mm/s (check Q and D)"));
    return false;
  }
  if (s == 1 && n.target_kind_ == TARGET_NONE) {
    o.p(BK_F("Error:M723 S1 needs a flow Q or an extruder rate R"));
    return false;
  }
  if (s == 1 && !on_) n.stats_ = WidthStats();  // statistics count from entering the mode
  if (s >= 0) n.on_ = (s == 1);
  *this = n;
  return true;
}

void WidthMode::report(char *reply, uint8_t reply_size) const {
  ReplyText o(reply, reply_size);
  o.p(BK_F("echo:  M723 S"));
  o.c(on_ ? '1' : '0');
  if (target_kind_ != TARGET_NONE) {
    o.p(target_kind_ == TARGET_FLOW ? BK_F(" Q") : BK_F(" R"));
    o.fixed(target_, 3);
  }
  o.p(BK_F(" D"));
  o.fixed(dia_, 3);
  o.p(BK_F(" H"));
  o.fixed(h_, 3);
  o.p(BK_F(" L"));
  o.fixed(min_v_, 2);
  o.p(BK_F(" U"));
  o.fixed(max_v_, 2);
  o.p(BK_F("\necho:WidthMode rate:"));
  o.fixed(rate_, 3);
  o.p(BK_F("mm/s feed%:"));
  o.u((uint32_t)percent_);
  o.p(BK_F(" moves:"));
  o.u(stats_.moves);
  o.p(BK_F(" low:"));
  o.u(stats_.clamped_low);
  o.p(BK_F(" high:"));
  o.u(stats_.clamped_high);
  o.p(BK_F(" maxdev:"));
  o.fixed(stats_.max_dev * 100.0f, 2);
  o.p(BK_F("% meandev:"));
  uint32_t clamped = stats_.clamped_low + stats_.clamped_high;
  o.fixed(clamped ? stats_.sum_dev * 100.0f / (float)clamped : 0.0f, 2);
  o.c('%');
}

// v = L * r / dE, kept within [L, U]. A clamped move's extruder rate differs from
// r by the factor clamped / wanted; that deviation goes into the statistics.
float WidthMode::retime(float xy_len, float de) {
  stats_.moves++;
  float v = xy_len * rate_ / de;
  float dev;
  if (v < min_v_) {
    dev = min_v_ / v - 1.0f;
    stats_.clamped_low++;
    v = min_v_;
  } else if (v > max_v_) {
    dev = 1.0f - max_v_ / v;
    stats_.clamped_high++;
    v = max_v_;
  } else {
    return v;
  }
  if (dev > stats_.max_dev) stats_.max_dev = dev;
  stats_.sum_dev += dev;
  return v;
}

float WidthMode::feed(float xy_len, float de, float feed_mm_s) {
  if (!on_ || !(de > 0.0f) || !(xy_len > 0.0f)) return feed_mm_s;
  return retime(xy_len, de);
}

float WidthMode::feed_xy(float dx, float dy, float de, float feed_mm_s) {
  if (!on_ || !(de > 0.0f)) return feed_mm_s;  // no sqrt for travels, retractions, mode off
  return feed(sqrtf(dx * dx + dy * dy), de, feed_mm_s);
}

bool WidthMode::width_e(float w, bool has_e, float xy_len, float &de_out, char *reply,
                        uint8_t reply_size) {
  ReplyText o(reply, reply_size);
  if (reply_size < ERROR_REPLY_MIN) {
    o.p(BK_F("Error:W reply buffer too small"));
    return false;
  }
  if (!on_) {
    o.p(BK_F("Error:W needs width mode on (M723 S1)"));
    return false;
  }
  if (!(h_ > 0)) {
    o.p(BK_F("Error:W needs a layer height (M723 H)"));
    return false;
  }
  if (has_e) {
    o.p(BK_F("Error:W and E in one move; send one of them"));
    return false;
  }
  if (!(w > 0) || w > BK_WIDTH_MAX_LINE_MM) {
    o.p(BK_F("Error:W"));
    o.fixed(w, 3);
    o.p(BK_F(" outside 0.."));
    o.fixed(BK_WIDTH_MAX_LINE_MM, 2);
    o.p(BK_F(" mm"));
    return false;
  }
  if (!(xy_len > 0)) {
    o.p(BK_F("Error:W on a move without XY travel"));
    return false;
  }
  de_out = w * h_ * xy_len * inv_area_;
  return true;
}

bool WidthMode::width_e_xy(float w, bool has_e, float dx, float dy, float &de_out, char *reply,
                           uint8_t reply_size) {
  return width_e(w, has_e, sqrtf(dx * dx + dy * dy), de_out, reply, reply_size);
}

bool WidthMode::set_feed_percent(int16_t percent) {
  if (percent <= 0) return false;
  percent_ = percent;
  rate_ = base_rate_ * (float)percent_ * 0.01f;
  return true;
}

}  // namespace bk
