#include "gcode_args.h"

#include "reply_text.h"

namespace bk {

static char upper(char c) { return (c >= 'a' && c <= 'z') ? (char)(c - 'a' + 'A') : c; }
static bool is_end(char c) { return c == 0 || c == ';' || c == '*' || c == '\n' || c == '\r'; }
static bool is_space(char c) { return c == ' ' || c == '\t'; }
static bool is_digit(char c) { return c >= '0' && c <= '9'; }
static bool is_letter(char c) { c = upper(c); return c >= 'A' && c <= 'Z'; }

bool GcodeArgs::parse(const char *p) {
  count_ = 0;
  code_letter_ = 0;
  code_ = -1;
  while (is_space(*p)) p++;
  if (upper(*p) == 'N') {  // line number
    p++;
    while (is_digit(*p) || *p == '-') p++;
    while (is_space(*p)) p++;
  }
  char c = upper(*p);
  if (c != 'M' && c != 'G') return false;
  p++;
  if (!is_digit(*p)) return false;
  int32_t code = 0;
  while (is_digit(*p)) {
    code = code * 10 + (*p - '0');
    if (code > 9999) return false;
    p++;
  }
  code_letter_ = c;
  code_ = (int16_t)code;
  // Words: a letter, then its text up to the next blank or the end.
  while (!is_end(*p)) {
    if (is_space(*p)) {
      p++;
      continue;
    }
    const char *start = p;
    while (!is_end(*p) && !is_space(*p)) p++;
    if (count_ < MAX_WORDS) {
      Word &w = words_[count_++];
      w.letter = is_letter(*start) ? upper(*start) : '?';
      w.text = start + 1;
      w.len = (uint8_t)((p - start - 1) > 255 ? 255 : (p - start - 1));
      if (!is_letter(*start)) w.text = start, w.len = (uint8_t)(p - start);
    } else {
      // More words than we keep: mark so callers reject the line rather than
      // silently ignoring parameters.
      words_[MAX_WORDS - 1].letter = '?';
    }
  }
  return true;
}

const GcodeArgs::Word *GcodeArgs::find(char letter) const {
  letter = upper(letter);
  for (uint8_t i = 0; i < count_; i++)
    if (words_[i].letter == letter) return &words_[i];
  return nullptr;
}

bool GcodeArgs::has(char letter) const { return find(letter) != nullptr; }

char GcodeArgs::unknown(const char *allowed_flash) const {
  for (uint8_t i = 0; i < count_; i++) {
    const char l = words_[i].letter;
    bool ok = false;
    for (const char *a = allowed_flash; char c = (char)BK_RD8(a); a++) ok |= (upper(c) == l);
    if (!ok) return l;
  }
  return 0;
}

char GcodeArgs::duplicate() const {
  for (uint8_t i = 1; i < count_; i++)
    for (uint8_t j = 0; j < i; j++)
      if (words_[i].letter == words_[j].letter) return words_[i].letter;
  return 0;
}

bool check_words(const GcodeArgs &a, const char *allowed_flash, const char *code_flash, ReplyText &r) {
  char bad = a.unknown(allowed_flash);
  const bool twice = !bad && (bad = a.duplicate()) != 0;
  if (!bad) return true;
  r.p(BK_F("Error:"));
  r.p(code_flash);
  r.p(twice ? BK_F(" duplicate parameter ") : BK_F(" unknown parameter "));
  r.c(bad);
  return false;
}

// "Error:M723 Q" (the start of every value error)
static void value_error(const char *code_flash, char letter, ReplyText &r) {
  r.p(BK_F("Error:"));
  r.p(code_flash);
  r.c(' ');
  r.c(letter);
}

int8_t read_number(const GcodeArgs &a, char letter, const char *code_flash, float &out, ReplyText &r) {
  float v = 0;
  const ArgStatus st = a.get_float(letter, v);
  if (st == ARG_ABSENT) return 0;
  if (st == ARG_OK) {
    out = v;
    return 1;
  }
  value_error(code_flash, letter, r);
  r.p(BK_F(" bad number"));
  return -1;
}

bool check_limit(const Limit &lim, float v, const char *code_flash, ReplyText &r) {
  if ((lim.lo_open ? v > lim.lo : v >= lim.lo) && v <= lim.hi) return true;
  value_error(code_flash, lim.letter, r);
  r.fixed(v, 3);
  r.p(BK_F(" not in "));
  r.c(lim.lo_open ? '(' : '[');
  r.fixed(lim.lo, 3);
  r.p(BK_F(".."));
  r.fixed(lim.hi, 3);
  r.c(']');
  return false;
}

int8_t read_limited(const GcodeArgs &a, const Limit &lim, const char *code_flash, float &out, ReplyText &r) {
  float v = 0;
  const int8_t k = read_number(a, lim.letter, code_flash, v, r);
  if (k <= 0) return k;
  if (!check_limit(lim, v, code_flash, r)) return -1;
  out = v;
  return 1;
}

bool GcodeArgs::raw(char letter, const char *&text, uint8_t &len) const {
  const Word *w = find(letter);
  if (!w) return false;
  text = w->text;
  len = w->len;
  return true;
}

// Strict decimal: [+-]digits[.digits] or [+-].digits; at least one digit.
ArgStatus GcodeArgs::get_float(char letter, float &out) const {
  const Word *w = find(letter);
  if (!w) return ARG_ABSENT;
  if (w->len == 0) return ARG_EMPTY;
  const char *s = w->text, *e = w->text + w->len;
  bool neg = false;
  if (*s == '+' || *s == '-') neg = (*s++ == '-');
  // Accumulate as an integer mantissa and a decimal exponent: exact for the
  // few digits G-code uses, and cheaper on AVR than repeated float multiplies.
  uint32_t mant = 0;
  int8_t frac_digits = 0;
  uint8_t digits = 0;
  bool dot = false;
  for (; s < e; s++) {
    if (*s == '.') {
      if (dot) return ARG_BAD;
      dot = true;
    } else if (is_digit(*s)) {
      digits++;
      if (mant < 100000000u) {
        mant = mant * 10 + (uint32_t)(*s - '0');
        if (dot) frac_digits++;
      } else if (!dot) {
        return ARG_BAD;  // integer part too large to be a sane setting
      }
    } else {
      return ARG_BAD;
    }
  }
  if (!digits) return ARG_BAD;
  float v = (float)mant;
  while (frac_digits--) v /= 10.0f;
  out = neg ? -v : v;
  return ARG_OK;
}

// Whole number up to max, with an optional sign ('-' only where allowed).
static ArgStatus read_whole(const char *s, const char *e, uint32_t max, bool minus_ok, bool &neg, uint32_t &v) {
  neg = false;
  if (*s == '+' || (minus_ok && *s == '-')) neg = (*s++ == '-');
  if (s == e) return ARG_BAD;
  v = 0;
  for (; s < e; s++) {
    if (!is_digit(*s)) return ARG_BAD;
    const uint32_t d = (uint32_t)(*s - '0');
    if (v > (max - d) / 10) return ARG_BAD;  // checked before it can wrap
    v = v * 10 + d;
  }
  return ARG_OK;
}

ArgStatus GcodeArgs::get_ulong(char letter, uint32_t &out) const {
  const Word *w = find(letter);
  if (!w) return ARG_ABSENT;
  if (w->len == 0) return ARG_EMPTY;
  bool neg;
  uint32_t v;
  if (read_whole(w->text, w->text + w->len, 0xFFFFFFFFu, false, neg, v) != ARG_OK) return ARG_BAD;
  out = v;
  return ARG_OK;
}

ArgStatus GcodeArgs::get_long(char letter, int32_t &out) const {
  const Word *w = find(letter);
  if (!w) return ARG_ABSENT;
  if (w->len == 0) return ARG_EMPTY;
  bool neg;
  uint32_t v;
  if (read_whole(w->text, w->text + w->len, 0x7FFFFFFFu, true, neg, v) != ARG_OK) return ARG_BAD;
  out = neg ? -(int32_t)v : (int32_t)v;
  return ARG_OK;
}

}  // namespace bk
