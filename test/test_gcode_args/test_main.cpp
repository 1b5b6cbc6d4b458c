// M-code argument parsing: values, malformed words, line numbers, checksums.
#include <string.h>

#include "bktest.h"
#include "gcode_args.h"
#include "reply_text.h"

using bk::GcodeArgs;

static void test_code_and_words(void) {
  GcodeArgs a;
  TEST_ASSERT_TRUE(a.parse("N12 M720 S1 P100 E0.1 T.25*57"));
  TEST_ASSERT_EQUAL_INT('M', a.code_letter());
  TEST_ASSERT_EQUAL_INT(720, a.code());
  float f = 0;
  TEST_ASSERT_EQUAL_INT(bk::ARG_OK, a.get_float('E', f));
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.1f, f);
  TEST_ASSERT_EQUAL_INT(bk::ARG_OK, a.get_float('t', f));
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.25f, f);
  int32_t l = 0;
  TEST_ASSERT_EQUAL_INT(bk::ARG_OK, a.get_long('P', l));
  TEST_ASSERT_EQUAL_INT(100, l);
  TEST_ASSERT_EQUAL_INT(bk::ARG_ABSENT, a.get_long('X', l));
  TEST_ASSERT_EQUAL_INT(0, a.unknown(BKT_S("SPET")));
  TEST_ASSERT_EQUAL_INT('T', a.unknown(BKT_S("SPE")));
}

static void test_malformed_values(void) {
  GcodeArgs a;
  float f;
  int32_t l;
  TEST_ASSERT_TRUE(a.parse("M720 P1x E. S--1 T"));
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_long('P', l));
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_float('E', f));
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_float('S', f));
  TEST_ASSERT_EQUAL_INT(bk::ARG_EMPTY, a.get_float('T', f));
  TEST_ASSERT_TRUE(a.parse("M720 P1.5"));
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_long('P', l));  // integer expected
  TEST_ASSERT_FALSE(a.parse("X10"));
  TEST_ASSERT_FALSE(a.parse("M"));
}

static void test_ulong_range_and_comment(void) {
  GcodeArgs a;
  uint32_t u = 0;
  TEST_ASSERT_TRUE(a.parse("m721 s2048 c4294967295 ; comment X1"));
  TEST_ASSERT_EQUAL_INT(721, a.code());
  TEST_ASSERT_EQUAL_INT(bk::ARG_OK, a.get_ulong('C', u));
  TEST_ASSERT_EQUAL_UINT32(4294967295u, u);
  TEST_ASSERT_FALSE(a.has('X'));  // after the comment
  TEST_ASSERT_TRUE(a.parse("M721 C4294967296"));
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_ulong('C', u));
}

static void test_long_overflow_is_rejected_not_wrapped(void) {
  GcodeArgs a;
  int32_t l = 7;
  // 4294967296 would wrap to 0 and 4294967298 to 2 if checked after the multiply
  TEST_ASSERT_TRUE(a.parse("M720 P4294967296 S4294967298 T2147483647 E2147483648"));
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_long('P', l));
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_long('S', l));
  TEST_ASSERT_EQUAL_INT(bk::ARG_OK, a.get_long('T', l));
  TEST_ASSERT_EQUAL_INT32(2147483647L, l);
  TEST_ASSERT_EQUAL_INT(bk::ARG_BAD, a.get_long('E', l));
}

static void test_duplicate_and_unknown_words(void) {
  GcodeArgs a;
  char reply[48];
  bk::ReplyText r(reply, sizeof reply);
  TEST_ASSERT_TRUE(a.parse("M720 P100 S1 P3000"));
  TEST_ASSERT_EQUAL_INT('P', a.duplicate());
  TEST_ASSERT_FALSE(bk::check_words(a, BKT_S("SPET"), BKT_S("M720"), r));
  TEST_ASSERT_EQUAL_STRING("Error:M720 duplicate parameter P", reply);
  bk::ReplyText r2(reply, sizeof reply);
  TEST_ASSERT_TRUE(a.parse("M720 S1 Q5"));
  TEST_ASSERT_FALSE(bk::check_words(a, BKT_S("SPET"), BKT_S("M720"), r2));
  TEST_ASSERT_EQUAL_STRING("Error:M720 unknown parameter Q", reply);
  bk::ReplyText r3(reply, sizeof reply);
  TEST_ASSERT_TRUE(a.parse("M720 S1 P100"));
  TEST_ASSERT_TRUE(bk::check_words(a, BKT_S("SPET"), BKT_S("M720"), r3));
  TEST_ASSERT_EQUAL_STRING("", reply);
}

// Decimals come out as the float nearest the number (as a correctly rounded
// strtod: the host's reference planner reads G-code that way), and trailing
// zeros change nothing. Dividing by 10 once per decimal was an ulp off.
static void test_decimals_are_the_nearest_float(void) {
  static const struct { const char *line; uint32_t bits; } cases[] = {
      {"M720 T7.02", 0x40e0a3d7UL},  {"M720 T17.44", 0x418b851fUL}, {"M720 T0.01", 0x3c23d70aUL},
      {"M720 T2.85", 0x40366666UL},  {"M720 T2.850", 0x40366666UL}, {"M720 T3.217", 0x404de354UL},
      {"M720 T-7.020", 0xc0e0a3d7UL},
  };
  GcodeArgs a;
  for (uint8_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    TEST_ASSERT_TRUE(a.parse(cases[i].line));
    float f = 0;
    TEST_ASSERT_EQUAL_INT(bk::ARG_OK, a.get_float('T', f));
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    TEST_ASSERT_EQUAL_HEX32(cases[i].bits, bits);
  }
}

static void test_raw_word(void) {
  GcodeArgs a;
  TEST_ASSERT_TRUE(a.parse("N7 M721 O40 DMFRGGZDFMZTWQ2LK*99"));
  const char *t;
  uint8_t n;
  TEST_ASSERT_TRUE(a.raw('D', t, n));
  TEST_ASSERT_EQUAL_INT(16, n);
  TEST_ASSERT_EQUAL_INT('M', t[0]);
  TEST_ASSERT_EQUAL_INT('K', t[15]);
}

static void test_read_limited(void) {
  static const bk::Limit q = {'Q', true, 0.0f, 100.0f}, l = {'L', false, 0.1f, 1000.0f};
  GcodeArgs a;
  char buf[64];
  float v = -7;
  bk::ReplyText r(buf, sizeof(buf));
  TEST_ASSERT_TRUE(a.parse("M723 Q100 L0.1"));
  TEST_ASSERT_EQUAL_INT(1, bk::read_limited(a, q, BK_F("M723"), v, r));
  TEST_ASSERT_EQUAL_FLOAT(100.0f, v);
  TEST_ASSERT_EQUAL_INT(1, bk::read_limited(a, l, BK_F("M723"), v, r));  // closed end
  TEST_ASSERT_EQUAL_STRING("", buf);
  TEST_ASSERT_TRUE(a.parse("M723 Q0 L0.05"));
  v = -7;
  TEST_ASSERT_EQUAL_INT(-1, bk::read_limited(a, q, BK_F("M723"), v, r));  // open end
  TEST_ASSERT_EQUAL_STRING("Error:M723 Q0.000 not in (0.000..100.000]", buf);
  TEST_ASSERT_EQUAL_FLOAT(-7.0f, v);  // untouched on an error
  bk::ReplyText r2(buf, sizeof(buf));
  TEST_ASSERT_EQUAL_INT(-1, bk::read_limited(a, l, BK_F("M723"), v, r2));
  TEST_ASSERT_EQUAL_STRING("Error:M723 L0.050 not in [0.100..1000.000]", buf);
  TEST_ASSERT_TRUE(a.parse("M723 Q1e3 U"));
  bk::ReplyText r3(buf, sizeof(buf));
  TEST_ASSERT_EQUAL_INT(-1, bk::read_limited(a, q, BK_F("M723"), v, r3));
  TEST_ASSERT_EQUAL_STRING("Error:M723 Q bad number", buf);
  static const bk::Limit u = {'U', false, 0.0f, 1.0f};
  bk::ReplyText r4(buf, sizeof(buf));
  TEST_ASSERT_EQUAL_INT(-1, bk::read_limited(a, u, BK_F("M723"), v, r4));  // empty value
  TEST_ASSERT_EQUAL_STRING("Error:M723 U bad number", buf);
  static const bk::Limit x = {'X', false, 0.0f, 1.0f};
  TEST_ASSERT_EQUAL_INT(0, bk::read_limited(a, x, BK_F("M723"), v, r4));  // absent
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_code_and_words);
  RUN_TEST(test_malformed_values);
  RUN_TEST(test_ulong_range_and_comment);
  RUN_TEST(test_raw_word);
  RUN_TEST(test_decimals_are_the_nearest_float);
  RUN_TEST(test_long_overflow_is_rejected_not_wrapped);
  RUN_TEST(test_duplicate_and_unknown_words);
  RUN_TEST(test_read_limited);
  return UNITY_END();
}
