// Width mode (M723): retiming at a constant extruder rate, W words, clamping and
// its statistics, M220, passthrough when off, and bad arguments.
#include <string.h>

#include "bktest.h"
#include "width_mode.h"

using bk::ReplyText;
using bk::WidthMode;

static char reply[WidthMode::REPLY_MIN];
static char before[WidthMode::REPLY_MIN];

// Filament cross-section for 1.75 mm, computed here independently of the core.
static const float kArea175 = 3.14159265f * 1.75f * 1.75f / 4.0f;

static bool cmd(WidthMode &m, const char *line) { return m.command(line, reply, sizeof reply); }

// Snapshot of everything the mode shows: settings, rate, M220 and statistics.
static void snapshot(WidthMode &m, char *out) {
  TEST_ASSERT_TRUE(m.command("M723", out, WidthMode::REPLY_MIN));
}

static bool same_bits(float a, float b) { return memcmp(&a, &b, sizeof a) == 0; }

// Extruder rate the core's output implies: dE over the time L / v.
static float rate_of(float len, float de, float v) { return de * v / len; }

static void test_defaults_and_report(void) {
  WidthMode m;
  TEST_ASSERT_FALSE(m.active());
  TEST_ASSERT_FALSE(m.has_target());
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  TEST_ASSERT_EQUAL_STRING(
      "echo:  M723 S0 D1.750 H0.000 L5.000 U150.000\n"
      "echo:width rate:0.000 feed%:100 moves:0 low:0 high:0 maxdev:0.00% meandev:0.00%",
      reply);
}

static void test_enter_with_flow(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 Q3.6 H0.2"));
  TEST_ASSERT_EQUAL_STRING("", reply);
  TEST_ASSERT_TRUE(m.active());
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 3.6f / kArea175, m.rate());
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 3.6f, m.flow());
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  TEST_ASSERT_EQUAL_STRING(
      "echo:  M723 S1 Q3.600 D1.750 H0.200 L5.000 U150.000\n"
      "echo:width rate:1.497 feed%:100 moves:0 low:0 high:0 maxdev:0.00% meandev:0.00%",
      reply);
  // A new diameter keeps the flow target and changes the extruder rate.
  TEST_ASSERT_TRUE(cmd(m, "M723 D2.85"));
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 3.6f / (3.14159265f * 2.85f * 2.85f / 4.0f), m.rate());
}

static void test_enter_with_rate(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R2 D2.85"));
  TEST_ASSERT_EQUAL_FLOAT(2.0f, m.rate());  // R is the rate itself, whatever D is
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  TEST_ASSERT_EQUAL_STRING(
      "echo:  M723 S1 R2.000 D2.850 H0.000 L5.000 U150.000\n"
      "echo:width rate:2.000 feed%:100 moves:0 low:0 high:0 maxdev:0.00% meandev:0.00%",
      reply);
}

// The goal: the extruder turns at r on every unclamped move, whatever the width,
// length or the feed the host asked for.
static void test_constant_rate_across_widths(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 Q3.6 H0.2"));
  const float r = m.rate();
  const float widths[] = {0.25f, 0.4f, 0.62f, 0.9f, 1.3f, 1.8f};
  const float lens[] = {0.5f, 3.0f, 12.5f};
  float v_prev = 1e9f;
  for (uint8_t i = 0; i < sizeof widths / sizeof widths[0]; i++) {
    float v_first = 0;
    for (uint8_t j = 0; j < sizeof lens / sizeof lens[0]; j++) {
      float de = widths[i] * 0.2f * lens[j] / kArea175;
      float v = m.feed(lens[j], de, 40.0f);
      TEST_ASSERT_FLOAT_WITHIN_MESSAGE(r * 0.001f, r, rate_of(lens[j], de, v), "rate off by > 0.1 %");
      // Expected head speed straight from A = W*H = Q / v.
      TEST_ASSERT_FLOAT_WITHIN(0.001f * v, 3.6f / (widths[i] * 0.2f), v);
      if (j == 0) v_first = v;
      TEST_ASSERT_FLOAT_WITHIN(1e-4f * v, v_first, v);  // speed depends on width, not on length
    }
    TEST_ASSERT_TRUE(v_first < v_prev);  // wider line, slower head
    v_prev = v_first;
  }
  TEST_ASSERT_EQUAL_UINT32(18, m.stats().moves);
  TEST_ASSERT_EQUAL_UINT32(0, m.stats().clamped_low + m.stats().clamped_high);
}

static void test_feed_xy_matches_length(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1.5"));
  float v1 = m.feed_xy(3.0f, -4.0f, 0.2f, 40.0f);
  float v2 = m.feed(5.0f, 0.2f, 40.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-5f * v2, v2, v1);
  TEST_ASSERT_FLOAT_WITHIN(1e-3f, 5.0f * 1.5f / 0.2f, v1);  // 37.5 mm/s
}

static void test_clamping_and_statistics(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1.5 U60"));
  // r = 1.5, L = 10: dE 0.1 wants 150 mm/s -> 60 (rate 0.4 r: dev 0.6)
  float v = m.feed(10.0f, 0.1f, 40.0f);
  TEST_ASSERT_EQUAL_FLOAT(60.0f, v);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 0.4f * 1.5f, rate_of(10.0f, 0.1f, v));
  // dE 10 wants 1.5 mm/s -> 5 (rate 3.333 r: dev 2.3333)
  v = m.feed(10.0f, 10.0f, 40.0f);
  TEST_ASSERT_EQUAL_FLOAT(5.0f, v);
  // an unclamped move between them
  v = m.feed(10.0f, 0.5f, 40.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 30.0f, v);
  const bk::WidthStats &s = m.stats();
  TEST_ASSERT_EQUAL_UINT32(3, s.moves);
  TEST_ASSERT_EQUAL_UINT32(1, s.clamped_low);
  TEST_ASSERT_EQUAL_UINT32(1, s.clamped_high);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 5.0f / 1.5f - 1.0f, s.max_dev);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 0.6f + 5.0f / 1.5f - 1.0f, s.sum_dev);
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  TEST_ASSERT_EQUAL_STRING(
      "echo:  M723 S1 R1.500 D1.750 H0.000 L5.000 U60.000\n"
      "echo:width rate:1.500 feed%:100 moves:3 low:1 high:1 maxdev:233.33% meandev:146.67%",
      reply);
  // Limits exactly at the bound are not clamps.
  v = m.feed(10.0f, 0.25f, 40.0f);  // exactly 60
  TEST_ASSERT_EQUAL_FLOAT(60.0f, v);
  TEST_ASSERT_EQUAL_UINT32(1, m.stats().clamped_high);
}

static void test_statistics_reset_on_entering(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1.5 U60"));
  m.feed(10.0f, 0.1f, 40.0f);
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1.4"));  // already on: counting goes on
  TEST_ASSERT_EQUAL_UINT32(1, m.stats().moves);
  TEST_ASSERT_TRUE(cmd(m, "M723 S0"));
  TEST_ASSERT_EQUAL_UINT32(1, m.stats().clamped_high);  // still reported after leaving
  TEST_ASSERT_TRUE(cmd(m, "M723 S1"));                  // target kept from before
  TEST_ASSERT_EQUAL_UINT32(0, m.stats().moves);
  TEST_ASSERT_EQUAL_UINT32(0, m.stats().clamped_high);
  TEST_ASSERT_EQUAL_FLOAT(0.0f, m.stats().max_dev);
}

static void test_non_extruding_moves_untouched(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1.5"));
  const float f = 123.456f;
  TEST_ASSERT_TRUE(same_bits(f, m.feed(20.0f, 0.0f, f)));       // travel
  TEST_ASSERT_TRUE(same_bits(f, m.feed(0.0f, -0.8f, f)));       // retraction
  TEST_ASSERT_TRUE(same_bits(f, m.feed(5.0f, -0.3f, f)));       // wipe while retracting
  TEST_ASSERT_TRUE(same_bits(f, m.feed(0.0f, 0.8f, f)));        // unretract / prime (no XY)
  TEST_ASSERT_TRUE(same_bits(f, m.feed_xy(0.0f, 0.0f, 0.8f, f)));
  TEST_ASSERT_TRUE(same_bits(f, m.feed_xy(3.0f, 4.0f, 0.0f, f)));
  TEST_ASSERT_EQUAL_UINT32(0, m.stats().moves);
}

// Off (before any M723 and after S0) the hook hands back the very same float.
static void test_off_is_bit_identical(void) {
  WidthMode m;
  const float feeds[] = {0.0f, 1e-30f, 0.1f, 33.333333f, 100.0f, 3.4e38f, -5.0f};
  for (uint8_t i = 0; i < sizeof feeds / sizeof feeds[0]; i++) {
    TEST_ASSERT_TRUE(same_bits(feeds[i], m.feed(10.0f, 0.4f, feeds[i])));
    TEST_ASSERT_TRUE(same_bits(feeds[i], m.feed_xy(6.0f, 8.0f, 0.4f, feeds[i])));
  }
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 Q3.6 H0.2 U60"));
  TEST_ASSERT_FALSE(same_bits(40.0f, m.feed(10.0f, 0.4f, 40.0f)));  // on: retimed
  TEST_ASSERT_TRUE(cmd(m, "M723 S0"));
  TEST_ASSERT_FALSE(m.active());
  uint32_t moves = m.stats().moves;
  for (uint8_t i = 0; i < sizeof feeds / sizeof feeds[0]; i++) {
    TEST_ASSERT_TRUE(same_bits(feeds[i], m.feed(10.0f, 0.4f, feeds[i])));
    TEST_ASSERT_TRUE(same_bits(feeds[i], m.feed_xy(6.0f, 8.0f, 0.4f, feeds[i])));
  }
  TEST_ASSERT_EQUAL_UINT32(moves, m.stats().moves);
  // Settings survive S0 so S1 alone resumes.
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  static const char line1[] = "echo:  M723 S0 Q3.600 D1.750 H0.200 L5.000 U60.000\n";
  TEST_ASSERT_EQUAL_INT(0, strncmp(reply, line1, sizeof line1 - 1));
  float de = 0;
  TEST_ASSERT_FALSE(m.width_e(0.5f, false, 10.0f, de, reply, sizeof reply));  // W refused when off
}

static void test_width_word_arithmetic(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 Q3.6 H0.2"));
  float de = -1;
  TEST_ASSERT_TRUE(m.width_e(0.62f, false, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("", reply);
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 0.62f * 0.2f * 10.0f / kArea175, de);  // 0.51553
  float v = m.feed(10.0f, de, 40.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-3f, 3.6f / (0.62f * 0.2f), v);  // 29.03 mm/s
  // Same through dx/dy, and with another H and D.
  float de2 = -1;
  TEST_ASSERT_TRUE(m.width_e_xy(0.62f, false, 6.0f, 8.0f, de2, reply, sizeof reply));
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, de, de2);
  TEST_ASSERT_TRUE(cmd(m, "M723 H0.3 D2.85"));
  TEST_ASSERT_TRUE(m.width_e(1.2f, false, 4.0f, de, reply, sizeof reply));
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.2f * 0.3f * 4.0f / (3.14159265f * 2.85f * 2.85f / 4.0f), de);
}

static void test_width_word_errors(void) {
  WidthMode m;
  float de = 7.0f;
  TEST_ASSERT_FALSE(m.width_e(0.5f, false, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W needs M723 S1 and H", reply);
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1.5"));
  TEST_ASSERT_FALSE(m.width_e(0.5f, false, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W needs M723 S1 and H", reply);
  TEST_ASSERT_TRUE(cmd(m, "M723 H0.2"));
  TEST_ASSERT_FALSE(m.width_e(0.5f, true, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W and E in one move", reply);
  TEST_ASSERT_FALSE(m.width_e(0.0f, false, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W0.000 not in (0.000..5.000]", reply);
  TEST_ASSERT_FALSE(m.width_e(-0.4f, false, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W-0.400 not in (0.000..5.000]", reply);
  TEST_ASSERT_FALSE(m.width_e(5.5f, false, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W5.500 not in (0.000..5.000]", reply);
  TEST_ASSERT_FALSE(m.width_e(0.5f, false, 0.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W without XY travel", reply);
  TEST_ASSERT_EQUAL_FLOAT(7.0f, de);  // never written on failure
  TEST_ASSERT_TRUE(cmd(m, "M723 H0"));  // H0: no layer height again
  TEST_ASSERT_FALSE(m.width_e(0.5f, false, 10.0f, de, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:W needs M723 S1 and H", reply);
}

struct BadCase {
  const char *line;
  const char *error;
};

// Each bad command gives exactly this reply and leaves every setting and
// statistic as it was, including the valid words given with the bad one.
static void test_bad_arguments(void) {
  static const BadCase cases[] = {
      {"M723 Q0", "Error:M723 Q0.000 not in (0.000..100.000]"},
      {"M723 Q-2", "Error:M723 Q-2.000 not in (0.000..100.000]"},
      {"M723 Q150", "Error:M723 Q150.000 not in (0.000..100.000]"},
      {"M723 R0", "Error:M723 R0.000 not in (0.000..50.000]"},
      {"M723 R60", "Error:M723 R60.000 not in (0.000..50.000]"},
      {"M723 Q3 R1", "Error:M723 Q or R, not both"},
      {"M723 R1 Q3", "Error:M723 Q or R, not both"},
      {"M723 Q3 R", "Error:M723 R bad number"},
      {"M723 D0", "Error:M723 D0.000 not in [1.000..3.500]"},
      {"M723 D-1.75", "Error:M723 D-1.750 not in [1.000..3.500]"},
      {"M723 D5", "Error:M723 D5.000 not in [1.000..3.500]"},
      {"M723 S1 Q3 D0", "Error:M723 D0.000 not in [1.000..3.500]"},
      {"M723 H-0.1", "Error:M723 H-0.100 not in [0.000..2.000]"},
      {"M723 H2.5", "Error:M723 H2.500 not in [0.000..2.000]"},
      {"M723 L0", "Error:M723 L0.000 not in [0.100..1000.000]"},
      {"M723 L0.05 U900", "Error:M723 L0.050 not in [0.100..1000.000]"},
      {"M723 U0", "Error:M723 U0.000 not in [0.100..1000.000]"},
      {"M723 U1500", "Error:M723 U1500.000 not in [0.100..1000.000]"},
      {"M723 S1 R2 D1.8 H0.5 L1 U1500", "Error:M723 U1500.000 not in [0.100..1000.000]"},  // last word
      {"M723 L50 U20", "Error:M723 L50.000 > U20.000"},
      {"M723 L90", "Error:M723 L90.000 > U80.000"},  // against the U in force
      {"M723 U7.5", "Error:M723 L8.000 > U7.500"},   // against the L in force
      {"M723 Q100 D1", "Error:M723 extruder rate 127.324 > 50.000 (Q, D)"},
      {"M723 D1", "Error:M723 extruder rate 50.930 > 50.000 (Q, D)"},  // Q40 in force
      {"M723 S2", "Error:M723 S must be 0 or 1"},
      {"M723 S-1", "Error:M723 S must be 0 or 1"},
      {"M723 S1.0", "Error:M723 S must be 0 or 1"},
      {"M723 S", "Error:M723 S must be 0 or 1"},
      {"M723 Q1x", "Error:M723 Q bad number"},
      {"M723 H", "Error:M723 H bad number"},
      {"M723 S1 H0.3 U", "Error:M723 U bad number"},
      {"M723 S1 X5", "Error:M723 unknown parameter X"},
      {"M723 W0.5", "Error:M723 unknown parameter W"},
      {"M723 D2 D3", "Error:M723 duplicate parameter D"},
      {"hello", "Error:M723 not a G-code line"},
  };
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 Q40 D2.85 H0.2 L8 U80"));  // valid, mode off
  m.feed(10.0f, 0.1f, 40.0f);  // off: not counted, state stays the valid one
  snapshot(m, before);
  for (uint8_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    reply[0] = 0;
    TEST_ASSERT_FALSE_MESSAGE(cmd(m, cases[i].line), "bad command accepted");
    if (strcmp(cases[i].error, reply) != 0) {
      TEST_PRINT("  line: ");
      bkt_puts(cases[i].line);
      TEST_PRINT("\n  got:  ");
      bkt_puts(reply);
      bkt_putc('\n');
    }
    TEST_ASSERT_EQUAL_STRING(cases[i].error, reply);
    snapshot(m, reply);
    TEST_ASSERT_EQUAL_STRING_MESSAGE(before, reply, "state changed by a bad command");
    TEST_ASSERT_FALSE(m.active());
  }
  // S1 needs a target; a fresh mode has none.
  WidthMode fresh;
  TEST_ASSERT_FALSE(cmd(fresh, "M723 S1 H0.2"));
  TEST_ASSERT_EQUAL_STRING("Error:M723 S1 needs Q or R", reply);
  TEST_ASSERT_FALSE(fresh.active());
  TEST_ASSERT_EQUAL_FLOAT(0.0f, fresh.layer_height());
}

// M220: the percentage scales r, hence every retimed speed; widths stay.
static void test_feed_percentage(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1.5 H0.2"));
  float v100 = m.feed(10.0f, 0.5f, 40.0f);  // 30 mm/s
  TEST_ASSERT_TRUE(m.set_feed_percent(50));
  TEST_ASSERT_EQUAL_INT(50, m.feed_percent());
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 0.75f, m.rate());
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.5f, m.base_rate());
  float v50 = m.feed(10.0f, 0.5f, 40.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, v100 * 0.5f, v50);
  // The W word gives the same dE at any percentage: the width is the host's.
  float de50 = 0, de100 = 0;
  TEST_ASSERT_TRUE(m.width_e(0.6f, false, 10.0f, de50, reply, sizeof reply));
  TEST_ASSERT_TRUE(m.set_feed_percent(100));
  TEST_ASSERT_TRUE(m.width_e(0.6f, false, 10.0f, de100, reply, sizeof reply));
  TEST_ASSERT_TRUE(same_bits(de50, de100));
  // The limits hold for the scaled speed: 30 mm/s at 600 % is 180 > U 150.
  TEST_ASSERT_TRUE(m.set_feed_percent(600));
  TEST_ASSERT_EQUAL_FLOAT(150.0f, m.feed(10.0f, 0.5f, 40.0f));
  TEST_ASSERT_EQUAL_UINT32(1, m.stats().clamped_high);
  // Nonsense percentages are refused and change nothing.
  TEST_ASSERT_FALSE(m.set_feed_percent(0));
  TEST_ASSERT_FALSE(m.set_feed_percent(-20));
  TEST_ASSERT_EQUAL_INT(600, m.feed_percent());
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 9.0f, m.rate());
  // The percentage set while off applies once on, and a new Q/R keeps it.
  TEST_ASSERT_TRUE(cmd(m, "M723 S0"));
  TEST_ASSERT_TRUE(m.set_feed_percent(80));
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R2"));
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.6f, m.rate());
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  TEST_ASSERT_EQUAL_INT(0, strncmp(strchr(reply, '\n') + 1, "echo:width rate:1.600 feed%:80 ", 31));
}

// The settings line is what M500 stores and the Marlin adapter sends back on load
// (without "echo:  "): it must be a valid M723 giving the very same settings.
static void read_back(const char *set) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, set));
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  char line[WidthMode::REPLY_MIN];
  const char *start = reply + 7;  // after "echo:  "
  const size_t len = (size_t)(strchr(reply, '\n') - start);
  memcpy(line, start, len);
  line[len] = 0;
  WidthMode back;
  const bool ok = back.command(line, before, sizeof before);
  if (!ok) {
    TEST_PRINT("  line: ");
    bkt_puts(line);
    bkt_putc('\n');
  }
  TEST_ASSERT_TRUE_MESSAGE(ok, "settings line refused");
  TEST_ASSERT_TRUE(m.active() == back.active());
  TEST_ASSERT_TRUE(same_bits(m.flow(), back.flow()));
  TEST_ASSERT_TRUE(same_bits(m.rate(), back.rate()));
  TEST_ASSERT_TRUE(same_bits(m.filament_dia(), back.filament_dia()));
  TEST_ASSERT_TRUE(same_bits(m.layer_height(), back.layer_height()));
  TEST_ASSERT_TRUE(same_bits(m.min_speed(), back.min_speed()));
  TEST_ASSERT_TRUE(same_bits(m.max_speed(), back.max_speed()));
}

static void test_settings_line_reads_back(void) {
  read_back("M723 S0");
  read_back("M723 S1 Q3.217 D2.85 H0.123 L0.125 U999.999");
  read_back("M723 R0.001 D1 H2 L0.1 U0.1");
  read_back("M723 S1 Q100 D3.5 H0 L1000 U1000");
}

// The report's worst case must fit REPLY_MIN: largest settings, deviations over
// the printable bound, and counters that may grow to 10 digits.
static void test_report_fits(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 Q100 D3.5 H2 L1000 U1000"));
  m.set_feed_percent(999);
  m.feed(0.001f, 1000.0f, 1.0f);  // wants ~0 mm/s: deviation far beyond 1e6 %
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  TEST_ASSERT_TRUE(strstr(reply, "maxdev:>=1000000% meandev:>=1000000%") != NULL);
  // Three counters shown with 1 digit here could need 10.
  TEST_ASSERT_LESS_THAN_INT(WidthMode::REPLY_MIN, (int32_t)strlen(reply) + 3 * 9 + 1);
}

// M501: the stored values (target kind, Q|R D H L U) come back through M723's
// checks, the mode untouched; one refused value refuses the set.
static void test_restore_checks_each_value(void) {
  WidthMode m;
  TEST_ASSERT_TRUE(cmd(m, "M723 S1 R1"));
  const float ok[5] = {3.2f, 2.85f, 0.2f, 8.0f, 90.0f};
  ReplyText r(reply, sizeof reply);
  TEST_ASSERT_TRUE(m.restore(1, ok, r));
  TEST_ASSERT_TRUE(r.empty());
  TEST_ASSERT_TRUE(m.active());  // the mode is not a stored setting
  TEST_ASSERT_TRUE(cmd(m, "M723"));
  static const char line1[] = "echo:  M723 S1 Q3.200 D2.850 H0.200 L8.000 U90.000\n";
  TEST_ASSERT_EQUAL_INT(0, strncmp(reply, line1, sizeof line1 - 1));
  snapshot(m, before);
  const struct { uint8_t kind; float v[5]; const char *error; } bad[] = {
      {1, {150.0f, 2.85f, 0.2f, 8.0f, 90.0f}, "Error:M723 Q150.000 not in (0.000..100.000]"},
      {2, {0.0f, 2.85f, 0.2f, 8.0f, 90.0f}, "Error:M723 R0.000 not in (0.000..50.000]"},
      {1, {3.2f, 0.5f, 0.2f, 8.0f, 90.0f}, "Error:M723 D0.500 not in [1.000..3.500]"},
      {1, {3.2f, 2.85f, 0.2f, 95.0f, 90.0f}, "Error:M723 L95.000 > U90.000"},
      {1, {90.0f, 1.0f, 0.2f, 8.0f, 90.0f}, "Error:M723 extruder rate 114.592 > 50.000 (Q, D)"},
  };
  for (uint8_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    ReplyText e(reply, sizeof reply);
    TEST_ASSERT_FALSE(m.restore(bad[i].kind, bad[i].v, e));
    TEST_ASSERT_EQUAL_STRING(bad[i].error, reply);
    snapshot(m, reply);
    TEST_ASSERT_EQUAL_STRING_MESSAGE(before, reply, "state changed by a refused restore");
  }
  // No target stored: the stored target value does not matter, the target in
  // force stays, so a mode that is on keeps one (S1 needs Q or R).
  const float none[5] = {123.0f, 1.75f, 0.0f, 5.0f, 150.0f};
  WidthMode fresh;
  ReplyText f(reply, sizeof reply);
  TEST_ASSERT_TRUE(fresh.restore(0, none, f));
  TEST_ASSERT_FALSE(fresh.has_target());
  TEST_ASSERT_EQUAL_FLOAT(0.0f, fresh.target());
  WidthMode on;
  TEST_ASSERT_TRUE(cmd(on, "M723 S1 R1.5 H0.2"));
  ReplyText g(reply, sizeof reply);
  TEST_ASSERT_TRUE(on.restore(0, none, g));
  TEST_ASSERT_TRUE(on.active());
  TEST_ASSERT_TRUE(on.has_target());
  TEST_ASSERT_EQUAL_FLOAT(1.5f, on.target());
  TEST_ASSERT_EQUAL_FLOAT(0.0f, on.layer_height());  // the stored H came back
  TEST_ASSERT_EQUAL_FLOAT(15.0f, on.feed(10.0f, 1.0f, 40.0f));  // v = L r / dE = 10 * 1.5 / 1, not L
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_defaults_and_report);
  RUN_TEST(test_enter_with_flow);
  RUN_TEST(test_enter_with_rate);
  RUN_TEST(test_constant_rate_across_widths);
  RUN_TEST(test_feed_xy_matches_length);
  RUN_TEST(test_clamping_and_statistics);
  RUN_TEST(test_statistics_reset_on_entering);
  RUN_TEST(test_non_extruding_moves_untouched);
  RUN_TEST(test_off_is_bit_identical);
  RUN_TEST(test_width_word_arithmetic);
  RUN_TEST(test_width_word_errors);
  RUN_TEST(test_bad_arguments);
  RUN_TEST(test_feed_percentage);
  RUN_TEST(test_settings_line_reads_back);
  RUN_TEST(test_report_fits);
  RUN_TEST(test_restore_checks_each_value);
  return UNITY_END();
}
