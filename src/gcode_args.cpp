#include "gcode_args.h"

#include <stdlib.h>
#include <string.h>

#include "reply_text.h"
#include "float_strict.h"  // last: no fused multiply-add below

namespace bk {

static char upper(char c) { return (c >= 'a' && c <= 'z') ? (char)(c - 'a' + 'A') : c; }
static bool is_end(char c) { return c == 0 || c == ';' || c == '*' || c == '\n' || c == '\r'; }
static bool is_space(char c) { return c == ' ' || c == '\t'; }
static bool is_digit(char c) { return c >= '0' && c <= '9'; }
static bool is_letter(char c) { c = upper(c); return c >= 'A' && c <= 'Z'; }

// The next word at or after p (blanks skipped); at the line's end, its end.
static const char *word_at(const char *p) {
  while (is_space(*p)) p++;
  return p;
}

// Past the word that starts at p.
static const char *word_end(const char *p) {
  while (!is_end(*p) && !is_space(*p)) p++;
  return p;
}

// A word's letter: its first character upper-cased, '?' if not a letter.
static char letter_of(const char *p) { return is_letter(*p) ? upper(*p) : '?'; }

bool GcodeArgs::parse(const char *p) {
  args_ = p;
  seen_ = 0;
  any_ = odd_ = false;
  dup_ = 0;
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
  args_ = p;
  // One pass over the words: which letters appear, and the first one twice.
  for (p = word_at(p); !is_end(*p); p = word_at(word_end(p))) {
    any_ = true;
    if (!is_letter(*p)) {
      odd_ = true;  // unknown() reports it as '?'
      continue;
    }
    const uint32_t bit = 1UL << (uint8_t)(upper(*p) - 'A');
    if ((seen_ & bit) && !dup_) dup_ = upper(*p);
    seen_ |= bit;
  }
  return true;
}

const char *GcodeArgs::find(char letter, uint8_t &len) const {
  letter = upper(letter);
  for (const char *p = word_at(args_); !is_end(*p); p = word_at(p)) {
    const char *e = word_end(p);
    if (letter_of(p) == letter) {
      len = (uint8_t)(e - p - 1 > 255 ? 255 : e - p - 1);
      return p + 1;
    }
    p = e;
  }
  return nullptr;
}

bool GcodeArgs::has(char letter) const {
  letter = upper(letter);
  return is_letter(letter) && (seen_ >> (uint8_t)(letter - 'A')) & 1;
}

char GcodeArgs::unknown(const char *allowed_flash) const {
  if (odd_) return '?';
  uint32_t allowed = 0;
  for (const char *a = allowed_flash; char c = (char)BK_RD8(a); a++) allowed |= 1UL << (uint8_t)(upper(c) - 'A');
  const uint32_t bad = seen_ & ~allowed;
  if (!bad) return 0;
  char l = 'A';
  while (!((bad >> (uint8_t)(l - 'A')) & 1)) l++;
  return l;
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
  text = find(letter, len);
  return text != nullptr;
}

// Strict decimal: [+-]digits[.digits] or [+-].digits; at least one digit.
ArgStatus GcodeArgs::get_float(char letter, float &out) const {
  uint8_t len;
  const char *s = find(letter, len);
  if (!s) return ARG_ABSENT;
  if (len == 0) return ARG_EMPTY;
  const char *e = s + len;
  bool neg = false;
  if (*s == '+' || *s == '-') neg = (*s++ == '-');
  // An integer mantissa and a decimal exponent, not the C library's strtod:
  // the same bits on every target (avr-libc's strtod is not correctly
  // rounded), and trailing zeros change nothing (the quotient is the same
  // number), so a reported setting sent back (M503) gives the very same value.
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
  // One division by 10^k, itself exact as a float up to k = 10: with up to 7
  // significant digits (mant exact too) the quotient is rounded once, i.e. the
  // float nearest the decimal, as a correct strtod gives (dividing by 10 k
  // times was off by an ulp at times: "7.02" gave 7.0199995).
  float scale = 1.0f;
  while (frac_digits--) scale *= 10.0f;
  const float v = (float)mant / scale;
  out = neg ? -v : v;
  return ARG_OK;
}

// A whole number within max (its decimal text in flash, max_text), an optional sign
// ('-' only where allowed): checked as text, converted by strtoul.
static ArgStatus read_whole(const char *s, const char *e, const char *max_text, bool minus_ok, bool &neg,
                            uint32_t &v) {
  neg = false;
  if (*s == '+' || (minus_ok && *s == '-')) neg = (*s++ == '-');
  while (s < e - 1 && *s == '0') s++;  // leading zeros do not count
  const uint8_t n = (uint8_t)(e - s);
  if (!n || n > 10) return ARG_BAD;
  for (const char *p = s; p < e; p++)
    if (!is_digit(*p)) return ARG_BAD;
  // ten digits: compared with the largest as text, so nothing wraps
  if (n == 10 && BK_STRNCMP(s, max_text, 10) > 0) return ARG_BAD;
  v = (uint32_t)strtoul(s, nullptr, 10);
  return ARG_OK;
}

ArgStatus GcodeArgs::get_ulong(char letter, uint32_t &out) const {
  uint8_t len;
  const char *t = find(letter, len);
  if (!t) return ARG_ABSENT;
  if (len == 0) return ARG_EMPTY;
  bool neg;
  uint32_t v;
  if (read_whole(t, t + len, BK_F("4294967295"), false, neg, v) != ARG_OK) return ARG_BAD;
  out = v;
  return ARG_OK;
}

ArgStatus GcodeArgs::get_long(char letter, int32_t &out) const {
  uint8_t len;
  const char *t = find(letter, len);
  if (!t) return ARG_ABSENT;
  if (len == 0) return ARG_EMPTY;
  bool neg;
  uint32_t v;
  if (read_whole(t, t + len, BK_F("2147483647"), true, neg, v) != ARG_OK) return ARG_BAD;
  out = neg ? -(int32_t)v : (int32_t)v;
  return ARG_OK;
}

}  // namespace bk
