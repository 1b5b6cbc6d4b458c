// Benchmark of the benchmark mechanism itself, and a reference table of what
// basic operations cost on the target (cycles on the simulated ATmega2560, ns on
// the host). The assertions check that the counts are real: an empty marker
// pair costs almost nothing and a loop of N iterations costs at least N cycles.
#include "bktest.h"

static volatile float vf1 = 1.2345f, vf2 = 6.789f;
static volatile int32_t vl1 = 123456, vl2 = 789;
static volatile int16_t vs1 = 1234, vs2 = 56;
static volatile uint8_t sink8;

static void row(const char *label, uint32_t v) {
  bkt_puts("| ");
  bkt_puts(label);
  bkt_puts(" | ");
  bkt_put_uint(v);
  bkt_puts(" ");
  bkt_puts(bkt_bench_unit());
  bkt_puts(" |\n");
}

static void test_empty_pair_is_cheap(void) {
  BKT_BENCH_BEGIN();
  BKT_BENCH_END();
  uint32_t empty = bkt_bench_last();
  row("empty marker pair", empty);
  // LDI + OUT per marker: 2 cycles at -Os (6 unoptimised), the constant to
  // subtract from very short measurements.
  if (bkt_on_avr()) TEST_ASSERT_LESS_OR_EQUAL_INT(6, (int32_t)empty);
}

static void test_loop_counts_scale(void) {
  // Each iteration touches a volatile, so the loop cannot be folded away.
  BKT_BENCH_BEGIN();
  for (uint16_t i = 0; i < 1000; i++) sink8 = (uint8_t)i;
  BKT_BENCH_END();
  uint32_t n1000 = bkt_bench_last();
  BKT_BENCH_BEGIN();
  for (uint16_t i = 0; i < 2000; i++) sink8 = (uint8_t)i;
  BKT_BENCH_END();
  uint32_t n2000 = bkt_bench_last();
  row("1000-iteration loop", n1000);
  row("2000-iteration loop", n2000);
  if (bkt_on_avr()) {
    TEST_ASSERT_GREATER_OR_EQUAL_INT(1000, (int32_t)n1000);
    // twice the work costs twice the cycles, up to the loop's set-up (< 1 %)
    int32_t excess = (int32_t)n2000 - 2 * (int32_t)n1000;
    if (excess < 0) excess = -excess;
    TEST_ASSERT_LESS_OR_EQUAL_INT((int32_t)n1000 / 100, excess);
  }
}

// Results go to volatile sinks inside the markers: a plain local could be
// computed after BKT_BENCH_END, since only memory is ordered by the markers.
static volatile float sink_f;
static volatile int32_t sink_l;
static volatile int16_t sink_s;

static void test_reference_costs(void) {
  BKT_BENCH_BEGIN();
  sink_f = vf1 * vf2;
  BKT_BENCH_END();
  row("float multiply (volatile loads/store)", bkt_bench_last());
  TEST_ASSERT_FLOAT_WITHIN(1e-3f, 1.2345f * 6.789f, sink_f);
  BKT_BENCH_BEGIN();
  sink_f = vf1 / vf2;
  BKT_BENCH_END();
  row("float divide", bkt_bench_last());
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.2345f / 6.789f, sink_f);
  BKT_BENCH_BEGIN();
  sink_l = vl1 * vl2;
  BKT_BENCH_END();
  row("int32 multiply", bkt_bench_last());
  TEST_ASSERT_EQUAL_INT32(123456L * 789L, sink_l);
  BKT_BENCH_BEGIN();
  sink_s = (int16_t)(vs1 < vs2 ? vs1 : vs2);
  BKT_BENCH_END();
  row("int16 compare", bkt_bench_last());
  TEST_ASSERT_EQUAL_INT(56, sink_s);
  if (bkt_on_avr()) {
    // avr-libc's float multiply is a library call of well over 50 cycles: a
    // smaller figure would mean the measurement missed the work.
    BKT_BENCH_BEGIN();
    sink_f = vf1 * vf2;
    BKT_BENCH_END();
    TEST_ASSERT_GREATER_THAN_INT(50, (int32_t)bkt_bench_last());
  }
}

int main(void) {
  UNITY_BEGIN();
  TEST_PRINT("| operation | cost |\n|---|---|\n");
  RUN_TEST(test_empty_pair_is_cheap);
  RUN_TEST(test_loop_counts_scale);
  RUN_TEST(test_reference_costs);
  return UNITY_END();
}
