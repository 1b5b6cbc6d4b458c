// M721 map upload. See map_upload.h and docs/reference/mcodes.md.
#include "map_upload.h"

#include "reply_text.h"

namespace bk {

// ---- base32 ------------------------------------------------------------------------
int16_t base32_decode(const char *s, uint8_t len, uint8_t *out, uint8_t &bad_pos) {
  uint16_t acc = 0;  // at most 7 + 5 pending bits
  uint8_t bits = 0;
  for (uint8_t i = 0; i < len; i++) {
    const char ch = s[i], lower = (char)(ch | 0x20);
    uint8_t v;
    if (lower >= 'a' && lower <= 'z') v = (uint8_t)(lower - 'a');
    else if (ch >= '2' && ch <= '7') v = (uint8_t)(ch - '2' + 26);
    else {
      bad_pos = i;
      return B32_BAD_CHAR;
    }
    acc = (uint16_t)((acc << 5) | v);
    bits = (uint8_t)(bits + 5);
    if (bits >= 8) {
      bits = (uint8_t)(bits - 8);
      *out++ = (uint8_t)(acc >> bits);
    }
  }
  // Unpadded groups end after 2, 4, 5 or 7 chars (1..4 bytes), leaving 0..4
  // bits of the last char unused; they must be zero (the canonical form).
  bad_pos = len;
  if (bits > 4) return B32_BAD_LENGTH;
  if (acc & ((1u << bits) - 1)) {
    bad_pos = (uint8_t)(len - 1);
    return B32_BAD_TAIL;
  }
  return (int16_t)((uint16_t)len * 5 / 8);
}

// ---- replies -------------------------------------------------------------------------
static const char s_error[] BK_FLASH = "Error:M721 ";
static const char s_missing[] BK_FLASH = " missing or bad";
static const char s_append[] BK_FLASH = " append";

// Writes flash text fmt, each '#' taking the next of x, y, z as a decimal: one
// call per message instead of one per piece. 16-bit numbers: every count of
// bytes or layers here fits, and fewer argument registers to load per call.
static void say(ReplyText &r, const char *fmt, uint16_t x = 0, uint16_t y = 0, uint16_t z = 0) {
  for (char ch; (ch = (char)BK_RD8(fmt)) != 0; fmt++) {
    if (ch != '#') {
      r.c(ch);
      continue;
    }
    r.u(x);
    x = y;
    y = z;
  }
}

// "Error:M721 " + fmt as say() writes it.
static UploadStatus fail(ReplyText &r, const char *fmt, uint16_t x, uint16_t y = 0, uint16_t z = 0) {
  r.p(s_error);
  say(r, fmt, x, y, z);
  return UPLOAD_ERROR;
}

// "Error:M721 " + text (no numbers: no argument registers to load).
static UploadStatus fail(ReplyText &r, const char *text) {
  r.p(s_error);
  r.p(text);
  return UPLOAD_ERROR;
}

// "Error:M721 S missing or bad".
static UploadStatus missing(ReplyText &r, char letter) {
  r.p(s_error);
  r.c(letter);
  r.p(s_missing);
  return UPLOAD_ERROR;
}

// Reads letter's whole number into v when it lies in lo..hi; otherwise writes
// "Error:M721 S missing or bad" or "Error:M721 S2057 not in 8..2056" (the
// value as sent, so a large one shows as it is).
static bool get_in(const GcodeArgs &a, char letter, uint16_t lo, uint16_t hi, uint32_t &v, ReplyText &r) {
  if (a.get_ulong(letter, v) != ARG_OK) {
    missing(r, letter);
    return false;
  }
  if (v >= lo && v <= hi) return true;
  const char *text;
  uint8_t len;
  a.raw(letter, text, len);
  r.p(s_error);
  r.c(letter);
  r.raw(text, len);
  say(r, BK_F(" not in #..#"), lo, hi);
  return false;
}

// z in 0.01 mm as mm with two decimals ("0.30").
static void cmm(ReplyText &r, uint16_t z) {
  r.u(z / 100u);
  r.c('.');
  z %= 100u;
  r.c((char)('0' + z / 10u));
  r.c((char)('0' + z % 10u));
}

// ---- M721 ------------------------------------------------------------------------------
void MapUpload::abort() {
  if (open()) store_.stage_close();
  size_ = received_ = 0;
}

#if !BK_REPLY_SERIAL
UploadStatus MapUpload::handle(const GcodeArgs &a, char *reply, uint16_t reply_size) {
  ReplyText r(reply, reply_size);
  return handle(a, r);
}
#endif

UploadStatus MapUpload::handle(const GcodeArgs &a, ReplyText &r) {
  if (a.code_letter() != 'M' || a.code() != 721) return fail(r, BK_F("got another code"));
  if (!check_words(a, BK_F("SCAODEX"), BK_F("M721"), r)) return UPLOAD_ERROR;
  // One action a line, named by its letters: 1 begin, 2 chunk, 3 commit, 4 clear.
  static const char groups[] BK_FLASH = "SCA OD E X";
  uint8_t act = 0, g = 1;
  for (const char *p = groups; char ch = (char)BK_RD8(p); p++) {
    if (ch == ' ') {
      g++;
    } else if (a.has(ch)) {
      if (act && act != g) return fail(r, BK_F("mixed actions"));
      act = g;
    }
  }
  if ((act == 2 || act == 3) && !open()) return fail(r, BK_F("no upload open"));
  switch (act) {
    case 1: return begin(a, r);
    case 2: return chunk(a, r);
    case 3: return commit(r);
    case 4:
      abort();
      store_.clear();
      r.p(BK_F("echo:BulgeMap cleared"));
      return UPLOAD_CLEARED;
  }
  status(r);
  return UPLOAD_OK;
}

UploadStatus MapUpload::begin(const GcodeArgs &a, ReplyText &r) {
  uint32_t v = 0, crc;
  const ArgStatus as = a.get_ulong('A', v);
  if (as == ARG_EMPTY) v = 1;  // a bare "A" reads as A1
  else if (as != ARG_ABSENT && !get_in(a, 'A', 0, 1, v, r)) return UPLOAD_ERROR;
  const bool app = v != 0;
  if (app && !store_.loaded()) return fail(r, BK_F("A1 needs a map"));
  // S: a new map is its header (8, kept here) plus records that fit the free
  // space; an append, records alone. While an upload is open its bytes sit in
  // the free space: the room counts as free, since this begin replaces it.
  const uint8_t head = app ? 0 : MAP_HEADER_BYTES;
  if (!get_in(a, 'S', (uint16_t)(head | app), (uint16_t)(store_.free_bytes() + head), v, r)) return UPLOAD_ERROR;
  if (a.get_ulong('C', crc) != ARG_OK) return missing(r, 'C');
  if (open()) say(r, BK_F("echo:M721 upload #/# dropped\n"), received_, size_);
  size_ = (uint16_t)v;
  crc_ = crc;
  received_ = 0;
  append_ = app;
  store_.stage_open(stage_bytes());  // fits: checked above
  say(r, BK_F("echo:M721 receiving # bytes"), size_);
  if (app) r.p(BK_F(" (append)"));
  return UPLOAD_OK;
}

UploadStatus MapUpload::chunk(const GcodeArgs &a, ReplyText &r) {
  uint32_t v;
  const char *text;
  uint8_t len, pos = BK_M721_CHUNK_CHARS_MAX;  // too long: the first char too many
  uint8_t bytes[(BK_M721_CHUNK_CHARS_MAX * 5 + 7) / 8];
  // An offset beyond the bytes received so far would leave a gap.
  if (!get_in(a, 'O', 0, received_, v, r)) return UPLOAD_ERROR;
  const uint16_t off = (uint16_t)v;
  if (!a.raw('D', text, len) || len == 0) return missing(r, 'D');
  const int16_t n = len > BK_M721_CHUNK_CHARS_MAX ? -1 : base32_decode(text, len, bytes, pos);
  if (n < 0) return fail(r, BK_F("D bad base32 at char #"), pos);
  const uint16_t end = (uint16_t)(off + n);
  if (end > size_) return fail(r, BK_F("O#+# > S#"), off, (uint16_t)n, size_);
  // A resent line rewrites the same bytes at the same offset: harmless. A new
  // map's header bytes go to head_, the rest into the arena's staging area.
  const uint8_t head = head_bytes();
  uint8_t *stage = store_.stage_data();
  for (uint8_t i = 0; i < (uint8_t)n; i++) {
    const uint16_t at = (uint16_t)(off + i);
    if (at < head) head_[at] = bytes[i];
    else stage[at - head] = bytes[i];
  }
  if (end > received_) received_ = end;
  return UPLOAD_OK;
}

UploadStatus MapUpload::commit(ReplyText &r) {
  // Not all bytes yet: stays open, the host may send the missing lines.
  if (received_ != size_) return fail(r, BK_F("received #/#"), received_, size_);
  const uint16_t n = stage_bytes();
  uint8_t *stage = store_.stage_data();
  // An append has no header bytes: the first CRC call is then a no-op (0).
  const uint32_t crc = crc32_update(crc32_update(0, head_, head_bytes()), stage, n);
  MapError e;
  if (crc != crc_) {
    fail(r, BK_F("CRC "));
    r.u(crc);
    r.p(BK_F(" != C"));
    r.u(crc_);
  } else if ((e = append_ ? store_.append(stage, n) : store_.load_parts(head_, stage, n)) != MAP_OK) {
    fail(r, map_error_text(e));
    say(r, BK_F(" at byte #"), store_.error_offset());
  } else {
    size_ = received_ = 0;  // the store closed the staging
    status(r);
    return UPLOAD_COMMITTED;
  }
  abort();  // the map in force stays as it was
  return UPLOAD_ERROR;
}

void MapUpload::status(ReplyText &r) const {
  uint16_t points;
  const uint16_t layers = store_.counts(points);
  say(r, BK_F("echo:BulgeMap layers:# bytes:#/#"), layers, store_.bytes_used(), store_.capacity());
  say(r, BK_F(" points:# z:"), points);
  if (store_.empty()) {
    r.c('-');
  } else {
    cmm(r, store_.first_z());
    r.p(BK_F(".."));
    cmm(r, store_.last_z());
  }
  if (open()) {
    say(r, BK_F(" upload:#/#"), received_, size_);
    if (append_) r.p(s_append);
  }
}

}  // namespace bk
