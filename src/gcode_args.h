// M-code argument logic shared by M720-M723: reads letter/value words from the
// raw command text (what Marlin's parser.command_ptr points at), so the same
// checks run in the unit tests and in the firmware. Whole numbers are checked
// here character by character, then converted by the C library's strtoul,
// which Marlin's own parser already links. No heap, no STL.
#ifndef BK_GCODE_ARGS_H
#define BK_GCODE_ARGS_H

#include <stdint.h>

namespace bk {

enum ArgStatus : int8_t {
  ARG_ABSENT = 0,   // the letter does not appear
  ARG_OK = 1,       // present with a well-formed value
  ARG_EMPTY = 2,    // present with no value ("M720 S")
  ARG_BAD = -1,     // present with a malformed value ("P1x", "E.", "S--1")
};

// A parsed command line: "M720 S1 P100" -> code 720, words S, P. A word is a
// run of non-blank characters and its first one is its letter; the text after
// the code may also hold one raw payload word (M721 D...) that callers read
// with raw(). parse() notes which letters appear in one pass; values are found
// in the text when asked, so the line must outlive this object.
class GcodeArgs {
 public:
  // Parses text such as "N12 M720 S1 P100*57" (line number and checksum are
  // skipped; a ';' comment ends the line). Returns false if the text does not
  // start with an M or G code.
  bool parse(const char *line);

  char code_letter() const { return code_letter_; }
  int16_t code() const { return code_; }
  bool has(char letter) const;  // letter appears at all (with or without value)
  bool none() const { return !any_; }  // no parameters at all
  // Value accessors. Letters are case-insensitive.
  ArgStatus get_float(char letter, float &out) const;
  ArgStatus get_long(char letter, int32_t &out) const;      // integer only, no '.'
  ArgStatus get_ulong(char letter, uint32_t &out) const;    // 0..4294967295
  // The raw word after letter (up to the next space, ';' or '*'): pointer and length.
  bool raw(char letter, const char *&text, uint8_t &len) const;
  // A letter present that is not in allowed (flash text: BK_F("SPET")), the
  // first in the alphabet; '?' if a word does not start with a letter; or 0.
  char unknown(const char *allowed_flash) const;
  // The first letter that appears twice ("M720 P100 P3000"), or 0.
  char duplicate() const { return dup_; }

 private:
  // The first word of letter: the text after the letter and its length.
  const char *find(char letter, uint8_t &len) const;
  const char *args_ = nullptr;  // the text after the code
  uint32_t seen_ = 0;           // bit n: letter 'A' + n appears
  bool any_ = false;            // a word of any kind appears
  bool odd_ = false;            // a word that does not start with a letter
  char dup_ = 0;
  char code_letter_ = 0;
  int16_t code_ = -1;
};

class ReplyText;

// The check every M-code handler starts with: each word's letter is in allowed
// and appears once. Otherwise writes "Error:<code> unknown parameter X" (or
// "duplicate parameter X") and returns false. code_flash: e.g. BK_F("M720").
bool check_words(const GcodeArgs &a, const char *allowed_flash, const char *code_flash, ReplyText &r);

// A setting with limits, for the table-driven handlers (M720, M723): the value of
// letter must lie in [lo, hi], or in (lo, hi] when lo_open. Kept in RAM or flash
// by the caller; read with read_limited(). A table in flash (BK_FLASH): copy the
// entry out first with BK_RDBLOCK(&lim, &table[i], sizeof(Limit)).
struct Limit {
  char letter;
  bool lo_open;
  float lo, hi;
};

// Reads letter's number: 0 absent (out unchanged); 1 present and well-formed
// (out set); -1 malformed or empty, with "Error:M723 Q bad number" written.
// code_flash: e.g. BK_F("M723").
int8_t read_number(const GcodeArgs &a, char letter, const char *code_flash, float &out, ReplyText &r);
// v within lim, or false with "Error:M723 Q150.000 not in (0.000..100.000]".
bool check_limit(const Limit &lim, float v, const char *code_flash, ReplyText &r);
// Both: 0 absent; 1 present, well-formed and within the limits (out set); -1
// otherwise, with one Error: line written.
int8_t read_limited(const GcodeArgs &a, const Limit &lim, const char *code_flash, float &out, ReplyText &r);

}  // namespace bk

#endif  // BK_GCODE_ARGS_H
