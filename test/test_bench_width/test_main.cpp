// Width mode cost per move: cycles on the simulated ATmega2560 (ns on the host),
// printed as a table. The assertions check that each case ran and computed the
// right thing, not how fast it was.
#include <string.h>

#include "bktest.h"
#include "width_mode.h"

using bk::WidthMode;

static const uint8_t N = 8;  // calls per measurement

// Inputs read through volatile so the compiler cannot fold the calls away.
static volatile float in_len[N] = {10.0f, 2.5f, 0.8f, 14.0f, 6.0f, 1.2f, 3.3f, 9.9f};
static volatile float in_dx[N] = {6.0f, 1.5f, 0.48f, 8.4f, 3.6f, 0.72f, 1.98f, 5.94f};
static volatile float in_dy[N] = {8.0f, 2.0f, 0.64f, 11.2f, 4.8f, 0.96f, 2.64f, 7.92f};
static volatile float in_w[N] = {0.45f, 0.6f, 0.9f, 1.2f, 0.3f, 1.5f, 0.75f, 0.5f};
static volatile float in_feed = 40.0f;
static volatile float sink;

static WidthMode mode;
static char reply[WidthMode::REPLY_MIN];
static float de_for_w[N];  // dE of each width at its length, filled by the W case

struct Row {
  const char *name;  // flash string
  uint32_t per_call;
};
static Row rows[10];
static uint8_t nrows;

// Per iteration, loop and input reads included; the first row measures the loop
// alone so the reader can take it off.
static void add_row(const char *name, uint32_t total) {
  rows[nrows].name = name;
  rows[nrows].per_call = total / N;
  nrows++;
}

static uint8_t name_len(const char *flash) {
#ifdef __AVR__
  return (uint8_t)strlen_P(flash);
#else
  return (uint8_t)strlen(flash);
#endif
}

static void setUp_mode(const char *line) {
  mode.reset();
  TEST_ASSERT_TRUE(mode.command(line, reply, sizeof reply));
}

void setUp(void) {}
void tearDown(void) {}

static void bench_overhead(void) {
  float acc = 0;
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) acc += in_len[i];
  BKT_BENCH_END();
  add_row(BKT_S("loop alone (reference)"), bkt_bench_last());
  sink = acc;
}

static void bench_off(void) {
  setUp_mode("M723 S0");
  float acc = 0;
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) acc += mode.feed(in_len[i], 0.4f, in_feed);
  BKT_BENCH_END();
  add_row(BKT_S("off: passthrough"), bkt_bench_last());
  TEST_ASSERT_FLOAT_WITHIN(1e-3f, 40.0f * N, acc);
}

static void bench_travel(void) {
  setUp_mode("M723 S1 Q3.6 H0.2");
  float acc = 0;
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) acc += mode.feed_xy(in_dx[i], in_dy[i], 0.0f, in_feed);
  BKT_BENCH_END();
  add_row(BKT_S("on: travel, dE = 0"), bkt_bench_last());
  TEST_ASSERT_FLOAT_WITHIN(1e-3f, 40.0f * N, acc);
  TEST_ASSERT_EQUAL_UINT32(0, mode.stats().moves);
}

// dE for width w: w * 0.2 * L / area(1.75).
static float de_of(float w, float len) { return w * 0.2f * len / (3.14159265f * 1.75f * 1.75f / 4.0f); }

static void bench_extruding_len(void) {
  setUp_mode("M723 S1 Q3.6 H0.2");
  float de[N];
  for (uint8_t i = 0; i < N; i++) de[i] = de_of(in_w[i], in_len[i]);
  float out[N];
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) out[i] = mode.feed(in_len[i], de[i], in_feed);
  BKT_BENCH_END();
  add_row(BKT_S("on: extruding, L given"), bkt_bench_last());
  for (uint8_t i = 0; i < N; i++) TEST_ASSERT_FLOAT_WITHIN(out[i] * 1e-3f, 3.6f / (in_w[i] * 0.2f), out[i]);
  TEST_ASSERT_EQUAL_UINT32(N, mode.stats().moves);
}

static void bench_extruding_xy(void) {
  setUp_mode("M723 S1 Q3.6 H0.2");
  float de[N];
  for (uint8_t i = 0; i < N; i++) de[i] = de_of(in_w[i], in_len[i]);  // dx,dy are 3-4-5 of len
  float out[N];
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) out[i] = mode.feed_xy(in_dx[i], in_dy[i], de[i], in_feed);
  BKT_BENCH_END();
  add_row(BKT_S("on: extruding, dx/dy (sqrt)"), bkt_bench_last());
  for (uint8_t i = 0; i < N; i++) TEST_ASSERT_FLOAT_WITHIN(out[i] * 1e-3f, 3.6f / (in_w[i] * 0.2f), out[i]);
}

static void bench_clamped(void) {
  setUp_mode("M723 S1 Q3.6 H0.2 L19 U25");  // six of the eight speeds lie outside [19, 25]
  float de[N];
  for (uint8_t i = 0; i < N; i++) de[i] = de_of(in_w[i], in_len[i]);
  float acc = 0;
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) acc += mode.feed(in_len[i], de[i], in_feed);
  BKT_BENCH_END();
  add_row(BKT_S("on: extruding, clamped"), bkt_bench_last());
  sink = acc;
  // widths 0.45 0.6 0.9 1.2 0.3 1.5 0.75 0.5 want 40 30 20 15 60 12 24 36 mm/s
  TEST_ASSERT_EQUAL_UINT32(2, mode.stats().clamped_low);
  TEST_ASSERT_EQUAL_UINT32(4, mode.stats().clamped_high);
}

static void bench_width_word(void) {
  setUp_mode("M723 S1 Q3.6 H0.2");
  uint8_t ok = 0;
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) ok += mode.width_e(in_w[i], false, in_len[i], de_for_w[i], reply, sizeof reply);
  BKT_BENCH_END();
  add_row(BKT_S("W word -> dE, L given"), bkt_bench_last());
  TEST_ASSERT_EQUAL_INT(N, ok);
  for (uint8_t i = 0; i < N; i++) TEST_ASSERT_FLOAT_WITHIN(1e-5f, de_of(in_w[i], in_len[i]), de_for_w[i]);
}

static void bench_command(void) {
  mode.reset();
  uint8_t ok = 0;
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) ok += mode.command("M723 S1 Q3.6 D1.75 H0.2 L5 U150", reply, sizeof reply);
  BKT_BENCH_END();
  add_row(BKT_S("M723 S1 Q D H L U (parse+apply)"), bkt_bench_last());
  TEST_ASSERT_EQUAL_INT(N, ok);
  TEST_ASSERT_TRUE(mode.active());
}

static void bench_report(void) {
  uint8_t ok = 0;
  BKT_BENCH_BEGIN();
  for (uint8_t i = 0; i < N; i++) ok += mode.command("M723", reply, sizeof reply);
  BKT_BENCH_END();
  add_row(BKT_S("M723 report"), bkt_bench_last());
  TEST_ASSERT_EQUAL_INT(N, ok);
  TEST_ASSERT_EQUAL_INT(0, strncmp(reply, "echo:  M723 S1 Q3.600", 21));
}

// Sanity only: every case ran, costs something, and is not absurd.
static void test_table(void) {
  TEST_ASSERT_EQUAL_INT(9, nrows);
  const char *unit = bkt_bench_unit();
  TEST_PRINT("  width mode, per call (");
  bkt_puts(unit);
  TEST_PRINT(", loop included):\n");
  for (uint8_t i = 0; i < nrows; i++) {
    TEST_PRINT("    ");
    bkt_puts_P(rows[i].name);
    for (uint8_t len = name_len(rows[i].name); len < 34; len++) bkt_putc(' ');
    bkt_put_uint(rows[i].per_call);
    if (bkt_on_avr()) {
      TEST_PRINT(" (");
      bkt_put_float((double)rows[i].per_call / 16.0, 1);
      TEST_PRINT(" us at 16 MHz)");
    }
    bkt_putc('\n');
  }
  for (uint8_t i = 0; i < nrows; i++) {
    TEST_ASSERT_GREATER_THAN_INT(0, (int32_t)rows[i].per_call);
    TEST_ASSERT_LESS_THAN_INT(200000, (int32_t)rows[i].per_call);  // cycles or ns: far above either
  }
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(bench_overhead);
  RUN_TEST(bench_off);
  RUN_TEST(bench_travel);
  RUN_TEST(bench_extruding_len);
  RUN_TEST(bench_extruding_xy);
  RUN_TEST(bench_clamped);
  RUN_TEST(bench_width_word);
  RUN_TEST(bench_command);
  RUN_TEST(bench_report);
  RUN_TEST(test_table);
  return UNITY_END();
}
