// Width mode (M723): line width set by head speed at a constant extruder rate.
//
// Jang & Hong (2017) observe that a change of extruder speed reaches the nozzle
// late (the filament path between drive gear and nozzle delays it), so they keep
// the extruder turning at one rate and set the cross-section A = W*H = q / v with
// the head speed v instead. Here that happens in the firmware: while the mode is
// on, every extruding XY move is retimed to
//     v = L * r / dE        (L: XY length, dE: filament mm, r: extruder rate)
// so the extruder turns at r whatever width the host asked for; the host may also
// send a width W instead of E (dE = W*H*L / filament area).
//
// Pure logic: no I/O, no heap. Replies go into a caller buffer; the Marlin
// adapter prints them and keeps Marlin's own state (feedrate_mm_s, E position).
#ifndef BK_WIDTH_MODE_H
#define BK_WIDTH_MODE_H

#include <stdint.h>

#include "bulgekit_config.h"
#include "gcode_args.h"
#include "reply_text.h"

namespace bk {

// Clamping statistics since the mode was last switched on.
struct WidthStats {
  uint32_t moves;         // extruding moves retimed
  uint32_t clamped_low;   // speed raised to L: extruder ran faster than r
  uint32_t clamped_high;  // speed lowered to U: extruder ran slower than r
  float max_dev;          // largest |actual rate / target rate - 1| of a clamped move
  float sum_dev;          // sum of the same over clamped moves (mean = sum / clamped)
};

class WidthMode {
 public:
  // A reply buffer of this size holds every reply M723 writes (the report is two
  // lines; tests and tools that reply into a buffer).
  static const uint8_t REPLY_MIN = 200;
  // Enough for every Error: line of width_e().
  static const uint8_t ERROR_REPLY_MIN = 64;

  WidthMode() { reset(); }
  // Power-on state: off, no target rate, D/L/U from bulgekit_config.h, no H, M220 100 %.
  void reset();

  // M723. Parameters (all optional, applied together or not at all):
  //   S0|S1 leave/enter    Q flow mm^3/s | R extruder rate mm/s (filament)
  //   D filament dia mm    H layer height mm (0 = none; W words need it)
  //   L min speed, U max speed (mm/s, applied after the M220 percentage)
  // No parameters: two "echo:" report lines. Returns false with an "Error:..."
  // reply and unchanged state on a bad command; true with nothing or the report.
  // Replies may hold several lines separated by '\n' (no trailing newline).
  bool command(const GcodeArgs &args, ReplyText &r);
  // The settings line, "  M723 S0 Q3.200 D1.750 H0.200 L5.000 U60.000" (M503),
  // after "echo:" when echo is set; stats adds the statistics line (M723 alone).
  void report(ReplyText &r, bool echo, bool stats) const;
  // Stored settings (EEPROM) back in force, each value checked as M723 checks
  // it; the mode (S) is not touched. kind: 1 Q (target = flow), 2 R (target =
  // rate), anything else none stored: the target in force stays (as after an
  // M723 without Q or R). False with an Error: line, nothing changed, when one
  // is refused.
  bool restore(uint8_t kind, const float *target_d_h_l_u, ReplyText &r);
#if !BK_REPLY_SERIAL
  // Tests and tools: the reply into a buffer (>= REPLY_MIN), from a parsed or
  // a raw line.
  bool command(const GcodeArgs &args, char *reply, uint8_t reply_size) {
    ReplyText r(reply, reply_size);
    return command(args, r);
  }
  bool command(const char *line, char *reply, uint8_t reply_size);
#endif

  // --- per-move hooks (called by the adapter for each G0/G1, before any bulge
  // split, with the host's dE, i.e. before the M221 flow factor) --------------
  // feed_mm_s is what the adapter would hand the planner (M220 already applied).
  // Returns the feed to use instead: the input itself, bit for bit, when the mode
  // is off or the move does not extrude (dE <= 0 or no XY travel).
  // (The mode test is inline: with the mode off a move costs no call.)
  float feed(float xy_len, float de, float feed_mm_s) {
    return on_ ? feed_on(xy_len, de, feed_mm_s) : feed_mm_s;
  }
  // Same, computing L = hypot(dx, dy) only for moves that need it.
  float feed_xy(float dx, float dy, float de, float feed_mm_s) {
    return on_ ? feed_xy_on(dx, dy, de, feed_mm_s) : feed_mm_s;
  }

  // A move carrying a W word: writes the filament length for that width into
  // de_out (dE = W*H*L / area). has_e: the move also has an E word (refused).
  // On false, r holds "Error:..." and the adapter must drop the move. On true
  // nothing is written.
  bool width_e(float w, bool has_e, float xy_len, float &de_out, ReplyText &r);
  bool width_e_xy(float w, bool has_e, float dx, float dy, float &de_out, ReplyText &r);
#if !BK_REPLY_SERIAL
  bool width_e(float w, bool has_e, float xy_len, float &de_out, char *reply, uint8_t reply_size) {
    ReplyText r(reply, reply_size);
    return width_e(w, has_e, xy_len, de_out, r);
  }
  bool width_e_xy(float w, bool has_e, float dx, float dy, float &de_out, char *reply, uint8_t reply_size) {
    ReplyText r(reply, reply_size);
    return width_e_xy(w, has_e, dx, dy, de_out, r);
  }
#endif

  // M220 hook: the adapter passes Marlin's feedrate percentage after every
  // change. In width mode it scales the extruder rate r, so all retimed speeds
  // scale with it and widths stay as commanded (see docs/width-mode.md).
  // Returns false (and keeps the previous value) for percent <= 0.
  bool set_feed_percent(int16_t percent);

  // --- state, for the adapter and the tests ---------------------------------
  bool active() const { return on_; }
  bool has_target() const { return target_kind_ != TARGET_NONE; }
  uint8_t target_kind() const { return target_kind_; }  // 0 none, 1 Q, 2 R (restore())
  float target() const { return set_[TARGET]; }          // Q or R as given
  float rate() const { return rate_; }  // r in force, mm/s of filament, M220 applied
  float base_rate() const;              // r as set by Q/R, without M220
  float flow() const { return base_rate() / inv_area_; }  // mm^3/s without M220
  float filament_dia() const { return set_[DIA]; }
  float filament_area() const { return 1.0f / inv_area_; }
  float layer_height() const { return set_[HEIGHT]; }
  float min_speed() const { return set_[MIN_V]; }
  float max_speed() const { return set_[MAX_V]; }
  int16_t feed_percent() const { return percent_; }
  const WidthStats &stats() const { return stats_; }

 private:
  enum TargetKind : uint8_t { TARGET_NONE = 0, TARGET_FLOW = 1, TARGET_RATE = 2 };
  // The settings M723 sets, in the order of its words (Q and R share TARGET),
  // so one table of limits checks and reports them all.
  enum Setting : uint8_t { TARGET, DIA, HEIGHT, MIN_V, MAX_V, SETTINGS };

  float feed_on(float xy_len, float de, float feed_mm_s);
  float feed_xy_on(float dx, float dy, float de, float feed_mm_s);
  float retime(float xy_len, float de);
  void recompute();
  bool finish(WidthMode &n, int8_t on, ReplyText &o);

  bool on_;
  uint8_t target_kind_;
  float set_[SETTINGS];  // Q (mm^3/s) or R (mm/s) as given, D mm, H mm (0 = none), L, U mm/s
  float inv_area_;       // 1 / filament cross-section, so the W path needs no division
  float rate_;           // r from the target, D and percent_: the r the moves use
  int16_t percent_;      // M220
  WidthStats stats_;
};

}  // namespace bk

#endif  // BK_WIDTH_MODE_H
