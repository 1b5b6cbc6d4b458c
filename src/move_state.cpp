#include "move_state.h"

#include "bulgekit_config.h"
#include "gcode_args.h"
#include "float_strict.h"  // last: no fused multiply-add below

namespace bk {

void MoveState::reset() {
  for (uint8_t i = 0; i < 4; i++) pos_[i] = 0.0f;
  feed_ = BK_MOVE_DEFAULT_FEED_MM_MIN;
  e_offset_ = 0.0f;
  abs_xyz_ = abs_e_ = true;
}

Move MoveState::line(const AxisWords &w) {
  Move m;
  m.x0 = pos_[0];
  m.y0 = pos_[1];
  m.z0 = pos_[2];
  const float *v[3] = {&w.x, &w.y, &w.z};
  for (uint8_t i = 0; i < 3; i++) {
    if (w.mask & (1 << i)) pos_[i] = abs_xyz_ ? *v[i] : pos_[i] + *v[i];
  }
  m.x1 = pos_[0];
  m.y1 = pos_[1];
  m.z1 = pos_[2];
  m.e = 0.0f;
  if (w.mask & AxisWords::E) {
    if (abs_e_) {
      m.e = w.e - pos_[3];
      pos_[3] = w.e;  // the host's own number, not start + delta: no drift
    } else {
      m.e = w.e;
      pos_[3] += w.e;
    }
  }
  if ((w.mask & AxisWords::F) && w.f > 0.0f) feed_ = w.f;
  m.f = feed_;
  return m;
}

void MoveState::set_position(const AxisWords &w) {
  const float *v[4] = {&w.x, &w.y, &w.z, &w.e};
  for (uint8_t i = 0; i < 4; i++)
    if (w.mask & (1 << i)) pos_[i] = v[i][0];
  if (w.mask & AxisWords::E) e_offset_ = 0.0f;
}

// One word into w: false if present but malformed or empty.
static bool take(const GcodeArgs &a, char letter, uint8_t bit, float &dst, uint8_t &mask) {
  ArgStatus s = a.get_float(letter, dst);
  if (s == ARG_OK) mask |= bit;
  return s == ARG_OK || s == ARG_ABSENT;
}

char MoveState::words_from(const GcodeArgs &a, AxisWords &w) {
  // Spelled out rather than looped over a letter table: a table would sit in
  // RAM on AVR.
  w.mask = 0;
  if (!take(a, 'X', AxisWords::X, w.x, w.mask)) return 'X';
  if (!take(a, 'Y', AxisWords::Y, w.y, w.mask)) return 'Y';
  if (!take(a, 'Z', AxisWords::Z, w.z, w.mask)) return 'Z';
  if (!take(a, 'E', AxisWords::E, w.e, w.mask)) return 'E';
  if (!take(a, 'F', AxisWords::F, w.f, w.mask)) return 'F';
  return 0;
}

}  // namespace bk
