#include "width_mode.h"

#include <math.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define WM_P(s) PSTR(s)  // reply texts stay in flash: RAM is 8 KiB
#define WM_READ(p) ((char)pgm_read_byte(p))
#else
#define WM_P(s) (s)
#define WM_READ(p) (*(p))
#endif

namespace bk {

namespace {

// Appends to the caller's reply buffer; never writes past it. Callers size the
// buffer with REPLY_MIN / ERROR_REPLY_MIN, which hold every reply written here.
class Out {
 public:
  Out(char *buf, uint8_t size) : p_(buf), left_(size) {
    if (left_) *p_ = 0;
  }
  void c(char ch) {
    if (left_ > 1) {
      *p_++ = ch;
      *p_ = 0;
      left_--;
    }
  }
  void s(const char *flash) {
    for (char ch; (ch = WM_READ(flash)) != 0; flash++) c(ch);
  }
  void u(uint32_t v) {
    char tmp[10];
    uint8_t n = 0;
    do {
      tmp[n++] = (char)('0' + v % 10);
      v /= 10;
    } while (v);
    while (n) c(tmp[--n]);
  }
  // Fixed-point: dec decimals (0..3), rounded half up. Values too large for that
  // are written as ">=" and the bound, so a report never shows a wrong number.
  void f(float v, uint8_t dec) {
    if (v != v) {
      s(WM_P("nan"));
      return;
    }
    if (v < 0) {
      c('-');
      v = -v;
    }
    uint32_t scale = 1;
    for (uint8_t i = 0; i < dec; i++) scale *= 10;
    if (v >= 1.0e6f) {
      s(WM_P(">=1000000"));
      return;
    }
    uint32_t r = (uint32_t)(v * (float)scale + 0.5f);
    u(r / scale);
    if (dec) {
      c('.');
      uint32_t frac = r % scale;
      for (uint32_t d = scale / 10; d; d /= 10) c((char)('0' + (frac / d) % 10));
    }
  }

 private:
  char *p_;
  uint8_t left_;
};

const float kPi = 3.14159265f;

// Reads letter as a float: 0 absent, 1 present and well-formed, -1 malformed
// (then the Error: line is written).
int8_t get_value(const GcodeArgs &a, char letter, float &v, Out &o) {
  ArgStatus st = a.get_float(letter, v);
  if (st == ARG_ABSENT) return 0;
  if (st == ARG_OK) return 1;
  o.s(WM_P("Error:M723 bad value for "));
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
    Out o(reply, reply_size);
    o.s(WM_P("Error:M723 not a G-code line"));
    return false;
  }
  return command(a, reply, reply_size);
}

bool WidthMode::command(const GcodeArgs &a, char *reply, uint8_t reply_size) {
  Out o(reply, reply_size);
  if (reply_size < REPLY_MIN) {
    o.s(WM_P("Error:M723 reply buffer too small"));
    return false;
  }
  if (a.code_letter() != 'M' || a.code() != 723) {
    o.s(WM_P("Error:M723 handler given another command"));
    return false;
  }
  if (a.none()) {
    report(reply, reply_size);
    return true;
  }
  char bad = a.unknown("SQRDHLU");
  if (bad) {
    o.s(WM_P("Error:M723 unknown parameter "));
    o.c(bad);
    return false;
  }

  // Work on a copy and commit only when every word passed: all-or-nothing.
  WidthMode n = *this;
  int32_t s = -1;
  ArgStatus st = a.get_long('S', s);
  if (st != ARG_ABSENT && (st != ARG_OK || (s != 0 && s != 1))) {
    o.s(WM_P("Error:M723 S must be 0 (off) or 1 (on)"));
    return false;
  }

  float v;
  int8_t q = get_value(a, 'Q', v, o);
  if (q < 0) return false;
  if (q) {
    if (!(v > 0)) {
      o.s(WM_P("Error:M723 Q must be > 0 mm3/s"));
      return false;
    }
    if (v > BK_WIDTH_MAX_FLOW_MM3S) {
      o.s(WM_P("Error:M723 Q"));
      o.f(v, 3);
      o.s(WM_P(" exceeds max flow "));
      o.f(BK_WIDTH_MAX_FLOW_MM3S, 1);
      o.s(WM_P(" mm3/s"));
      return false;
    }
    n.target_kind_ = TARGET_FLOW;
    n.target_ = v;
  }
  int8_t r = get_value(a, 'R', v, o);
  if (r < 0) return false;
  if (r) {
    if (q) {
      o.s(WM_P("Error:M723 give Q (flow) or R (rate), not both"));
      return false;
    }
    if (!(v > 0)) {
      o.s(WM_P("Error:M723 R must be > 0 mm/s"));
      return false;
    }
    if (v > BK_WIDTH_MAX_E_RATE) {
      o.s(WM_P("Error:M723 R"));
      o.f(v, 3);
      o.s(WM_P(" exceeds max extruder rate "));
      o.f(BK_WIDTH_MAX_E_RATE, 1);
      o.s(WM_P(" mm/s"));
      return false;
    }
    n.target_kind_ = TARGET_RATE;
    n.target_ = v;
  }
  int8_t d = get_value(a, 'D', v, o);
  if (d < 0) return false;
  if (d) {
    if (!(v > 0)) {
      o.s(WM_P("Error:M723 D must be > 0 mm"));
      return false;
    }
    if (v < BK_WIDTH_MIN_FILAMENT_DIA || v > BK_WIDTH_MAX_FILAMENT_DIA) {
      o.s(WM_P("Error:M723 D"));
      o.f(v, 3);
      o.s(WM_P(" outside "));
      o.f(BK_WIDTH_MIN_FILAMENT_DIA, 2);
      o.s(WM_P(".."));
      o.f(BK_WIDTH_MAX_FILAMENT_DIA, 2);
      o.s(WM_P(" mm"));
      return false;
    }
    n.dia_ = v;
  }
  int8_t h = get_value(a, 'H', v, o);
  if (h < 0) return false;
  if (h) {
    if (v < 0) {
      o.s(WM_P("Error:M723 H must be >= 0 mm (0: no layer height)"));
      return false;
    }
    if (v > BK_WIDTH_MAX_LAYER_MM) {
      o.s(WM_P("Error:M723 H"));
      o.f(v, 3);
      o.s(WM_P(" exceeds max layer height "));
      o.f(BK_WIDTH_MAX_LAYER_MM, 2);
      o.s(WM_P(" mm"));
      return false;
    }
    n.h_ = v;
  }
  int8_t l = get_value(a, 'L', v, o);
  if (l < 0) return false;
  if (l) {
    if (!(v >= BK_WIDTH_MIN_SPEED_LIMIT)) {
      o.s(WM_P("Error:M723 L must be at least "));
      o.f(BK_WIDTH_MIN_SPEED_LIMIT, 2);
      o.s(WM_P(" mm/s"));
      return false;
    }
    n.min_v_ = v;
  }
  int8_t u = get_value(a, 'U', v, o);
  if (u < 0) return false;
  if (u) {
    if (!(v >= BK_WIDTH_MIN_SPEED_LIMIT)) {
      o.s(WM_P("Error:M723 U must be at least "));
      o.f(BK_WIDTH_MIN_SPEED_LIMIT, 2);
      o.s(WM_P(" mm/s"));
      return false;
    }
    if (v > BK_WIDTH_MAX_SPEED_LIMIT) {
      o.s(WM_P("Error:M723 U"));
      o.f(v, 2);
      o.s(WM_P(" exceeds max "));
      o.f(BK_WIDTH_MAX_SPEED_LIMIT, 1);
      o.s(WM_P(" mm/s"));
      return false;
    }
    n.max_v_ = v;
  }
  if (n.min_v_ > n.max_v_) {
    o.s(WM_P("Error:M723 L"));
    o.f(n.min_v_, 2);
    o.s(WM_P(" above U"));
    o.f(n.max_v_, 2);
    o.s(WM_P(" mm/s"));
    return false;
  }
  n.recompute();
  // Q is checked against the flow limit; with a thin filament it may still ask
  // for an extruder rate beyond the rate limit.
  if (n.base_rate_ > BK_WIDTH_MAX_E_RATE) {
    o.s(WM_P("Error:M723 extruder rate "));
    o.f(n.base_rate_, 3);
    o.s(WM_P(" exceeds max "));
    o.f(BK_WIDTH_MAX_E_RATE, 1);
    o.s(WM_P(" mm/s (check Q and D)"));
    return false;
  }
  if (s == 1 && n.target_kind_ == TARGET_NONE) {
    o.s(WM_P("Error:M723 S1 needs a flow Q or an extruder rate R"));
    return false;
  }
  if (s == 1 && !on_) n.stats_ = WidthStats();  // statistics count from entering the mode
  if (s >= 0) n.on_ = (s == 1);
  *this = n;
  return true;
}

void WidthMode::report(char *reply, uint8_t reply_size) const {
  Out o(reply, reply_size);
  o.s(WM_P("echo:  M723 S"));
  o.c(on_ ? '1' : '0');
  if (target_kind_ != TARGET_NONE) {
    o.s(target_kind_ == TARGET_FLOW ? WM_P(" Q") : WM_P(" R"));
    o.f(target_, 3);
  }
  o.s(WM_P(" D"));
  o.f(dia_, 3);
  o.s(WM_P(" H"));
  o.f(h_, 3);
  o.s(WM_P(" L"));
  o.f(min_v_, 2);
  o.s(WM_P(" U"));
  o.f(max_v_, 2);
  o.s(WM_P("\necho:WidthMode rate:"));
  o.f(rate_, 3);
  o.s(WM_P("mm/s feed%:"));
  o.u((uint32_t)percent_);
  o.s(WM_P(" moves:"));
  o.u(stats_.moves);
  o.s(WM_P(" low:"));
  o.u(stats_.clamped_low);
  o.s(WM_P(" high:"));
  o.u(stats_.clamped_high);
  o.s(WM_P(" maxdev:"));
  o.f(stats_.max_dev * 100.0f, 2);
  o.s(WM_P("% meandev:"));
  uint32_t clamped = stats_.clamped_low + stats_.clamped_high;
  o.f(clamped ? stats_.sum_dev * 100.0f / (float)clamped : 0.0f, 2);
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
  Out o(reply, reply_size);
  if (reply_size < ERROR_REPLY_MIN) {
    o.s(WM_P("Error:W reply buffer too small"));
    return false;
  }
  if (!on_) {
    o.s(WM_P("Error:W needs width mode on (M723 S1)"));
    return false;
  }
  if (!(h_ > 0)) {
    o.s(WM_P("Error:W needs a layer height (M723 H)"));
    return false;
  }
  if (has_e) {
    o.s(WM_P("Error:W and E in one move; send one of them"));
    return false;
  }
  if (!(w > 0) || w > BK_WIDTH_MAX_LINE_MM) {
    o.s(WM_P("Error:W"));
    o.f(w, 3);
    o.s(WM_P(" outside 0.."));
    o.f(BK_WIDTH_MAX_LINE_MM, 2);
    o.s(WM_P(" mm"));
    return false;
  }
  if (!(xy_len > 0)) {
    o.s(WM_P("Error:W on a move without XY travel"));
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
