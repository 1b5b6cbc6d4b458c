// The buffer implementation of ReplyText (tests and host tools). The firmware
// prints instead: see reply_text.h.
#include "reply_text.h"
#include "float_strict.h"  // last: no fused multiply-add below

#if !BK_REPLY_SERIAL

namespace bk {

ReplyText::ReplyText(char *buf, uint16_t size) : b_(buf), size_(size), n_(0), cut_(false) {
  if (size_) b_[0] = 0;
}

void ReplyText::c(char ch) {
  if (!size_) return;
  if (n_ + 1 < size_) {
    b_[n_++] = ch;
    b_[n_] = 0;
  } else if (!cut_) {
    cut_ = true;
    for (uint16_t i = 0; i < 3 && i < n_; i++) b_[n_ - 1 - i] = '.';
  }
}

void ReplyText::p(const char *flash) {
  for (char ch; (ch = (char)BK_RD8(flash)) != 0; flash++) c(ch);
}

void ReplyText::raw(const char *ram, uint8_t n) {
  while (n--) c(*ram++);
}

void ReplyText::u(uint32_t v) {
  char t[10];
  uint8_t k = 0;
  do {
    t[k++] = (char)('0' + v % 10);
    v /= 10;
  } while (v);
  while (k) c(t[--k]);
}

}  // namespace bk

#endif  // !BK_REPLY_SERIAL

namespace bk {

// Shared by both implementations, so the tests pin the firmware's digits.
// Rounded half up at the last decimal, then printed as two whole numbers: no
// float printing (Marlin's takes the digit count at run time only in a larger
// general copy).
void ReplyText::fixed(float v, uint8_t dec) {
  if (v != v) {
    p(BK_F("nan"));
    return;
  }
  if (v < 0) {
    c('-');
    v = -v;
  }
  if (v >= 1.0e6f) {
    p(BK_F(">=1000000"));
    return;
  }
  uint16_t scale = 1;
  for (uint8_t i = 0; i < dec; i++) scale = (uint16_t)(scale * 10u);
  const uint32_t n = (uint32_t)(v * (float)scale + 0.5f);
  u(n / scale);
  if (!dec) return;
  c('.');
  uint32_t frac = n % scale;
  while (dec--) {
    scale = (uint16_t)(scale / 10u);
    c((char)('0' + frac / scale));
    frac %= scale;
  }
}
}  // namespace bk
