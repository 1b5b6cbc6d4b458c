// Bounded writer for M-code replies ("echo:..." / "Error:..."), shared by the
// core's M-code handlers. Never writes past the caller's buffer; text that does
// not fit ends in "..." so a short buffer shows, rather than hides, the cut.
// Numbers are formatted here without printf (no float printf on AVR).
#ifndef BK_REPLY_TEXT_H
#define BK_REPLY_TEXT_H

#include <stdint.h>

#include "flash_text.h"

namespace bk {

class ReplyText {
 public:
  ReplyText(char *buf, uint16_t size);
  void c(char ch);
  void p(const char *flash);              // a BK_F literal or flash text
  void raw(const char *ram, uint8_t n);   // n characters from RAM
  void u(uint32_t v);                     // decimal
  void decimal(uint32_t v, uint8_t dec);  // v / 10^dec with dec (0..9) digits: (1234, 2) -> "12.34"
  // A float with dec decimals (0..3), rounded half up; NaN as "nan", values of a
  // million or more as ">=1000000", so a report never shows a wrong number.
  void fixed(float v, uint8_t dec);
  bool cut() const { return cut_; }

 private:
  char *b_;
  uint16_t size_, n_;
  bool cut_;
};

}  // namespace bk

#endif  // BK_REPLY_TEXT_H
