// Bulge planner cost per G1: cycles on the simulated ATmega2560 (ns on the
// host), printed as a table. The layer is a 20 mm square wall with 0, 16 or 64
// bulge points spread evenly along it (64 points: one every 1.25 mm).
// Every timed call is one plan() (plus its plan_more() calls where noted),
// marker overhead included (6 cycles on AVR). The assertions check that each
// case did what its name says; on AVR the common case must stay within the
// 2,000-cycle goal.
#include <string.h>

#include "bktest.h"
#include "bulge_map.h"
#include "bulge_planner.h"
#include "gcode_args.h"
#include "move_state.h"

using bk::Action;
using bk::ActionList;
using bk::BulgePlanner;
using bk::Move;

static BulgePlanner P;
static bk::MapLayer L;
static ActionList out;
static char reply[BK_PLAN_REPLY_MAX];
static const float PERIM = 80.0f;  // 20 mm square
static const uint8_t N = 8;        // moves per measurement

// A place on the square's perimeter, s in [0, 80).
static void at(float s, float &x, float &y) {
  while (s >= PERIM) s -= PERIM;
  while (s < 0) s += PERIM;
  if (s < 20) {
    x = s;
    y = 0;
  } else if (s < 40) {
    x = 20;
    y = s - 20;
  } else if (s < 60) {
    x = 60 - s;
    y = 20;
  } else {
    x = 0;
    y = 80 - s;
  }
}

static Move along(float s0, float s1, float e) {
  Move m;
  at(s0, m.x0, m.y0);
  at(s1, m.x1, m.y1);
  m.z0 = m.z1 = 0.3f;
  m.e = e;
  m.f = 1800;
  return m;
}

static void setup_layer(uint8_t n) {
  P.reset();
  bk::GcodeArgs g;
  g.parse("M720 S2");
  P.m720(g, reply, sizeof reply);
  L.z_cmm = 30;
  L.count = n;
  for (uint8_t k = 0; k < n; k++) {
    float x, y;
    at(((float)k + 0.5f) * PERIM / (float)n, x, y);
    L.pts[k].x = (int16_t)(x * 20.0f + 0.5f);
    L.pts[k].y = (int16_t)(y * 20.0f + 0.5f);
    L.pts[k].w = 255;
  }
  P.load_layer(L, 50, 30);
}

struct Stat {
  uint32_t sum, max;
  uint8_t n;
};
static void add(Stat &s, uint32_t v) {
  s.sum += v;
  if (v > s.max) s.max = v;
  s.n++;
}

static void row(const char *label_flash, uint8_t pts, const Stat &s) {
  bkt_puts("| ");
  bkt_puts_P(label_flash);
  bkt_puts(" | ");
  bkt_put_uint(pts);
  bkt_puts(" | ");
  bkt_put_uint(s.n ? s.sum / s.n : 0);
  bkt_puts(" | ");
  bkt_put_uint(s.max);
  bkt_puts(" ");
  bkt_puts(bkt_bench_unit());
  bkt_puts(" |\n");
}

static uint8_t dwells() {
  uint8_t c = 0;
  for (uint8_t i = 0; i < out.count; i++) c += out.a[i].kind == Action::DWELL;
  return c;
}

void setUp(void) {}
void tearDown(void) {}

static void header(void) {
  TEST_MESSAGE("| case | points in layer | mean | max |");
  TEST_MESSAGE("|---|---|---|---|");
}

// The common case: a short wall move between two points (0.25 mm, starting
// where the previous wall move ended), hitting nothing.
static uint32_t common_case(uint8_t n, bool chained) {
  setup_layer(n);
  Stat s = {0, 0, 0};
  const float gap = n ? PERIM / (float)n : 10.0f;
  for (uint8_t i = 0; i < N; i++) {
    // Centred between points k and k+1 (k spread over all four sides), at
    // least 0.3 mm from either, so nothing may fire.
    const uint8_t k = (uint8_t)(n ? i * (n / N) : i);
    const float mid = (float)(k + 1) * gap;
    const float s1 = mid - 0.125f, s2 = mid + 0.125f, s0 = s1 - 0.2f;
    if (chained) P.plan(along(s0, s1, 0.02f), out);
    Move m = along(s1, s2, 0.02f);
    BKT_BENCH_BEGIN();
    bool more = P.plan(m, out);
    BKT_BENCH_END();
    add(s, bkt_bench_last());
    TEST_ASSERT_FALSE(more);
    TEST_ASSERT_EQUAL_INT(1, out.count);
    TEST_ASSERT_EQUAL_INT(0, dwells());
  }
  row(chained ? BKT_S("short wall move, no hit, start = last end") : BKT_S("short wall move, no hit, cold start"),
      n, s);
  return s.sum / s.n;
}

static void test_common_case(void) {
  header();
  common_case(0, true);
  common_case(16, true);
  uint32_t c64 = common_case(64, true);
  common_case(64, false);
  if (bkt_on_avr()) {
    // The goal is 2,000 cycles (issues 6 and 13: keep it); the figure is
    // printed against it and held to it. simavr counts cycles exactly, so the
    // check cannot flake; an out-of-line helper once cost 130 cycles (2,039)
    // and a guard with headroom let it pass.
    TEST_PRINT("goal <= 2000 cycles at 64 points (common case): ");
    if (c64 <= 2000) TEST_PRINT("met, ");
    else TEST_PRINT("MISSED, ");
    bkt_put_uint(c64);
    TEST_PRINT(" cycles\n");
    TEST_ASSERT_LESS_OR_EQUAL_INT(2000, (int32_t)c64);
  }
}

static void test_hit_one_point(void) {
  setup_layer(64);
  Stat s = {0, 0, 0};
  for (uint8_t i = 0; i < N; i++) {
    float sp = ((float)(i * 8) + 0.5f) * 1.25f;  // point k = 8 i
    P.plan(along(sp - 1.0f, sp - 0.5f, 0.05f), out);  // the wall move before
    Move m = along(sp - 0.5f, sp + 0.5f, 0.073f);
    BKT_BENCH_BEGIN();
    bool more = P.plan(m, out);
    BKT_BENCH_END();
    add(s, bkt_bench_last());
    TEST_ASSERT_FALSE(more);
    TEST_ASSERT_EQUAL_INT(3, out.count);
    TEST_ASSERT_EQUAL_INT(1, dwells());
  }
  row(BKT_S("1 mm wall move through 1 point (line+dwell+line)"), 64, s);
}

static void test_long_wall_move_many_points(void) {
  // One 20 mm side in a single G1 passes 16 points: all lists, summed.
  setup_layer(64);
  Stat s = {0, 0, 0};
  Move m = along(0.01f, 19.99f, 1.46f);
  uint8_t total = 0;
  BKT_BENCH_BEGIN();
  bool more = P.plan(m, out);
  BKT_BENCH_END();
  uint32_t cyc = bkt_bench_last();
  total += dwells();
  while (more) {
    BKT_BENCH_BEGIN();
    more = P.plan_more(out);
    BKT_BENCH_END();
    cyc += bkt_bench_last();
    total += dwells();
  }
  add(s, cyc);
  TEST_ASSERT_EQUAL_INT(16, total);
  row(BKT_S("20 mm wall move through 16 points, all lists"), 64, s);
}

static void test_worst_case_infill(void) {
  // Geometric mode sees every extruding move: a long diagonal infill line
  // spans the whole layer, so every point passes the box test and the
  // integer line test must reject each one.
  for (uint8_t pass = 0; pass < 2; pass++) {
    const uint8_t n = pass ? 64 : 16;
    setup_layer(n);
    Stat s = {0, 0, 0};
    for (uint8_t i = 0; i < N; i++) {
      float o = 0.6f + 0.1f * (float)i;
      Move m;
      m.x0 = o;
      m.y0 = 0.6f;
      m.x1 = 19.4f;
      m.y1 = 20.0f - o;
      m.z0 = m.z1 = 0.3f;
      m.e = 1.0f;
      m.f = 3000;
      BKT_BENCH_BEGIN();
      P.plan(m, out);
      BKT_BENCH_END();
      add(s, bkt_bench_last());
      TEST_ASSERT_EQUAL_INT(0, dwells());
    }
    row(BKT_S("27 mm diagonal infill, geometric mode, no hit"), n, s);
  }
}

static void test_passthrough(void) {
  setup_layer(64);
  Stat t = {0, 0, 0}, g = {0, 0, 0};
  for (uint8_t i = 0; i < N; i++) {
    Move m = along((float)i * 10.0f, (float)i * 10.0f + 5.0f, 0.0f);  // travel
    BKT_BENCH_BEGIN();
    P.plan(m, out);
    BKT_BENCH_END();
    add(t, bkt_bench_last());
    TEST_ASSERT_EQUAL_INT(1, out.count);
  }
  row(BKT_S("travel (passthrough)"), 64, t);
  bk::GcodeArgs a;
  a.parse("M720 S1");
  P.m720(a, reply, sizeof reply);
  for (uint8_t i = 0; i < N; i++) {
    Move m = along((float)i * 10.0f, (float)i * 10.0f + 5.0f, 0.3f);
    BKT_BENCH_BEGIN();
    P.plan(m, out);
    BKT_BENCH_END();
    add(g, bkt_bench_last());
    TEST_ASSERT_EQUAL_INT(1, out.count);
  }
  row(BKT_S("extruding move outside M722 (mode 1)"), 64, g);
}

static void test_move_state_line(void) {
  // G1 words -> Move (what the adapter adds when it uses MoveState).
  bk::MoveState st;
  Stat s = {0, 0, 0};
  bk::AxisWords w;
  w.mask = bk::AxisWords::X | bk::AxisWords::Y | bk::AxisWords::E;
  for (uint8_t i = 0; i < N; i++) {
    w.x = (float)i;
    w.y = 2.0f * (float)i;
    w.e = 0.1f * (float)i;
    BKT_BENCH_BEGIN();
    Move m = st.line(w);
    BKT_BENCH_END();
    add(s, bkt_bench_last());
    TEST_ASSERT_TRUE(m.x1 == (float)i);
  }
  row(BKT_S("MoveState::line (G1 X Y E)"), 0, s);
}

// Layer change through the store: find_layer (decode 64 points), sort by x,
// release the layer below (arena memmove).
static uint8_t img[420];
static uint16_t img_n;
static bk::MapStore store;
static void put_layer(uint16_t z) {
  uint16_t start = img_n;
  img[img_n++] = (uint8_t)z;
  img[img_n++] = (uint8_t)(z >> 8);
  uint8_t body[260];
  uint16_t bl = 0;
  int16_t px = 0, py = 0;
  for (uint8_t k = 0; k < 64; k++) {
    float x, y;
    at(((float)k + 0.5f) * 1.25f, x, y);
    int16_t qx = (int16_t)(x * 20.0f + 0.5f), qy = (int16_t)(y * 20.0f + 0.5f);
    bl += bk::varint_write(body + bl, bk::zigzag_encode(qx - px));
    bl += bk::varint_write(body + bl, bk::zigzag_encode(qy - py));
    px = qx;
    py = qy;
  }
  img_n += bk::varint_write(img + img_n, 64);
  img_n += bk::varint_write(img + img_n, bl);
  memcpy(img + img_n, body, bl);
  img_n += bl;
  img[img_n] = bk::crc8(img + start, (uint16_t)(img_n - start));
  img_n++;
}

static void test_layer_change(void) {
  const uint8_t h[7] = {'B', 'K', 'M', 1, 0, 50, 30};
  memcpy(img, h, 7);
  img[7] = bk::crc8(img, 7);
  img_n = 8;
  put_layer(30);
  put_layer(60);
  TEST_ASSERT_EQUAL_INT(bk::MAP_OK, store.load(img, img_n));
  P.reset();
  bk::GcodeArgs g;
  g.parse("M720 S2");
  P.m720(g, reply, sizeof reply);
  P.attach(&store);
  Stat s = {0, 0, 0};
  P.plan(along(0.3f, 0.5f, 0.02f), out);  // loads z 0.30
  Move m = along(0.5f, 0.7f, 0.02f);
  m.z0 = m.z1 = 0.6f;
  BKT_BENCH_BEGIN();
  P.plan(m, out);
  BKT_BENCH_END();
  add(s, bkt_bench_last());
  TEST_ASSERT_EQUAL_INT(60, P.layer().z_cmm);
  TEST_ASSERT_EQUAL_INT(64, P.layer().count);
  TEST_ASSERT_EQUAL_INT(1, store.layer_count());  // z 0.30 released
  row(BKT_S("first move of a new layer (decode + sort + release)"), 64, s);
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_common_case);
  RUN_TEST(test_hit_one_point);
  RUN_TEST(test_long_wall_move_many_points);
  RUN_TEST(test_worst_case_infill);
  RUN_TEST(test_passthrough);
  RUN_TEST(test_move_state_line);
  RUN_TEST(test_layer_change);
  return UNITY_END();
}
