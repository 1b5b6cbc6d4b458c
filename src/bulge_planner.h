// Outer-wall segment planner: splits extruding moves at the bulge points of
// the current layer (Takahashi & Miyashita, sec. 5.3).
//
// For a move Pa->Pb extruding E_ab and a bulge point Pt on it:
//   Pa->Pt  extrudes E_at = E_ab * |PaPt| / |PaPb|          (eq. 1)
//   dwell   P ms at Pt (times w/255 when the map has weights)
//   Pt->Pb  extrudes its proportional share plus the extra E
// Several points on one move are taken in order from Pa. Pieces always lie on
// the host's own segment (Pt is projected onto it), so XYZ never change; the
// extra filament is reported per ActionList (e_added) and goes into the
// MoveState E offset, so the host's E never changes either.
//
// Typical use (the Marlin adapter calls this per G0/G1):
//
//   bk::Move m = state.line(words);           // or built from Marlin's
//   bk::ActionList out;                       //   current_position/destination
//   bool more = planner.plan(m, out);
//   for (;;) {
//     for (i < out.count) LINE -> line to x,y,z with E += e at m.f;
//                         DWELL -> finish queued moves, wait ms (0 = stop only)
//     state.add_e_offset(out.e_added);        // Marlin: current_position.e -=
//     if (!more) break;                       //   e_added; set_e_position_mm()
//     more = planner.plan_more(out);
//   }
//
// Bounded output: an ActionList holds at most BK_PLAN_HITS_MAX cuts (a line
// to a stop and the stop: 2*BK_PLAN_HITS_MAX+1 actions with the final line).
// If the move passes more, plan() returns true and plan_more() gives the next
// list, until it returns false. Points that share a stop (closer than
// BK_MIN_PIECE_MM) make one DWELL: a list only ends before a cut. No point is
// dropped; a caller that stops calling plan_more() leaves the rest of the move
// unexecuted, so it must not.
// The planner reads the Move given to plan() again in plan_more() (it keeps a
// pointer, not a copy): keep it alive and unchanged until plan() or
// plan_more() has returned false.
//
// No heap, no STL; builds with avr-gcc 5.4 (gnu++11).
#ifndef BK_BULGE_PLANNER_H
#define BK_BULGE_PLANNER_H

#include <stdint.h>

#include "bulge_map.h"
#include "bulgekit_config.h"
#include "move_state.h"
#include "reply_text.h"

namespace bk {

class GcodeArgs;

enum BulgeMode : uint8_t {
  BULGE_OFF = 0,        // every move passes through unchanged
  BULGE_MARKED = 1,     // only between M722 S1 and M722 S0
  BULGE_GEOMETRIC = 2,  // every extruding move; the tolerance picks the outer wall
};

struct Action {
  enum Kind : uint8_t { LINE = 0, DWELL = 1 };
  uint8_t kind;
  float x, y, z;  // LINE: target, host = machine coordinates
  union {
    float e;      // LINE: filament for this piece (mm), extra included
    uint16_t ms;  // DWELL: milliseconds (0 still means: stop here); x y z unused
  };
};

static const uint8_t BK_PLAN_ACTIONS_MAX = 2 * BK_PLAN_HITS_MAX + 1;

struct ActionList {
  uint8_t count;
  float e_added;  // extra filament in these lines: add to the E offset
  Action a[BK_PLAN_ACTIONS_MAX];
};

// Stop statistics (stats()), for the host tools (bkcore) and tests. The
// firmware never reads them, so AVR builds leave them out (18 bytes of RAM and
// the code that counts); define BK_PLAN_STATS 1 to keep them.
#ifndef BK_PLAN_STATS
#ifdef __AVR__
#define BK_PLAN_STATS 0
#else
#define BK_PLAN_STATS 1
#endif
#endif

struct PlannerStats {
  uint32_t moves_split;    // moves that got at least one stop
  uint32_t points_fired;   // bulge points that made a stop
  float extra_applied;     // extra filament extruded, mm
  float extra_dropped;     // extra not extruded, mm: owed by a stop at a wall's
                           // last vertex when a travel came first, or above the
                           // per-stop limit when points merged into one stop
  uint16_t layers_loaded;
};

class BulgePlanner {
 public:
  BulgePlanner() { reset(); }
  // Defaults from bulgekit_config.h, no layer, marker off, stats cleared.
  void reset();

  // Layer source. With a store the layer window follows the moves' z by itself:
  // when a move's z leaves the current layer it asks store.find_layer() and
  // releases the layers below the newly found one.
  void attach(MapStore *store) { store_ = store; map_changed(); }
  // Call after the map in force was replaced or cleared (M721 E of a full map,
  // M721 X): forgets the decoded layer. Appends need no call.
  void map_changed();
  // Without a store (tests, tools): use this layer until the next call. The
  // points are copied and sorted; fired marks are cleared.
  void load_layer(const MapLayer &layer, uint8_t quantum_um, uint8_t layer_height_cmm);
  bool has_layer() const { return has_layer_; }
  const MapLayer &layer() const { return layer_; }  // sorted by x, then y
  // Point i of layer() has stopped since the layer was loaded (tests, fuzzer).
  bool fired(uint8_t i) const { return fired_[i >> 3] & (uint8_t)(1 << (i & 7)); }

  // A move in host coordinates. Fills out with the primitive actions; returns
  // true if the move continues in plan_more(). A move that does not qualify
  // (mode, marker, travel, retraction, Z-only, E-only, no layer) comes back as
  // one LINE action equal to the move.
  bool plan(const Move &m, ActionList &out);
  bool plan_more(ActionList &out);

  // M720 and M722. The reply is one line ("echo:..." or "Error:..."), or
  // nothing. Returns false on an Error, which changes nothing.
  bool m720(const GcodeArgs &a, ReplyText &r);
  bool m722(const GcodeArgs &a, ReplyText &r);
  // The settings as the command that sets them, "  M720 S2 P100 E0.100 T0.250"
  // (M503), after "echo:" when echo is set (M720 alone).
  void report(ReplyText &r, bool echo) const;
  // Stored settings (EEPROM) back in force: each value checked as M720 checks
  // it. False with an Error: line, nothing changed, when one is out of range.
  bool restore(float dwell_ms, float extra_e, float tolerance, ReplyText &r);
#if !BK_REPLY_SERIAL
  // The same into a buffer (tests, tools): size >= BK_PLAN_REPLY_MAX.
  bool m720(const GcodeArgs &a, char *reply, uint8_t size) {
    ReplyText r(reply, size);
    return m720(a, r);
  }
  bool m722(const GcodeArgs &a, char *reply, uint8_t size) {
    ReplyText r(reply, size);
    return m722(a, r);
  }
#endif

  BulgeMode mode() const { return (BulgeMode)mode_; }
  uint16_t dwell_ms() const { return dwell_ms_; }
  float extra_e() const { return extra_e_; }
  float tolerance() const { return tol_mm_; }
  bool in_outer_wall() const { return marker_; }
  void set_in_outer_wall(bool on) { marker_ = on; }  // M722 without the text (a settings reset keeps it)
#if BK_PLAN_STATS
  const PlannerStats &stats() const { return stats_; }
  void clear_stats();
#endif

 private:
  bool qualifies(const Move &m) const;
  bool eligible(const Move &m);
  bool window(float z);
  bool keeps(int32_t z_cmm) const;
  void set_window(int32_t below, int32_t above);
  void derive();
  void collect(const Move &mv);
  bool exact(const Move &mv, uint8_t i, float *fd, float &t);
  void apply(const float *v);
  bool emit(ActionList &out);
  void stop(ActionList &out, uint8_t i);
  void flush(const Move &m, ActionList &out);
  void line_to(ActionList &out, float t, float e);
  void pay_owed(ActionList &out, Action &a);
  void pass(const Move &m, ActionList &out);

  // What every G1 reads or writes comes first: an AVR reaches the first 64
  // bytes of an object without address arithmetic.
  uint8_t mode_;  // M720 S
  // Flags in one byte (RAM is what an ATmega2560 lacks).
  bool marker_ : 1;     // M722 S1 seen, no S0 since
  bool has_layer_ : 1;  // layer_ is a layer of the map (or load_layer's)
  bool has_miss_ : 1;   // miss_z_ is known to have no layer
  bool cache_ok_ : 1;   // cache_* hold the last move's end
  bool cache_far_ : 1;  // that end was beyond the integer range (see to_q)
  bool hit_ : 1;        // collect() found a point (hit_i_, hit_t_)...
  bool more_ : 1;       // ...and more beyond it
  bool has_defer_ : 1;  // defer_ has a point (flush())
  int16_t tol_q_;       // tolerance in quanta, rounded up, plus rounding margin (derive())
  float inv_q_;         // quanta per mm

  // the last move end, in quanta: the next move usually starts there
  int16_t cache_qx_, cache_qy_;
  float cache_x_, cache_y_, cache_z_;
  int32_t cache_z_cmm_;

  // the move being split (the caller's, see plan_more())
  const Move *m_;
  float t_done_;       // parameter where the next piece starts
  float owed_;         // extra for the next piece, of this move or the next
  uint16_t stop_ms_;   // dwell given at the current stop so far (merged points)
  uint8_t fired_[(BK_LAYER_POINTS_MAX + 7) / 8];  // points of layer_ that stopped
  uint8_t defer_[(BK_LAYER_POINTS_MAX + 7) / 8];  // left by the last move to the next
  // The nearest unfired point on the move (collect()): hit_i_, at hit_t_.
  uint8_t hit_i_;
  float hit_t_;

  // the other settings (M720 P E T)
  uint16_t dwell_ms_;
  float extra_e_, tol_mm_;

  // layer window
  MapStore *store_;
  uint8_t q_um_, lh_cmm_;
  // The loaded layer stays in use while a move's z (cmm) is within
  // [win_lo_, win_hi_]: half a layer height around it, narrowed to the
  // half-way marks towards the records next to it (MapStore::neighbors).
  uint16_t win_lo_, win_hi_;
  int32_t miss_z_;        // z (cmm) known to have no layer
  // The map's last z when the neighbours (or the miss) were read: an append
  // changes it, and then both are read again, so a late layer is still found.
  uint16_t seen_last_z_;

#if BK_PLAN_STATS
  PlannerStats stats_;
#endif
  MapLayer layer_;  // the decoded working set (the "arena" of this module)
};

}  // namespace bk

#endif  // BK_BULGE_PLANNER_H
