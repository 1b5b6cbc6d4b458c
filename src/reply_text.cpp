#include "reply_text.h"

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

void ReplyText::u(uint32_t v) { decimal(v, 0); }

// Digits from the right, the point dec places in; at least one digit before it.
void ReplyText::decimal(uint32_t v, uint8_t dec) {
  char t[12];
  uint8_t k = 0;
  do {
    t[k++] = (char)('0' + v % 10);
    v /= 10;
    if (k == dec) t[k++] = '.';
  } while (v || k <= dec + (dec != 0));
  while (k) c(t[--k]);
}

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
  float scale = 1;
  for (uint8_t i = 0; i < dec; i++) scale *= 10;
  decimal((uint32_t)(v * scale + 0.5f), dec);
}

}  // namespace bk
