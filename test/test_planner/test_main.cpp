// Bulge planner: splitting (eq. 1), stops, E accounting, matching, modes,
// layer window, M720/M722. Runs on the host and on the simulated ATmega2560.
#include <math.h>
#include <string.h>

#include "bktest.h"
#include "bulge_map.h"
#include "bulge_planner.h"
#include "gcode_args.h"
#include "move_state.h"

using bk::Action;
using bk::ActionList;
using bk::BulgePlanner;
using bk::MapLayer;
using bk::Move;

static BulgePlanner P;
static MapLayer L;  // hand-made layers (quantum 50 um, layer height 0.30 mm)
static char reply[BK_PLAN_REPLY_MAX];

// Every action of one move, plan() and all plan_more() calls concatenated.
struct Trace {
  uint8_t n;
  uint8_t lists;
  float e_added;
  Action a[24];
};
static Trace T;

void setUp(void) {
  P.reset();
  bk::GcodeArgs g;
  g.parse("M720 S2");
  P.m720(g, reply, sizeof reply);
  L.count = 0;
  L.z_cmm = 30;
}
void tearDown(void) {}

// Points in mm, converted to 50 um quanta here.
static void add_point(float x, float y, uint8_t w = 255) {
  bk::MapPoint &p = L.pts[L.count++];
  p.x = (int16_t)(x * 20.0f + (x < 0 ? -0.5f : 0.5f));
  p.y = (int16_t)(y * 20.0f + (y < 0 ? -0.5f : 0.5f));
  p.w = w;
}
static void load() { P.load_layer(L, 50, 30); }

static Move mv(float x0, float y0, float x1, float y1, float e, float z = 0.3f) {
  Move m;
  m.x0 = x0;
  m.y0 = y0;
  m.z0 = z;
  m.x1 = x1;
  m.y1 = y1;
  m.z1 = z;
  m.e = e;
  m.f = 1800.0f;
  return m;
}

static void run(const Move &m) {
  T.n = 0;
  T.lists = 0;
  T.e_added = 0;
  ActionList out;
  bool more = P.plan(m, out);
  for (;;) {
    T.lists++;
    TEST_ASSERT_LESS_OR_EQUAL_INT(bk::BK_PLAN_ACTIONS_MAX, out.count);
    for (uint8_t i = 0; i < out.count; i++) {
      TEST_ASSERT_LESS_THAN_INT(24, T.n);
      T.a[T.n++] = out.a[i];
    }
    T.e_added += out.e_added;
    if (!more) break;
    TEST_ASSERT_LESS_THAN_INT(20, T.lists);
    more = P.plan_more(out);
  }
}

static uint8_t count_kind(uint8_t kind) {
  uint8_t c = 0;
  for (uint8_t i = 0; i < T.n; i++) c += T.a[i].kind == kind;
  return c;
}
static float sum_e() {
  float s = 0;
  for (uint8_t i = 0; i < T.n; i++)
    if (T.a[i].kind == Action::LINE) s += T.a[i].e;
  return s;
}
static void assert_line(uint8_t i, float x, float y, float e) {
  TEST_ASSERT_LESS_THAN_INT(T.n, i);
  TEST_ASSERT_EQUAL_INT(Action::LINE, T.a[i].kind);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, x, T.a[i].x);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, y, T.a[i].y);
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, e, T.a[i].e);
}
static void assert_dwell(uint8_t i, uint16_t ms) {
  TEST_ASSERT_LESS_THAN_INT(T.n, i);
  TEST_ASSERT_EQUAL_INT(Action::DWELL, T.a[i].kind);
  TEST_ASSERT_EQUAL_UINT(ms, T.a[i].ms);
}
// The move is unchanged: one line to the host's end with the host's E.
static void assert_identity(const Move &m) {
  TEST_ASSERT_EQUAL_INT(1, T.n);
  TEST_ASSERT_EQUAL_INT(Action::LINE, T.a[0].kind);
  TEST_ASSERT_TRUE(T.a[0].x == m.x1 && T.a[0].y == m.y1 && T.a[0].z == m.z1 && T.a[0].e == m.e);
  TEST_ASSERT_TRUE(T.e_added == 0.0f);
}

// ---- eq. 1 -----------------------------------------------------------------------

static void test_eq1_split_on_axis(void) {
  add_point(2.5f, 0);
  load();
  run(mv(0, 0, 10, 0, 0.73f));
  TEST_ASSERT_EQUAL_INT(3, T.n);
  assert_line(0, 2.5f, 0, 0.73f * 0.25f);  // E_at = E_ab |PaPt| / |PaPb|
  assert_dwell(1, 100);
  assert_line(2, 10, 0, 0.73f * 0.75f + 0.1f);
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.1f, T.e_added);
}

static void test_eq1_split_on_diagonal(void) {
  // 3-4-5 triangle: |PaPb| = 10, Pt at 3/10 of the way.
  add_point(10 + 1.8f, 20 + 2.4f);
  load();
  run(mv(10, 20, 16, 28, 2.0f));
  TEST_ASSERT_EQUAL_INT(3, T.n);
  assert_line(0, 11.8f, 22.4f, 0.6f);
  assert_line(2, 16, 28, 1.4f + 0.1f);
}

static void test_point_projected_onto_move(void) {
  // A point 0.15 mm beside the path: the piece ends on the host's segment,
  // never at the point itself, so the wall keeps its shape.
  add_point(4, 0.15f);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(3, T.n);
  assert_line(0, 4, 0, 0.4f);
  TEST_ASSERT_TRUE(T.a[0].y == 0.0f);
}

// ---- several points, bounded lists -----------------------------------------------

static void test_several_points_in_order_from_start(void) {
  add_point(2, 0);
  add_point(8, 0);
  add_point(5, 0);
  load();
  run(mv(10, 0, 0, 0, 1.0f));  // backwards: order is 8, 5, 2
  TEST_ASSERT_EQUAL_INT(7, T.n);
  assert_line(0, 8, 0, 0.2f);
  assert_dwell(1, 100);
  assert_line(2, 5, 0, 0.3f + 0.1f);
  assert_dwell(3, 100);
  assert_line(4, 2, 0, 0.3f + 0.1f);
  assert_dwell(5, 100);
  assert_line(6, 0, 0, 0.2f + 0.1f);
}

static void test_more_points_than_one_list(void) {
  // 10 points on one move: plan() + plan_more() must deliver all of them in
  // order, none dropped, and the E sums must hold across the lists.
  for (uint8_t i = 0; i < 10; i++) add_point(1.0f + (float)((i * 7) % 10) * 1.5f, 0);  // shuffled
  load();
  const float e = 1.2f;
  run(mv(0, 0, 20, 0, e));
  TEST_ASSERT_GREATER_THAN_INT(1, T.lists);
  TEST_ASSERT_EQUAL_INT(10, count_kind(Action::DWELL));
  TEST_ASSERT_EQUAL_INT(11, count_kind(Action::LINE));
  float last_x = 0;
  for (uint8_t i = 0; i < T.n; i++) {
    if (T.a[i].kind != Action::LINE) continue;
    TEST_ASSERT_TRUE(T.a[i].x > last_x);
    last_x = T.a[i].x;
  }
  TEST_ASSERT_TRUE(T.a[T.n - 1].x == 20.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, e + 10 * 0.1f, sum_e());
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 10 * 0.1f, T.e_added);
#if BK_PLAN_STATS  // counted on the host; AVR builds leave the statistics out
  TEST_ASSERT_EQUAL_UINT(10, P.stats().points_fired);
  TEST_ASSERT_EQUAL_UINT(1, P.stats().moves_split);
#endif
}

static void test_sum_of_pieces_and_exact_end(void) {
  add_point(1.3f, 1.3f);
  add_point(3.05f, 3.05f);
  add_point(4.4f, 4.4f);
  load();
  const float e = 0.4321f;
  Move m = mv(0.0137f, 0.0137f, 5.2f, 5.2f, e);
  run(m);
  TEST_ASSERT_EQUAL_INT(3, count_kind(Action::DWELL));
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, e + 3 * 0.1f, sum_e());
  // The last piece ends on the host's own numbers, bit for bit.
  const Action &z = T.a[T.n - 1];
  TEST_ASSERT_TRUE(z.kind == Action::LINE && z.x == m.x1 && z.y == m.y1 && z.z == m.z1);
}

// ---- vertices, minimum piece, once per layer ---------------------------------

static void test_vertex_point_stops_once(void) {
  // Point on the corner shared by two wall moves: one stop, at the corner;
  // its extra goes into the next move's first piece.
  add_point(10, 0);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(2, T.n);
  assert_line(0, 10, 0, 1.0f);
  assert_dwell(1, 100);
  TEST_ASSERT_TRUE(T.e_added == 0.0f);
  run(mv(10, 0, 10, 10, 1.0f));
  TEST_ASSERT_EQUAL_INT(1, T.n);
  assert_line(0, 10, 10, 1.0f + 0.1f);
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.1f, T.e_added);
#if BK_PLAN_STATS
  TEST_ASSERT_EQUAL_UINT(1, P.stats().points_fired);
#endif
}

static void test_point_near_start_stops_before_moving(void) {
  add_point(0.05f, 0);  // 0.05 mm < BK_MIN_PIECE_MM from the start
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(2, T.n);
  assert_dwell(0, 100);
  assert_line(1, 10, 0, 1.1f);
}

static void test_null_move_keeps_owed_extra(void) {
  add_point(9.95f, 0);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  assert_dwell(1, 100);
  run(mv(10, 0, 10, 0, 0.0f));  // "G1 F1200": no motion, no E
  run(mv(10, 0, 10, 10, 1.0f));
  assert_line(0, 10, 10, 1.1f);  // the owed 0.1 mm goes into the next piece
#if BK_PLAN_STATS
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.0f, P.stats().extra_dropped);
#endif
}

static void test_point_near_end_stops_at_end(void) {
  add_point(9.95f, 0);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(2, T.n);
  assert_line(0, 10, 0, 1.0f);  // no 0.05 mm piece
  assert_dwell(1, 100);
  // No extruding move follows (a travel does): the owed extra is dropped and
  // counted, never extruded during the travel.
  run(mv(10, 0, 30, 30, 0.0f));
  TEST_ASSERT_TRUE(T.a[0].e == 0.0f);
  TEST_ASSERT_TRUE(T.e_added == 0.0f);
#if BK_PLAN_STATS
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.1f, P.stats().extra_dropped);
#endif
  // ...nor later: the next wall move gets only its own E.
  run(mv(30, 30, 30, 40, 1.0f));
  assert_line(0, 30, 40, 1.0f);
  TEST_ASSERT_TRUE(T.e_added == 0.0f);
}

static void test_close_points_share_one_stop(void) {
  add_point(5, 0);
  add_point(5.05f, 0);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(3, T.n);
  assert_line(0, 5, 0, 0.5f);
  assert_dwell(1, 200);
  assert_line(2, 10, 0, 0.5f + 0.2f);
}

static void test_once_per_layer(void) {
  add_point(5, 0);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  Move back = mv(10, 0, 0, 0, 1.0f);
  run(back);  // same layer, same point: no second stop
  assert_identity(back);
  load();  // a new layer (here: the same points again) fires again
  run(back);
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
}

// ---- tolerance ----------------------------------------------------------------

static void test_tolerance_edges(void) {
  add_point(5, 0.25f);
  load();
  Move out = mv(0, -0.005f, 10, -0.005f, 1.0f);  // 0.255 mm away: outside 0.25
  run(out);
  assert_identity(out);
  run(mv(0, 0.005f, 10, 0.005f, 1.0f));  // 0.245 mm away: inside
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
}

static void test_tolerance_beyond_move_end(void) {
  add_point(10.2f, 0);  // 0.2 mm past the end: within T of the path's end
  add_point(-0.3f, 0);  // 0.3 mm before the start: not
  load();
  Move m = mv(0, 0, 10, 0, 1.0f);
  run(m);
  assert_identity(m);  // its foot is beyond B: the next move decides
  // A travel from B: the wall ended there, so the point stops at B first.
  run(mv(10, 0, 30, 0, 0));
  TEST_ASSERT_EQUAL_INT(2, T.n);
  assert_dwell(0, 100);
  assert_line(1, 30, 0, 0);
  TEST_ASSERT_TRUE(T.e_added == 0.0f);  // no extra during a travel
#if BK_PLAN_STATS
  TEST_ASSERT_EQUAL_UINT(1, P.stats().points_fired);
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.1f, P.stats().extra_dropped);
#endif
}

// A polygon wall turning by a few degrees (a cylinder's facets): a point whose
// foot is 0.2 mm into the second edge is also within T of the first edge's end.
// It stops at its foot on the second edge, not at the vertex.
static void test_corner_point_stops_at_its_foot(void) {
  add_point(10.2f, 0.05f);  // 0.206 mm from the vertex (10, 0)
  load();
  Move a = mv(0, 0, 10, 0, 1.0f);
  run(a);
  assert_identity(a);
  run(mv(10, 0, 20, 2, 1.0f));
  TEST_ASSERT_EQUAL_INT(3, T.n);
  // the foot of (10.2, 0.05) on the edge: t = (0.2*10 + 0.05*2) / 104
  const float t = (0.2f * 10 + 0.05f * 2) / 104.0f;
  assert_line(0, 10 + 10 * t, 2 * t, 1.0f * t);
  assert_dwell(1, 100);
  assert_line(2, 20, 2, 1.0f * (1 - t) + 0.1f);
#if BK_PLAN_STATS
  TEST_ASSERT_EQUAL_UINT(1, P.stats().points_fired);
#endif
}

// Outside a convex corner the point is beyond both edges' ends: the second
// edge takes it at its start, the vertex, once.
static void test_point_outside_corner_stops_at_vertex(void) {
  add_point(10.15f, -0.15f);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  run(mv(10, 0, 10, 10, 1.0f));
  TEST_ASSERT_EQUAL_INT(2, T.n);
  assert_dwell(0, 100);
  assert_line(1, 10, 10, 1.1f);
  run(mv(10, 10, 0, 10, 1.0f));
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
}

// Spiral vase: z rises with every move, but within the layer's window the
// next edge still takes the point. A move that leaves the layer (its z in
// another window) cannot: the point stops at the vertex before it.
static void test_deferred_point_in_vase_and_at_layer_change(void) {
  add_point(10.2f, 0.05f);
  load();
  run(mv(0, 0, 10, 0, 1.0f, 0.30f));
  run(mv(10, 0, 20, 2, 1.0f, 0.31f));
  TEST_ASSERT_EQUAL_INT(3, T.n);
  assert_dwell(1, 100);
  TEST_ASSERT_TRUE(T.a[0].x > 10.1f);
  setUp();  // a fresh planner with the same point
  add_point(10.2f, 0.05f);
  load();
  run(mv(0, 0, 10, 0, 1.0f, 0.30f));
  run(mv(10, 0, 20, 2, 1.0f, 0.50f));  // 0.2 mm up: beyond half a layer
  TEST_ASSERT_EQUAL_INT(2, T.n);
  assert_dwell(0, 100);
  TEST_ASSERT_TRUE(T.a[1].kind == Action::LINE && T.a[1].x == 20.0f);
}

// "G1 F..." between the edges moves nothing and keeps the deferred point; a
// retraction at B ends the wall: the point stops before it.
static void test_deferred_point_waits_for_motion(void) {
  add_point(10.2f, 0.05f);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  run(mv(10, 0, 10, 0, 0));  // G1 F1200
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  Move r = mv(10, 0, 10, 0, -0.8f);  // retraction
  run(r);
  TEST_ASSERT_EQUAL_INT(2, T.n);
  assert_dwell(0, 100);
  TEST_ASSERT_TRUE(T.a[1].kind == Action::LINE && T.a[1].e == -0.8f);
}

// Something moved the head between the edges (an arc, homing): the next move
// does not start at B. No stop at a place the head has left; the point stays
// unfired for a later move of the layer that passes it.
static void test_deferred_point_not_stopped_elsewhere(void) {
  add_point(10.2f, 0.05f);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  run(mv(30, 0, 40, 0, 0));  // starts at 30: the head is not at B
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  run(mv(10.2f, -5, 10.2f, 5, 1.0f));  // passes through the point
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 10.2f, T.a[0].x);
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 0.05f, T.a[0].y);
}

static void test_tolerance_setting_widens_match(void) {
  add_point(5, 0.25f);
  load();
  bk::GcodeArgs g;
  TEST_ASSERT_TRUE(g.parse("M720 T0.3"));
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  run(mv(0, -0.005f, 10, -0.005f, 1.0f));  // 0.255 mm: inside 0.3
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
}

static void test_geometric_mode_skips_inner_wall(void) {
  // Outer wall at y = 0, inner wall one 0.45 mm line width inward, infill
  // further in: only the outer wall stops.
  for (uint8_t i = 1; i <= 4; i++) add_point(2.0f * i, 0);
  load();
  Move inner = mv(0, 0.45f, 10, 0.45f, 0.5f);
  run(inner);
  assert_identity(inner);
  Move infill = mv(0.5f, 0.9f, 9.5f, 0.9f, 0.5f);
  run(infill);
  assert_identity(infill);
  run(mv(0, 0, 10, 0, 0.5f));
  TEST_ASSERT_EQUAL_INT(4, count_kind(Action::DWELL));
}

// ---- what passes through -------------------------------------------------------

static void test_non_extruding_moves_pass(void) {
  add_point(5, 0);
  load();
  Move m = mv(0, 0, 10, 0, 0.0f);  // travel
  run(m);
  assert_identity(m);
  m = mv(0, 0, 10, 0, -0.8f);  // retraction with a move
  run(m);
  assert_identity(m);
  m = mv(5, 0, 5, 0, 0.8f);  // E-only (unretract) on the point
  run(m);
  assert_identity(m);
  m = mv(5, 0, 5, 0, 0.0f);  // Z-only
  m.z1 = 0.6f;
  run(m);
  assert_identity(m);
#if BK_PLAN_STATS
  TEST_ASSERT_EQUAL_UINT(0, P.stats().points_fired);
#endif
  run(mv(0, 0, 10, 0, 1.0f));  // the point is still there for the wall
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
}

static void test_mode_off_is_identity(void) {
  add_point(5, 0);
  load();
  bk::GcodeArgs g;
  g.parse("M720 S0");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  Move m = mv(0, 0, 10, 0, 1.0f);
  run(m);
  assert_identity(m);
  g.parse("M722 S1");
  P.m722(g, reply, sizeof reply);
  run(m);
  assert_identity(m);
}

static void test_marker_gating(void) {
  add_point(2, 0);
  add_point(5, 0);
  add_point(8, 0);
  load();
  bk::GcodeArgs g;
  g.parse("M720 S1");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  Move a = mv(0, 0, 3, 0, 0.3f);
  run(a);  // before M722 S1: not outer wall
  assert_identity(a);
  g.parse("M722 S1");
  TEST_ASSERT_TRUE(P.m722(g, reply, sizeof reply));
  TEST_ASSERT_TRUE(P.in_outer_wall());
  run(mv(3, 0, 6, 0, 0.3f));
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  g.parse("M722 S0");
  TEST_ASSERT_TRUE(P.m722(g, reply, sizeof reply));
  Move c = mv(6, 0, 10, 0, 0.4f);
  run(c);
  assert_identity(c);
  g.parse("M722 S1");
  P.m722(g, reply, sizeof reply);
  run(mv(0, 0, 10, 0, 1.0f));  // the two skipped points are still unfired
  TEST_ASSERT_EQUAL_INT(2, count_kind(Action::DWELL));
}

static void test_no_layer_at_move_z(void) {
  add_point(5, 0);
  load();  // z 0.30, half layer 0.15
  Move m = mv(0, 0, 10, 0, 1.0f, 0.46f);
  run(m);
  assert_identity(m);
  run(mv(0, 0, 10, 0, 1.0f, 0.45f));  // edge of the window: matches
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
}

// ---- weights ---------------------------------------------------------------------

static void test_weights_scale_dwell(void) {
  add_point(2, 0, 255);
  add_point(4, 0, 128);
  add_point(6, 0, 0);
  add_point(8, 0, 51);
  load();
  bk::GcodeArgs g;
  g.parse("M720 P200");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  run(mv(0, 0, 10, 0, 1.0f));
  TEST_ASSERT_EQUAL_INT(9, T.n);
  assert_dwell(1, 200);
  assert_dwell(3, 100);  // 200 * 128 / 255 = 100.4
  assert_dwell(5, 0);    // weight 0 still stops (0 ms), like the paper's G4 P0
  assert_dwell(7, 40);
}

// ---- E accounting with the host model -------------------------------------------

// Feeds one G-code line through MoveState + planner as the adapter would.
static bk::MoveState S;
static float machine_e;  // what the extruder was really driven to
static float run_line(const char *line) {
  bk::GcodeArgs g;
  TEST_ASSERT_TRUE(g.parse(line));
  if (g.code_letter() == 'M') {  // M82 / M83
    S.set_e_absolute(g.code() == 82);
    return 0;
  }
  bk::AxisWords w;
  TEST_ASSERT_EQUAL_INT(0, bk::MoveState::words_from(g, w));
  if (g.code() == 92) {
    S.set_position(w);
    machine_e = S.machine_e();
    return 0;
  }
  run(S.line(w));
  for (uint8_t i = 0; i < T.n; i++)
    if (T.a[i].kind == Action::LINE) machine_e += T.a[i].e;
  S.add_e_offset(T.e_added);
  return T.e_added;
}

static void test_absolute_e_host_never_disturbed(void) {
  add_point(5, 0);
  add_point(10, 5);
  load();
  S.reset();
  machine_e = 0;
  run_line("G1 X0 Y0 Z0.3 F1800");
  run_line("G1 X10 Y0 E1.0");
  run_line("G1 X10 Y10 E2.0");
  TEST_ASSERT_TRUE(S.e() == 2.0f);  // the host's number, exactly
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 2.2f, machine_e);
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 0.2f, S.e_offset());
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, machine_e, S.machine_e());
  TEST_ASSERT_TRUE(S.x() == 10.0f && S.y() == 10.0f && S.z() == 0.3f);
  // G92 in between: host E restarts at 0, the offset is folded in.
  run_line("G92 E0");
  TEST_ASSERT_TRUE(S.e() == 0.0f && S.e_offset() == 0.0f);
  run_line("G1 X0 Y10 E1.0");
  TEST_ASSERT_TRUE(S.e() == 1.0f);
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 1.0f, sum_e());  // no point on this edge
}

static void test_relative_e_host_never_disturbed(void) {
  add_point(5, 0);
  add_point(10, 5);
  load();
  S.reset();
  machine_e = 0;
  run_line("M83");
  run_line("G1 X0 Y0 Z0.3 F1800");
  run_line("G1 X10 Y0 E1.0");
  TEST_ASSERT_FLOAT_WITHIN(1e-6f, 1.1f, sum_e());  // the extra went out...
  run_line("G1 X10 Y10 E1.0");
  TEST_ASSERT_TRUE(S.e() == 2.0f);  // ...but the host still counts 1.0 + 1.0
  run_line("G1 E-0.8");             // retraction
  TEST_ASSERT_TRUE(T.n == 1 && T.a[0].e == -0.8f);
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.2f, S.e());
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.4f, machine_e);  // 1.1 + 1.1 - 0.8
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, machine_e, S.machine_e());
  run_line("G92 E0");
  run_line("G1 E0.8");
  TEST_ASSERT_TRUE(S.e() == 0.8f);
  TEST_ASSERT_TRUE(S.machine_e() == 0.8f);
}

// ---- spiral vase through the store's layer window ----------------------------------

// A tiny encoder for the compact map (the test's own, from the format spec).
static uint8_t img[160];
static uint16_t img_n;
static void put_varint(uint32_t v) { img_n += bk::varint_write(img + img_n, v); }
static void put_record(uint16_t z, const int16_t *xy, uint8_t n) {
  uint16_t start = img_n;
  img[img_n++] = (uint8_t)(z & 0xFF);
  img[img_n++] = (uint8_t)(z >> 8);
  uint8_t body[64];
  uint8_t bl = 0;
  int16_t px = 0, py = 0;
  for (uint8_t i = 0; i < n; i++) {
    bl += bk::varint_write(body + bl, bk::zigzag_encode(xy[2 * i] - px));
    bl += bk::varint_write(body + bl, bk::zigzag_encode(xy[2 * i + 1] - py));
    px = xy[2 * i];
    py = xy[2 * i + 1];
  }
  put_varint(n);
  put_varint(bl);
  memcpy(img + img_n, body, bl);
  img_n += bl;
  img[img_n] = bk::crc8(img + start, (uint16_t)(img_n - start));
  img_n++;
}
static void put_header() {
  const uint8_t h[7] = {'B', 'K', 'M', 1, 0, 50, 30};
  memcpy(img, h, 7);
  img[7] = bk::crc8(img, 7);
  img_n = 8;
}

static bk::MapStore store;

static void test_vase_mode_layer_window(void) {
  // Layers at z 0.30, 0.60, 0.90, each with one point on a different side of
  // a 20 mm square.
  put_header();
  const int16_t l1[2] = {200, 0}, l2[2] = {400, 200}, l3[2] = {200, 400};
  put_record(30, l1, 1);
  put_record(60, l2, 1);
  put_record(90, l3, 1);
  TEST_ASSERT_EQUAL_INT(bk::MAP_OK, store.load(img, img_n));
  P.attach(&store);
  // Spiral: z climbs 0.3 mm per lap, 1 mm per move (20 moves a lap).
  float x = 0, y = 0, z = 0.22f;
  uint8_t dwells = 0;
  uint16_t at_z[3] = {0, 0, 0};
  for (uint8_t k = 0; k < 60; k++) {
    uint8_t side = (uint8_t)((k / 5) % 4);
    float nx = x + (side == 0 ? 4.0f : side == 2 ? -4.0f : 0);
    float ny = y + (side == 1 ? 4.0f : side == 3 ? -4.0f : 0);
    float nz = z + 0.015f;
    Move m = mv(x, y, nx, ny, 0.2f, nz);
    m.z0 = z;
    run(m);
    for (uint8_t i = 0; i < T.n; i++)
      if (T.a[i].kind == Action::DWELL) {
        TEST_ASSERT_LESS_THAN_INT(3, dwells);
        at_z[dwells++] = (uint16_t)(nz * 100.0f + 0.5f);
      }
    x = nx;
    y = ny;
    z = nz;
  }
  TEST_ASSERT_EQUAL_INT(3, dwells);  // one per layer, each once
  TEST_ASSERT_LESS_OR_EQUAL_INT(15, at_z[0] > 30 ? at_z[0] - 30 : 30 - at_z[0]);
  TEST_ASSERT_LESS_OR_EQUAL_INT(15, at_z[1] > 60 ? at_z[1] - 60 : 60 - at_z[1]);
  TEST_ASSERT_LESS_OR_EQUAL_INT(15, at_z[2] > 90 ? at_z[2] - 90 : 90 - at_z[2]);
  // Consumed layers were released from the store as printing moved up.
  TEST_ASSERT_EQUAL_INT(1, store.layer_count());
  TEST_ASSERT_EQUAL_INT(90, store.first_z());
#if BK_PLAN_STATS
  TEST_ASSERT_EQUAL_UINT(3, P.stats().layers_loaded);
#endif
}

static void test_store_layer_change_resets_fired(void) {
  put_header();
  const int16_t pt[2] = {100, 0};
  put_record(30, pt, 1);
  put_record(60, pt, 1);
  TEST_ASSERT_EQUAL_INT(bk::MAP_OK, store.load(img, img_n));
  P.attach(&store);
  run(mv(0, 0, 10, 0, 1.0f, 0.3f));
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  run(mv(10, 0, 0, 0, 1.0f, 0.3f));
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  run(mv(0, 0, 10, 0, 1.0f, 1.2f));  // no layer there: unchanged
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  run(mv(10, 0, 0, 0, 1.0f, 0.3f));  // back at 0.30: still fired, no repeat
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  run(mv(0, 0, 10, 0, 1.0f, 0.6f));  // next layer: same XY fires again
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  store.clear();
  P.map_changed();
  Move m = mv(10, 0, 0, 0, 1.0f, 0.6f);
  run(m);
  assert_identity(m);
}

static void test_close_layers_hand_over_to_the_nearer(void) {
  // Adaptive layer heights: records 0.07 mm apart with a 0.30 mm header
  // height. At z 0.37 the layer at 0.30 is still within its window, but 0.37
  // is nearer and must be used (its point would otherwise never fire, and be
  // released when printing reaches 0.44).
  put_header();
  const int16_t a[2] = {100, 0}, b[2] = {100, 0}, c[2] = {100, 0};
  put_record(30, a, 1);
  put_record(37, b, 1);
  put_record(44, c, 1);
  TEST_ASSERT_EQUAL_INT(bk::MAP_OK, store.load(img, img_n));
  P.attach(&store);
  run(mv(0, 0, 10, 0, 1.0f, 0.30f));
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  run(mv(0, 0, 10, 0, 1.0f, 0.37f));
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  run(mv(0, 0, 10, 0, 1.0f, 0.44f));
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
#if BK_PLAN_STATS
  TEST_ASSERT_EQUAL_UINT(3, P.stats().layers_loaded);
#endif
  store.clear();
  P.map_changed();
}

static void test_layer_appended_after_a_miss_is_found(void) {
  // A move at z 0.60 before the layer 0.60 arrives (a slow sender) caches
  // "no layer here"; the append must end that, or the layer never fires.
  put_header();
  const int16_t pt[2] = {100, 0};
  put_record(30, pt, 1);
  TEST_ASSERT_EQUAL_INT(bk::MAP_OK, store.load(img, img_n));
  P.attach(&store);
  run(mv(0, 0, 10, 0, 1.0f, 0.6f));
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  const uint16_t from = img_n;
  put_record(60, pt, 1);
  TEST_ASSERT_EQUAL_INT(bk::MAP_OK, store.append(img + from, (uint16_t)(img_n - from)));
  run(mv(10, 0, 0, 0, 1.0f, 0.6f));
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));
  // And an append while a layer is loaded keeps that layer's fired marks.
  run(mv(0, 0, 10, 0, 1.0f, 0.6f));
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  const uint16_t from2 = img_n;
  put_record(90, pt, 1);
  TEST_ASSERT_EQUAL_INT(bk::MAP_OK, store.append(img + from2, (uint16_t)(img_n - from2)));
  run(mv(10, 0, 0, 0, 1.0f, 0.6f));
  TEST_ASSERT_EQUAL_INT(0, count_kind(Action::DWELL));
  store.clear();
  P.map_changed();
}

static void test_merged_stop_respects_the_limits(void) {
  // Ten points within the minimum piece share one stop: with P2000 E1.0 per
  // point, that stop still dwells at most 2000 ms and adds at most 1.0 mm.
  bk::GcodeArgs g;
  g.parse("M720 S2 P2000 E1.0");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  for (uint8_t i = 0; i < 10; i++) add_point(5.0f + 0.005f * i, 0);
  load();
  run(mv(0, 0, 10, 0, 1.0f));
  uint32_t ms = 0;
  float e = 0;
  for (uint8_t i = 0; i < T.n; i++) {
    if (T.a[i].kind == Action::DWELL) ms += T.a[i].ms;
    else e += T.a[i].e;
  }
  TEST_ASSERT_EQUAL_UINT32(2000, ms);
  TEST_ASSERT_EQUAL_INT(1, count_kind(Action::DWELL));  // one stop: one dwell, across lists too
  TEST_ASSERT_FLOAT_WITHIN(1e-5f, 1.0f + 1.0f, e);  // the host's 1.0 + one stop's 1.0
#if BK_PLAN_STATS  // counted on the host; AVR builds leave the statistics out
  TEST_ASSERT_FLOAT_WITHIN(1e-4f, 9.0f, P.stats().extra_dropped);
  TEST_ASSERT_EQUAL_UINT(10, P.stats().points_fired);
#endif
}

// ---- matching against a brute-force reference ---------------------------------

static uint32_t rng = 12345;
static int32_t rnd(int32_t lo, int32_t hi) {  // inclusive, deterministic LCG
  rng = rng * 1103515245u + 12345u;
  return lo + (int32_t)((rng >> 8) % (uint32_t)(hi - lo + 1));
}

static void test_matching_agrees_with_reference(void) {
  // Random moves (diagonal, negative, long and short, every quantum from 1 um
  // - where long moves take the wide path - to 255 um) and random points near
  // them: the planner's integer prefilter must never reject a point that the
  // plain float distance test accepts, nor accept one it rejects.
  static const uint8_t quanta[4] = {1, 10, 50, 255};
  static const float tols[4] = {0.1f, 0.25f, 0.37f, 0.5f};
  uint16_t hits = 0, misses = 0;
  for (uint16_t k = 0; k < 400; k++) {
    P.reset();
    bk::GcodeArgs g;
    g.parse("M720 S2");
    P.m720(g, reply, sizeof reply);
    const uint8_t qu = quanta[k & 3];
    const float tol = tols[(k >> 2) & 3];
    char cmd[20] = "M720 T0.";
    uint16_t tm = (uint16_t)(tol * 1000.0f + 0.5f);
    cmd[8] = (char)('0' + tm / 100);
    cmd[9] = (char)('0' + tm / 10 % 10);
    cmd[10] = (char)('0' + tm % 10);
    cmd[11] = 0;
    g.parse(cmd);
    TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
    const float span = qu == 1 ? 30.0f : 150.0f;  // stay inside int16 quanta
    const float x0 = (float)rnd(-1000, 1000) * span / 1000.0f, y0 = (float)rnd(-1000, 1000) * span / 1000.0f;
    const float x1 = (k % 5 == 0) ? x0 + (float)rnd(-300, 300) / 1000.0f : (float)rnd(-1000, 1000) * span / 1000.0f;
    const float y1 = (k % 5 == 0) ? y0 + (float)rnd(-300, 300) / 1000.0f : (float)rnd(-1000, 1000) * span / 1000.0f;
    // A point at a random place along the move (or a little beyond its ends),
    // pushed sideways by up to 2 tolerances.
    const float s = (float)rnd(-100, 1100) / 1000.0f;
    const float dx = x1 - x0, dy = y1 - y0;
    const float len = sqrtf(dx * dx + dy * dy);
    if (len < 1e-3f) continue;
    const float side = (float)rnd(-2000, 2000) / 1000.0f * tol;
    const float px = x0 + s * dx - dy / len * side, py = y0 + s * dy + dx / len * side;
    const float qmm = (float)qu * 0.001f;
    L.count = 0;
    L.z_cmm = 30;
    bk::MapPoint &p = L.pts[L.count++];
    p.x = (int16_t)lroundf(px / qmm);
    p.y = (int16_t)lroundf(py / qmm);
    p.w = 255;
    P.load_layer(L, qu, 30);
    // Reference: distance from the grid point to the segment, plain floats.
    const float ux = (float)p.x * qmm - x0, uy = (float)p.y * qmm - y0;
    float t = (ux * dx + uy * dy) / (dx * dx + dy * dy);
    if (t < 0) t = 0;
    const bool beyond = t > 1;  // foot beyond the end: left to the next move
    if (fabsf(t - 1) < 1e-5f) continue;  // too close to call
    if (beyond) t = 1;
    const float ex = ux - t * dx, ey = uy - t * dy;
    const float d = sqrtf(ex * ex + ey * ey);
    if (fabsf(d - tol) < 1e-4f * (1.0f + tol)) continue;  // too close to call
    run(mv(x0, y0, x1, y1, 1.0f));
    bool fired = count_kind(Action::DWELL) == 1;
    if (d < tol && beyond) {
      TEST_ASSERT_FALSE_MESSAGE(fired, "point beyond the end fired on this move");
      run(mv(x1, y1, x1, y1, -0.5f));  // a retraction at the end: it stops now
      fired = count_kind(Action::DWELL) == 1 && T.a[0].kind == Action::DWELL;
    }
    if (d < tol) {
      TEST_ASSERT_TRUE_MESSAGE(fired, "reference hit missed");
      hits++;
    } else {
      TEST_ASSERT_FALSE_MESSAGE(fired, "reference miss fired");
      misses++;
    }
  }
  TEST_ASSERT_GREATER_THAN_INT(100, hits);
  TEST_ASSERT_GREATER_THAN_INT(100, misses);
}

// ---- M720 / M722 -----------------------------------------------------------------

static void test_m720_report_and_set(void) {
  bk::GcodeArgs g;
  g.parse("M720");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("echo:  M720 S2 P100 E0.100 T0.250", reply);
  g.parse("M720 S1 P250 E0.05 T0.3");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("", reply);
  g.parse("M720");
  P.m720(g, reply, sizeof reply);
  TEST_ASSERT_EQUAL_STRING("echo:  M720 S1 P250 E0.050 T0.300", reply);
  g.parse("M720 P2000 E1.0 T2 S0");  // the hard limits themselves are allowed
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  g.parse("M720 P0 E0 T0.01");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  g.parse("M720");
  P.m720(g, reply, sizeof reply);
  TEST_ASSERT_EQUAL_STRING("echo:  M720 S0 P0 E0.000 T0.010", reply);
}

static void test_m720_report_is_a_command(void) {
  // M503 prints the report line as a command (for replay, without "echo:"):
  // sent back, it gives the same settings.
  bk::GcodeArgs g;
  g.parse("M720 S1 P1999 E0.123 T1.25");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  g.parse("M720");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("echo:  M720 S1 P1999 E0.123 T1.250", reply);
  char line[BK_PLAN_REPLY_MAX];
  strcpy(line, reply + 7);               // "M720 S1 P1999 E0.123 T1.250"
  memmove(line + 4, line + 7, strlen(line + 7) + 1);  // "M720 P1999 E0.123 T1.250"
  TEST_ASSERT_EQUAL_STRING("M720 P1999 E0.123 T1.250", line);
  P.reset();
  TEST_ASSERT_TRUE(g.parse(line));
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("", reply);
  TEST_ASSERT_EQUAL_INT(1999, P.dwell_ms());
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.123f, P.extra_e());
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 1.25f, P.tolerance());
  TEST_ASSERT_EQUAL_INT(0, P.mode());  // without its S word the mode stays as it was
}

// M501: stored values come back through the same checks as M720's words; a
// set with one value out of range is refused whole with an Error: line.
static void test_m720_restore_checks_each_value(void) {
  bk::GcodeArgs g;
  g.parse("M720 S2");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  bk::ReplyText r(reply, sizeof reply);
  TEST_ASSERT_TRUE(P.restore(250.0f, 0.2f, 0.3f, r));
  TEST_ASSERT_TRUE(r.empty());
  TEST_ASSERT_EQUAL_INT(250, P.dwell_ms());
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.2f, P.extra_e());
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.3f, P.tolerance());
  TEST_ASSERT_EQUAL_INT(2, P.mode());  // the mode is not a stored setting
  const struct { float p, e, t; const char *error; } bad[] = {
      {2500.0f, 0.2f, 0.3f, "Error:M720 P2500.000 not in [0.000..2000.000]"},
      {100.5f, 0.2f, 0.3f, "Error:M720 P100.500 not a whole number"},
      {100.0f, 1.5f, 0.3f, "Error:M720 E1.500 not in [0.000..1.000]"},
      {100.0f, 0.1f, 0.0f, "Error:M720 T0.000 not in [0.010..2.000]"},
  };
  for (uint8_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    bk::ReplyText e(reply, sizeof reply);
    TEST_ASSERT_FALSE(P.restore(bad[i].p, bad[i].e, bad[i].t, e));
    TEST_ASSERT_EQUAL_STRING(bad[i].error, reply);
    TEST_ASSERT_EQUAL_INT(250, P.dwell_ms());  // nothing changed
    TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.2f, P.extra_e());
    TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.3f, P.tolerance());
  }
}

// Each bad line gives one Error: line and leaves S1 P250 E0.05 T0.3 in force.
static void expect_m720_error(const char *line, const char *text) {
  bk::GcodeArgs g;
  TEST_ASSERT_TRUE(g.parse(line));
  TEST_ASSERT_FALSE(P.m720(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING(text, reply);
  TEST_ASSERT_EQUAL_INT(1, P.mode());
  TEST_ASSERT_EQUAL_INT(250, P.dwell_ms());
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.05f, P.extra_e());
  TEST_ASSERT_FLOAT_WITHIN(1e-7f, 0.3f, P.tolerance());
}

static void test_m720_errors_leave_settings(void) {
  bk::GcodeArgs g;
  g.parse("M720 S1 P250 E0.05 T0.3");
  TEST_ASSERT_TRUE(P.m720(g, reply, sizeof reply));
  expect_m720_error("M720 S2 P2500", "Error:M720 P2500.000 not in [0.000..2000.000]");
  expect_m720_error("M720 P100 E1.5", "Error:M720 E1.500 not in [0.000..1.000]");
  expect_m720_error("M720 E-0.1", "Error:M720 E-0.100 not in [0.000..1.000]");
  expect_m720_error("M720 T0.005 S0", "Error:M720 T0.005 not in [0.010..2.000]");
  expect_m720_error("M720 T2.5", "Error:M720 T2.500 not in [0.010..2.000]");
  expect_m720_error("M720 S3", "Error:M720 S3.000 not in [0.000..2.000]");
  expect_m720_error("M720 S-1", "Error:M720 S-1.000 not in [0.000..2.000]");
  expect_m720_error("M720 S1.5", "Error:M720 S1.500 not a whole number");
  expect_m720_error("M720 P1.5", "Error:M720 P1.500 not a whole number");
  expect_m720_error("M720 P", "Error:M720 P bad number");
  expect_m720_error("M720 S0 Q1", "Error:M720 unknown parameter Q");
  expect_m720_error("M720 E0.2x", "Error:M720 E bad number");
  expect_m720_error("M720 P100 P3000", "Error:M720 duplicate parameter P");
  // all or nothing: a good S before a bad T changes nothing
  expect_m720_error("M720 S0 P0 T9", "Error:M720 T9.000 not in [0.010..2.000]");
  // a number that would wrap to 0 past 2^32 is refused, not taken as P0
  expect_m720_error("M720 P4294967296", "Error:M720 P bad number");
  // a whole value written with decimals is that value
  bk::GcodeArgs g2;
  g2.parse("M720 P2000.0 S1");
  TEST_ASSERT_TRUE(P.m720(g2, reply, sizeof reply));
  TEST_ASSERT_EQUAL_INT(2000, P.dwell_ms());
}

static void test_m722_errors(void) {
  bk::GcodeArgs g;
  g.parse("M722 S1");
  TEST_ASSERT_TRUE(P.m722(g, reply, sizeof reply));
  g.parse("M722 S2");
  TEST_ASSERT_FALSE(P.m722(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:M722 needs S0 or S1", reply);
  TEST_ASSERT_TRUE(P.in_outer_wall());
  g.parse("M722");
  TEST_ASSERT_FALSE(P.m722(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:M722 needs S0 or S1", reply);
  g.parse("M722 S0 X1");
  TEST_ASSERT_FALSE(P.m722(g, reply, sizeof reply));
  TEST_ASSERT_EQUAL_STRING("Error:M722 unknown parameter X", reply);
  TEST_ASSERT_TRUE(P.in_outer_wall());
}

static void test_reply_never_overflows(void) {
  bk::GcodeArgs g;
  g.parse("M720 S3");
  char small[12];
  memset(small, 'Z', sizeof small);
  TEST_ASSERT_FALSE(P.m720(g, small, 10));
  // cut to the room given, NUL kept, and the cut shown by "..."
  TEST_ASSERT_EQUAL_STRING("Error:...", small);
  TEST_ASSERT_EQUAL_INT('Z', small[10]);
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_eq1_split_on_axis);
  RUN_TEST(test_eq1_split_on_diagonal);
  RUN_TEST(test_point_projected_onto_move);
  RUN_TEST(test_several_points_in_order_from_start);
  RUN_TEST(test_more_points_than_one_list);
  RUN_TEST(test_sum_of_pieces_and_exact_end);
  RUN_TEST(test_vertex_point_stops_once);
  RUN_TEST(test_point_near_start_stops_before_moving);
  RUN_TEST(test_point_near_end_stops_at_end);
  RUN_TEST(test_null_move_keeps_owed_extra);
  RUN_TEST(test_close_layers_hand_over_to_the_nearer);
  RUN_TEST(test_layer_appended_after_a_miss_is_found);
  RUN_TEST(test_merged_stop_respects_the_limits);
  RUN_TEST(test_close_points_share_one_stop);
  RUN_TEST(test_once_per_layer);
  RUN_TEST(test_tolerance_edges);
  RUN_TEST(test_tolerance_beyond_move_end);
  RUN_TEST(test_corner_point_stops_at_its_foot);
  RUN_TEST(test_point_outside_corner_stops_at_vertex);
  RUN_TEST(test_deferred_point_in_vase_and_at_layer_change);
  RUN_TEST(test_deferred_point_waits_for_motion);
  RUN_TEST(test_deferred_point_not_stopped_elsewhere);
  RUN_TEST(test_tolerance_setting_widens_match);
  RUN_TEST(test_geometric_mode_skips_inner_wall);
  RUN_TEST(test_matching_agrees_with_reference);
  RUN_TEST(test_non_extruding_moves_pass);
  RUN_TEST(test_mode_off_is_identity);
  RUN_TEST(test_marker_gating);
  RUN_TEST(test_no_layer_at_move_z);
  RUN_TEST(test_weights_scale_dwell);
  RUN_TEST(test_absolute_e_host_never_disturbed);
  RUN_TEST(test_relative_e_host_never_disturbed);
  RUN_TEST(test_vase_mode_layer_window);
  RUN_TEST(test_store_layer_change_resets_fired);
  RUN_TEST(test_m720_report_and_set);
  RUN_TEST(test_m720_report_is_a_command);
  RUN_TEST(test_m720_restore_checks_each_value);
  RUN_TEST(test_m720_errors_leave_settings);
  RUN_TEST(test_m722_errors);
  RUN_TEST(test_reply_never_overflows);
  return UNITY_END();
}
