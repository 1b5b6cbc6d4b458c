// libFuzzer target: random but well-formed print streams through the segment
// planner and width mode, with the invariants checked after every move.
//
// The input drives a small print: a bulge map (quantum, layer height, layers of
// points near the origin, weights or not), then a stream of G0/G1 moves
// (absolute and relative, layer changes, retractions, zero-length and very
// short moves, moves aimed through map points and corners), G92, G90/G91,
// M82/M83, marker toggles (M722), mode and setting changes (M720), map
// appends and clears mid-print, and width mode on and off (M723).
//
// After every move:
//   - every LINE piece lies on the host's segment, in order along it, and the
//     last one ends exactly (bit for bit) at the host's end point (a stop
//     there may follow it);
//   - the pieces' E add up to the host's dE plus the extra the list reports;
//   - a move the planner may not split (mode off, marker off in mode 1,
//     travel, retraction, Z or E only) comes back as that one move, after at
//     most the stops deferred from the move before it;
//   - every stop lies within sqrt(T^2 + BK_MIN_PIECE_MM^2) of a map point;
//   - within one layer no point stops twice (stops <= the layer's points);
//   - reached => stopped: after a qualifying move at one z that used a layer,
//     every point of that layer it passes clearly inside the tolerance (0.02
//     mm margin, foot at 10-90 % of a move over 0.5 mm: the ends are where the
//     corner rule and the minimum piece decide) has stopped, on this move or
//     an earlier one of the same layer visit;
//   - width mode: a move it leaves alone keeps its feed bit for bit, a retimed
//     one gets a feed within [L, U].
// The exact place of each stop is the differential check's (against the
// host's RefPlanner, host/tests/bulge/test_e2e_bkcore.py).
// Build with -DFUZZ_DEBUG to print each move, stop and layer count.
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bulge_map.h"
#include "bulge_planner.h"
#include "float_bits.h"
#include "gcode_args.h"
#include "move_state.h"
#include "width_mode.h"

using namespace bk;

#define CHECK(c)                                                    \
  do {                                                              \
    if (!(c)) {                                                     \
      fprintf(stderr, "invariant failed: %s (line %d)\n", #c, __LINE__); \
      abort();                                                      \
    }                                                               \
  } while (0)

// ---- input reader ------------------------------------------------------------------
struct Input {
  const uint8_t *p, *end;
  uint8_t u8() { return p < end ? *p++ : 0; }
  uint16_t u16() { return (uint16_t)(u8() | u8() << 8); }
  bool more() const { return p < end; }
  // a value in [lo, hi]
  int32_t range(int32_t lo, int32_t hi) { return lo + (int32_t)(u16() % (uint32_t)(hi - lo + 1)); }
};

// ---- the map, built here in the format's own units ---------------------------------
struct Pt {
  int16_t x, y;
  uint8_t w;
};
static const uint8_t kMaxLayers = 8, kMaxPts = 24;
struct GenLayer {
  uint16_t z;
  uint8_t n;
  Pt pts[kMaxPts];
};
static GenLayer layers[kMaxLayers];
static uint8_t n_layers, quantum_um, lh_cmm;
static bool weights;

// One layer record: z, n, len, zigzag deltas x0 y0 x1 y1 ..., weights, CRC-8.
static uint16_t encode_record(const GenLayer &l, uint8_t *out) {
  uint8_t body[kMaxPts * 6 + kMaxPts];
  uint16_t b = 0;
  int32_t px = 0, py = 0;  // each coordinate is a step from the point before's
  for (uint8_t i = 0; i < l.n; i++) {
    b = (uint16_t)(b + varint_write(body + b, zigzag_encode((int32_t)l.pts[i].x - px)));
    b = (uint16_t)(b + varint_write(body + b, zigzag_encode((int32_t)l.pts[i].y - py)));
    px = l.pts[i].x;
    py = l.pts[i].y;
  }
  if (weights)
    for (uint8_t i = 0; i < l.n; i++) body[b++] = l.pts[i].w;
  uint16_t k = 0;
  out[k++] = (uint8_t)l.z;
  out[k++] = (uint8_t)(l.z >> 8);
  k = (uint16_t)(k + varint_write(out + k, l.n));
  k = (uint16_t)(k + varint_write(out + k, b));
  memcpy(out + k, body, b);
  k = (uint16_t)(k + b);
  out[k] = crc8(out, k);
  return (uint16_t)(k + 1);
}

static uint16_t encode_header(uint8_t *out) {
  out[0] = 'B', out[1] = 'K', out[2] = 'M', out[3] = MAP_VERSION;
  out[4] = weights ? MAP_FLAG_WEIGHTS : 0;
  out[5] = quantum_um, out[6] = lh_cmm;
  out[7] = crc8(out, 7);
  return MAP_HEADER_BYTES;
}

static uint32_t fired_in_layer;     // points stopped in this visit of the layer in use
static uint16_t layer_z_seen = 0xFFFF;
static uint32_t fired_total, points_sent;  // since the map was loaded
static MapStore store;
static BulgePlanner planner;
static MoveState state;
static WidthMode width;
static ActionList out;
static uint8_t image[BK_MAP_ARENA_BYTES + MAP_HEADER_BYTES];

// ---- invariants -----------------------------------------------------------------------
static float dist_to_segment(float px, float py, const Move &m, float *t_out) {
  const float dx = m.x1 - m.x0, dy = m.y1 - m.y0, l2 = dx * dx + dy * dy;
  float t = l2 > 0 ? ((px - m.x0) * dx + (py - m.y0) * dy) / l2 : 0;
  if (t < 0) t = 0;
  if (t > 1) t = 1;
  if (t_out) *t_out = t;
  const float ex = m.x0 + t * dx - px, ey = m.y0 + t * dy - py;
  return sqrtf(ex * ex + ey * ey);
}

// The nearest map point to (x, y), mm, of any layer within a layer height of
// z or of z2 (a stop at a move's start may take a point of the layer the move
// climbs to).
static float nearest_point(float x, float y, float z, float z2) {
  float best = 1e30f;
  const float q = quantum_um * 0.001f;
  for (uint8_t i = 0; i < n_layers; i++) {
    const float lz = layers[i].z * 0.01f, h = lh_cmm * 0.01f + 1e-3f;
    if (fabsf(lz - z) > h && fabsf(lz - z2) > h) continue;
    for (uint8_t k = 0; k < layers[i].n; k++) {
      const float ex = layers[i].pts[k].x * q - x, ey = layers[i].pts[k].y * q - y;
      const float d = sqrtf(ex * ex + ey * ey);
      if (d < best) best = d;
    }
  }
  return best;
}

static bool same_bits(float a, float b) { return fbits(a) == fbits(b); }


// The planner may split m: its mode and marker allow it, and it extrudes with
// XY motion (the layer aside).
static bool splittable(const Move &m) {
  return (planner.mode() == BULGE_GEOMETRIC || (planner.mode() == BULGE_MARKED && planner.in_outer_wall())) &&
         m.extruding();
}

static void check_move(const Move &m, bool prev_qualified) {
  const bool qualifies = splittable(m);
  const uint32_t fired_before = planner.stats().points_fired;
  const bool had_layer = planner.has_layer();
  const uint16_t z_before = had_layer ? planner.layer().z_cmm : 0xFFFF;
  float e_sum = 0, e_added = 0, t_last = -1;
  float hx = m.x0, hy = m.y0, hz = m.z0;  // where the head is
  uint16_t lines = 0, dwells = 0;
  bool last_is_end = false;
#ifdef FUZZ_DEBUG
  fprintf(stderr, "move %.4f %.4f %.4f -> %.4f %.4f %.4f e %.4f mode %d marker %d layer %d\n", m.x0, m.y0, m.z0, m.x1,
          m.y1, m.z1, m.e, planner.mode(), planner.in_outer_wall(), planner.has_layer() ? planner.layer().z_cmm : -1);
#endif
  bool more = planner.plan(m, out);
  for (uint16_t lists = 0;; lists++) {
    CHECK(lists < 4 * BK_LAYER_POINTS_MAX + 8);  // a move ends
    CHECK(out.count >= 1 && out.count <= BK_PLAN_ACTIONS_MAX);
    e_added += out.e_added;
    for (uint8_t i = 0; i < out.count; i++) {
      const Action &a = out.a[i];
      if (a.kind == Action::DWELL) {
        dwells++;
        CHECK(a.ms <= BK_MAX_DWELL_MS);
        const float tol = planner.tolerance();
#ifdef FUZZ_DEBUG
        fprintf(stderr, "  DWELL at %.4f %.4f %.4f nearest %.4f tol %.3f\n", hx, hy, hz, nearest_point(hx, hy, hz, m.z1),
                tol);
#endif
        CHECK(nearest_point(hx, hy, hz, m.z1) <= sqrtf(tol * tol + BK_MIN_PIECE_MM * BK_MIN_PIECE_MM) + 2e-3f);
        continue;  // (a stop at the move's end may follow its last line)
      }
      CHECK(a.kind == Action::LINE);
      lines++;
      float t;
      CHECK(dist_to_segment(a.x, a.y, m, &t) <= 1e-3f + 1e-5f * (fabsf(m.x1) + fabsf(m.y1)));
      CHECK(t >= t_last - 1e-4f);  // in order along the move
      t_last = t;
      e_sum += a.e;
      hx = a.x, hy = a.y, hz = a.z;
      last_is_end = same_bits(a.x, m.x1) && same_bits(a.y, m.y1) && same_bits(a.z, m.z1);
    }
    if (!more) break;
    more = planner.plan_more(out);
  }
  CHECK(lines >= 1 && last_is_end);  // the last line ends where the host said, exactly
  CHECK(fabsf(e_sum - (m.e + e_added)) <= 1e-4f * (1.0f + fabsf(m.e) + e_added));
  CHECK(e_added >= 0.0f && e_added <= BK_MAX_EXTRA_E_MM * (dwells + 1) + 1e-5f);
  if (!qualifies) {
    // the move itself, after stops deferred from the wall move before it
    CHECK(lines == 1);
    CHECK(dwells == 0 || prev_qualified);
  }
  // No point stops twice: since the map was loaded, no more points stopped
  // than it has had; within one visit of a layer (the move neither left nor
  // changed it), no more than that layer has. (A move that changes the layer
  // may stop points of both: stops deferred from the old one come first.)
  const uint32_t fired = planner.stats().points_fired - fired_before;
  fired_total += fired;
  CHECK(fired_total <= points_sent);
  if (planner.has_layer()) {
    if (planner.layer().z_cmm != layer_z_seen || !had_layer || z_before != planner.layer().z_cmm) {
      layer_z_seen = planner.layer().z_cmm;
      fired_in_layer = 0;
    } else {
      fired_in_layer += fired;
    }
#ifdef FUZZ_DEBUG
    fprintf(stderr, "  layer %d: %u stops in this visit, %d points\n", planner.layer().z_cmm, fired_in_layer,
            planner.layer().count);
#endif
    CHECK(fired_in_layer <= planner.layer().count);
  }
  // Reached => stopped, for a move at the loaded layer's own z (the planner
  // keeps a layer at its own z without asking the store; the layer after the
  // move is then the one it used).
  const float dx = m.x1 - m.x0, dy = m.y1 - m.y0, l2 = dx * dx + dy * dy;
  if (qualifies && same_bits(m.z0, m.z1) && l2 > 0.25f && planner.has_layer() &&
      lroundf(m.z1 * 100.0f) == planner.layer().z_cmm) {
    const MapLayer &l = planner.layer();
    const float q = quantum_um * 0.001f, tol = planner.tolerance();
    for (uint8_t i = 0; i < l.count; i++) {
      const float px = l.pts[i].x * q, py = l.pts[i].y * q;
      float t;  // (clamped to [0, 1], which the middle 80 % never needs)
      if (dist_to_segment(px, py, m, &t) > tol - 0.02f || t <= 0.1f || t >= 0.9f) continue;
#ifdef FUZZ_DEBUG
      if (!planner.fired(i)) fprintf(stderr, "  point %d (%.4f %.4f) reached, not stopped\n", i, px, py);
#endif
      CHECK(planner.fired(i));
    }
  }
}

// ---- the stream ------------------------------------------------------------------------
static void gen_map(Input &in) {
  quantum_um = (uint8_t)(in.u8() & 1 ? 50 : 100);
  lh_cmm = (uint8_t)in.range(10, 40);
  weights = in.u8() & 1;
  n_layers = (uint8_t)in.range(1, kMaxLayers);
  uint16_t z = (uint16_t)in.range(lh_cmm / 2, 2 * lh_cmm);
  for (uint8_t i = 0; i < n_layers; i++) {
    GenLayer &l = layers[i];
    l.z = z;
    l.n = (uint8_t)in.range(1, kMaxPts);
    const int16_t span = (int16_t)(in.u8() & 1 ? 40 : 400);  // quanta: a tight or a wide cluster
    for (uint8_t k = 0; k < l.n; k++) {
      l.pts[k].x = (int16_t)in.range(-span, span);
      l.pts[k].y = (int16_t)in.range(-span, span);
      l.pts[k].w = weights ? in.u8() : MAP_WEIGHT_FULL;
    }
    z = (uint16_t)(z + in.range(1, 2 * lh_cmm));  // closer than a layer height at times
  }
}

// Loads layers [0, upto) as a map; the rest can come as appends.
static void load_map(uint8_t upto) {
  uint16_t k = encode_header(image);
  for (uint8_t i = 0; i < upto; i++) {
    uint8_t rec[2 + 3 + 3 + kMaxPts * 7 + 1];
    const uint16_t n = encode_record(layers[i], rec);
    if (k + n > sizeof image) break;
    memcpy(image + k, rec, n);
    k = (uint16_t)(k + n);
  }
  CHECK(store.load(image, k) == MAP_OK || k - MAP_HEADER_BYTES > BK_MAP_ARENA_BYTES);
  planner.map_changed();
  layer_z_seen = 0xFFFF;  // a new map: its points may stop again
  fired_total = 0;
  points_sent = 0;
  for (uint8_t i = 0; i < upto; i++) points_sent += layers[i].n;
}

static void command(const char *text) {
  GcodeArgs a;
  CHECK(a.parse(text));
  char reply[BK_PLAN_REPLY_MAX];
  if (a.code() == 720) planner.m720(a, reply, sizeof reply);
  if (a.code() == 722) planner.m722(a, reply, sizeof reply);
}

// A target near map point k of layer li, or a corner around it, mm.
static void aim(Input &in, float &x, float &y) {
  const GenLayer &l = layers[in.u8() % n_layers];
  const Pt &p = l.pts[in.u8() % l.n];
  const float q = quantum_um * 0.001f;
  x = p.x * q + (float)in.range(-300, 300) * 0.001f;
  y = p.y * q + (float)in.range(-300, 300) * 0.001f;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (size < 8 || size > 4096) return 0;
  Input in = {data, data + size};
  store.clear();
  planner.reset();
  planner.attach(&store);
  state.reset();
  width.reset();
  layer_z_seen = 0xFFFF;
  gen_map(in);
  uint8_t sent = (uint8_t)in.range(1, n_layers);
  load_map(sent);
  char line[48];
  snprintf(line, sizeof line, "M720 S%d P%d E0.%02d T0.%02d", in.u8() % 3, in.range(0, 300), in.range(0, 30),
           in.range(5, 60));
  command(line);
  float z = layers[0].z * 0.01f;
  bool prev_qualified = false;
  while (in.more()) {
    const uint8_t op = in.u8();
    AxisWords w = {};
    switch (op % 16) {
      case 0: command(in.u8() & 1 ? "M722 S1" : "M722 S0"); break;
      case 1: state.set_absolute(in.u8() & 1); break;
      case 2: state.set_e_absolute(in.u8() & 1); break;
      case 3:  // G92
        w.mask = (uint8_t)(in.u8() & (AxisWords::X | AxisWords::Y | AxisWords::E));
        w.x = (float)in.range(-50, 50), w.y = (float)in.range(-50, 50), w.e = (float)in.range(0, 100) * 0.1f;
        state.set_position(w);
        break;
      case 4:  // layer change (sometimes between records, sometimes a spiral step)
        z = layers[in.u8() % n_layers].z * 0.01f + (float)in.range(-20, 20) * 0.001f;
        w.mask = AxisWords::Z;
        w.z = state.xyz_absolute() ? z : z - state.z();
        goto move;
      case 5:  // append the next layers, or clear and load again
#ifdef FUZZ_DEBUG
        fprintf(stderr, "map op (sent %d of %d)\n", sent, n_layers);
#endif
        if (sent < n_layers && (in.u8() & 3)) {
          uint8_t rec[2 + 3 + 3 + kMaxPts * 7 + 1];
          const uint16_t n = encode_record(layers[sent], rec);
          if (store.append(rec, n) == MAP_OK) points_sent += layers[sent++].n;
        } else {
          store.clear();
          planner.map_changed();
          layer_z_seen = 0xFFFF;
          fired_total = points_sent = 0;
          if (in.u8() & 1) load_map(sent = (uint8_t)in.range(1, n_layers));
        }
        break;
      case 6:
        snprintf(line, sizeof line, "M720 S%d", in.u8() % 3);
        command(line);
        break;
      case 7: {  // width mode on or off
        char reply[WidthMode::REPLY_MIN];
        snprintf(line, sizeof line, "M723 S%d R%d.%d H0.2 L%d U%d", in.u8() & 1, in.range(0, 9), in.range(1, 9),
                 in.range(1, 20), in.range(21, 300));
        width.command(line, reply, sizeof reply);
        break;
      }
      default: {  // G1 moves of several kinds
        const uint8_t kind = in.u8() % 6;
        float x, y;
        if (kind <= 2) aim(in, x, y);  // through or near a point
        else x = (float)in.range(-400, 400) * 0.1f, y = (float)in.range(-400, 400) * 0.1f;
        if (kind == 3) x = state.x(), y = state.y();                       // zero length (E or F only)
        if (kind == 4) x = state.x() + (float)in.range(-50, 50) * 0.001f;  // very short
        w.mask = AxisWords::X | AxisWords::Y | AxisWords::E;
        const bool rel = !state.xyz_absolute();
        w.x = rel ? x - state.x() : x;
        w.y = rel ? y - state.y() : y;
        const float de = kind == 5 ? -(float)in.range(1, 40) * 0.1f : (float)in.range(0, 80) * 0.01f;
        w.e = state.e_absolute() ? state.e() + de : de;
        if (in.u8() & 1) w.mask |= AxisWords::F, w.f = (float)in.range(300, 9000);
        goto move;
      }
    }
    continue;
  move : {
    const Move m = state.line(w);
    // width mode: the feed a move gets
    const float feed = m.f / 60.0f;
    const float dx = m.x1 - m.x0, dy = m.y1 - m.y0;
    const float v = width.feed_xy(dx, dy, m.e, feed);
    if (!width.active() || !m.extruding()) CHECK(same_bits(v, feed));
    else CHECK(v >= width.min_speed() * 0.999f && v <= width.max_speed() * 1.001f);
    check_move(m, prev_qualified);
    // Stops deferred to the next move wait through a move that moves nothing
    // ("G1 F1200"), so only a real move decides what the last one was.
    const bool still = m.x0 == m.x1 && m.y0 == m.y1 && m.z0 == m.z1 && m.e == 0.0f;
    if (!still) prev_qualified = splittable(m);
  }
  }
  return 0;
}
