// Host-position model: turns G0/G1/G92/G90/G91/M82/M83 into Moves the bulge
// planner can split, and keeps the internal E offset that absorbs the extra
// filament of each bulge so the host never sees its E coordinate change.
//
// Coordinates:
//   host E     what the G-code says (M114 must report this)
//   machine E  host E + e_offset(); what the extruder has really been driven to
// XYZ are never changed by bulges, so host and machine XYZ are the same.
//
// Modes follow Marlin: G90/G91 set every axis including E (they clear an
// earlier M82/M83); M82/M83 then override E alone. G92 sets the given axes and,
// if it sets E, re-syncs machine E to host E (offset back to 0), which is the
// paper's "G92 E..." rewrite done once, inside the firmware.
//
// No heap, no STL; builds with avr-gcc 5.4 (gnu++11).
#ifndef BK_MOVE_STATE_H
#define BK_MOVE_STATE_H

#include <stdint.h>

namespace bk {

class GcodeArgs;

// One linear move in host coordinates (mm, mm/min).
struct Move {
  union {
    struct {
      float x0, y0, z0;  // start
      float x1, y1, z1;  // end
    };
    float p[6];  // the same by index (start x y z, end x y z): one loop per
                 // axis; the anonymous struct is the GNU/Marlin XYZval idiom
  };
  float e;           // filament for the move (end E - start E, host terms)
  float f;           // feedrate mm/min
  bool xy_motion() const { return x0 != x1 || y0 != y1; }
  // A move the planner may split: XY motion that extrudes.
  bool extruding() const { return e > 0.0f && xy_motion(); }
};

// The axis words of one G0/G1/G92, as the caller parsed them.
struct AxisWords {
  enum : uint8_t { X = 1, Y = 2, Z = 4, E = 8, F = 16 };
  uint8_t mask;
  float x, y, z, e, f;
};

class MoveState {
 public:
  MoveState() { reset(); }
  // Power-on state: origin, G90 + M82, feed BK_MOVE_DEFAULT_FEED, offset 0.
  void reset();

  void set_absolute(bool abs) { abs_xyz_ = abs_e_ = abs; }  // G90 / G91
  void set_e_absolute(bool abs) { abs_e_ = abs; }            // M82 / M83
  bool xyz_absolute() const { return abs_xyz_; }
  bool e_absolute() const { return abs_e_; }

  // G0/G1: the move from the current host position to the words' target. The
  // host position advances to the target at once (as Marlin's current_position
  // does), whatever the planner later makes of the move.
  Move line(const AxisWords &w);
  // G92: set the named axes' host coordinates; nothing moves.
  void set_position(const AxisWords &w);

  // The planner extruded extra filament (sum of ActionList::e_added).
  void add_e_offset(float mm) { e_offset_ += mm; }

  float x() const { return pos_[0]; }
  float y() const { return pos_[1]; }
  float z() const { return pos_[2]; }
  float e() const { return pos_[3]; }  // host E, exactly as the G-code has it
  float feed() const { return feed_; }
  float e_offset() const { return e_offset_; }
  float machine_e() const { return pos_[3] + e_offset_; }

  // Reads X Y Z E F from a parsed G0/G1/G92 line. Returns 0, or the first
  // letter that is not an axis word or is malformed (the caller reports it).
  static char words_from(const GcodeArgs &a, AxisWords &w);

 private:
  float pos_[4];
  float feed_;
  float e_offset_;
  bool abs_xyz_, abs_e_;
};

}  // namespace bk

#endif  // BK_MOVE_STATE_H
