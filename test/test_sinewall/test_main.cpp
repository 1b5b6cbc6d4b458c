// The sine-wave wall test (Jang & Hong 2017, Fig. 4) through the width mode core:
// the extruder rate is the same on every unclamped move while the width varies
// ninefold; clamped moves are exactly the too-narrow infill; travels untouched.
// Prints the figures on both targets (tools/sinewall prints more, on the host).
#include "bktest.h"
#include "../../tools/sinewall/sinewall.h"

static bk::WidthMode mode;

static void print_figures(const sinewall::Figures &f) {
  TEST_PRINT("  moves ");
  bkt_put_uint(f.moves);
  TEST_PRINT(" (clamped ");
  bkt_put_uint(f.clamped);
  TEST_PRINT(")  widths ");
  bkt_put_float(f.w_min, 3);
  TEST_PRINT("..");
  bkt_put_float(f.w_max, 3);
  TEST_PRINT(" mm  speeds ");
  bkt_put_float(f.v_min, 2);
  TEST_PRINT("..");
  bkt_put_float(f.v_max, 2);
  TEST_PRINT(" mm/s\n  E rate ");
  bkt_put_float(f.r_min, 5);
  TEST_PRINT("..");
  bkt_put_float(f.r_max, 5);
  TEST_PRINT(" mm/s unclamped (spread ");
  bkt_put_float(f.spread * 1e6, 2);
  TEST_PRINT(" ppm)  without width mode ");
  bkt_put_float(f.plain_r_min, 4);
  TEST_PRINT("..");
  bkt_put_float(f.plain_r_max, 4);
  TEST_PRINT("\n");
  if (f.clamped) {
    TEST_PRINT("  clamped rate deviation max ");
    bkt_put_float(f.clamp_max_dev * 100, 1);
    TEST_PRINT(" %, mean ");
    bkt_put_float(f.clamp_mean_dev * 100, 1);
    TEST_PRINT(" %\n");
  }
}

static void check_common(const sinewall::Figures &f) {
  TEST_ASSERT_EQUAL_UINT(0, f.errors);
  TEST_ASSERT_EQUAL_UINT(600, f.moves);  // three lines of 200 segments
  TEST_ASSERT_EQUAL_UINT(9, f.untouched);
  TEST_ASSERT_EQUAL_UINT_MESSAGE(0, f.untouched_bad, "a travel or retraction was retimed");
  TEST_ASSERT_EQUAL_UINT(f.clamped, f.clamp_flags);
  TEST_ASSERT_EQUAL_UINT(f.moves, f.clamped + f.unclamped);
  // The goal: one extruder rate on every unclamped move, whatever the width.
  TEST_ASSERT_TRUE_MESSAGE(f.spread < 1e-3f, "extruder rate varies by more than 0.1 %");
  TEST_ASSERT_FLOAT_WITHIN(f.r * 1e-3f, f.r, f.r_min);
  TEST_ASSERT_FLOAT_WITHIN(f.r * 1e-3f, f.r, f.r_max);
  // Q = 0.4 * 0.2 * 40; r = Q / area(1.75).
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 3.2f, f.q);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 3.2f / (3.14159265f * 1.75f * 1.75f / 4.0f), f.r);
  // Widths: walls 0.4, infill T - 0.8 sampled at segment middles, T in 1.0..2.6.
  TEST_ASSERT_FLOAT_WITHIN(0.005f, 0.2f, f.w_min);
  TEST_ASSERT_FLOAT_WITHIN(0.005f, 1.8f, f.w_max);
  // Without width mode the same E at F40 would swing the extruder rate ninefold.
  TEST_ASSERT_TRUE(f.plain_r_max / f.plain_r_min > 8.0f);
}

static void test_default_limits(void) {
  sinewall::Spec s = sinewall::default_spec();
  sinewall::Figures f;
  sinewall::run(s, mode, f);
  print_figures(f);
  check_common(f);
  TEST_ASSERT_EQUAL_UINT(0, f.clamped);
  // v = Q / (H W): the widest and narrowest lines set the speed range.
  TEST_ASSERT_FLOAT_WITHIN(0.01f, 3.2f / (0.2f * f.w_max), f.v_min);
  TEST_ASSERT_FLOAT_WITHIN(0.05f, 3.2f / (0.2f * f.w_min), f.v_max);
  // Constant rate: extrusion time is filament over r.
  TEST_ASSERT_FLOAT_WITHIN(f.time_s * 1e-3f, f.filament / f.r, f.time_s);
}

// The host may send E for the width at its own F instead of W: same timing.
static void test_e_words_same_as_w_words(void) {
  sinewall::Spec s = sinewall::default_spec();
  sinewall::Figures fw, fe;
  sinewall::run(s, mode, fw);
  s.use_w = false;
  sinewall::run(s, mode, fe);
  check_common(fe);
  TEST_ASSERT_FLOAT_WITHIN(fw.v_min * 1e-4f, fw.v_min, fe.v_min);
  TEST_ASSERT_FLOAT_WITHIN(fw.v_max * 1e-4f, fw.v_max, fe.v_max);
  TEST_ASSERT_FLOAT_WITHIN(fw.filament * 1e-4f, fw.filament, fe.filament);
  TEST_ASSERT_FLOAT_WITHIN(fw.time_s * 1e-4f, fw.time_s, fe.time_s);
}

struct ClampCheck {
  float w_limit;  // infill narrower than this needs more than U
  uint16_t wrong;
  uint16_t clamped;
  float area, h;
};

static void check_clamp(const sinewall::Move &m, void *ctx) {
  ClampCheck *c = static_cast<ClampCheck *>(ctx);
  float w = m.de * c->area / (c->h * m.len);
  bool should = m.line == 2 && w < c->w_limit;
  if (m.clamped) c->clamped++;
  if (m.clamped != should) c->wrong++;
}

// With U = 60 mm/s the infill narrower than Q / (H U) = 0.267 mm is clamped and
// counted; every other move keeps the rate.
static void test_tight_limit_clamps_narrow_infill(void) {
  sinewall::Spec s = sinewall::default_spec();
  s.max_v = 60.0f;
  ClampCheck c;
  c.w_limit = 3.2f / (0.2f * 60.0f);
  c.wrong = 0;
  c.clamped = 0;
  c.area = 3.14159265f * 1.75f * 1.75f / 4.0f;
  c.h = 0.2f;
  sinewall::Figures f;
  sinewall::run(s, mode, f, check_clamp, &c);
  print_figures(f);
  check_common(f);
  TEST_ASSERT_GREATER_THAN_INT(10, f.clamped);
  TEST_ASSERT_EQUAL_UINT(f.clamped, c.clamped);
  TEST_ASSERT_EQUAL_UINT_MESSAGE(0, c.wrong, "a move was clamped that should not be, or the reverse");
  TEST_ASSERT_FLOAT_WITHIN(1e-3f, 60.0f, f.v_max);
  // The narrowest line wanted Q / (H w_min); at 60 its rate is 60 / that of r.
  TEST_ASSERT_FLOAT_WITHIN(2e-3f, 1.0f - 60.0f * 0.2f * f.w_min / 3.2f, f.clamp_max_dev);
  TEST_ASSERT_TRUE(f.clamp_mean_dev > 0.0f && f.clamp_mean_dev <= f.clamp_max_dev);
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_default_limits);
  RUN_TEST(test_e_words_same_as_w_words);
  RUN_TEST(test_tight_limit_clamps_narrow_infill);
  return UNITY_END();
}
