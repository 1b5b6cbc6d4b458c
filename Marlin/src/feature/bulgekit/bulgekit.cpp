/**
 * bulgekit for Marlin: adapter (see bulgekit.h).
 */
#include "../../inc/MarlinConfig.h"
#include "bulgekit.h"

#if HAS_BULGEKIT

#include "../../module/motion.h"
#include "../../module/planner.h"
#include "../../module/stepper.h"
#include "../../gcode/parser.h"

// Definition order matters: the members are built before `bulgekit`, whose
// constructor wires them together.
#if ENABLED(BULGE_MAP)
  bk::MapStore BulgeKit::store;
  bk::MapUpload BulgeKit::upload(BulgeKit::store);
  bk::BulgePlanner BulgeKit::bulge;
  bk::ActionList BulgeKit::actions;
  float BulgeKit::e_offset_total;
#endif
#if ENABLED(WIDTH_BY_FEEDRATE)
  bk::WidthMode BulgeKit::width;
#endif

uint8_t BulgeKit::arc_told;

BulgeKit bulgekit;

BulgeKit::BulgeKit() {
  TERN_(BULGE_MAP, bulge.attach(&store));
}

// The core's replies, printed by Marlin's serial port and its number printing
// (core/reply_text.h; ReplyText::fixed is the core's, shared with the tests).
namespace bk {
  ReplyText::ReplyText(char *, uint16_t) : b_(nullptr), size_(0), n_(0), cut_(false) {}
  void ReplyText::c(const char ch) { n_++; SERIAL_CHAR(ch); }
  void ReplyText::p(const char *flash) { n_++; serial_print_P(flash); }
  void ReplyText::raw(const char *ram, uint8_t n) { while (n--) c(*ram++); }
  void ReplyText::u(const uint32_t v) { n_++; SERIAL_ECHO(v); }
}  // fixed() is the core's (reply_text.cpp), built on these


void BulgeKit::arc_notice() {
  // A travel or retraction arc is not something either mode would change
  if (!(destination.e > current_position.e)) return;
  #if ENABLED(BULGE_MAP)
    const bk::BulgeMode m = bulge.mode();
    if (!(arc_told & ARC_BULGE)
        && (m == bk::BULGE_GEOMETRIC || (m == bk::BULGE_MARKED && bulge.in_outer_wall()))) {
      arc_told |= ARC_BULGE;
      SERIAL_ECHO_MSG("bulgekit: G2/G3 arcs not split at bulge points (turn off arc fitting)");
    }
  #endif
  #if ENABLED(WIDTH_BY_FEEDRATE)
    if (!(arc_told & ARC_WIDTH) && width.active()) {
      arc_told |= ARC_WIDTH;
      SERIAL_ECHO_MSG("bulgekit: G2/G3 arcs not retimed by M723 (turn off arc fitting)");
    }
  #endif
}

void BulgeKit::settings_save(const uint16_t code, settings_t &s) {
  memset(&s, 0, sizeof(s));
  #if ENABLED(BULGE_MAP)
    if (code == 720) {
      s.v[0] = bulge.dwell_ms();
      s.v[1] = bulge.extra_e();
      s.v[2] = bulge.tolerance();
    }
  #endif
  #if ENABLED(WIDTH_BY_FEEDRATE)
    if (code == 723) {
      s.kind = width.target_kind();
      s.v[0] = width.target();
      s.v[1] = width.filament_dia();
      s.v[2] = width.layer_height();
      s.v[3] = width.min_speed();
      s.v[4] = width.max_speed();
    }
  #endif
}

void BulgeKit::settings_load(const uint16_t code, const settings_t &s) {
  bk::ReplyText r(nullptr, 0);
  bool ok = true;
  #if ENABLED(BULGE_MAP)
    if (code == 720) ok = bulge.restore(s.v[0], s.v[1], s.v[2], r);
  #endif
  #if ENABLED(WIDTH_BY_FEEDRATE)
    if (code == 723) ok = width.restore(s.kind, s.v, r);
  #endif
  end_reply(r);
  if (!ok) SERIAL_ECHOLNPGM("Error:stored M", code, " settings refused; defaults kept");
}

void BulgeKit::settings_reset() {
  arc_rearm(ARC_BULGE | ARC_WIDTH);
  #if ENABLED(BULGE_MAP)
    const bool marker = bulge.in_outer_wall();
    bulge.reset();        // mode, P, E, T to the defaults (and the stop statistics)
    bulge.attach(&store);  // reset() detaches; the map itself stays in force
    bulge.set_in_outer_wall(marker);  // a reset inside an outer wall stays inside it
  #endif
  #if ENABLED(WIDTH_BY_FEEDRATE)
    width.reset();
    width.set_feed_percent(feedrate_percentage);
  #endif
}

#if ENABLED(BULGE_MAP)

  /**
   * A stop at a bulge point. Both junctions around it plan to rest: clearing the
   * previous nominal speed makes the next block's maximum entry speed zero (as
   * after homing), and the reverse pass then brings the block before the dwell
   * down to zero as well. A dwell block follows in the queue (also for ms = 0:
   * it is what makes the stop last ms instead of Marlin's start interval); the
   * stepper ISR holds it for ms milliseconds, counted from the last step before
   * the point to the first step after it, with no steps (the steppers stay
   * enabled because the queue is not empty), then takes the next block.
   */
  void Planner::buffer_dwell(const uint16_t ms) {
    previous_nominal_speed = 0;
    previous_speed.reset();

    uint8_t next_buffer_head;
    block_t * const block = get_next_free_block(next_buffer_head);
    block->reset();
    block->flag.apply(BLOCK_BIT_DWELL);
    block->step_event_count = ms;  // a dwell block carries its duration here
    block->position = position;

    // No first-block delivery delay: a dwell that finds the queue empty has no
    // motion to wait for, it may start holding at once.
    block_buffer_head = next_buffer_head;
    stepper.wake_up();
  }

#endif // BULGE_MAP

/**
 * G0/G1. Marlin has already filled `destination` (host coordinates, native
 * frame) and feedrate_mm_s. Three things can make the move ours:
 *  - a W word (width mode): the filament comes from the width, not from E;
 *  - width mode retimes an extruding move;
 *  - the bulge planner splits it at bulge points.
 * Otherwise we return false and Marlin queues the move exactly as stock.
 */
bool BulgeKit::line_to_destination() {
  float de = destination.e - current_position.e;  // host filament, before M221
  bool machine_only_e = false;                     // filament the host's E does not count
  float feed_scaled = MMS_SCALED(feedrate_mm_s);   // what the planner would get, mm/s
  bool retimed = false;

  #if ENABLED(WIDTH_BY_FEEDRATE)
    const float dx = destination.x - current_position.x,
                dy = destination.y - current_position.y;
    if (feedrate_percentage != width.feed_percent()) width.set_feed_percent(feedrate_percentage);

    if (parser.seen('W')) {
      const float w = parser.value_float();
      const bool has_e = parser.seen('E');
      bk::ReplyText err(nullptr, 0);
      float w_de;
      if (!width.width_e_xy(w, has_e, dx, dy, w_de, err)) {
        end_reply(err);  // the move is not executed
        destination = current_position;
        return true;
      }
      de = w_de;
      machine_only_e = true;
    }

    const float v = width.feed_xy(dx, dy, de, feed_scaled);
    if (v != feed_scaled) { feed_scaled = v; retimed = true; }
  #endif

  const xyze_pos_t end = destination;
  const float host_e_end = machine_only_e ? current_position.e : end.e;

  #if ENABLED(BULGE_MAP)
    bk::Move m;
    m.x0 = NATIVE_TO_LOGICAL(current_position.x, X_AXIS);
    m.y0 = NATIVE_TO_LOGICAL(current_position.y, Y_AXIS);
    m.z0 = NATIVE_TO_LOGICAL(current_position.z, Z_AXIS);
    m.x1 = NATIVE_TO_LOGICAL(end.x, X_AXIS);
    m.y1 = NATIVE_TO_LOGICAL(end.y, Y_AXIS);
    m.z1 = NATIVE_TO_LOGICAL(end.z, Z_AXIS);
    m.e = de;  // (m.f is not read by the planner: the pieces keep feedrate_mm_s)
    bool more = bulge.plan(m, actions);
    const bool split = more || actions.count != 1 || actions.a[0].kind != bk::Action::LINE || actions.e_added != 0.0f;
  #else
    constexpr bool split = false;
  #endif

  if (!split && !retimed && !machine_only_e) return false;  // stock path, bit for bit

  // Our move: each piece through prepare_line_to_destination() at one speed.
  const feedRate_t saved_feedrate = feedrate_mm_s;
  if (retimed) feedrate_mm_s = feed_scaled * 100.0f / feedrate_percentage;  // MMS_SCALED undoes this

  float e_run = current_position.e;  // the E the planner is given (host E + extra so far)

  #if ENABLED(BULGE_MAP)
    for (;;) {
      for (uint8_t i = 0; i < actions.count; ++i) {
        const bk::Action &a = actions.a[i];
        if (a.kind == bk::Action::DWELL) { planner.buffer_dwell(a.ms); continue; }
        if (a.x == m.x1 && a.y == m.y1 && a.z == m.z1)
          destination = end;  // the host's own end point, untouched by the frame round trip
        else {
          destination.x = LOGICAL_TO_NATIVE(a.x, X_AXIS);
          destination.y = LOGICAL_TO_NATIVE(a.y, Y_AXIS);
          destination.z = LOGICAL_TO_NATIVE(a.z, Z_AXIS);
        }
        e_run += a.e;
        destination.e = e_run;
        prepare_line_to_destination();
      }
      e_offset_total += actions.e_added;
      if (!more) break;
      more = bulge.plan_more(actions);
    }
  #else
    destination = end;
    e_run += de;
    destination.e = e_run;
    prepare_line_to_destination();
  #endif

  feedrate_mm_s = saved_feedrate;

  // Re-base E: the extra (and W) filament stays extruded, the host's E is what
  // the G-code said. The planner's sync block lies between two moves that keep
  // their junction speed (the planner passes skip sync blocks).
  if (current_position.e != host_e_end) {
    current_position.e = host_e_end;
    planner.set_e_position_mm(host_e_end);
  }
  destination = current_position;
  return true;
}

#endif // HAS_BULGEKIT
