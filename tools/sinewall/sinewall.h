// The sine-wave wall test of Jang & Hong (2017, Fig. 4), run through the width
// mode core. One layer of a wall whose inner face is flat (y = 0) and whose
// outer face is a sine wave, thickness T(x) = t_mid + t_amp sin(2 pi x / lambda):
//   inner wall line, outer wall line (constant width), then one infill line
//   along the middle whose width fills the gap between them, T(x) - 2 wall_w.
// The host side sends the infill either as W words or as E computed for the
// width at a fixed F (what a slicer would write); walls carry ordinary E.
// Every move goes through WidthMode::feed_xy, travels and retractions included.
//
// Header-only and heap-free so the same code runs in the native figures tool
// (tools/sinewall/main.cpp) and in the test suite on host and ATmega2560.
#ifndef BK_SINEWALL_H
#define BK_SINEWALL_H

#include <math.h>
#include <string.h>

#include "width_mode.h"

namespace sinewall {

struct Spec {
  float length;      // wall length along X, mm
  float wavelength;  // of the outer face, mm
  float t_mid;       // mean wall thickness, mm
  float t_amp;       // sine amplitude, mm
  float wall_w;      // inner and outer wall line width, mm
  float seg;         // segment length along X, mm
  float h;           // layer height, mm
  float v0;          // nominal speed: walls print at it, so Q = wall_w * h * v0
  float dia;         // filament diameter, mm
  float min_v;       // M723 L
  float max_v;       // M723 U
  bool use_w;        // infill as W words (else E for the width at F = v0)
};

// 100 mm wall, 20 mm wave, 1.0..2.6 mm thick: infill 0.2..1.8 mm wide. 0.4 mm
// walls at the paper's 40 mm/s give Q = 3.2 mm^3/s.
inline Spec default_spec() {
  Spec s;
  s.length = 100.0f;
  s.wavelength = 20.0f;
  s.t_mid = 1.8f;
  s.t_amp = 0.8f;
  s.wall_w = 0.4f;
  s.seg = 0.5f;
  s.h = 0.2f;
  s.v0 = 40.0f;
  s.dia = 1.75f;
  s.min_v = BK_DEFAULT_WIDTH_MIN_SPEED;
  s.max_v = BK_DEFAULT_WIDTH_MAX_SPEED;
  s.use_w = true;
  return s;
}

// One extruding move as the core timed it.
struct Move {
  uint8_t line;  // 0 inner wall, 1 outer wall, 2 infill
  float len;     // XY length, mm
  float de;      // filament, mm
  float v;       // head speed from the core, mm/s
  bool clamped;
};

struct Figures {
  uint16_t moves;            // extruding moves
  uint16_t clamped;          // of which clamped (core statistics)
  uint16_t clamp_flags;      // moves seen clamped one by one (must equal clamped)
  uint16_t unclamped;
  uint16_t untouched;        // travels and retractions passed through
  uint16_t untouched_bad;    // of those, feeds the core changed (must be 0)
  uint16_t errors;           // M723 / W replies that were Error: (must be 0)
  float q;                   // target flow, mm^3/s
  float r;                   // target extruder rate, mm/s of filament
  float w_min, w_max;        // commanded widths (all lines), from dE
  float v_min, v_max;        // head speeds the core chose
  float r_min, r_max;        // extruder rate dE * v / L on unclamped moves
  float spread;              // (r_max - r_min) / r
  float clamp_max_dev;       // from the core's statistics
  float clamp_mean_dev;
  float plain_r_min, plain_r_max;  // same E at a constant F = v0, no width mode
  float filament;            // total dE, mm
  float time_s;              // extrusion time at the core's speeds (no acceleration)
  float plain_time_s;        // same at v0
};

typedef void (*MoveSink)(const Move &m, void *ctx);

namespace detail {

inline float thickness(const Spec &s, float x) {
  return s.t_mid + s.t_amp * sinf(6.2831853f * x / s.wavelength);
}

// Writes v with 3 decimals; enough for M723 words, no printf needed on AVR.
inline char *put_fixed(char *p, float v) {
  uint32_t m = (uint32_t)(v * 1000.0f + 0.5f);
  uint32_t ip = m / 1000, fp = m % 1000;
  char tmp[10];
  uint8_t n = 0;
  do {
    tmp[n++] = (char)('0' + ip % 10);
    ip /= 10;
  } while (ip);
  while (n) *p++ = tmp[--n];
  *p++ = '.';
  *p++ = (char)('0' + fp / 100);
  *p++ = (char)('0' + fp / 10 % 10);
  *p++ = (char)('0' + fp % 10);
  return p;
}

inline char *put_word(char *p, char letter, float v) {
  *p++ = ' ';
  *p++ = letter;
  return put_fixed(p, v);
}

struct Runner {
  const Spec &s;
  bk::WidthMode &mode;
  Figures &f;
  MoveSink sink;
  void *ctx;
  float area;
  float x, y;  // head position
  char reply[bk::WidthMode::REPLY_MIN];

  Runner(const Spec &spec, bk::WidthMode &m, Figures &fig, MoveSink snk, void *c)
      : s(spec), mode(m), f(fig), sink(snk), ctx(c), area(0), x(0), y(0) {}

  void untouched(float dx, float dy, float de, float feed) {
    float out = mode.feed_xy(dx, dy, de, feed);
    f.untouched++;
    if (memcmp(&out, &feed, sizeof out) != 0) f.untouched_bad++;
  }

  void travel(float tx, float ty) {
    untouched(0, 0, -0.8f, 35.0f);             // retract
    untouched(tx - x, ty - y, 0.0f, 150.0f);   // G0
    untouched(0, 0, 0.8f, 35.0f);              // unretract (no XY travel)
    x = tx;
    y = ty;
  }

  // An extruding move to (tx, ty): width w either as a W word or as E at F = v0.
  void extrude(uint8_t line, float tx, float ty, float w, bool as_w) {
    float dx = tx - x, dy = ty - y;
    float len = sqrtf(dx * dx + dy * dy);
    float de;
    if (as_w) {
      if (!mode.width_e(w, false, len, de, reply, sizeof reply)) {
        f.errors++;
        return;
      }
    } else {
      de = w * s.h * len / area;  // the host's E for this width
    }
    const bk::WidthStats &st = mode.stats();
    uint32_t clamped_before = st.clamped_low + st.clamped_high;
    float v = mode.feed(len, de, s.v0);
    Move m;
    m.line = line;
    m.len = len;
    m.de = de;
    m.v = v;
    m.clamped = st.clamped_low + st.clamped_high != clamped_before;
    account(m);
    if (sink) sink(m, ctx);
    x = tx;
    y = ty;
  }

  void account(const Move &m) {
    float w = m.de * area / (s.h * m.len);
    float rate = m.de * m.v / m.len;
    float plain = m.de * s.v0 / m.len;
    if (f.moves == 0) {
      f.w_min = f.w_max = w;
      f.v_min = f.v_max = m.v;
      f.plain_r_min = f.plain_r_max = plain;
    }
    f.moves++;
    if (w < f.w_min) f.w_min = w;
    if (w > f.w_max) f.w_max = w;
    if (m.v < f.v_min) f.v_min = m.v;
    if (m.v > f.v_max) f.v_max = m.v;
    if (plain < f.plain_r_min) f.plain_r_min = plain;
    if (plain > f.plain_r_max) f.plain_r_max = plain;
    f.filament += m.de;
    f.time_s += m.len / m.v;
    f.plain_time_s += m.len / s.v0;
    if (m.clamped) {
      f.clamp_flags++;
      return;
    }
    f.unclamped++;
    if (f.unclamped == 1 || rate < f.r_min) f.r_min = rate;
    if (f.unclamped == 1 || rate > f.r_max) f.r_max = rate;
  }

  void run() {
    memset(&f, 0, sizeof f);
    f.q = s.wall_w * s.h * s.v0;
    char line[64];
    char *p = line;
    memcpy(p, "M723 S1", 7);
    p += 7;
    p = put_word(p, 'Q', f.q);
    p = put_word(p, 'D', s.dia);
    p = put_word(p, 'H', s.h);
    p = put_word(p, 'L', s.min_v);
    p = put_word(p, 'U', s.max_v);
    *p = 0;
    mode.reset();
    if (!mode.command(line, reply, sizeof reply)) {
      f.errors++;
      return;
    }
    area = mode.filament_area();
    f.r = mode.rate();
    const uint16_t n = (uint16_t)(s.length / s.seg + 0.5f);
    const float half = s.wall_w * 0.5f;
    // Inner wall, left to right.
    x = 0;
    y = 0;
    travel(0, half);
    for (uint16_t i = 1; i <= n; i++) extrude(0, i * s.seg, half, s.wall_w, false);
    // Outer wall, right to left along the sine.
    travel(s.length, thickness(s, s.length) - half);
    for (uint16_t i = 1; i <= n; i++) {
      float tx = s.length - i * s.seg;
      extrude(1, tx, thickness(s, tx) - half, s.wall_w, false);
    }
    // Infill along the middle, left to right; width from the segment's middle.
    travel(0, thickness(s, 0) * 0.5f);
    for (uint16_t i = 1; i <= n; i++) {
      float tx = i * s.seg;
      float w = thickness(s, tx - 0.5f * s.seg) - 2.0f * s.wall_w;
      extrude(2, tx, thickness(s, tx) * 0.5f, w, s.use_w);
    }
    const bk::WidthStats &st = mode.stats();
    f.clamped = (uint16_t)(st.clamped_low + st.clamped_high);
    f.clamp_max_dev = st.max_dev;
    f.clamp_mean_dev = f.clamped ? st.sum_dev / f.clamped : 0.0f;
    f.spread = f.r > 0 ? (f.r_max - f.r_min) / f.r : 0.0f;
    if (!mode.command("M723 S0", reply, sizeof reply)) f.errors++;
  }
};

}  // namespace detail

// Runs the test; sink (may be null) sees every extruding move in order.
inline void run(const Spec &s, bk::WidthMode &mode, Figures &f, MoveSink sink = 0, void *ctx = 0) {
  detail::Runner r(s, mode, f, sink, ctx);
  r.run();
}

}  // namespace sinewall

#endif  // BK_SINEWALL_H
