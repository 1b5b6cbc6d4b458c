// Self-test of the bktest library and of both targets' runtime: integer and
// float arithmetic, memory compare, strings. Building with -DBKT_SELFTEST_FAIL
// adds a failing case and -DBKT_SELFTEST_HANG a case that never returns; both
// exist to show that the rig reports failures and hangs on each target.
#include <string.h>

#include "bktest.h"

static int set_up_calls;

void setUp(void) { set_up_calls++; }

static void test_integers(void) {
  int32_t a = 100000;
  TEST_ASSERT_EQUAL_INT32(200000, a * 2);
  TEST_ASSERT_EQUAL_UINT8(255, (uint8_t)0xFF);
  TEST_ASSERT_EQUAL_INT16(-2, (int16_t)0xFFFE);
  TEST_ASSERT_LESS_OR_EQUAL_INT(10, 10);
  TEST_ASSERT_GREATER_THAN_INT(-1, 0);
}

static void test_floats(void) {
  // float is 32-bit on both targets; double is 32-bit on AVR, so compare at float precision.
  float third = 1.0f / 3.0f;
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.333333f, third);
  TEST_ASSERT_EQUAL_FLOAT(0.1f, 0.3f / 3.0f);
  TEST_ASSERT_EQUAL_INT(4, (int)sizeof(float));
}

static void test_memory_and_strings(void) {
  const uint8_t expected[4] = {1, 2, 3, 4};
  uint8_t actual[4];
  for (uint8_t i = 0; i < 4; i++) actual[i] = (uint8_t)(i + 1);
  TEST_ASSERT_EQUAL_UINT8_ARRAY(expected, actual, 4);
  char buf[8];
  strcpy(buf, "bulge");
  TEST_ASSERT_EQUAL_STRING("bulge", buf);
  TEST_ASSERT_NOT_NULL(buf);
}

static void test_setup_runs_before_each_case(void) {
  // setUp ran once before each of the cases so far, this one included.
  TEST_ASSERT_EQUAL_INT(4, set_up_calls);
}

#ifdef BKT_SELFTEST_FAIL
static void test_deliberate_failure(void) { TEST_ASSERT_EQUAL_INT_MESSAGE(1, 2, "deliberate failure"); }
#endif
#ifdef BKT_SELFTEST_HANG
static volatile uint8_t never;
static void test_deliberate_hang(void) {
  while (!never) {
  }
}
#endif

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_integers);
  RUN_TEST(test_floats);
  RUN_TEST(test_memory_and_strings);
  RUN_TEST(test_setup_runs_before_each_case);
#ifdef BKT_SELFTEST_FAIL
  RUN_TEST(test_deliberate_failure);
#endif
#ifdef BKT_SELFTEST_HANG
  RUN_TEST(test_deliberate_hang);
#endif
  return UNITY_END();
}
