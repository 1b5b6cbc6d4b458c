// Host-position model: G90/G91, M82/M83, G92, F, and the internal E offset.
#include "bktest.h"
#include "bulgekit_config.h"
#include "gcode_args.h"
#include "move_state.h"

using bk::AxisWords;
using bk::Move;
using bk::MoveState;

static MoveState S;

void setUp(void) { S.reset(); }
void tearDown(void) {}

static Move g1(const char *line) {
  bk::GcodeArgs g;
  TEST_ASSERT_TRUE(g.parse(line));
  AxisWords w;
  TEST_ASSERT_EQUAL_INT(0, MoveState::words_from(g, w));
  return S.line(w);
}
static void g92(const char *line) {
  bk::GcodeArgs g;
  TEST_ASSERT_TRUE(g.parse(line));
  AxisWords w;
  TEST_ASSERT_EQUAL_INT(0, MoveState::words_from(g, w));
  S.set_position(w);
}

static void test_power_on_state(void) {
  TEST_ASSERT_TRUE(S.xyz_absolute() && S.e_absolute());
  TEST_ASSERT_TRUE(S.x() == 0 && S.y() == 0 && S.z() == 0 && S.e() == 0);
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, BK_MOVE_DEFAULT_FEED_MM_MIN, S.feed());
}

static void test_absolute_move(void) {
  Move m = g1("G1 X10 Y5 Z0.3 E1.25 F1800");
  TEST_ASSERT_TRUE(m.x0 == 0 && m.y0 == 0 && m.z0 == 0);
  TEST_ASSERT_TRUE(m.x1 == 10.0f && m.y1 == 5.0f && m.z1 == 0.3f);
  TEST_ASSERT_TRUE(m.e == 1.25f && m.f == 1800.0f);
  TEST_ASSERT_TRUE(m.extruding());
  m = g1("G1 X20 E2.0");  // Y, Z, F modal
  TEST_ASSERT_TRUE(m.x0 == 10.0f && m.y1 == 5.0f && m.z1 == 0.3f && m.f == 1800.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.75f, m.e);
  TEST_ASSERT_TRUE(S.e() == 2.0f);
}

static void test_ends_by_index(void) {
  // The planner loops over the axes through p[]: the same six numbers.
  Move m = g1("G1 X10 Y5 Z0.3 E1.25");
  TEST_ASSERT_TRUE(m.p[0] == m.x0 && m.p[1] == m.y0 && m.p[2] == m.z0);
  TEST_ASSERT_TRUE(m.p[3] == 10.0f && m.p[4] == 5.0f && m.p[5] == 0.3f);
  m.p[4] = 7.0f;
  TEST_ASSERT_TRUE(m.y1 == 7.0f && m.e == 1.25f);
}

static void test_relative_xyz_and_e(void) {
  g1("G1 X10 Y10 E5");
  S.set_absolute(false);  // G91: everything relative, E included
  Move m = g1("G1 X-2.5 Y1 E0.5");
  TEST_ASSERT_TRUE(m.x1 == 7.5f && m.y1 == 11.0f && m.e == 0.5f);
  TEST_ASSERT_TRUE(S.e() == 5.5f);
  S.set_absolute(true);  // G90: E absolute again (Marlin clears M83 here)
  TEST_ASSERT_TRUE(S.e_absolute());
  S.set_e_absolute(false);  // M83 after G90: only E relative
  m = g1("G1 X0 E0.25");
  TEST_ASSERT_TRUE(m.x1 == 0.0f && m.e == 0.25f && S.e() == 5.75f);
  S.set_e_absolute(true);  // M82
  m = g1("G1 E5.0");
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, -0.75f, m.e);
  TEST_ASSERT_FALSE(m.extruding());
}

static void test_move_kinds(void) {
  g1("G1 X5 Y5 Z0.2 E1");
  TEST_ASSERT_FALSE(g1("G0 X20 Y20").extruding());      // travel
  TEST_ASSERT_FALSE(g1("G1 X21 E0.2").extruding());     // retract with motion
  TEST_ASSERT_FALSE(g1("G1 E1").extruding());           // E-only
  TEST_ASSERT_FALSE(g1("G1 Z0.6").extruding());         // Z-only
  TEST_ASSERT_FALSE(g1("G1 X21 Z0.6 E1").xy_motion());  // same place
  TEST_ASSERT_TRUE(g1("G1 X22 E1.1").extruding());
}

static void test_g92_and_offset(void) {
  g1("G1 X10 E3");
  S.add_e_offset(0.1f);
  S.add_e_offset(0.1f);
  TEST_ASSERT_TRUE(S.e() == 3.0f);  // the host's E never moves
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 3.2f, S.machine_e());
  g92("G92 X0");  // no E: the offset stays
  TEST_ASSERT_TRUE(S.x() == 0.0f && S.e() == 3.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.2f, S.e_offset());
  Move m = g1("G1 X5 E4");
  TEST_ASSERT_TRUE(m.x0 == 0.0f && m.x1 == 5.0f && m.e == 1.0f);
  g92("G92 E0");  // re-syncs machine E with the host
  TEST_ASSERT_TRUE(S.e() == 0.0f && S.e_offset() == 0.0f && S.machine_e() == 0.0f);
  m = g1("G1 X6 E0.5");
  TEST_ASSERT_TRUE(m.e == 0.5f);
  g92("G92 X1 Y2 Z3 E4");
  TEST_ASSERT_TRUE(S.x() == 1.0f && S.y() == 2.0f && S.z() == 3.0f && S.e() == 4.0f);
}

static void test_feed_rules(void) {
  g1("G1 X1 F600");
  TEST_ASSERT_TRUE(S.feed() == 600.0f);
  g1("G1 X2 F0");  // Marlin ignores a zero feedrate
  TEST_ASSERT_TRUE(S.feed() == 600.0f);
  g1("G1 X3 F-5");
  TEST_ASSERT_TRUE(S.feed() == 600.0f);
}

static void test_malformed_words(void) {
  bk::GcodeArgs g;
  AxisWords w;
  TEST_ASSERT_TRUE(g.parse("G1 X10 Y1.2.3 E1"));
  TEST_ASSERT_EQUAL_INT('Y', MoveState::words_from(g, w));
  TEST_ASSERT_TRUE(g.parse("G1 X10 E"));
  TEST_ASSERT_EQUAL_INT('E', MoveState::words_from(g, w));
  TEST_ASSERT_TRUE(g.parse("G1 X10 S255 E1"));  // other letters are not ours
  TEST_ASSERT_EQUAL_INT(0, MoveState::words_from(g, w));
  TEST_ASSERT_EQUAL_INT(AxisWords::X | AxisWords::E, w.mask);
}

static void test_long_relative_run_tracks_like_marlin(void) {
  // M83 with 1000 small extrusions: host E is the float sum Marlin keeps too,
  // and the offset is kept apart from it.
  S.set_e_absolute(false);
  float expect = 0;
  for (uint16_t i = 0; i < 1000; i++) {
    g1("G1 X1 E0.0123");
    expect += 0.0123f;
    if (i % 100 == 0) S.add_e_offset(0.1f);
  }
  TEST_ASSERT_TRUE(S.e() == expect);
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.0f, S.e_offset());
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_power_on_state);
  RUN_TEST(test_absolute_move);
  RUN_TEST(test_ends_by_index);
  RUN_TEST(test_relative_xyz_and_e);
  RUN_TEST(test_move_kinds);
  RUN_TEST(test_g92_and_offset);
  RUN_TEST(test_feed_rules);
  RUN_TEST(test_malformed_words);
  RUN_TEST(test_long_relative_run_tracks_like_marlin);
  return UNITY_END();
}
