// Float tests on the IEEE-754 bits, for the per-move paths: on an 8-bit CPU
// every float compare is a library call, an integer compare is a few cycles.
// Shared by the planner and width mode. No heap, no STL.
#ifndef BK_FLOAT_BITS_H
#define BK_FLOAT_BITS_H

#include <stdint.h>
#include <string.h>

namespace bk {

static inline uint32_t fbits(float f) {
  uint32_t u;
  memcpy(&u, &f, sizeof u);
  return u;
}

// x > 0: +tiny .. +inf. False for 0, -0, negatives and NaN (their bits wrap
// below zero or lie above +inf), as the float compare x > 0 is.
static inline bool fpos(float x) { return fbits(x) - 1u < 0x7f800000u; }

}  // namespace bk

#endif  // BK_FLOAT_BITS_H
