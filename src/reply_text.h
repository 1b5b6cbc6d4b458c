// Where the core's M-code replies go: "echo:..." and "Error:..." lines, written
// piece by piece as the handlers decide (no text is formatted at run time and
// then printed). The same calls have two implementations:
//   - in the firmware (BK_REPLY_SERIAL 1, set by the Marlin install) the Marlin
//     adapter defines them on Marlin's serial port and its own number printing;
//   - in tests and host tools (reply_text.cpp) they fill a bounded buffer.
// Numbers with decimals (fixed()) are formatted by the core in both, so a
// test pins the digits the printer sends.
// Lines are separated by '\n'; the caller ends the last one (end()).
#ifndef BK_REPLY_TEXT_H
#define BK_REPLY_TEXT_H

#include <stdint.h>

#include "bulgekit_config.h"
#include "flash_text.h"

namespace bk {

class ReplyText {
 public:
  // Buffer implementation: never writes past size; text that does not fit ends
  // in "..." so a short buffer shows, rather than hides, the cut. The firmware
  // passes (nullptr, 0).
  ReplyText(char *buf, uint16_t size);
  void c(char ch);
  void p(const char *flash);             // a BK_F literal or flash text
  void raw(const char *ram, uint8_t n);  // n characters from RAM
  void u(uint32_t v);                    // decimal
  // A float with dec decimals (0..3), rounded half up; NaN as "nan", values
  // of a million or more as ">=1000000", so a reply never shows a wrong
  // number. Shared by both implementations (built on c, p and u).
  void fixed(float v, uint8_t dec);
  bool empty() const { return n_ == 0; }  // nothing written yet
  bool cut() const { return cut_; }

 private:
  char *b_;
  uint16_t size_, n_;  // n_: characters written (the firmware counts pieces)
  bool cut_;
};

}  // namespace bk

#endif  // BK_REPLY_TEXT_H
